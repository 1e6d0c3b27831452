//! Stage 6: one robot of a team, end to end, as a poll-driven step machine
//! ([`Robot::poll`], like smoltcp's interface poll): the firmware drives it
//! with its UARTs and SysTick, a host drives the same machine with byte
//! buffers and a simulated line, so the host's answer on the same data is
//! the robot's, to the bit.
//!
//! The sequence: the feed ([`crate::wire::feed`]: a set-up, then labelled
//! points already in the robot's anchor frame) is fused into the robot's
//! map ([`insert_points`]); at the end of the feed the robot exchanges maps
//! with its peer over the link ([`crate::link`]); then it aligns the
//! received map (scene) to its own (model) from the prior, or with none
//! from the maps alone ([`align`]), and reports a
//! [`RobotReport`] over its feed line (or where and why it stopped).
//!
//! Every buffer belongs to the caller: its own map, what it receives the
//! peer's map into (a [`SceneMap`](crate::map::SceneMap) on a board: only
//! what matching it as a scene reads), a scratch of one `u32` per voxel
//! (the link's Morton order), the link's buffers and two pyramid storages.
//! In this pair robot the link's memory and the pyramids' are never used
//! at once: the link's endpoint is dropped before preparing starts, so a
//! board may overlay them; and with a model storage that has room for a
//! copied level 0 ([`ModelLevel0`] in a
//! [`SplitStorage`](crate::matching::SplitStorage)) the own map is read for
//! the last time when the model is built (first), so its memory may hold
//! the pyramids' other parts. The capacities a robot's firmware uses are
//! the constants below.

use crate::geometry::{from_rows, Isometry3};
use crate::link::sim::{ScriptPort, SimLine};
use crate::link::{Endpoint, LinkBuffers, LinkConfig, LinkError, LinkStats, Progress};
use crate::map::{
    ArrayStorage, ConfigError, FullPolicy, InsertError, LocalMap, MapConfig, ScenePoint, VoxelSink, VoxelStorage,
};
use crate::matching::global::{align_searched, Searched};
use crate::matching::search::GlobalSearch;
use crate::matching::{
    ArrayPyramidStorage, ArraySceneStorage, CopiedLevel, MatchError, MatchResult, MatchSettings, Matcher, Pyramid,
    PyramidError, PyramidStorage, SceneSource,
};
use crate::wire::feed::{self, FeedError, FeedMessage, GlobalReport, RobotMessage, RobotReport, Setup, Stage};
use crate::wire::frame::{DeframeError, Deframer, MAX_FRAME};
use crate::wire::share::Estimate;
use embedded_io::{Read, ReadReady, Write, WriteReady};

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
/// [`sender::SenderRobot`], which sends its map and takes none. A full map
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
/// ([`GlobalSearch::max_evaluations`]), with [`EM_ITERATIONS`] its compute
/// budget. Robot maps (up to 8,192 voxels of 0.5 m, 25 m of range) that
/// overlap met their best placement within 2-24 thousand nodes and proved
/// it within 7-41 thousand, with ground truth and with a network's labels;
/// maps that share nothing prune little (45-94 thousand nodes, and a
/// second search and two more refinements: 5-7e8 instructions on a
/// Cortex-M4). With this budget a robot spends at most about 1e8
/// instructions searching, and after a search that took more than half of
/// it refines only its best placement.
pub const SEARCH_NODES: u32 = 40_000;
/// EM iterations a robot's refinement may take
/// ([`MatchSettings::max_iterations`]; the paper's 50 serve a host):
/// converging matches took at most 16 (prior-free protocol with a network's
/// labels at twice the usual severity, and the paper's grid of priors); a
/// refinement that does not converge (a wrong placement, maps that share
/// nothing) costs about 3.5e6 instructions per iteration.
pub const EM_ITERATIONS: u32 = 30;
/// Pyramid levels (0.5 m maps: cells of 0.5, 1 and 2 m).
pub const LEVELS: usize = 3;
/// First footprint cell tried (m); doubled until the grids fit.
pub const FOOTPRINT_CELL: f32 = 1.0;

/// A robot's map storage (16-bit index slots).
pub type MapStorage = ArrayStorage<VOXELS, u16>;
/// A small board's map storage (16-bit index slots).
pub type SmallMapStorage = ArrayStorage<SMALL_VOXELS, u16>;
/// Pyramid storage of a robot's own map (the model).
pub type ModelStorage = ArrayPyramidStorage<VOXELS, COARSE, MODEL_WORDS>;
/// Room for the model's level 0 copied out of the robot's map (176 KiB: 22
/// bytes per voxel): with it, the model's other parts and the scene's
/// pyramid may lie over the map's memory ([`align`] builds the model
/// first, and reads the map no more once it is copied).
pub type ModelLevel0 = CopiedLevel<VOXELS>;
/// The model's coarse levels, normals, index and footprint beside a copied
/// level 0 ([`ModelLevel0`]): no extras.
pub type ModelRest = ArrayPyramidStorage<0, COARSE, MODEL_WORDS>;
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
/// ([`align_searched`]: every heading and offset, then the matcher).
/// `on_phase(k)` runs before preparation (0), before the prior-free search
/// (1), before the match (2) and after it (3), e.g. to read an instruction
/// counter. Returns the match and, without a prior, what the search found.
pub fn align<A: VoxelStorage, B: SceneSource + ?Sized, P: PyramidStorage, Q: PyramidStorage>(
    own: &LocalMap<A>,
    received: &B,
    prior: Option<&Isometry3<f32>>,
    model_storage: P,
    scene_storage: Q,
    mut on_phase: impl FnMut(u8),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    on_phase(0);
    // The model first: with room for a copied level 0 in its storage the
    // own map is read for the last time here (a board reuses its memory for
    // the pyramids' other parts).
    let model = Pyramid::build_model(own, LEVELS, FOOTPRINT_CELL, model_storage).map_err(AlignError::Pyramid)?;
    let scene = received.prepare_scene(LEVELS, FOOTPRINT_CELL, scene_storage).map_err(AlignError::Pyramid)?;
    on_phase(1);
    let matcher = Matcher::new(MatchSettings { max_iterations: EM_ITERATIONS, ..MatchSettings::default() });
    let r = match prior {
        Some(p) => {
            on_phase(2);
            (matcher.align(&model, &scene, p).map_err(AlignError::Match)?, None)
        }
        None => {
            let search = GlobalSearch { max_evaluations: SEARCH_NODES, ..GlobalSearch::default() };
            align_searched(&matcher, &model, &scene, &search, || on_phase(2))
        }
        .map_err(AlignError::Match)?,
    };
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
    /// [`align`] with `meter` read at each phase.
    fn align<A, B, P, Q, T>(
        own: &LocalMap<A>,
        received: &B,
        prior: Option<&Isometry3<f32>>,
        model: P,
        scene: Q,
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
        let (result, located) = align(own, received, prior, model, scene, |k| {
            let k = usize::from(k);
            if let (Some(m), Some(b)) = (marks.instructions.get_mut(k), marks.link.get_mut(k)) {
                *m = meter.instructions();
                *b = meter.link_bytes();
            }
        })
        .map_err(RobotError::Align)?;
        Ok((result, located, marks))
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
    /// `poll` was called after the robot finished.
    Finished,
    /// The team's consistency check or pose graph refused its input.
    Team(crate::team::TeamError),
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
            RobotError::Config(_) | RobotError::Points(_) => Stage::Map,
            RobotError::Link(_) => Stage::Link,
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
pub enum Poll {
    /// Still working: poll again.
    Busy,
    /// Finished; the report went out over the feed line too.
    Done(RobotReport),
}

// The link's state (its frame buffer) is the large variant; without an
// allocator there is nothing to box it in, and a robot holds one state.
#[allow(clippy::large_enum_variant)]
enum State<'a, M: VoxelStorage, R: VoxelSink + SceneSource> {
    Feed {
        own: &'a mut LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
    },
    Link {
        own: &'a LocalMap<M>,
        endpoint: Endpoint<'a, M, R>,
    },
    Align {
        own: &'a LocalMap<M>,
        received: &'a R,
        stats: LinkStats,
    },
    /// A one-sided exchange (the peer took no map): telling the peer the
    /// result before reporting it.
    Tell {
        report: RobotReport,
        teller: tell::Teller,
    },
    Done,
}

/// One robot: its maps, its link, its alignment, driven by [`Robot::poll`].
pub struct Robot<'a, M: VoxelStorage, R: VoxelSink + SceneSource, P: PyramidStorage, Q: PyramidStorage> {
    state: State<'a, M, R>,
    pyramids: Option<(P, Q)>,
    fed: FeedIn,
    link_started_ms: u64,
    link_ms: u32,
    /// The peer took no map: it is told the result (its robot id).
    tell_peer: Option<u8>,
    link_config: LinkConfig,
}

/// What a robot took from its feed line: the set-up, the points inserted,
/// and the feed's framing and timing. Shared by the pair robot and the
/// team robot ([`team`]).
struct FeedIn {
    config: RobotConfig,
    deframer: Deframer,
    setup: Option<Setup>,
    /// Robots in the team (a team robot only).
    team: Option<u8>,
    points: u32,
    map_instructions: u64,
    last_fed_ms: Option<u64>,
}

impl FeedIn {
    fn new(config: RobotConfig) -> Self {
        FeedIn {
            config,
            deframer: Deframer::new(),
            setup: None,
            team: None,
            points: 0,
            map_instructions: 0,
            last_fed_ms: None,
        }
    }

    /// Reads what the feed line holds into `own` (both maps reconfigured by
    /// the set-up; a robot that receives no map has no `received`); `true`
    /// at the end of the feed. A team robot (`team`)
    /// needs [`FeedMessage::Team`] after the set-up and no prior; a pair
    /// robot refuses it.
    fn read<F: Read + Write + ReadReady, M: VoxelStorage, R: VoxelSink, T: Meter>(
        &mut self,
        feed: &mut F,
        own: &mut LocalMap<M>,
        mut received: Option<&mut R>,
        team: bool,
        now_ms: u64,
        meter: &T,
    ) -> Result<bool, RobotError> {
        if self.last_fed_ms.is_none() {
            // First call: tell the feeder the robot listens.
            send(feed, &RobotMessage::Ready);
        }
        let last = *self.last_fed_ms.get_or_insert(now_ms);
        let mut buf = [0u8; 64];
        while feed.read_ready().map_err(|_| RobotError::FeedIo)? {
            let n = feed.read(&mut buf).map_err(|_| RobotError::FeedIo)?;
            if n == 0 {
                break;
            }
            self.last_fed_ms = Some(now_ms);
            for &b in buf.get(..n).unwrap_or(&[]) {
                let FeedIn { deframer, setup, points, map_instructions, team: robots, .. } = self;
                let Some(payload) = deframer.push(b).map_err(RobotError::Frame)? else { continue };
                let ready = setup.is_some() && robots.is_some() == team;
                match FeedMessage::decode(payload).map_err(RobotError::Feed)? {
                    FeedMessage::Setup(s) if setup.is_none() && !(team && s.prior.is_some()) => {
                        let config = map_config(s.resolution);
                        own.reset(config).map_err(RobotError::Config)?;
                        if let Some(r) = received.as_deref_mut() {
                            r.configure(config).map_err(RobotError::Config)?;
                        }
                        *setup = Some(s);
                    }
                    FeedMessage::Team { robots: n }
                        if team && robots.is_none() && setup.is_some_and(|s| s.robot_id < n) =>
                    {
                        *robots = Some(n);
                    }
                    FeedMessage::Points { data, .. } if ready => {
                        let t0 = meter.instructions();
                        *points += insert_points(own, data).map_err(RobotError::Points)?;
                        *map_instructions += meter.instructions().saturating_sub(t0);
                    }
                    FeedMessage::EndOfFeed { points: sent, .. } if ready => {
                        if sent != *points {
                            return Err(RobotError::PointCount { sent, received: *points });
                        }
                        return Ok(true);
                    }
                    _ => return Err(RobotError::Feed(FeedError::Order)),
                }
            }
        }
        if now_ms.saturating_sub(self.last_fed_ms.unwrap_or(last)) > self.config.feed_silence_ms {
            return Err(RobotError::FeederSilent { points: self.points });
        }
        Ok(false)
    }
}

impl<'a, M: VoxelStorage, R: VoxelSink + SceneSource, P: PyramidStorage, Q: PyramidStorage> Robot<'a, M, R, P, Q> {
    /// A robot over the caller's buffers: its own map and the received map
    /// (reconfigured by the set-up), a scratch of one `u32` per voxel of the
    /// larger map, the link's buffers, and the model's and scene's pyramid
    /// storages.
    pub fn new(
        config: RobotConfig,
        own: &'a mut LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
        model: P,
        scene: Q,
    ) -> Self {
        Robot {
            state: State::Feed { own, received, scratch, buffers },
            pyramids: Some((model, scene)),
            fed: FeedIn::new(config),
            link_started_ms: 0,
            link_ms: 0,
            tell_peer: None,
            link_config: LinkConfig::default(),
        }
    }

    /// The set-up, once it arrived.
    pub fn setup(&self) -> Option<&Setup> {
        self.fed.setup.as_ref()
    }

    /// Does what can be done now: reads the feed, exchanges maps, aligns
    /// (one long step), reports. On an error the robot tells its feeder
    /// where and why, best effort, and stops.
    pub fn poll<F, L, T>(&mut self, feed: &mut F, link: &mut L, now_ms: u64, meter: &T) -> Result<Poll, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let r = self.step(feed, link, now_ms, meter);
        match &r {
            Ok(Poll::Done(report)) => send(feed, &RobotMessage::Report(*report)),
            Err(RobotError::Finished) | Ok(Poll::Busy) => {}
            Err(e) => {
                self.state = State::Done;
                send_failure(feed, e);
            }
        }
        r
    }

    fn step<F, L, T>(&mut self, feed: &mut F, link: &mut L, now_ms: u64, meter: &T) -> Result<Poll, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        // The waiting states are polled in place: moving the state out and
        // back (the link's endpoint is kilobytes) on every poll was most of
        // a waiting robot's instructions.
        match &mut self.state {
            State::Feed { own, received, .. } => {
                if self.fed.read(feed, own, Some(&mut **received), false, now_ms, meter)? {
                    self.start_link(now_ms)?;
                }
                return Ok(Poll::Busy);
            }
            State::Link { endpoint, .. } => {
                let progress = endpoint.step(link, now_ms).map_err(RobotError::Link)?;
                if progress == Progress::Busy {
                    return Ok(Poll::Busy);
                }
            }
            _ => {}
        }
        match core::mem::replace(&mut self.state, State::Done) {
            State::Feed { .. } => Err(RobotError::Finished),
            State::Link { own, endpoint } => {
                // The exchange is done (the step above said so).
                self.link_ms = now_ms.saturating_sub(self.link_started_ms).min(u64::from(u32::MAX)) as u32;
                let stats = endpoint.stats();
                if endpoint.peer_takes_map() == Some(false) {
                    self.tell_peer = endpoint.peer_id();
                }
                let (_, received) = endpoint.into_parts();
                let Some(received) = received else { return Err(RobotError::Link(LinkError::Setup)) };
                self.state = State::Align { own, received, stats };
                Ok(Poll::Busy)
            }
            State::Align { own, received, stats } => {
                let (report, estimate) = self.align(own, received, &stats, meter)?;
                match self.tell_peer {
                    Some(peer) => {
                        let estimate = Estimate { b: peer, ..estimate };
                        self.state = State::Tell { report, teller: tell::Teller::new(estimate, now_ms) };
                        Ok(Poll::Busy)
                    }
                    None => Ok(Poll::Done(report)),
                }
            }
            State::Tell { report, mut teller } => {
                let io = |_| RobotError::Link(LinkError::Io(embedded_io::ErrorKind::Other));
                if teller.step(link, now_ms, &self.link_config).map_err(io)? {
                    return Ok(Poll::Done(report));
                }
                self.state = State::Tell { report, teller };
                Ok(Poll::Busy)
            }
            State::Done => Err(RobotError::Finished),
        }
    }

    fn start_link(&mut self, now_ms: u64) -> Result<(), RobotError> {
        let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
        let State::Feed { own, received, scratch, buffers } = core::mem::replace(&mut self.state, State::Done) else {
            return Err(RobotError::Feed(FeedError::Order));
        };
        let own: &'a LocalMap<M> = own;
        let config = LinkConfig { silence_ms: setup.silence_ms, ..LinkConfig::default() };
        self.link_config = config;
        let id = setup.robot_id;
        let endpoint = Endpoint::new(config, id, u32::from(id), 0, Some((own, scratch)), Some(received), buffers)
            .map_err(RobotError::Link)?;
        self.link_started_ms = now_ms;
        self.state = State::Link { own, endpoint };
        Ok(())
    }

    fn align<T: Meter>(
        &mut self,
        own: &LocalMap<M>,
        received: &R,
        stats: &LinkStats,
        meter: &T,
    ) -> Result<(RobotReport, Estimate), RobotError> {
        let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
        let (model, scene) = self.pyramids.take().ok_or(RobotError::Finished)?;
        let prior = setup.prior.as_ref().map(from_rows);
        let (result, located, marks) = PhaseMarks::align(own, received, prior.as_ref(), model, scene, meter)?;
        let estimate = result.estimate(setup.robot_id, 0);
        let mut report = RobotReport {
            result: result.report(setup.robot_id),
            points: self.fed.points,
            map_voxels: own.len() as u32,
            received_voxels: received.len() as u32,
            bytes_sent: stats.bytes_sent,
            bytes_received: stats.bytes_received,
            retransmissions: stats.retransmissions,
            link_ms: self.link_ms,
            map_instructions: self.fed.map_instructions,
            prepare_instructions: 0,
            locate_instructions: 0,
            match_instructions: 0,
            global: located.as_ref().map(GlobalReport::from),
            peak_stack: meter.peak_stack(),
            link_bytes_while_matching: 0,
        };
        marks.write_to(&mut report);
        Ok((report, estimate))
    }
}

/// Runs two robots to their end on one simulated line (the robots' UARTs
/// joined through `line`), each fed `feeds[i]` (framed feed messages) from
/// a [`ScriptPort`], in virtual time: one millisecond per round, the line
/// ticked, each robot polled. This is how a host computes, on its own
/// data, exactly what two boards compute. Stops after `limit_ms`.
pub fn simulate_pair<M, R, P, Q, const N: usize>(
    robots: [&mut Robot<'_, M, R, P, Q>; 2],
    feeds: [&[u8]; 2],
    line: &core::cell::RefCell<SimLine<N>>,
    limit_ms: u64,
) -> [Result<RobotReport, RobotError>; 2]
where
    M: VoxelStorage,
    R: VoxelSink + SceneSource,
    P: PyramidStorage,
    Q: PyramidStorage,
{
    let [a, b] = robots;
    let (mut la, mut lb) = SimLine::ports(line);
    let mut fa = ScriptPort::<256>::new(feeds[0], 64);
    let mut fb = ScriptPort::<256>::new(feeds[1], 64);
    let mut out: [Option<Result<RobotReport, RobotError>>; 2] = [None, None];
    let mut now = 0u64;
    while out.iter().any(Option::is_none) && now <= limit_ms {
        line.borrow_mut().tick(now);
        for (i, (robot, feed, port)) in
            [(&mut *a, &mut fa, &mut la), (&mut *b, &mut fb, &mut lb)].into_iter().enumerate()
        {
            if let Some(slot) = out.get_mut(i).filter(|o| o.is_none()) {
                match robot.poll(feed, port, now, &()) {
                    Ok(Poll::Busy) => {}
                    Ok(Poll::Done(r)) => *slot = Some(Ok(r)),
                    Err(e) => *slot = Some(Err(e)),
                }
            }
        }
        now += 1;
    }
    out.map(|o| o.unwrap_or(Err(RobotError::Link(LinkError::Silent))))
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

pub mod sender;
pub mod team;
mod tell;

#[cfg(test)]
mod tests;
