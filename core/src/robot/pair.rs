//! The robot of a pair: fed, it maps, exchanges maps with its peer, and
//! either aligns the peer's map to its own (it has room to receive one) or,
//! a small board's role, only sends its own and is told the peer's result
//! ([`Robot::sender`]). Both roles are this one machine; what the caller
//! gives it (a received map and pyramid storages, or none) decides.

use super::feed_in::FeedIn;
use super::memory::{carve_map, carve_pyramids, AlignParts, Capacity, OwnMap, Spare};
use super::tell::{Awaited, Awaiter, Teller};
use super::{
    align_prepared, map_config, AlignError, Machine, Meter, PhaseMarks, Poll, RobotConfig, RobotError, FOOTPRINT_CELL,
};
use crate::geometry::{from_rows, rows};
use crate::link::{Endpoint, Finished, LinkConfig, LinkError, LinkStats, Progress};
use crate::map::{LocalMap, SceneMap, ScenePoint, VoxelSink, WordStorage};
use crate::matching::search::SearchScratch;
use crate::matching::{CopiedBase, Pyramid, PyramidError, SceneSource, SplitStorage};
use crate::wire::feed::{FeedError, GlobalReport, RobotMessage, RobotReport, Setup};
use crate::wire::share::Estimate;
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// A robot that sends its map and is told the result.
pub type Sender<'a> = Robot<'a, [ScenePoint; 0]>;

/// The link's endpoint of a pair robot: it owns the robot's map while it
/// sends it, and its buffers are the turn region's words.
type PairEndpoint<'a, P> = Endpoint<'a, WordStorage<'a>, SceneMap<P>, &'a mut [u32], OwnMap<'a>>;

enum State<'a, P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> {
    Feed {
        own: OwnMap<'a>,
        received: Option<&'a mut SceneMap<P>>,
        spare: Spare<'a>,
    },
    /// Exchanging maps (the endpoint is [`Robot`]'s, outside the state:
    /// moving a state moves no kilobytes).
    Link,
    Align {
        own: OwnMap<'a>,
        received: &'a SceneMap<P>,
        stats: LinkStats,
        spare: Spare<'a>,
    },
    /// A one-sided exchange (the peer took no map): telling the peer the
    /// result before reporting it.
    Tell {
        report: RobotReport,
        teller: Teller,
    },
    /// A sender waiting to be told the peer's result.
    Await {
        voxels: usize,
        stats: LinkStats,
        awaiter: Awaiter,
    },
    Done,
}

/// One robot of a pair: its maps, its link, its alignment, driven by
/// [`Machine::poll`] (the link is `ports[0]`), in memory the caller
/// declares once ([`super::memory`]).
pub struct Robot<'a, P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> {
    state: State<'a, P>,
    /// The link's endpoint while maps are exchanged.
    endpoint: Option<PairEndpoint<'a, P>>,
    capacity: Capacity,
    fed: FeedIn,
    link_started_ms: u64,
    link_ms: u32,
    /// The peer took no map: it is told the result (its robot id).
    tell_peer: Option<u8>,
    link_config: LinkConfig,
}

impl<'a, P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> Robot<'a, P> {
    /// A robot that matches, in its two regions of words (`own`: at least
    /// [`Capacity::own_words`], `turn`: [`Capacity::turn_words`]; any
    /// contents) and receiving the peer's map into `received`
    /// (reconfigured by the set-up).
    pub fn new(
        config: RobotConfig,
        own: &'a mut [u32],
        turn: &'a mut [u32],
        capacity: Capacity,
        received: &'a mut SceneMap<P>,
    ) -> Result<Self, RobotError> {
        Self::in_memory(config, own, turn, capacity, Some(received))
    }

    fn in_memory(
        config: RobotConfig,
        own: &'a mut [u32],
        turn: &'a mut [u32],
        capacity: Capacity,
        received: Option<&'a mut SceneMap<P>>,
    ) -> Result<Self, RobotError> {
        let (storage, spare) = carve_map(own, turn, &capacity).map_err(RobotError::Memory)?;
        // The set-up names the voxel size; until then the map waits empty.
        let own = LocalMap::new(storage, map_config(0.5)).map_err(RobotError::Config)?;
        Ok(Robot {
            state: State::Feed { own, received, spare },
            endpoint: None,
            capacity,
            fed: FeedIn::new(config),
            link_started_ms: 0,
            link_ms: 0,
            tell_peer: None,
            link_config: LinkConfig::default(),
        })
    }

    /// The set-up, once it arrived.
    pub fn setup(&self) -> Option<&Setup> {
        self.fed.setup.as_ref()
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
                if self.fed.read(feed, own, received.as_deref_mut(), false, now_ms, meter)? {
                    self.start_link(now_ms)?;
                }
                return Ok(Poll::Busy);
            }
            State::Link => {
                let endpoint = self.endpoint.as_mut().ok_or(RobotError::Finished)?;
                let progress = endpoint.step(link, now_ms).map_err(RobotError::Link)?;
                if progress == Progress::Busy {
                    return Ok(Poll::Busy);
                }
            }
            _ => {}
        }
        match self.state {
            State::Link => self.finish_link(now_ms),
            State::Align { .. } => self.run_align(now_ms, meter),
            _ => self.step_told(link, now_ms, meter),
        }
    }

    /// The exchange is done (the step before said so): the robot aligns,
    /// or, a sender, awaits the peer's result. Apart from [`Robot::step`]
    /// (never inlined), as each stage below: a stage's moved state stays
    /// out of the frames under the matcher, the deepest stack.
    #[inline(never)]
    fn finish_link(&mut self, now_ms: u64) -> Result<Poll, RobotError> {
        let State::Link = core::mem::replace(&mut self.state, State::Done) else {
            return Err(RobotError::Finished);
        };
        let endpoint = self.endpoint.take().ok_or(RobotError::Finished)?;
        self.link_ms = now_ms.saturating_sub(self.link_started_ms).min(u64::from(u32::MAX)) as u32;
        let stats = endpoint.stats();
        let peer = endpoint.peer_id();
        if endpoint.peer_takes_map() == Some(false) {
            self.tell_peer = peer;
        }
        let Finished { map: Some(own), scratch: Some(scratch), staging, buffers: link } = endpoint.finish() else {
            return Err(RobotError::Link(LinkError::Setup));
        };
        self.state = match staging {
            Some(received) => State::Align { own, received, stats, spare: Spare { scratch, link } },
            // A sender: no received map; the peer tells the result.
            None => {
                let peer = peer.ok_or(RobotError::Link(LinkError::Silent))?;
                State::Await { voxels: own.len(), stats, awaiter: Awaiter::new(self.fed.me(), peer, now_ms) }
            }
        };
        Ok(Poll::Busy)
    }

    /// Aligns; then reports, or tells a peer that took no map first.
    #[inline(never)]
    fn run_align<T: Meter>(&mut self, now_ms: u64, meter: &T) -> Result<Poll, RobotError> {
        let State::Align { own, received, stats, spare } = core::mem::replace(&mut self.state, State::Done) else {
            return Err(RobotError::Finished);
        };
        let (report, estimate) = self.align(own, received, &stats, spare, meter)?;
        match self.tell_peer {
            Some(peer) => {
                let estimate = Estimate { b: peer, ..estimate };
                self.state = State::Tell { report, teller: Teller::new(estimate, now_ms) };
                Ok(Poll::Busy)
            }
            None => Ok(Poll::Done(report)),
        }
    }

    /// Telling the peer the result, or awaiting the peer's.
    #[inline(never)]
    fn step_told<L, T>(&mut self, link: &mut L, now_ms: u64, meter: &T) -> Result<Poll, RobotError>
    where
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let io = |_| RobotError::Link(LinkError::Io(embedded_io::ErrorKind::Other));
        match &mut self.state {
            State::Tell { report, teller } => {
                if teller.step(link, now_ms, &self.link_config).map_err(io)? {
                    let report = *report;
                    self.state = State::Done;
                    return Ok(Poll::Done(report));
                }
                Ok(Poll::Busy)
            }
            State::Await { voxels, stats, awaiter } => {
                match awaiter.step(link, now_ms, &self.link_config).map_err(io)? {
                    Awaited::Busy => Ok(Poll::Busy),
                    Awaited::Silent => {
                        self.state = State::Done;
                        Err(RobotError::Link(LinkError::Silent))
                    }
                    Awaited::Told(e) => {
                        let (voxels, stats) = (*voxels, *stats);
                        let report = self.told(voxels, &stats, &e, meter.peak_stack());
                        self.state = State::Done;
                        Ok(Poll::Done(report))
                    }
                }
            }
            _ => Err(RobotError::Finished),
        }
    }

    #[inline(never)]
    fn start_link(&mut self, now_ms: u64) -> Result<(), RobotError> {
        let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
        let State::Feed { own, received, spare } = core::mem::replace(&mut self.state, State::Done) else {
            return Err(RobotError::Feed(FeedError::Order));
        };
        let config = LinkConfig { silence_ms: setup.silence_ms, ..LinkConfig::default() };
        self.link_config = config;
        let id = setup.robot_id;
        let Spare { scratch, link } = spare;
        let endpoint = Endpoint::new(config, id, u32::from(id), 0, Some((own, scratch)), received, link)
            .map_err(RobotError::Link)?;
        self.link_started_ms = now_ms;
        self.endpoint = Some(endpoint);
        self.state = State::Link;
        Ok(())
    }

    /// Prepares both maps and aligns them. The own map's voxels become the
    /// model's level 0 where they lie; the pyramids' other parts are carved
    /// out of what that leaves and of the turn region's words, which the
    /// link gave back.
    fn align<T: Meter>(
        &mut self,
        own: OwnMap<'a>,
        received: &SceneMap<P>,
        stats: &LinkStats,
        spare: Spare<'a>,
        meter: &T,
    ) -> Result<(RobotReport, Estimate), RobotError> {
        let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
        let prior = setup.prior.as_ref().map(from_rows);
        let voxels = own.len();
        let mut marks = PhaseMarks::default();
        marks.mark(0, meter);
        let empty = RobotError::Align(AlignError::Pyramid(PyramidError::EmptyMap));
        let (copied, level0, leaves) = CopiedBase::compact(own).ok_or(empty)?;
        let AlignParts { model, scene, search } =
            carve_pyramids(leaves, spare, &self.capacity).map_err(RobotError::Memory)?;
        let model = SplitStorage { level0, rest: model };
        let pyramid = |e| RobotError::Align(AlignError::Pyramid(e));
        let levels = self.capacity.levels;
        let model = Pyramid::build_copied(copied, levels, FOOTPRINT_CELL, model).map_err(pyramid)?;
        let scene = received.prepare_scene(levels, FOOTPRINT_CELL, scene).map_err(pyramid)?;
        marks.mark(1, meter);
        let on_phase = |k| marks.mark(k, meter);
        let (result, located) = if search.is_empty() {
            align_on_stack(&model, &scene, prior.as_ref(), self.capacity.em_iterations, on_phase)
        } else {
            let scratch = &mut SearchScratch::new(search);
            align_prepared(&model, &scene, prior.as_ref(), self.capacity.em_iterations, scratch, on_phase)
        }
        .map_err(RobotError::Align)?;
        let estimate = result.estimate(setup.robot_id, 0);
        let mut report = self.fed.report(voxels, stats, self.link_ms, meter.peak_stack());
        report.result = result.report(setup.robot_id);
        report.received_voxels = received.len() as u32;
        report.global = located.as_ref().map(GlobalReport::from);
        marks.write_to(&mut report);
        Ok((report, estimate))
    }

    /// The report of a sender told the peer's result `e` (the peer's
    /// `T_peer_me`, reported as `T_me_peer`, with the peer's status).
    fn told(&self, voxels: usize, stats: &LinkStats, e: &Estimate, peak_stack: u32) -> RobotReport {
        let mut report = self.fed.report(voxels, stats, self.link_ms, peak_stack);
        report.result.status = e.status;
        report.result.transform = rows(&e.transform().inverse());
        report
    }
}

/// [`align_prepared`] with the searches' caches on the stack (a robot
/// whose capacity plans no words for them). Never inlined: a robot that
/// plans them carries no such frame.
#[inline(never)]
fn align_on_stack<P: crate::matching::PyramidStorage, Q: crate::matching::PyramidStorage>(
    model: &Pyramid<'_, P>,
    scene: &Pyramid<'_, Q>,
    prior: Option<&crate::geometry::Isometry3<f32>>,
    iterations: u32,
    on_phase: impl FnMut(u8),
) -> Result<(crate::matching::MatchResult, Option<crate::matching::global::Searched>), AlignError> {
    let mut words = [0u32; SearchScratch::WINDOWED];
    align_prepared(model, scene, prior, iterations, &mut SearchScratch::new(&mut words), on_phase)
}

impl<'a> Sender<'a> {
    /// A robot that sends its map and is told the result (a board with no
    /// room for a second map), in its two regions of words (sized by
    /// [`Capacity::sender`]).
    pub fn sender(
        config: RobotConfig,
        own: &'a mut [u32],
        turn: &'a mut [u32],
        capacity: Capacity,
    ) -> Result<Self, RobotError> {
        Self::in_memory(config, own, turn, capacity, None)
    }
}

impl<P, F, L, T> Machine<F, L, T> for Robot<'_, P>
where
    P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>,
    F: Read + Write + ReadReady,
    L: Read + Write + ReadReady + WriteReady,
    T: Meter,
{
    type Report = RobotReport;

    /// Does what can be done now: reads the feed, exchanges maps over
    /// `ports[0]`, aligns (one long step) or awaits the peer's result,
    /// reports. On an error the robot tells its feeder where and why, best
    /// effort, and stops.
    fn poll(&mut self, feed: &mut F, ports: &mut [L], now_ms: u64, meter: &T) -> Result<Poll, RobotError> {
        let r = match ports.first_mut() {
            Some(link) => self.step(feed, link, now_ms, meter),
            None => Err(RobotError::Link(LinkError::Setup)),
        };
        match &r {
            Ok(Poll::Done(report)) => super::send(feed, &RobotMessage::Report(*report)),
            Err(RobotError::Finished) | Ok(Poll::Busy) => {}
            Err(e) => {
                self.state = State::Done;
                super::send_failure(feed, e);
            }
        }
        r
    }
}
