//! Layer 8: one robot, end to end, as a poll-driven step machine
//! ([`Machine::poll`], like smoltcp's interface poll): the firmware drives
//! it with its UARTs and SysTick, a host drives the same machine with byte
//! buffers and simulated lines (`crate::sim`, feature `sim`), so the host's
//! answer on the same data is the robot's, to the bit. Every role is a
//! [`Machine`]: the robot of a pair ([`Robot`]), which matches, or, on a
//! board with no room for a second map, only sends its map and is told the
//! result ([`Robot::sender`]); and the member of a team
//! ([`team::TeamRobot`]). They share one reading of the feed and one
//! report builder.
//!
//! The sequence: the feed ([`crate::wire::feed`]: a set-up, then labelled
//! points already in the robot's anchor frame) is fused into the robot's
//! map ([`insert_points`]); at the end of the feed the robot exchanges maps
//! with its peer over the link ([`crate::link`]); then it aligns the
//! received map (scene) to its own (model) from the prior, or with none
//! from the maps alone ([`align`]), and reports a
//! [`RobotReport`] over its feed line (or where and why it stopped).
//!
//! Every buffer belongs to the caller. A pair robot takes two regions of
//! words and what it receives the peer's map into (a
//! [`SceneMap`](crate::map::SceneMap): only what matching it as a scene
//! reads); it carves its map, the link's scratch and buffers, and later
//! the pyramids out of the regions itself, each stage handing its buffers
//! to the next by ownership ([`memory`]: the map's voxels become the
//! model's level 0 where they lie, the link's words and what the level 0
//! leaves hold the pyramids), so a board
//! declares two zeroed statics and nothing of it depends on call order. A
//! team robot takes its map, scratch, link buffers and pyramid storages
//! apart. The capacities a robot's firmware uses are the constants below
//! ([`Capacity::BOARD`]).

use crate::geometry::Isometry3;
use crate::link::LinkError;
use crate::map::{ArrayStorage, ConfigError, FullPolicy, InsertError, LocalMap, MapConfig, ScenePoint, VoxelStorage};
use crate::matching::global::Searched;
use crate::matching::search::SearchScratch;
use crate::matching::Alignment;
use crate::matching::{
    ArrayPyramidStorage, ArraySceneStorage, MatchError, MatchResult, MatchSettings, Pyramid, PyramidError,
    PyramidStorage, SceneSource,
};
use crate::pipeline::Pipeline;
use crate::wire::feed::{self, FeedError, RobotMessage, RobotReport, Stage};
use crate::wire::frame::{DeframeError, MAX_FRAME};
use embedded_io::Write;

/// Exit code of a robot's firmware that panicked: its panic handler ends
/// the program at once with it (under QEMU, through semihosting), so the
/// host tells a panic from a robot that reported.
pub const EXIT_PANIC: u8 = 101;
/// Exit code of a robot's firmware that took a hard fault (e.g. its stack
/// ran into the statics).
pub const EXIT_FAULT: u8 = 102;

/// Voxels a robot's map holds (and the received map): 224 KiB for its own
/// (28 bytes per voxel with 16-bit index slots), 64 KiB for the received
/// one (a [`SceneMap`](crate::map::SceneMap): 8 bytes per voxel). When a map is full the voxels
/// farthest from the anchor are evicted ([`FullPolicy::EvictFarthest`]).
pub const VOXELS: usize = 8192;
/// Voxels of a robot on a small board (an STM32F405: its 128 KiB of main
/// SRAM hold this map, 28 bytes per voxel, and nothing else): a
/// [`Robot::sender`], which sends its map and takes none. A full map
/// evicts its farthest eighth (585 voxels) and keeps 4,096.
pub const SMALL_VOXELS: usize = 4681;
/// Coarse pyramid entries per map (0.5 m maps with [`LEVELS`] levels take
/// about 0.42 per voxel).
pub const COARSE: usize = 3840;
/// Footprint words of the model's pyramid: one per voxel (level 0's sweep
/// order while normals are fitted), then the pooled grids (six of one-byte
/// cells: two words per cell) and the occupied cells: 1 m cells over up to
/// about 58 m x 58 m (3,350 cells), coarser beyond.
pub const MODEL_WORDS: usize = 9216;
/// Footprint words of the scene's pyramid: the coarse merge's hash table
/// (two 16-bit slots per entry of a level, two to a word) while its levels
/// are built, then its grid and its 2 x 2 pooling (one word per cell) and
/// its occupied cells: room for every grid the 32-bit cells of before held
/// at 1 m.
pub const SCENE_WORDS: usize = 6656;
/// Nodes a robot's prior-free search may score
/// ([`crate::matching::search::GlobalSearch::max_evaluations`]), with [`EM_ITERATIONS`] its compute
/// budget. Robot maps (up to 8,192 voxels of 0.5 m, 25 m of range) that
/// overlap met their best placement within 2-24 thousand nodes and proved
/// it within 7-41 thousand, with ground truth and with a network's labels;
/// maps that share nothing prune little (45-94 thousand nodes, and a
/// second search and two more refinements: 5-7e8 instructions on a
/// Cortex-M4). With this budget a robot spends at most about 1e8
/// instructions searching, and after a search that took more than half of
/// it refines only its best placement.
pub const SEARCH_NODES: u32 = Pipeline::MPS2.alignment.search.max_evaluations;
/// EM iterations a robot's refinement may take
/// ([`MatchSettings::max_iterations`]; the paper's 50 serve a host):
/// converging matches took at most 16 (prior-free protocol with a network's
/// labels at twice the usual severity, and the paper's grid of priors); a
/// refinement that does not converge (a wrong placement, maps that share
/// nothing) costs about 3.5e6 instructions per iteration.
pub const EM_ITERATIONS: u32 = Pipeline::MPS2.alignment.settings.max_iterations;
/// Pyramid levels (0.5 m maps: cells of 0.5, 1 and 2 m).
pub const LEVELS: usize = Pipeline::MPS2.levels;
/// First footprint cell tried (m); doubled until the grids fit.
pub const FOOTPRINT_CELL: f32 = Pipeline::MPS2.footprint_cell;

/// A robot's map storage (16-bit index slots): a team robot's.
pub type MapStorage = ArrayStorage<VOXELS, u16>;
/// Pyramid storage of a robot's own map (the model).
pub type ModelStorage = ArrayPyramidStorage<VOXELS, COARSE, MODEL_WORDS>;
/// Pyramid storage of the received map (the scene) kept as a
/// [`SceneMap`](crate::map::SceneMap): no extras, no index slots.
pub type SceneStorage = ArraySceneStorage<COARSE, SCENE_WORDS>;
/// What a robot receives its peer's map into: [`VOXELS`] scene points,
/// 8 bytes each (a [`SceneMap`](crate::map::SceneMap) over them).
pub type ReceivedStorage = [ScenePoint; VOXELS];

/// The map configuration of a robot at `resolution`: full maps evict the
/// voxels farthest from the anchor.
pub fn map_config(resolution: f32) -> MapConfig {
    MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::with_resolution(resolution) }
}

/// Inserts fed points into `map`; returns how many. Stops at the first bad
/// point (its byte offset in the error) or insertion error.
pub fn insert_points<S: VoxelStorage>(map: &mut LocalMap<S>, data: &[u8]) -> Result<u32, PointsError> {
    let mut n = 0u32;
    for point in feed::points(data) {
        let (p, class) = point.map_err(PointsError::Feed)?;
        map.insert_point(p, class).map_err(PointsError::Insert)?;
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
}

impl core::fmt::Display for AlignError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            AlignError::Pyramid(e) => write!(f, "preparing a map: {e}"),
            AlignError::Match(e) => write!(f, "matching: {e}"),
        }
    }
}

impl core::error::Error for AlignError {}

/// Prepares both maps (own as model, received as scene) and aligns them:
/// from `prior` (`T_own_peer`) when there is one, else with none
/// ([`align_searched`](crate::matching::global::align_searched): every
/// heading and offset, then the matcher).
/// `on_phase(k)` runs before preparation (0), before the prior-free search
/// (1), before the match (2) and after it (3), e.g. to read an instruction
/// counter. Returns the match and, without a prior, what the search found.
pub fn align<A: VoxelStorage, B: SceneSource + ?Sized, P: PyramidStorage, Q: PyramidStorage>(
    own: &LocalMap<A>,
    received: &B,
    prior: Option<&Isometry3<f32>>,
    model_storage: P,
    scene_storage: Q,
    on_phase: impl FnMut(u8),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    let mut words = [0u32; SearchScratch::WINDOWED];
    let scratch = &mut SearchScratch::new(&mut words);
    align_in(own, received, prior, model_storage, scene_storage, EM_ITERATIONS, scratch, on_phase)
}

/// [`align`] in at most `iterations` EM iterations, the searches' caches
/// in `scratch` (a team robot's: the words that order its map for the
/// link, idle while it matches).
#[allow(clippy::too_many_arguments)]
pub fn align_in<A: VoxelStorage, B: SceneSource + ?Sized, P: PyramidStorage, Q: PyramidStorage>(
    own: &LocalMap<A>,
    received: &B,
    prior: Option<&Isometry3<f32>>,
    model_storage: P,
    scene_storage: Q,
    iterations: u32,
    scratch: &mut SearchScratch<'_>,
    mut on_phase: impl FnMut(u8),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    on_phase(0);
    let model = Pyramid::build_model(own, LEVELS, FOOTPRINT_CELL, model_storage).map_err(AlignError::Pyramid)?;
    let scene = received.prepare_scene(LEVELS, FOOTPRINT_CELL, scene_storage).map_err(AlignError::Pyramid)?;
    on_phase(1);
    align_prepared(&model, &scene, prior, iterations, scratch, on_phase)
}

/// [`align`] of maps already prepared, in at most `iterations` EM
/// iterations, the searches' caches in `scratch`; `on_phase` runs at phases
/// 2 and 3. The one matching path ([`crate::matching::align_prepared`])
/// with the robots' [`Alignment`]: `iterations` and a search of
/// [`SEARCH_NODES`].
fn align_prepared<P: PyramidStorage, Q: PyramidStorage>(
    model: &Pyramid<'_, P>,
    scene: &Pyramid<'_, Q>,
    prior: Option<&Isometry3<f32>>,
    iterations: u32,
    scratch: &mut SearchScratch<'_>,
    mut on_phase: impl FnMut(u8),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    let robots = Pipeline::MPS2.alignment;
    let how = Alignment { settings: MatchSettings { max_iterations: iterations, ..robots.settings }, ..robots };
    let r = crate::matching::align_prepared(model, scene, prior, &how, scratch, || on_phase(2))
        .map_err(AlignError::Match)?;
    on_phase(3);
    Ok(r)
}

/// What a [`Meter`] read at [`align`]'s phases (before preparing, before
/// the prior-free search, before the match, after it).
#[derive(Clone, Copy, Debug, Default)]
struct PhaseMarks {
    instructions: [u64; 4],
    link: [u32; 4],
}

impl PhaseMarks {
    /// [`align_in`] (no prior) with `meter` read at each phase.
    fn align<A, B, P, Q, T>(
        own: &LocalMap<A>,
        received: &B,
        (model, scene): (P, Q),
        iterations: u32,
        scratch: &mut SearchScratch<'_>,
        meter: &T,
    ) -> Result<(MatchResult, Option<Searched>, PhaseMarks), RobotError>
    where
        A: VoxelStorage,
        B: SceneSource + ?Sized,
        P: PyramidStorage,
        Q: PyramidStorage,
        T: Meter,
    {
        let mut marks = PhaseMarks::default();
        let on_phase = |k| marks.mark(k, meter);
        let (result, located) =
            align_in(own, received, None, model, scene, iterations, scratch, on_phase).map_err(RobotError::Align)?;
        Ok((result, located, marks))
    }

    /// Reads `meter` at phase `k`.
    fn mark<T: Meter>(&mut self, k: u8, meter: &T) {
        let k = usize::from(k);
        if let (Some(m), Some(b)) = (self.instructions.get_mut(k), self.link.get_mut(k)) {
            *m = meter.instructions();
            *b = meter.link_bytes();
        }
    }

    /// Puts each phase's instructions, and the bytes that came in on the
    /// link meanwhile, into `report`.
    fn write_to(&self, report: &mut RobotReport) {
        let m = &self.instructions;
        report.prepare_instructions = m[1].saturating_sub(m[0]);
        report.locate_instructions = m[2].saturating_sub(m[1]);
        report.match_instructions = m[3].saturating_sub(m[2]);
        report.link_bytes_while_matching = self.link[3].wrapping_sub(self.link[0]);
    }
}

/// What a platform measures for a robot's report. The defaults measure
/// nothing (a host); a board counts instructions and watches its stack.
pub trait Meter {
    /// Instructions executed so far (any origin).
    fn instructions(&self) -> u64 {
        0
    }
    /// Peak stack use so far (bytes).
    fn peak_stack(&self) -> u32 {
        0
    }
    /// Bytes taken off the link line so far (any origin; wrapping): a
    /// board counts what its receive interrupt put into its rings, which
    /// goes on while the robot prepares and matches.
    fn link_bytes(&self) -> u32 {
        0
    }
}

/// Measures nothing.
impl Meter for () {}

/// Why a robot stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RobotError {
    /// The feed line reported an error.
    FeedIo,
    /// A broken frame on the feed line (the feed has no retransmission).
    Frame(DeframeError),
    /// A feed message that is not one, or out of order.
    Feed(FeedError),
    /// The feeder sent nothing for [`RobotConfig::feed_silence_ms`].
    FeederSilent {
        /// Points received until then.
        points: u32,
    },
    /// The feeder's point count differs from the points received.
    PointCount {
        /// What the feeder says it sent.
        sent: u32,
        /// What arrived.
        received: u32,
    },
    /// The set-up's map configuration is invalid.
    Config(ConfigError),
    /// Fed points could not be inserted.
    Points(PointsError),
    /// The map exchange failed.
    Link(LinkError),
    /// Preparing or matching failed.
    Align(AlignError),
    /// The robot's memory regions are too small for its capacities.
    Memory(crate::region::RegionError),
    /// `poll` was called after the robot finished.
    Finished,
    /// The team's consistency check or pose graph refused its input.
    Team(crate::team::TeamError),
    /// A session robot's line to its peer failed.
    Courier(crate::link::courier::CourierError),
    /// A session robot could not write its update (its buffers are too
    /// small for its map).
    Update(crate::session::PublisherError),
}

impl RobotError {
    /// Where the robot was when it stopped.
    pub fn stage(&self) -> Stage {
        match self {
            RobotError::FeedIo
            | RobotError::Frame(_)
            | RobotError::Feed(_)
            | RobotError::FeederSilent { .. }
            | RobotError::PointCount { .. } => Stage::Feed,
            RobotError::Config(_) | RobotError::Points(_) | RobotError::Memory(_) => Stage::Map,
            RobotError::Link(_) | RobotError::Courier(_) | RobotError::Update(_) => Stage::Link,
            RobotError::Align(_) | RobotError::Team(_) | RobotError::Finished => Stage::Match,
        }
    }
}

impl core::fmt::Display for RobotError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RobotError::FeedIo => f.write_str("I/O error on the feed line"),
            RobotError::Frame(e) => write!(f, "feed line: {e}"),
            RobotError::Feed(e) => write!(f, "{e}"),
            RobotError::FeederSilent { points } => write!(f, "feeder silent after {points} points"),
            RobotError::PointCount { sent, received } => {
                write!(f, "the feeder sent {sent} points, {received} arrived")
            }
            RobotError::Config(e) => write!(f, "set-up: {e}"),
            RobotError::Points(e) => write!(f, "{e}"),
            RobotError::Link(e) => write!(f, "{e}"),
            RobotError::Align(e) => write!(f, "{e}"),
            RobotError::Team(e) => write!(f, "team: {e}"),
            RobotError::Memory(e) => write!(f, "{e}"),
            RobotError::Courier(e) => write!(f, "session line: {e}"),
            RobotError::Update(e) => write!(f, "update: {e}"),
            RobotError::Finished => f.write_str("the robot has finished"),
        }
    }
}

impl core::error::Error for RobotError {}

/// How a robot waits for its feeder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotConfig {
    /// Give up when the feeder sends nothing for this long (ms of the
    /// robot's clock; default 300 s: under an emulator's instruction clock a
    /// busy host can leave long gaps of virtual time between fed bytes).
    pub feed_silence_ms: u64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        RobotConfig { feed_silence_ms: 300_000 }
    }
}

/// Where a robot stands after a poll.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Poll<R = RobotReport> {
    /// Still working: poll again.
    Busy,
    /// Finished; the report went out over the feed line too.
    Done(R),
}

/// A robot: one poll-driven step machine over its feed line `F`, its ports
/// to its peers `L` (in peer index order, itself skipped: a pair robot has
/// one) and a platform's [`Meter`]. Every role implements it: the pair
/// robot and the sender ([`Robot`]), the team member ([`team::TeamRobot`]);
/// a board's main loop, the host's twin runs and the simulation drive them
/// through it alone.
pub trait Machine<F, L, T> {
    /// What the robot reports when it is done (also sent to the feeder).
    type Report;

    /// Does what can be done now (one long step at most: matching) and
    /// says whether the robot is done. Once done or failed, every further
    /// poll is [`RobotError::Finished`].
    fn poll(&mut self, feed: &mut F, ports: &mut [L], now_ms: u64, meter: &T)
        -> Result<Poll<Self::Report>, RobotError>;
}

/// Tells the feeder where and why the robot stopped, best effort.
fn send_failure<F: Write>(feed: &mut F, e: &RobotError) {
    let mut message: heapless::String<96> = heapless::String::new();
    let _ = core::fmt::write(&mut message, format_args!("{e}"));
    send(feed, &RobotMessage::Failed { stage: e.stage(), message: &message });
}

/// Sends one message to the feeder, best effort (a robot that cannot talk
/// to its feeder has no one else to tell).
fn send<F: Write>(feed: &mut F, msg: &RobotMessage<'_>) {
    let mut frame = [0u8; MAX_FRAME];
    if let Ok(len) = msg.to_frame(&mut frame) {
        let _ = feed.write_all(frame.get(..len).unwrap_or(&[]));
        let _ = feed.flush();
    }
}

mod feed_in;
pub mod memory;
mod pair;
pub mod session;
pub mod team;
mod tell;

pub use memory::Capacity;
pub use pair::{Robot, Sender};

#[cfg(test)]
mod tests;
