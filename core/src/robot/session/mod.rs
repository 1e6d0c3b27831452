//! The third role: a robot that keeps driving. Its feed comes in rounds
//! (the anchor where the robot is before each scan, the scan's points, an
//! end-of-round mark); each round it fuses its scans into its bounded map,
//! sends its peer what changed ([`Publisher`]) and takes the peer's
//! update into its copy ([`Replica`]), both over the [`Courier`] on its
//! link port, then re-estimates the peer ([`Tracker`]: prior-free until a
//! fix, then from it) and reports the round. The same machine runs on a
//! board and, through the simulation driver (`crate::sim`, feature
//! `sim`), as its host twin.
//!
//! Memory is the caller's ([`SessionParts`]): the map, the copy, the
//! publisher's records, the update buffers and the pyramid storages, which
//! are rebuilt every round (both maps change every round).

use super::feed_in::FeedIn;
use super::{map_config, Machine, Meter, Poll, RobotConfig, RobotError};
use crate::geometry::Isometry3;
use crate::link::courier::{Courier, CourierConfig, CourierError, CourierStats, Event};
use crate::map::{LocalMap, VoxelStorage};
use crate::matching::search::SearchScratch;
use crate::matching::{MatchStatus, Pyramid, PyramidStorage, Reach, Role, SceneSource};
use crate::matching::{Work, WorkCosts};
use crate::pipeline::Pipeline;
use crate::region::RegionError;
use crate::session::walk::BOARD_WALK_STRIDE;
use crate::session::{
    adopt_backed, made_this_round, pair_walk, Applied, Estimate, OdometryWalk, PeerView, Publisher, PublisherError,
    Replica, ScanFit, ShadowEntry, Tracker, UpdateCounts,
};
use crate::wire::feed::{FeedError, FeedMessage, RobotMessage, RoundReport, SessionEnd};
use crate::wire::frame::MAX_PAYLOAD;
use crate::wire::report::MatchReport;
use crate::wire::share::NO_EXCHANGE;
use crate::wire::update::{UpdateAck, ACK_BYTES};
use embedded_io::{Read, ReadReady, Write, WriteReady};
pub use head::ESTIMATE_BYTES;
use head::{Head, HeadEstimate, Said};

mod head;

/// Voxels of a session robot's map on a board, and of its copy of its
/// peer's (an mps2-an386 in its 1 MiB budget). What a session robot keeps
/// between rounds is its map and the copy (28 bytes a voxel each), the
/// publisher's records of what the peer holds and of the update in flight
/// (32 bytes a voxel of its map), the update buffers and a scratch word a
/// voxel; both pyramids (the map's as the model, the copy's as the scene)
/// are rebuilt every round, since both maps change every round. About
/// 650 KiB with 4,096 voxels: the pair robot's 8,192 do not fit beside a
/// copy and the records.
pub const SESSION_VOXELS: usize = 4096;
/// Coarse pyramid entries of a session robot's pyramids (0.69 per voxel:
/// maps of 0.5 m with a network's labels took up to 0.66).
pub const SESSION_COARSE: usize = 2816;
/// Bytes of each of a session robot's update buffers: a snapshot of its
/// whole map (codec records of 1.5-2 bytes a voxel, chunk and header
/// bytes) with room.
pub const SESSION_UPDATE_BYTES: usize = 4 * SESSION_VOXELS + 1024;
/// A session robot's map storage, and its copy's.
pub type SessionMapStorage = crate::map::ArrayStorage<SESSION_VOXELS, u16>;
/// The publisher's records of a session robot.
pub type SessionRecords = [ShadowEntry; SESSION_VOXELS];
/// Words of a session robot's model pyramid: a pair robot's (the
/// footprint of a prior-free round), or, when more, a word and six a voxel
/// (level 0's sweep order and its entries gathered in that order while its
/// normals are fitted: a tracking round's normals three times faster, the
/// same normals).
pub const SESSION_MODEL_WORDS: usize = {
    let gathered = 7 * SESSION_VOXELS;
    if gathered > super::MODEL_WORDS {
        gathered
    } else {
        super::MODEL_WORDS
    }
};
/// The pyramid storage of a session robot's map (the model).
pub type SessionModelStorage =
    crate::matching::ArrayPyramidStorage<SESSION_VOXELS, SESSION_COARSE, SESSION_MODEL_WORDS>;
/// The pyramid storage of its copy of the peer's map (the scene: a map's
/// scene pyramid keeps a voxel's extras too).
pub type SessionSceneStorage =
    crate::matching::ArrayPyramidStorage<SESSION_VOXELS, SESSION_COARSE, { super::SCENE_WORDS }>;

/// The session robots' pipeline: the mps2 robot's, its prior-free search
/// cut to 20,000 nodes (searched every round until a fix, on maps that
/// share nothing it would spend the whole budget: with 40,000 nodes such a
/// round took up to 4.6e8 instructions on an mps2-an386, over the 3e8 a
/// round may take), the verdict's least overlap a session's
/// ([`crate::session::MIN_OVERLAP`]).
pub const SESSION_PIPELINE: Pipeline = Pipeline {
    alignment: crate::matching::Alignment {
        search: crate::matching::search::GlobalSearch {
            max_evaluations: SESSION_SEARCH_NODES,
            ..Pipeline::MPS2.alignment.search
        },
        settings: crate::matching::MatchSettings {
            min_overlap: crate::session::MIN_OVERLAP,
            ..Pipeline::MPS2.alignment.settings
        },
    },
    ..Pipeline::MPS2
};
/// Nodes a session robot's prior-free search may score.
pub const SESSION_SEARCH_NODES: u32 = 20_000;
/// What a session robot's search, EM and verdict steps cost on an
/// mps2-an386 (instructions): a least-squares fit of the boards' counts
/// of 780 robot-rounds of whole town sessions, times 1.25, so that they
/// miss a round's count by at most 1.2e7 (docs/session.md "On the
/// boards").
pub const SESSION_WORK_COSTS: WorkCosts = WorkCosts {
    fine_iteration: 2_500_000,
    coarse_iteration: 1_600_000,
    placement: 11_500_000,
    global_node: 4_800,
    window_node: 2_100,
};
/// What a session robot's estimate may spend a round, at
/// [`SESSION_WORK_COSTS`] ([`Work`]): with the round's other work
/// (registering and fusing its scans, the updates, preparing both maps: at
/// most 8.0e7 instructions measured, 1.3e7 of it the scans' registration)
/// and the costs' largest miss, about 2.92e8, within the boards' 3e8
/// instructions a round. On the town it cuts only prior-free rounds on
/// maps that share little (361 of 3,360 robot-rounds of twelve whole
/// sessions at 2.15e8; 2.0e8 since the boards register their scans: 226
/// of 1,680 instead of 202 on six, every `Converged` estimate the same).
pub const SESSION_WORK: u64 = 200_000_000;
/// Scene entries whose blocks a session robot's EM remembers between its
/// iterations ([`SessionParts::reach`]): every entry its matcher samples.
pub const SESSION_REACH: usize = SESSION_PIPELINE.alignment.settings.max_scene_entries as usize;

/// After its last round a robot answers its peer's resends this long (ms)
/// before it reports its end: the peer may have missed its last answer.
pub const LINGER_MS: u64 = 3000;

/// What a session robot works in, all the caller's: a board's statics, a
/// host's heap.
pub struct SessionParts<'a, S, C, R, P, Q> {
    /// The robot's own map's storage (its capacity: the map's).
    pub map: S,
    /// The copy of the peer's map (its capacity: what the robot tells the
    /// peer it holds).
    pub copy: C,
    /// The publisher's two record lists, each at least the map's capacity.
    pub records: (R, R),
    /// A `u32` per voxel of the larger of the map and the copy.
    pub scratch: &'a mut [u32],
    /// The robot's update to its peer.
    pub out: &'a mut [u8],
    /// The peer's update.
    pub input: &'a mut [u8],
    /// The own map's pyramid (the model).
    pub model: P,
    /// The copy's pyramid (the scene).
    pub scene: Q,
    /// The windowed search's cache ([`SearchScratch::WINDOWED`] words).
    pub search: &'a mut [u32],
    /// EM's memory of the block each sampled scene entry reached, between
    /// its iterations ([`SearchScratch::with_reach`]; [`SESSION_REACH`]
    /// for every entry the session's matcher samples; fewer, the rest are
    /// looked up every iteration): the same answers, fewer lookups.
    pub reach: &'a mut [Reach],
}

enum State {
    /// Reading the round's scans.
    Feed,
    /// Before the first round: each robot tells its peer what it holds
    /// (its copy's first answer), so that not even the first update is
    /// more.
    Hello,
    /// Trading updates (`len`: this robot's).
    Exchange {
        len: usize,
        started_ms: u64,
    },
    /// Estimating the peer and reporting the round.
    Estimate,
    /// After the last round, answering the peer's resends until `until`.
    Linger {
        until: u64,
    },
    Done,
}

/// What a round measured until its estimate.
#[derive(Clone, Copy, Default)]
struct RoundMarks {
    points: u32,
    map_instructions: u64,
    update_instructions: u64,
    update_bytes: u32,
    counts: UpdateCounts,
    applied: Option<Applied>,
    exchange_ms: u32,
    line: CourierStats,
}

/// A robot that keeps driving, driven by [`Machine::poll`] (its peer is
/// `ports[0]`).
pub struct SessionRobot<'a, S: VoxelStorage, C: VoxelStorage, R, P, Q>
where
    R: AsRef<[ShadowEntry]> + AsMut<[ShadowEntry]>,
{
    state: State,
    fed: FeedIn,
    session: bool,
    map: LocalMap<S>,
    copy: Option<C>,
    replica: Option<Replica<C>>,
    records: Option<(R, R)>,
    publisher: Option<Publisher<R>>,
    tracker: Tracker,
    courier: Courier,
    scratch: &'a mut [u32],
    out: &'a mut [u8],
    input: &'a mut [u8],
    model: P,
    scene: Q,
    search: &'a mut [u32],
    reach: &'a mut [Reach],
    round: u16,
    marks: RoundMarks,
    stats_at_start: CourierStats,
    /// This robot's last estimate of its peer that passed the verdict, and
    /// what it said of it (reported `Converged`, confirmed and not
    /// contested; or a recall waiting for its vouch).
    last_estimate: Option<HeadEstimate>,
    /// The peer's, as its last message said.
    heard: Option<Isometry3<f32>>,
    /// What the peer said of that estimate.
    heard_said: Said,
    /// The peer's, as the message before it said: a fix it made in its
    /// last round is one heard when this was none ([`made_this_round`]).
    heard_before: Option<Isometry3<f32>>,
    /// Where the peer was (its frame) as its last message said.
    heard_at: Option<[f32; 3]>,
    /// Where this robot was when its copy last changed.
    copy_at: Option<[f32; 3]>,
    /// Its odometry's heading walk, measured scan by scan.
    walk: OdometryWalk,
    /// The fit of the scan being fed, against the map before it.
    scan_fit: Option<ScanFit>,
    /// The peer's figure of its walk, as its last message said.
    heard_walk: Option<f32>,
}

impl<'a, S, C, R, P, Q> SessionRobot<'a, S, C, R, P, Q>
where
    S: VoxelStorage,
    C: VoxelStorage,
    R: AsRef<[ShadowEntry]> + AsMut<[ShadowEntry]>,
    P: PyramidStorage,
    Q: PyramidStorage,
{
    /// A session robot in `parts`, its line to its peer run by a courier
    /// of `courier`'s sizes.
    pub fn new(
        config: RobotConfig,
        courier: CourierConfig,
        parts: SessionParts<'a, S, C, R, P, Q>,
    ) -> Result<Self, RobotError> {
        let SessionParts { map, copy, records, scratch, out, input, model, scene, search, reach } = parts;
        // The set-up names the voxel size; until then the map waits empty.
        let map = LocalMap::new(map, map_config(0.5)).map_err(RobotError::Config)?;
        let copy_capacity = copy.voxels().len();
        let need = map.capacity().max(copy_capacity);
        let records_have = records.0.as_ref().len().min(records.1.as_ref().len());
        if records_have < map.capacity() {
            return Err(RobotError::Memory(RegionError::Short { need: map.capacity(), have: records_have }));
        }
        if scratch.len() < need {
            return Err(RobotError::Memory(RegionError::Short { need, have: scratch.len() }));
        }
        Ok(SessionRobot {
            state: State::Feed,
            fed: FeedIn::new(config),
            session: false,
            map,
            copy: Some(copy),
            replica: None,
            records: Some(records),
            publisher: None,
            tracker: Tracker::new(),
            courier: Courier::new(courier).map_err(RobotError::Courier)?,
            scratch,
            out,
            input,
            model,
            scene,
            search,
            reach,
            round: 0,
            marks: RoundMarks::default(),
            stats_at_start: CourierStats::default(),
            last_estimate: None,
            heard: None,
            heard_said: Said::Passed,
            heard_before: None,
            heard_at: None,
            copy_at: None,
            walk: OdometryWalk::new(),
            scan_fit: None,
            heard_walk: None,
        })
    }

    /// The robot's map.
    pub fn map(&self) -> &LocalMap<S> {
        &self.map
    }

    /// Its copy of the peer's map, once the set-up came.
    pub fn copy(&self) -> Option<&LocalMap<C>> {
        self.replica.as_ref().map(Replica::map)
    }

    /// The fix held of the peer (`T_own_peer`), if any.
    pub fn fix(&self) -> Option<&Isometry3<f32>> {
        self.tracker.fix()
    }

    fn step<F, L, T>(
        &mut self,
        feed: &mut F,
        port: &mut L,
        now_ms: u64,
        meter: &T,
    ) -> Result<Poll<SessionEnd>, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        match self.state {
            State::Feed => {
                // The last round's resends are answered meanwhile.
                self.courier.step(port, &[], self.input, now_ms).map_err(RobotError::Courier)?;
                self.read_feed(feed, now_ms, meter)?;
                Ok(Poll::Busy)
            }
            State::Hello => {
                self.hello(port, now_ms)?;
                Ok(Poll::Busy)
            }
            State::Exchange { len, started_ms } => {
                self.exchange(port, len, started_ms, now_ms, meter)?;
                Ok(Poll::Busy)
            }
            State::Estimate => {
                self.estimate(feed, meter)?;
                Ok(Poll::Busy)
            }
            State::Linger { until } => {
                self.courier.step(port, &[], self.input, now_ms).map_err(RobotError::Courier)?;
                if now_ms < until {
                    return Ok(Poll::Busy);
                }
                self.state = State::Done;
                let stats = self.courier.stats();
                Ok(Poll::Done(SessionEnd {
                    rounds: self.round,
                    line_bytes: [stats.bytes_sent, stats.bytes_received],
                    resent: stats.resent,
                    peak_stack: meter.peak_stack(),
                }))
            }
            State::Done => Err(RobotError::Finished),
        }
    }

    /// Reads the feed up to the end of a round (one byte at a time: what
    /// follows the mark stays on the line for the next round).
    #[inline(never)]
    fn read_feed<F: Read + Write + ReadReady, T: Meter>(
        &mut self,
        feed: &mut F,
        now_ms: u64,
        meter: &T,
    ) -> Result<(), RobotError> {
        if self.fed.last_fed_ms.is_none() {
            super::send(feed, &RobotMessage::Ready);
        }
        let last = *self.fed.last_fed_ms.get_or_insert(now_ms);
        let mut byte = [0u8; 1];
        while feed.read_ready().map_err(|_| RobotError::FeedIo)? {
            if feed.read(&mut byte).map_err(|_| RobotError::FeedIo)? == 0 {
                break;
            }
            self.fed.last_fed_ms = Some(now_ms);
            let Some(payload) = self.fed.deframer.push(byte[0]).map_err(RobotError::Frame)? else { continue };
            // Copied off the deframer, which the robot's other state shares.
            let mut frame = [0u8; MAX_PAYLOAD];
            let n = payload.len().min(MAX_PAYLOAD);
            frame.get_mut(..n).unwrap_or(&mut []).copy_from_slice(payload.get(..n).unwrap_or(&[]));
            let msg = FeedMessage::decode(frame.get(..n).unwrap_or(&[])).map_err(RobotError::Feed)?;
            if self.on_feed(msg, now_ms, meter)? {
                return Ok(());
            }
        }
        if now_ms.saturating_sub(self.fed.last_fed_ms.unwrap_or(last)) > self.fed.config.feed_silence_ms {
            return Err(RobotError::FeederSilent { points: self.fed.points });
        }
        Ok(())
    }

    /// One feed message; `true` when it ended the round or the feed.
    fn on_feed<T: Meter>(&mut self, msg: FeedMessage<'_>, now_ms: u64, meter: &T) -> Result<bool, RobotError> {
        let ready = self.fed.setup.is_some() && self.session;
        match msg {
            FeedMessage::Setup(s) if self.fed.setup.is_none() && s.prior.is_none() => {
                let config = map_config(s.resolution);
                self.map.reset(config).map_err(RobotError::Config)?;
                let copy = self.copy.take().ok_or(RobotError::Feed(FeedError::Order))?;
                self.replica = Some(Replica::new(LocalMap::new(copy, config).map_err(RobotError::Config)?));
                let (held, sent) = self.records.take().ok_or(RobotError::Feed(FeedError::Order))?;
                // A robot's epoch: its id, so that its peer tells it from
                // the other robot of a test.
                self.publisher = Some(Publisher::new(u16::from(s.robot_id) + 1, held, sent));
                self.fed.setup = Some(s);
            }
            FeedMessage::Session { update_budget } if self.fed.setup.is_some() && !self.session => {
                self.session = true;
                let budget = (update_budget > 0).then_some(crate::session::UpdateBudget::Bytes(update_budget));
                if let Some(p) = self.publisher.as_mut() {
                    p.set_budget(budget);
                }
                // The copy's first answer, before any update: what it holds.
                let answer = self.replica.as_ref().ok_or(RobotError::Feed(FeedError::Order))?.answer().encode();
                let out = self.out.get_mut(..answer.len()).ok_or(RobotError::Update(PublisherError::Scratch))?;
                out.copy_from_slice(&answer);
                self.courier.start(0, answer.len(), now_ms).map_err(RobotError::Courier)?;
                self.state = State::Hello;
                return Ok(true);
            }
            FeedMessage::Anchor { at } if ready => {
                self.end_scan();
                self.map.move_anchor(at).map_err(RobotError::Config)?;
                self.scan_fit = Some(ScanFit::with_stride(at, BOARD_WALK_STRIDE));
            }
            FeedMessage::Points { data, .. } if ready => {
                let t0 = meter.instructions();
                // Each part of a scan is registered to the map before it is
                // fused (the parts are slabs of the scan's voxels in key
                // order, so a part meets little of the ones before it).
                if let Some(fit) = self.scan_fit.as_mut() {
                    for (p, _) in crate::wire::feed::points(data).map_while(Result::ok) {
                        fit.add(&self.map, p);
                    }
                }
                let n = super::insert_points(&mut self.map, data).map_err(RobotError::Points)?;
                self.fed.points += n;
                self.marks.points += n;
                self.marks.map_instructions += meter.instructions().saturating_sub(t0);
            }
            FeedMessage::EndOfRound { round, points } if ready && round == self.round => {
                if points != self.marks.points {
                    return Err(RobotError::PointCount { sent: points, received: self.marks.points });
                }
                self.end_scan();
                self.start_round(now_ms, meter)?;
                return Ok(true);
            }
            FeedMessage::EndOfFeed { points, .. } if ready => {
                if points != self.fed.points {
                    return Err(RobotError::PointCount { sent: points, received: self.fed.points });
                }
                self.state = State::Linger { until: now_ms + LINGER_MS };
                return Ok(true);
            }
            _ => return Err(RobotError::Feed(FeedError::Order)),
        }
        Ok(false)
    }

    /// This robot's walk and its peer's as the peer last said it
    /// ([`pair_walk`]).
    fn pair_walk(&self) -> Option<f32> {
        pair_walk(self.walk.excess(), self.heard_walk)
    }

    /// Takes the fed scan's turn against the map into the walk.
    fn end_scan(&mut self) {
        if let Some(fit) = self.scan_fit.take() {
            self.walk.push(fit.turn());
        }
    }

    /// Trades the copies' first answers: the peer's capacity for the
    /// publisher.
    fn hello<L: Read + Write + ReadReady + WriteReady>(&mut self, port: &mut L, now_ms: u64) -> Result<(), RobotError> {
        let out = self.out.get(..ACK_BYTES).unwrap_or(&[]);
        match self.courier.step(port, out, self.input, now_ms).map_err(RobotError::Courier)? {
            Event::Busy => {}
            Event::Delivered(n) => {
                let publisher = self.publisher.as_mut().ok_or(RobotError::Feed(FeedError::Order))?;
                let answer = self.input.get(..n).unwrap_or(&[]);
                let ack = UpdateAck::decode(answer).map_err(|e| RobotError::Update(PublisherError::Update(e)))?;
                publisher.on_ack(&ack);
                self.courier.reply(&[]).map_err(RobotError::Courier)?;
                self.courier.send_answer(port).map_err(RobotError::Courier)?;
            }
            Event::Done => self.state = State::Feed,
        }
        Ok(())
    }

    /// Writes the round's update and starts trading it (the courier's
    /// round: the session's plus one, the hello its 0).
    fn start_round<T: Meter>(&mut self, now_ms: u64, meter: &T) -> Result<(), RobotError> {
        let t0 = meter.instructions();
        let publisher = self.publisher.as_mut().ok_or(RobotError::Feed(FeedError::Order))?;
        // The message: this robot's last estimate of its peer, then the update.
        let (head, rest) =
            self.out.split_at_mut_checked(ESTIMATE_BYTES).ok_or(RobotError::Update(PublisherError::Scratch))?;
        let head_says =
            Head { estimate: self.last_estimate, at: Some(self.map.keep_centre()), walk: self.walk.excess() };
        head_says.write(head);
        let len = publisher.next_update(&self.map, self.scratch, rest).map_err(RobotError::Update)?;
        self.marks.counts = publisher.counts();
        self.marks.update_bytes = len as u32;
        let len = ESTIMATE_BYTES + len;
        self.marks.update_instructions = meter.instructions().saturating_sub(t0);
        self.stats_at_start = self.courier.stats();
        self.courier.start(self.round.wrapping_add(1), len, now_ms).map_err(RobotError::Courier)?;
        self.state = State::Exchange { len, started_ms: now_ms };
        Ok(())
    }

    /// Trades the round's updates: the peer's applied to the copy and
    /// answered, this robot's answer taken by its publisher.
    fn exchange<L, T>(
        &mut self,
        port: &mut L,
        len: usize,
        started_ms: u64,
        now_ms: u64,
        meter: &T,
    ) -> Result<(), RobotError>
    where
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let out = self.out.get(..len).unwrap_or(&[]);
        match self.courier.step(port, out, self.input, now_ms).map_err(RobotError::Courier)? {
            Event::Busy => {}
            Event::Delivered(n) => {
                let t0 = meter.instructions();
                let replica = self.replica.as_mut().ok_or(RobotError::Feed(FeedError::Order))?;
                let message = self.input.get(..n).unwrap_or(&[]);
                let (head, update) = message.split_at_checked(ESTIMATE_BYTES).unwrap_or((&[], message));
                self.heard_before = self.heard;
                let Head { estimate: heard, at, walk } = Head::read(head);
                (self.heard, self.heard_said, self.heard_at, self.heard_walk) =
                    (heard.map(|h| h.0), heard.map_or(Said::Passed, |h| h.1), at, walk);
                let applied = replica.apply(update, self.scratch);
                self.copy_at = Some(self.map.keep_centre());
                if matches!(applied, Applied::Diverged | Applied::Restarted) {
                    self.tracker.reset();
                }
                self.marks.applied = Some(applied);
                self.courier.reply(&replica.answer().encode()).map_err(RobotError::Courier)?;
                self.courier.send_answer(port).map_err(RobotError::Courier)?;
                self.marks.update_instructions += meter.instructions().saturating_sub(t0);
            }
            Event::Done => {
                let publisher = self.publisher.as_mut().ok_or(RobotError::Feed(FeedError::Order))?;
                // An answer that does not decode says nothing: the next
                // update goes from what was acknowledged before.
                if let Some(ack) = self.courier.answer().and_then(|a| UpdateAck::decode(a).ok()) {
                    publisher.on_ack(&ack);
                }
                self.marks.exchange_ms = now_ms.saturating_sub(started_ms).min(u64::from(u32::MAX)) as u32;
                let (a, b) = (self.courier.stats(), self.stats_at_start);
                self.marks.line = CourierStats {
                    bytes_sent: a.bytes_sent - b.bytes_sent,
                    bytes_received: a.bytes_received - b.bytes_received,
                    resent: a.resent - b.resent,
                    bad_frames: a.bad_frames - b.bad_frames,
                    blocks: a.blocks - b.blocks,
                };
                self.state = State::Estimate;
            }
        }
        Ok(())
    }

    /// Estimates the peer from the copy (one long step) and reports the
    /// round; then the next round's scans.
    #[inline(never)]
    fn estimate<F: Write, T: Meter>(&mut self, feed: &mut F, meter: &T) -> Result<(), RobotError> {
        let replica = self.replica.as_ref().ok_or(RobotError::Feed(FeedError::Order))?;
        let copy = replica.map();
        let me = self.fed.me();
        let t0 = meter.instructions();
        let mut t1 = t0;
        // One work budget for the round's every search, EM and verdict.
        let mut work = Work::new(SESSION_WORK_COSTS, SESSION_WORK);
        let estimate = if copy.is_empty() || self.map.is_empty() {
            None
        } else {
            let pyramid = |e| RobotError::Align(super::AlignError::Pyramid(e));
            let matching = |e| RobotError::Align(super::AlignError::Match(e));
            let how = SESSION_PIPELINE.alignment;
            let peer_at = self.heard_at.or(replica.peer_place());
            let view = PeerView {
                estimate: self.heard,
                at: self.map.keep_centre(),
                peer_at,
                copy_at: self.copy_at,
                walk: self.pair_walk(),
            };
            // From a fix, first only what tracking reads; the whole pyramids
            // when a search is needed (no fix, or EM did not settle from it).
            let tracked = match self.tracker.fix() {
                Some(_) => {
                    let model = Pyramid::build_tracked(&self.map, Role::Model, &mut self.model).map_err(pyramid)?;
                    let scene = Pyramid::build_tracked(copy, Role::Scene, &mut self.scene).map_err(pyramid)?;
                    t1 = meter.instructions();
                    let scratch = &mut SearchScratch::new(&mut []).with_reach(self.reach).with_work(&mut work);
                    Some(self.tracker.track(&model, &scene, &how, scratch, &view).map_err(matching)?)
                }
                None => None,
            };
            match tracked.and_then(|t| t.estimate().copied()) {
                Some(e) => Some(e),
                None => {
                    let (levels, cell) = (SESSION_PIPELINE.levels, SESSION_PIPELINE.footprint_cell);
                    let model = Pyramid::build_model(&self.map, levels, cell, &mut self.model).map_err(pyramid)?;
                    let scene = copy.prepare_scene(levels, cell, &mut self.scene).map_err(pyramid)?;
                    t1 = meter.instructions();
                    let scratch = &mut SearchScratch::new(self.search).with_reach(self.reach).with_work(&mut work);
                    let e = match tracked {
                        Some(t) => self.tracker.search(&model, &scene, &how, scratch, &view, t),
                        None => self.tracker.estimate(&model, &scene, &how, scratch, &view),
                    };
                    Some(e.map_err(matching)?)
                }
            }
        };
        let estimate = match estimate {
            Some(e) if e.result.status != MatchStatus::Converged => Some(self.adopt_heard(e, &mut work)?),
            other => other,
        };
        let t2 = meter.instructions();
        let passed = estimate.as_ref().filter(|e| e.offered());
        let said = match passed.map(Estimate::status) {
            Some(MatchStatus::Converged) => Said::Converged,
            _ if self.tracker.recalling() => Said::Recalling,
            _ => Said::Passed,
        };
        self.last_estimate = passed.map(|e| (e.result.transform, said));
        let report = self.round_report(me, estimate.as_ref(), [t0, t1, t2], meter.peak_stack(), &work);
        super::send(feed, &RobotMessage::Round(report));
        self.round = self.round.wrapping_add(1);
        self.marks = RoundMarks::default();
        self.state = State::Feed;
        Ok(())
    }

    /// A robot whose own estimate failed, with no fix, adopts the fix its
    /// peer made in its last round, heard in this round's message
    /// ([`Tracker::adopt`]: EM from it on both maps, this robot's verdict
    /// with the margin): the host session's adoption, a round later, since
    /// a board hears its peer's estimate of a round with the next round's
    /// update. A fix the peer held before (its message before carried an
    /// estimate: [`made_this_round`]) is not adopted, as on the host.
    /// Returns the round's estimate: the adopted one, or `own`.
    #[inline(never)]
    fn adopt_heard(&mut self, own: Estimate, work: &mut Work) -> Result<Estimate, RobotError> {
        let (at, walk) = (self.map.keep_centre(), self.pair_walk());
        let fresh = made_this_round(self.heard_before.as_ref());
        let Some(theirs) = self.heard.filter(|_| self.marks.applied.is_some() && fresh) else {
            return Ok(own);
        };
        let Some(replica) = self.replica.as_ref().filter(|_| self.tracker.fix().is_none()) else {
            return Ok(own);
        };
        let pyramid = |e| RobotError::Align(super::AlignError::Pyramid(e));
        let copy = replica.map();
        let model = Pyramid::build_tracked(&self.map, Role::Model, &mut self.model).map_err(pyramid)?;
        let scene = Pyramid::build_tracked(copy, Role::Scene, &mut self.scene).map_err(pyramid)?;
        let peer_at = self.heard_at.or(replica.peer_place());
        let view = PeerView { estimate: None, at, peer_at, copy_at: self.copy_at, walk };
        let scratch = &mut SearchScratch::new(&mut []).with_reach(self.reach).with_work(work);
        let how = SESSION_PIPELINE.alignment;
        // With the slack where the peer reports its fix `Converged`, or it
        // is the peer's recall that this robot's own search found too, as
        // on the host.
        let (converged, recalling) = (self.heard_said == Said::Converged, self.heard_said == Said::Recalling);
        let backed = adopt_backed(converged, recalling, Some((own.kind, &own.result.transform)), &theirs, at, peer_at);
        let adopted = self.tracker.adopt((&model, &scene), &how, scratch, &view, &theirs, backed);
        Ok(adopted.map_err(|e| RobotError::Align(super::AlignError::Match(e)))?.unwrap_or(own))
    }

    fn round_report(&self, me: u8, e: Option<&Estimate>, t: [u64; 3], peak_stack: u32, work: &Work) -> RoundReport {
        let identity = crate::geometry::rows(&Isometry3::identity());
        let result = match e {
            Some(e) => MatchReport { status: e.status().code(), ..e.result.report(me) },
            None => MatchReport {
                robot_id: me,
                status: NO_EXCHANGE,
                transform: identity,
                iterations: 0,
                inliers: 0,
                overlap: 0.0,
                rmse: 0.0,
            },
        };
        let m = &self.marks;
        RoundReport {
            round: self.round,
            result,
            kind: e.map_or(0, |e| e.kind.code()),
            fix: e.map_or(0, |e| e.fix.code()),
            applied: m.applied.map_or(u8::MAX, Applied::code),
            map_voxels: self.map.len() as u32,
            copy_voxels: self.replica.as_ref().map_or(0, |r| r.map().len() as u32),
            copy_version: self.replica.as_ref().map_or(0, Replica::version),
            update_bytes: m.update_bytes,
            update_counts: [m.counts.new, m.counts.changed, m.counts.removed],
            line_bytes: [m.line.bytes_sent as u32, m.line.bytes_received as u32],
            resent: m.line.resent,
            exchange_ms: m.exchange_ms,
            map_instructions: m.map_instructions,
            update_instructions: m.update_instructions,
            prepare_instructions: t[1].saturating_sub(t[0]),
            match_instructions: t[2].saturating_sub(t[1]),
            match_work: work.spent(),
            work_cut: work.refused(),
            peak_stack,
            walk: self.walk.excess().unwrap_or(-1.0),
            walked: e.is_some_and(|e| e.walked),
        }
    }
}

impl<S, C, R, P, Q, F, L, T> Machine<F, L, T> for SessionRobot<'_, S, C, R, P, Q>
where
    S: VoxelStorage,
    C: VoxelStorage,
    R: AsRef<[ShadowEntry]> + AsMut<[ShadowEntry]>,
    P: PyramidStorage,
    Q: PyramidStorage,
    F: Read + Write + ReadReady,
    L: Read + Write + ReadReady + WriteReady,
    T: Meter,
{
    type Report = SessionEnd;

    /// Does what can be done now: reads a round's scans, trades updates
    /// over `ports[0]`, estimates the peer (one long step) and reports the
    /// round, and after the last round lingers and reports its end. On an
    /// error the robot tells its feeder where and why, best effort, and
    /// stops.
    fn poll(&mut self, feed: &mut F, ports: &mut [L], now_ms: u64, meter: &T) -> Result<Poll<SessionEnd>, RobotError> {
        let r = match ports.first_mut() {
            Some(port) => self.step(feed, port, now_ms, meter),
            None => Err(RobotError::Courier(CourierError::Config)),
        };
        match &r {
            Ok(Poll::Done(end)) => super::send(feed, &RobotMessage::SessionEnd(*end)),
            Err(RobotError::Finished) | Ok(Poll::Busy) => {}
            Err(e) => {
                self.state = State::Done;
                super::send_failure(feed, e);
            }
        }
        r
    }
}

#[cfg(test)]
mod tests;
