//! Robots that keep driving (layer 6, beside matching): each keeps its map
//! bounded around itself and sends its peer what changed, as messages
//! ([`crate::wire::update`]) that any transport carries.
//!
//! - [`publisher`]: the sending side: what the peer holds (the voxels'
//!   records at the version it acknowledged), the next update against it,
//!   the answers;
//! - [`replica`]: the receiving side: the peer's map as
//!   `decode(encode(peer's map at version v))`, bit for bit, checked by the
//!   digest after every update; anything else (a lost, repeated, damaged or
//!   out-of-step update) is answered so that the sender resends or sends a
//!   snapshot, never silently diverges;
//! - [`tracker`]: the peer's relative pose, prior-free until a fix, then
//!   tracked from it, withdrawn when it stops agreeing;
//! - [`history`]: the confirmed fixes of a peer's pose so far, which a
//!   new fix must be consistent with up to the drift;
//! - [`smoother`]: the pose a fix's rounds report, their answers fused by
//!   a filter that moves only as fast as the odometry drifts;
//! - [`walk`]: how far a robot's odometry turns its scans from its own
//!   map, the heading walk it measures itself.

pub mod history;
pub mod publisher;
pub mod replica;
pub mod smoother;
pub mod tracker;
pub mod walk;

pub use history::{
    History, FIRST_APART_M, FIRST_GROWTH_M, FIRST_SEEN, FIRST_SURE, HISTORY_DEG, HISTORY_DEG_PER_M, HISTORY_HALF_M,
    HISTORY_M, HISTORY_SCALE,
};
pub use publisher::{Publisher, PublisherError, ShadowEntry, UpdateBudget, UpdateCounts};
pub use replica::{Applied, Replica};
pub use smoother::Smoother;
pub use tracker::{
    adopt_backed, agree, made_this_round, Estimate, Fix, Kind, PeerView, Tracked, Tracker, ADOPT_CONFIRMED_SLACK,
    ADOPT_MARGIN, AGREE_DEG, AGREE_M, HOLD_M, REFUSED_ROUNDS,
};
pub use walk::{pair_walk, walk_stride, OdometryWalk, ScanFit, WALK_LIMIT_DEG};

/// The verdict's least overlap in a session: 0.25, where a one-shot
/// match takes 0.2 ([`crate::matching::MatchSettings::min_overlap`]). A
/// robot that keeps driving matches again next round, so an answer on a
/// sliver of overlap buys little and risks much: its rotation rests on a
/// short lever and, on maps a drift has bent, the town's sessions (five
/// seeds, 2 and 3 robots, true and network-like labels) had it just over a
/// degree off at measured overlaps of 0.22-0.23 as robots parted, while no
/// right answer inside a meeting (true overlap 0.30 and more) measured
/// under 0.25.
pub const MIN_OVERLAP: f32 = 0.25;

/// Bytes a board's session robot's update may take by default (a board
/// takes its budget in bytes, through its feed): 1,024, about 5 KB/s
/// at the session's five rounds a second (two scans of a 10 Hz LiDAR a
/// round), under half of a 115,200-baud UART's 11.5 KB/s, so that a line
/// also carries the frames' overhead, resends and answers. A round that
/// changed more (a robot turning into a new street changes twice what a
/// straight one does) sends what is nearest the robot, and the rest
/// follows ([`Publisher::set_budget`]).
pub const DEFAULT_UPDATE_BUDGET: u32 = 1024;

/// A host session robot's update budget by default: 150 thousandths of
/// its map sent whole, the answer included ([`UpdateBudget::PerMille`]),
/// the share the session's goal allows a round. On the town's maps (about
/// 6 KB whole) that is 850-1,000 bytes, under [`DEFAULT_UPDATE_BUDGET`]:
/// five seeds, 2 and 3 robots, the update's bytes over the map at p95
/// 0.172 with 1,024 bytes, 0.150 with this; availability the same with
/// true labels, down with a network's (whose class flips resend more
/// voxels, so more wait).
pub const DEFAULT_UPDATE_SHARE: UpdateBudget = UpdateBudget::PerMille(150);

pub use crate::wire::update::MIN_UPDATE_BUDGET;

#[cfg(test)]
mod tests;
