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
//!   tracked from it, withdrawn when it stops agreeing.

pub mod publisher;
pub mod replica;
pub mod tracker;

pub use publisher::{Publisher, PublisherError, ShadowEntry, UpdateCounts};
pub use replica::{Applied, Replica};
pub use tracker::{agree, Estimate, Fix, Kind, PeerView, Tracked, Tracker, AGREE_DEG, AGREE_M, HOLD_M};

#[cfg(test)]
mod tests;
