//! The feed protocol: what a host (standing in for a robot's LiDAR,
//! segmentation and odometry) sends a robot over its serial line, and what
//! the robot answers.
//!
//! Host to robot ([`FeedMessage`]): a [`Setup`], then the scans as labelled
//! points already in the robot's anchor frame, thinned to about one point
//! per voxel and quantised to centimetres ([`POINT_BYTES`] bytes each, at
//! most [`MAX_POINTS_PER_MESSAGE`] per message), then
//! [`FeedMessage::EndOfFeed`]. Robot to host ([`RobotMessage`]): a
//! [`RobotReport`], or where and why it stopped.
//!
//! Every message travels in one frame ([`super::frame`]: COBS, CRC-32) as
//! the version byte [`FEED_VERSION`] and postcard. Floats from the line are
//! checked: a NaN or an infinity is a typed error, never a value.

use super::frame::{frame_with, FrameError};
use super::message::{decode_versioned, encode_versioned, MessageError};
use super::report::MatchReport;
use crate::classes::{Class, NUM_CLASSES};
use serde::{Deserialize, Serialize};

/// Version byte of the feed protocol.
pub const FEED_VERSION: u8 = 5;
/// Bytes of one fed point: x, y, z in centimetres (i16, little endian) and
/// the class index.
pub const POINT_BYTES: usize = 7;
/// Most points in one [`FeedMessage::Points`] (fits a frame with room).
pub const MAX_POINTS_PER_MESSAGE: usize = 32;

/// What a host tells a robot before its scans.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Setup {
    /// 0 for robot A (which sends first on a half-duplex line), 1 for B.
    pub robot_id: u8,
    /// Voxel size (m), 0.01 to 10.
    pub resolution: f32,
    /// The prior `T_own_peer` (model = own map, scene = the peer's), top
    /// three rows of the 4x4 matrix, row by row; `None`: no prior, align
    /// from the maps alone.
    pub prior: Option<[f32; 12]>,
    /// Give up on the link when nothing valid arrived for this long (ms).
    pub silence_ms: u32,
}

/// Host to robot.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum FeedMessage<'a> {
    /// Configuration; first.
    Setup(Setup),
    /// Points of one scan, [`POINT_BYTES`] each.
    Points {
        /// Scan index within the robot's range.
        scan: u16,
        /// The points.
        #[serde(borrow)]
        data: &'a [u8],
    },
    /// All scans were sent.
    EndOfFeed {
        /// Scans sent.
        scans: u16,
        /// Points sent.
        points: u32,
    },
    /// The robot is one of a team of `robots` (2 to 8), its index the
    /// set-up's `robot_id`: after the set-up, before the points. A pair
    /// robot refuses it.
    Team {
        /// Robots in the team.
        robots: u8,
    },
    /// The robot keeps driving (a session robot): after the set-up, before
    /// the points; its scans come in rounds. Any other robot refuses it.
    Session {
        /// Bytes each of its updates may take (0: unbounded; else at least
        /// [`super::update::MIN_UPDATE_BUDGET`]): what changed beyond it waits for the
        /// next rounds (the session's publisher).
        update_budget: u32,
    },
    /// Where the robot is now (its odometry frame, m), before a scan's
    /// points: its bounded map keeps what is nearest ([`crate::map::LocalMap::move_anchor`]).
    Anchor {
        /// The position.
        at: [f32; 3],
    },
    /// A session robot's round of scans is complete: it sends its peer
    /// what changed, takes the peer's, estimates and reports the round.
    EndOfRound {
        /// The round (0 first).
        round: u16,
        /// Points sent in the round.
        points: u32,
    },
}

/// What the prior-free alignment found, for the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GlobalReport {
    /// The coarse search's best score (footprint cells agreeing).
    pub score: u32,
    /// The best score of a placement away from it (0 when the best one's
    /// refinement passed and no other was looked for).
    pub runner_up: u32,
    /// Candidates refined until one passed the verdict (or all failed).
    pub refined: u8,
    /// The candidate the answer comes from (0: the best).
    pub chosen: u8,
    /// Nodes the coarse search scored.
    pub evaluations: u32,
}

/// What a robot did, for the host.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotReport {
    /// The match (`T_own_peer`: own map the model, the peer's the scene).
    pub result: MatchReport,
    /// Points fed.
    pub points: u32,
    /// Voxels of the robot's own map.
    pub map_voxels: u32,
    /// Voxels of the received map.
    pub received_voxels: u32,
    /// Bytes the robot wrote to the link.
    pub bytes_sent: u64,
    /// Bytes the robot read from the link.
    pub bytes_received: u64,
    /// Frames resent on the link.
    pub retransmissions: u32,
    /// Duration of the map exchange (ms of the robot's clock).
    pub link_ms: u32,
    /// Instructions spent inserting the fed points into the map.
    pub map_instructions: u64,
    /// Instructions spent preparing both maps for matching.
    pub prepare_instructions: u64,
    /// Instructions of the prior-free alignment (0 with a prior).
    pub locate_instructions: u64,
    /// Instructions of the match.
    pub match_instructions: u64,
    /// What the prior-free alignment found (`None` with a prior).
    pub global: Option<GlobalReport>,
    /// Peak stack (bytes).
    pub peak_stack: u32,
    /// Bytes that came in on the link lines while the robot prepared and
    /// matched (a board's receive interrupt took them into its rings; a
    /// UART without would have overrun): a team's next peer, or a peer
    /// resending its last frames.
    pub link_bytes_while_matching: u32,
}

/// Where a robot failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Stage {
    /// Receiving the feed.
    Feed,
    /// Building the map.
    Map,
    /// Exchanging maps.
    Link,
    /// Preparing or matching.
    Match,
}

impl Stage {
    /// Lower-case name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Stage::Feed => "feed",
            Stage::Map => "map",
            Stage::Link => "link",
            Stage::Match => "match",
        }
    }
}

/// Robot to host.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum RobotMessage<'a> {
    /// The result.
    Report(RobotReport),
    /// The robot stopped.
    Failed {
        /// Where.
        stage: Stage,
        /// What, in words.
        #[serde(borrow)]
        message: &'a str,
    },
    /// A team robot matched one peer (its report's match is
    /// `T_own_peer`).
    Matched {
        /// The peer.
        peer: u8,
        /// The report of that round.
        report: RobotReport,
    },
    /// Where a team robot placed one robot of the team (one message per
    /// robot, then [`RobotMessage::TeamEnd`]).
    Placed(PlacedRobot),
    /// A team robot's last message.
    TeamEnd(TeamEnd),
    /// The robot is up and listening: its first message, before which a
    /// feeder sends nothing (a UART that is not enabled yet drops what
    /// arrives, as an STM32's does).
    Ready,
    /// A session robot's round: its estimate of its peer, and what the
    /// round moved.
    Round(RoundReport),
    /// A session robot's last message, after its last round.
    SessionEnd(SessionEnd),
}

/// One round of a session robot (a robot that keeps driving).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoundReport {
    /// The round (0 first).
    pub round: u16,
    /// The estimate of `T_own_peer` (own map the model, the peer's copy the
    /// scene); status [`super::share::NO_EXCHANGE`] while no copy is held.
    pub result: MatchReport,
    /// How it was made: 0 prior-free, 1 from the last fix (tracking).
    pub kind: u8,
    /// What became of the fix: 0 none, 1 held, 2 kept, 3 withdrawn.
    pub fix: u8,
    /// What became of the peer's update: 0 applied, 1 repeated, 2 out of
    /// step, 3 refused, 4 diverged (copy emptied, snapshot asked), 5 the
    /// peer restarted.
    pub applied: u8,
    /// Voxels of the robot's map.
    pub map_voxels: u32,
    /// Voxels of its copy of the peer's map.
    pub copy_voxels: u32,
    /// The version of the peer's map the copy holds (0: none).
    pub copy_version: u32,
    /// Bytes of the update this robot sent.
    pub update_bytes: u32,
    /// Voxels new, changed and cells removed in it.
    pub update_counts: [u32; 3],
    /// Bytes the robot wrote to and read from its peer's line this round.
    pub line_bytes: [u32; 2],
    /// Data frames sent again this round.
    pub resent: u32,
    /// Duration of the exchange (ms of the robot's clock).
    pub exchange_ms: u32,
    /// Instructions spent fusing the round's points.
    pub map_instructions: u64,
    /// Instructions spent writing the update and applying the peer's.
    pub update_instructions: u64,
    /// Instructions spent preparing both maps.
    pub prepare_instructions: u64,
    /// Instructions of the estimate (search, EM, verdict).
    pub match_instructions: u64,
    /// The estimate's work as the round's meter counted it (instructions
    /// at the fitted costs, [`crate::matching::Work`]).
    pub match_work: u64,
    /// Whether the round's work budget refused a step (the estimate was
    /// cut short: not `Converged` where it was cut).
    pub work_cut: bool,
    /// Peak stack so far (bytes).
    pub peak_stack: u32,
    /// The robot's figure of its odometry's heading walk (degrees,
    /// [`crate::session::OdometryWalk::excess`]); negative while it has
    /// none.
    pub walk: f32,
    /// Whether the estimate passed the verdict but is not reported
    /// `Converged` because the two robots' walk together passed
    /// [`crate::session::WALK_LIMIT_DEG`] ([`crate::session::Estimate::walked`]).
    pub walked: bool,
}

/// A session robot's end.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SessionEnd {
    /// Rounds run.
    pub rounds: u16,
    /// Bytes written to and read from the peer's line, in all.
    pub line_bytes: [u64; 2],
    /// Data frames sent again, in all.
    pub resent: u32,
    /// Peak stack (bytes).
    pub peak_stack: u32,
}

/// One robot of a team as a team robot placed it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlacedRobot {
    /// The placed robot.
    pub index: u8,
    /// The lowest index of its group: 0 when placed in robot 0's frame.
    pub anchor: u8,
    /// `T_anchor_index`, top three rows, row by row.
    pub transform: [f32; 12],
    /// Its covariance (left perturbation in the anchor's frame, tx ty tz
    /// rx ry rz), upper triangle row by row.
    pub covariance: [f32; 21],
}

/// How a team robot's consistency check and pose graph went.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TeamEnd {
    /// Bit k: the k-th converged estimate (in the order a, then b) kept.
    pub kept: u64,
    /// Converged estimates checked.
    pub candidates: u8,
    /// The consistency search went through every set.
    pub exhaustive: bool,
    /// Bit r: robot r's estimates arrived (its own bit always set).
    pub heard: u8,
    /// Duration of sharing the estimates (ms of the robot's clock).
    pub share_ms: u32,
    /// Instructions of the consistency check and the pose graph.
    pub solve_instructions: u64,
    /// Peak stack over the whole run (bytes).
    pub peak_stack: u32,
}

/// Why a feed message is not one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FeedError {
    /// Empty payload.
    Empty,
    /// Another protocol version.
    Version(u8),
    /// Not a well-formed message.
    Malformed,
    /// A float is NaN or infinite.
    NonFinite,
    /// A voxel size outside a robot's map's ([`crate::map::VOXEL_SIZES`]).
    Resolution,
    /// The output buffer is too small.
    Buffer,
    /// Point data not a whole number of points.
    PointBytes {
        /// Bytes received.
        len: u32,
    },
    /// A point's class is not in the class table.
    Class {
        /// Byte offset of the point in the message's data.
        offset: u32,
        /// The class byte.
        class: u8,
    },
    /// A message out of order (points before the set-up, a second set-up).
    Order,
}

impl core::fmt::Display for FeedError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FeedError::Empty => f.write_str("empty payload"),
            FeedError::Version(v) => write!(f, "feed protocol version {v}, expected {FEED_VERSION}"),
            FeedError::Malformed => f.write_str("malformed feed message"),
            FeedError::NonFinite => f.write_str("non-finite number"),
            FeedError::Resolution => {
                let sizes = crate::map::VOXEL_SIZES;
                write!(f, "voxel size outside a robot map's {} to {} m", sizes.start(), sizes.end())
            }
            FeedError::Buffer => f.write_str("buffer too small"),
            FeedError::PointBytes { len } => write!(f, "{len} bytes of points is not a multiple of {POINT_BYTES}"),
            FeedError::Class { offset, class } => write!(f, "point at byte {offset}: class {class} not in the table"),
            FeedError::Order => f.write_str("feed message out of order"),
        }
    }
}

impl core::error::Error for FeedError {}

impl From<MessageError> for FeedError {
    fn from(e: MessageError) -> Self {
        match e {
            MessageError::Empty => FeedError::Empty,
            MessageError::Version(v) => FeedError::Version(v),
            MessageError::Buffer => FeedError::Buffer,
            MessageError::NonFinite => FeedError::NonFinite,
            MessageError::Malformed | MessageError::Trailing => FeedError::Malformed,
        }
    }
}

impl From<FrameError> for FeedError {
    fn from(_: FrameError) -> Self {
        FeedError::Buffer
    }
}

fn finite(values: &[f32]) -> Result<(), FeedError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(FeedError::NonFinite)
    }
}

/// `encode`, `to_frame` and `decode` of a feed-protocol message type (its
/// `check` refuses what must not cross the line, in both directions).
macro_rules! feed_codec {
    ($ty:ident) => {
        impl<'a> $ty<'a> {
            /// Encodes the message (version byte first) into `out`; returns
            /// its length.
            pub fn encode(&self, out: &mut [u8]) -> Result<usize, FeedError> {
                self.check()?;
                Ok(encode_versioned(FEED_VERSION, self, out)?)
            }

            /// Encodes the message as one frame (delimiter included) into `out`.
            pub fn to_frame(&self, out: &mut [u8]) -> Result<usize, FeedError> {
                frame_with(out, |payload| self.encode(payload))
            }

            /// Decodes and checks a payload; borrows byte and text fields from it.
            pub fn decode(payload: &'a [u8]) -> Result<Self, FeedError> {
                let msg: Self = decode_versioned(FEED_VERSION, payload)?;
                msg.check()?;
                Ok(msg)
            }
        }
    };
}

feed_codec!(FeedMessage);
feed_codec!(RobotMessage);

impl FeedMessage<'_> {
    fn check(&self) -> Result<(), FeedError> {
        match self {
            FeedMessage::Setup(s) => {
                if let Some(prior) = &s.prior {
                    finite(prior)?;
                }
                if !crate::map::VOXEL_SIZES.contains(&s.resolution) {
                    return Err(FeedError::Resolution);
                }
                Ok(())
            }
            FeedMessage::Points { data, .. } => {
                if !data.len().is_multiple_of(POINT_BYTES) {
                    return Err(FeedError::PointBytes { len: data.len() as u32 });
                }
                Ok(())
            }
            FeedMessage::EndOfFeed { .. } => Ok(()),
            FeedMessage::Team { robots } => {
                if !(2..=8).contains(robots) {
                    return Err(FeedError::Malformed);
                }
                Ok(())
            }
            FeedMessage::Anchor { at } => finite(at),
            FeedMessage::Session { update_budget } => {
                if (1..super::update::MIN_UPDATE_BUDGET).contains(update_budget) {
                    return Err(FeedError::Malformed);
                }
                Ok(())
            }
            FeedMessage::EndOfRound { .. } => Ok(()),
        }
    }
}

impl RobotMessage<'_> {
    fn check(&self) -> Result<(), FeedError> {
        match self {
            RobotMessage::Report(r) => r.result.check().map_err(FeedError::from),
            RobotMessage::Matched { report, .. } => report.result.check().map_err(FeedError::from),
            RobotMessage::Placed(p) => finite(&p.transform).and(finite(&p.covariance)),
            RobotMessage::Round(r) => r.result.check().map_err(FeedError::from).and(finite(&[r.walk])),
            RobotMessage::Failed { .. }
            | RobotMessage::TeamEnd(_)
            | RobotMessage::Ready
            | RobotMessage::SessionEnd(_) => Ok(()),
        }
    }
}

/// Packs one point (map frame, metres) for the feed: centimetres, clamped
/// to the i16 range (about +-327 m).
pub fn pack_point(p: [f32; 3], class: Class) -> [u8; POINT_BYTES] {
    let cm = |v: f32| libm::roundf(v * 100.0).clamp(f32::from(i16::MIN), f32::from(i16::MAX)) as i16;
    let (x, y, z) = (cm(p[0]).to_le_bytes(), cm(p[1]).to_le_bytes(), cm(p[2]).to_le_bytes());
    [x[0], x[1], y[0], y[1], z[0], z[1], class.index()]
}

/// The points of a [`FeedMessage::Points`] payload, position (m) and class;
/// a class outside the table is an error naming the point's byte offset.
/// Data that is not a whole number of points is refused before any point.
pub fn points(data: &[u8]) -> impl Iterator<Item = Result<([f32; 3], Class), FeedError>> + '_ {
    let whole = data.len().is_multiple_of(POINT_BYTES);
    let bad_len = (!whole).then_some(Err(FeedError::PointBytes { len: data.len() as u32 }));
    let chunks = if whole { data } else { &[] };
    bad_len.into_iter().chain(chunks.chunks_exact(POINT_BYTES).enumerate().map(|(i, p)| {
        let at = |a: usize| p.get(a..a + 2).map(|b| i16::from_le_bytes([b[0], b[1]])).unwrap_or(0);
        let class_byte = p.get(6).copied().unwrap_or(u8::MAX);
        let class = Class::from_index(class_byte)
            .filter(|c| usize::from(c.index()) < NUM_CLASSES)
            .ok_or(FeedError::Class { offset: (i * POINT_BYTES) as u32, class: class_byte })?;
        Ok(([f32::from(at(0)) * 0.01, f32::from(at(2)) * 0.01, f32::from(at(4)) * 0.01], class))
    }))
}

/// The robot report of [`GOLDEN_ROBOT`] (a prior-free run).
pub const GOLDEN_REPORT: RobotReport = RobotReport {
    result: super::report::GOLDEN_MATCH,
    points: 26_309,
    map_voxels: 7_493,
    received_voxels: 7_132,
    bytes_sent: 26_570,
    bytes_received: 25_508,
    retransmissions: 2,
    link_ms: 2_345,
    map_instructions: 24_000_000,
    prepare_instructions: 295_000_000,
    locate_instructions: 4_800_000,
    match_instructions: 149_000_000,
    global: Some(GlobalReport { score: 138, runner_up: 83, refined: 2, chosen: 1, evaluations: 51_032 }),
    peak_stack: 49_200,
    link_bytes_while_matching: 1_234,
};

/// Every feed message with its exact bytes: the feed format, frozen.
pub const GOLDEN_FEED: [(FeedMessage<'static>, &[u8]); 5] = [
    (
        FeedMessage::Setup(Setup {
            robot_id: 1,
            resolution: 0.5,
            prior: Some([1.0, 0.0, 0.0, 2.5, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0]),
            silence_ms: 30_000,
        }),
        &[
            5, 0, 1, 0, 0, 0, 63, 1, 0, 0, 128, 63, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 32, 64, 0, 0, 0, 0, 0, 0, 128, 63, 0,
            0, 0, 0, 0, 0, 128, 191, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 128, 63, 0, 0, 0, 0, 176, 234, 1,
        ],
    ),
    (
        FeedMessage::Setup(Setup { robot_id: 0, resolution: 0.5, prior: None, silence_ms: 30_000 }),
        &[5, 0, 0, 0, 0, 0, 63, 0, 176, 234, 1],
    ),
    (
        FeedMessage::Points { scan: 3, data: &[100, 0, 6, 255, 25, 0, 17, 0, 0, 0, 0, 0, 0, 8] },
        &[5, 1, 3, 14, 100, 0, 6, 255, 25, 0, 17, 0, 0, 0, 0, 0, 0, 8],
    ),
    (FeedMessage::EndOfFeed { scans: 5, points: 26_309 }, &[5, 2, 5, 197, 205, 1]),
    (FeedMessage::Session { update_budget: 1024 }, &[5, 4, 128, 8]),
];

/// Every robot message with its exact bytes.
pub const GOLDEN_ROBOT: [(RobotMessage<'static>, &[u8]); 2] = [
    (
        RobotMessage::Report(GOLDEN_REPORT),
        &[
            5, 0, 0, 0, 0, 0, 128, 63, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 32, 64, 0, 0, 0, 0, 0, 0, 128, 63, 0, 0, 0, 0, 0,
            0, 128, 191, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 128, 63, 0, 0, 0, 0, 17, 210, 9, 0, 0, 64, 63, 0, 0, 0, 62, 197,
            205, 1, 197, 58, 220, 55, 202, 207, 1, 164, 199, 1, 2, 169, 18, 128, 236, 184, 11, 192, 175, 213, 140, 1,
            128, 252, 164, 2, 192, 158, 134, 71, 1, 138, 1, 83, 2, 1, 216, 142, 3, 176, 128, 3, 210, 9,
        ],
    ),
    (
        RobotMessage::Failed { stage: Stage::Link, message: "peer silent" },
        &[5, 1, 2, 11, 112, 101, 101, 114, 32, 115, 105, 108, 101, 110, 116],
    ),
];

/// Encodes and decodes every golden feed and robot message; `Err(i)` names
/// the first that differs (robot messages counted after the feed's).
pub fn check_golden() -> Result<(), usize> {
    let mut buf = [0u8; 160];
    for (i, (msg, bytes)) in GOLDEN_FEED.iter().enumerate() {
        let ok = msg.encode(&mut buf).ok().and_then(|n| buf.get(..n)) == Some(*bytes)
            && FeedMessage::decode(bytes).as_ref() == Ok(msg);
        if !ok {
            return Err(i);
        }
    }
    for (i, (msg, bytes)) in GOLDEN_ROBOT.iter().enumerate() {
        let ok = msg.encode(&mut buf).ok().and_then(|n| buf.get(..n)) == Some(*bytes)
            && RobotMessage::decode(bytes).as_ref() == Ok(msg);
        if !ok {
            return Err(GOLDEN_FEED.len() + i);
        }
    }
    Ok(())
}
