//! Stage 4: one robot of a pair, as the firmware runs it and as a host
//! recomputes it. Both call the same functions with the same capacities, so
//! the host's answer on the same data is the robot's, to the bit.
//!
//! A robot is fed over a serial line by a host (a feeder standing in for
//! its LiDAR, segmentation and odometry): a [`Setup`], then its scans as
//! labelled points already in the robot's anchor frame, thinned to about one
//! point per voxel and quantised to centimetres ([`POINT_BYTES`] bytes each),
//! then [`FeedMessage::EndOfFeed`]. It builds its map on board
//! ([`insert_points`]), exchanges maps with the other robot over the link
//! ([`crate::link`]), aligns the received map (scene) to its own (model)
//! from the prior, or with none from their semantic landmarks ([`align`]),
//! and sends a [`RobotReport`] back to the host
//! (or [`RobotMessage::Failed`]).
//!
//! Messages travel in the link's frames ([`crate::wire::frame`]: COBS and
//! CRC-32), as a version byte and postcard.

use crate::classes::{Class, NUM_CLASSES};
use crate::geometry::Isometry3;
use crate::map::{ArrayStorage, FullPolicy, InsertError, LocalMap, MapConfig, VoxelStorage};
use crate::matching::global::{locate, refine, GlobalSettings, Located};
use crate::matching::landmarks::LandmarkError;
use crate::matching::{
    ArrayPyramidStorage, MatchError, MatchResult, MatchSettings, Matcher, Pyramid, PyramidError, PyramidStorage, Role,
};
use crate::wire::message::{self, MatchReport, MessageError};
use serde::{Deserialize, Serialize};

/// Voxels a robot's map holds (and the received map): 256 KiB each. When a
/// map is full the voxels farthest from the anchor are evicted
/// ([`FullPolicy::EvictFarthest`]).
pub const VOXELS: usize = 8192;
/// Coarse pyramid entries per map (0.5 m maps with [`LEVELS`] levels take
/// about 0.42 per voxel).
pub const COARSE: usize = 3840;
/// Footprint words of the model's pyramid (pooled grids: 2 m cells over
/// about 50 m x 50 m).
pub const MODEL_WORDS: usize = 20_480;
/// Footprint words of the scene's pyramid (occupied cells only).
pub const SCENE_WORDS: usize = 8192;
/// Pyramid levels (0.5 m maps: cells of 0.5, 1 and 2 m).
pub const LEVELS: usize = 3;
/// First footprint cell tried (m); doubled until the grids fit.
pub const FOOTPRINT_CELL: f32 = 1.0;
/// Bytes of one fed point: x, y, z in centimetres (i16, little endian) and
/// the class index.
pub const POINT_BYTES: usize = 7;
/// Most points in one [`FeedMessage::Points`] (fits a link frame).
pub const MAX_POINTS_PER_MESSAGE: usize = 64;

/// A robot's map storage.
pub type MapStorage = ArrayStorage<VOXELS>;
/// Pyramid storage of a robot's own map (the model).
pub type ModelStorage = ArrayPyramidStorage<VOXELS, COARSE, MODEL_WORDS>;
/// Pyramid storage of the received map (the scene).
pub type SceneStorage = ArrayPyramidStorage<VOXELS, COARSE, SCENE_WORDS>;

/// Version byte of the feed protocol.
pub const FEED_VERSION: u8 = 2;

/// The map configuration of a robot at `resolution`: full maps evict the
/// voxels farthest from the anchor.
pub fn map_config(resolution: f32) -> MapConfig {
    MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::with_resolution(resolution) }
}

/// What a host tells a robot before its scans.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Setup {
    /// 0 for robot A (which sends first on a half-duplex line), 1 for B.
    pub robot_id: u8,
    /// Voxel size (m).
    pub resolution: f32,
    /// The prior `T_own_peer` (model = own map, scene = the peer's), top
    /// three rows of the 4x4 matrix, row by row; `None`: no prior, align
    /// from semantic landmarks ([`crate::matching::global`]).
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
    /// Instructions of the prior-free landmark alignment (0 with a prior).
    pub locate_instructions: u64,
    /// Instructions of the match.
    pub match_instructions: u64,
    /// What the landmark alignment found (`None` with a prior).
    pub global: Option<GlobalReport>,
    /// Peak stack (bytes).
    pub peak_stack: u32,
}

/// The landmark alignment's figures, for the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GlobalReport {
    /// Landmarks of the robot's own map and of the received map.
    pub landmarks: [u32; 2],
    /// Correspondences in the largest consistent set (0: too few candidates).
    pub agreeing: u32,
    /// The largest consistent set the answer does not explain.
    pub runner_up: u32,
    /// Whether the answer was unique enough to refine (else `NoOverlap`).
    pub unique: bool,
}

impl From<&Located> for GlobalReport {
    fn from(l: &Located) -> Self {
        GlobalReport {
            landmarks: l.landmarks,
            agreeing: l.outcome.map(|o| o.agreeing).unwrap_or(0),
            runner_up: l.outcome.map(|o| o.runner_up).unwrap_or(0),
            unique: l.outcome.is_some_and(|o| o.unique),
        }
    }
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
    /// A float is NaN or infinite (or a resolution out of range).
    NonFinite,
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
            FeedError::NonFinite => f.write_str("non-finite or out-of-range number"),
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

fn encode_versioned<T: Serialize>(msg: &T, out: &mut [u8]) -> Result<usize, FeedError> {
    Ok(message::encode_versioned(FEED_VERSION, msg, out)?)
}

fn decode_versioned<'a, T: Deserialize<'a>>(payload: &'a [u8]) -> Result<T, FeedError> {
    Ok(message::decode_versioned(FEED_VERSION, payload)?)
}

fn finite(values: &[f32]) -> Result<(), FeedError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(FeedError::NonFinite)
    }
}

impl<'a> FeedMessage<'a> {
    /// Encodes the message (version byte first) into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, FeedError> {
        self.check()?;
        encode_versioned(self, out)
    }

    /// Decodes and checks a payload; borrows point data from it.
    pub fn decode(payload: &'a [u8]) -> Result<Self, FeedError> {
        let msg: Self = decode_versioned(payload)?;
        msg.check()?;
        Ok(msg)
    }

    fn check(&self) -> Result<(), FeedError> {
        match self {
            FeedMessage::Setup(s) => {
                if let Some(prior) = &s.prior {
                    finite(prior)?;
                }
                if !(s.resolution.is_finite() && (0.01..=10.0).contains(&s.resolution)) {
                    return Err(FeedError::NonFinite);
                }
                Ok(())
            }
            FeedMessage::Points { data, .. } => {
                if data.len() % POINT_BYTES != 0 {
                    return Err(FeedError::PointBytes { len: data.len() as u32 });
                }
                Ok(())
            }
            FeedMessage::EndOfFeed { .. } => Ok(()),
        }
    }
}

fn check_report(r: &RobotReport) -> Result<(), FeedError> {
    finite(&r.result.transform)?;
    finite(&[r.result.overlap, r.result.rmse])
}

impl<'a> RobotMessage<'a> {
    /// Encodes the message (version byte first) into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, FeedError> {
        if let RobotMessage::Report(r) = self {
            check_report(r)?;
        }
        encode_versioned(self, out)
    }

    /// Decodes a payload; borrows the failure message from it.
    pub fn decode(payload: &'a [u8]) -> Result<Self, FeedError> {
        let msg: Self = decode_versioned(payload)?;
        if let RobotMessage::Report(r) = &msg {
            check_report(r)?;
        }
        Ok(msg)
    }
}

/// Packs one point (map frame, metres) for the feed: centimetres, clamped
/// to the i16 range (about +-327 m).
pub fn pack_point(p: [f32; 3], class: Class) -> [u8; POINT_BYTES] {
    let cm = |v: f32| libm::roundf(v * 100.0).clamp(f32::from(i16::MIN), f32::from(i16::MAX)) as i16;
    let (x, y, z) = (cm(p[0]).to_le_bytes(), cm(p[1]).to_le_bytes(), cm(p[2]).to_le_bytes());
    [x[0], x[1], y[0], y[1], z[0], z[1], class.index()]
}

/// Inserts fed points into `map`; returns how many. Stops at the first bad
/// point (its byte offset in the error) or insertion error.
pub fn insert_points<S: VoxelStorage>(map: &mut LocalMap<S>, data: &[u8]) -> Result<u32, PointsError> {
    if data.len() % POINT_BYTES != 0 {
        return Err(PointsError::Feed(FeedError::PointBytes { len: data.len() as u32 }));
    }
    let mut n = 0u32;
    for (i, p) in data.chunks_exact(POINT_BYTES).enumerate() {
        let v = |a: usize| f32::from(i16::from_le_bytes([p[a], p[a + 1]])) * 0.01;
        let class = Class::from_index(p[6])
            .filter(|c| usize::from(c.index()) < NUM_CLASSES)
            .ok_or(PointsError::Feed(FeedError::Class { offset: (i * POINT_BYTES) as u32, class: p[6] }))?;
        map.insert_point([v(0), v(2), v(4)], class).map_err(PointsError::Insert)?;
        n += 1;
    }
    Ok(n)
}

/// Why fed points could not be inserted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PointsError {
    /// Bad point data.
    Feed(FeedError),
    /// The map refused a point.
    Insert(InsertError),
}

impl core::fmt::Display for PointsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PointsError::Feed(e) => write!(f, "{e}"),
            PointsError::Insert(e) => write!(f, "map insertion: {e}"),
        }
    }
}

impl core::error::Error for PointsError {}

/// Why a robot could not align.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AlignError {
    /// Preparing a map failed.
    Pyramid(PyramidError),
    /// The matcher refused its input.
    Match(MatchError),
    /// Extracting landmarks failed.
    Landmarks(LandmarkError),
}

impl core::fmt::Display for AlignError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            AlignError::Pyramid(e) => write!(f, "preparing a map: {e}"),
            AlignError::Match(e) => write!(f, "matching: {e:?}"),
            AlignError::Landmarks(e) => write!(f, "landmarks: {e}"),
        }
    }
}

impl core::error::Error for AlignError {}

/// Prepares both maps (own as model, received as scene) and aligns them:
/// from `prior` (`T_own_peer`) when there is one, else from the maps'
/// semantic landmarks ([`locate`], with `scratch` of one `u32` per voxel,
/// then [`refine`]; `NoOverlap` when they do not agree uniquely).
/// `on_phase(k)` runs before preparation (0), before the landmark alignment
/// (1), before the match (2) and after it (3), e.g. to read an instruction
/// counter. Returns the match and, without a prior, what the landmarks found.
pub fn align<A: VoxelStorage, B: VoxelStorage, P: PyramidStorage, Q: PyramidStorage>(
    own: &LocalMap<A>,
    received: &LocalMap<B>,
    prior: Option<&Isometry3<f32>>,
    scratch: &mut [u32],
    model_storage: P,
    scene_storage: Q,
    mut on_phase: impl FnMut(u8),
) -> Result<(MatchResult, Option<Located>), AlignError> {
    on_phase(0);
    let model =
        Pyramid::build_as(own, LEVELS, FOOTPRINT_CELL, Role::Model, model_storage).map_err(AlignError::Pyramid)?;
    let scene =
        Pyramid::build_as(received, LEVELS, FOOTPRINT_CELL, Role::Scene, scene_storage).map_err(AlignError::Pyramid)?;
    on_phase(1);
    let located = match prior {
        Some(_) => None,
        None => Some(locate(own, received, scratch, &GlobalSettings::default()).map_err(AlignError::Landmarks)?),
    };
    on_phase(2);
    let matcher = Matcher::new(MatchSettings::default());
    let r = match (prior, &located) {
        (Some(p), _) => matcher.align(&model, &scene, p),
        (None, l) => refine(&matcher, &model, &scene, l.as_ref().and_then(|l| l.outcome.as_ref())),
    };
    on_phase(3);
    Ok((r.map_err(AlignError::Match)?, located))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::from_xyz_rpy;

    #[test]
    fn messages_round_trip() {
        let setup = Setup {
            robot_id: 1,
            resolution: 0.5,
            prior: Some(crate::geometry::rows(&from_xyz_rpy(1.0, 2.0, 0.0, 0.0, 0.0, 0.3))),
            silence_ms: 5000,
        };
        let pts = [pack_point([1.0, -2.5, 0.25], Class::Pole), pack_point([300.0, 0.0, -1.0], Class::Road)];
        let flat: std::vec::Vec<u8> = pts.iter().flatten().copied().collect();
        let mut buf = [0u8; 512];
        for msg in [
            FeedMessage::Setup(setup),
            FeedMessage::Setup(Setup { prior: None, ..setup }),
            FeedMessage::Points { scan: 3, data: &flat },
            FeedMessage::EndOfFeed { scans: 5, points: 2 },
        ] {
            let n = msg.encode(&mut buf).unwrap();
            assert_eq!(FeedMessage::decode(&buf[..n]).unwrap(), msg);
            // Every truncation is an error, never a panic.
            for k in 0..n {
                assert!(FeedMessage::decode(&buf[..k]).is_err());
            }
        }
        let bad = FeedMessage::Points { scan: 0, data: &flat[..8] };
        assert_eq!(bad.encode(&mut buf), Err(FeedError::PointBytes { len: 8 }));
        let nan = Setup { prior: Some([f32::NAN; 12]), ..setup };
        assert_eq!(FeedMessage::Setup(nan).encode(&mut buf), Err(FeedError::NonFinite));
        let failed = RobotMessage::Failed { stage: Stage::Link, message: "peer silent" };
        let n = failed.encode(&mut buf).unwrap();
        assert_eq!(RobotMessage::decode(&buf[..n]).unwrap(), failed);
        buf[0] = 9;
        assert_eq!(RobotMessage::decode(&buf[..n]), Err(FeedError::Version(9)));
    }

    #[test]
    fn points_insert_and_bad_classes_are_named() {
        let mut map = crate::test_util::heap_map(64, map_config(0.5));
        let mut data = std::vec::Vec::new();
        data.extend_from_slice(&pack_point([1.02, 2.0, 0.3], Class::Trunk));
        data.extend_from_slice(&pack_point([1.04, 2.1, 0.3], Class::Trunk));
        assert_eq!(insert_points(&mut map, &data), Ok(2));
        assert_eq!(map.len(), 1);
        assert_eq!(map.voxels()[0].class(), Some(Class::Trunk));
        data[13] = 19;
        assert_eq!(insert_points(&mut map, &data), Err(PointsError::Feed(FeedError::Class { offset: 7, class: 19 })));
        assert!(matches!(
            insert_points(&mut map, &data[..5]),
            Err(PointsError::Feed(FeedError::PointBytes { len: 5 }))
        ));
    }
}
