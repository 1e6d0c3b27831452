//! The robot of a pair: fed, it maps, exchanges maps with its peer, and
//! either aligns the peer's map to its own (it has room to receive one) or,
//! a small board's role, only sends its own and is told the peer's result
//! ([`Robot::sender`]). Both roles are this one machine; what the caller
//! gives it (a received map and pyramid storages, or none) decides.

use super::feed_in::FeedIn;
use super::tell::{Awaited, Awaiter, Teller};
use super::{Machine, Meter, PhaseMarks, Poll, RobotConfig, RobotError};
use crate::geometry::{from_rows, rows};
use crate::link::{Endpoint, LinkBuffers, LinkConfig, LinkError, LinkStats, Progress};
use crate::map::{LocalMap, SceneMap, ScenePoint, VoxelSink, VoxelStorage};
use crate::matching::{ArrayPyramidStorage, PyramidStorage, SceneSource};
use crate::wire::feed::{FeedError, GlobalReport, RobotMessage, RobotReport, Setup};
use crate::wire::share::Estimate;
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// A received map that is never there: a sender's.
pub type NoScene = SceneMap<[ScenePoint; 0]>;

/// A pyramid storage that is never used: a sender's.
pub type NoPyramid = ArrayPyramidStorage<0, 0, 0>;

/// A robot that sends its map and is told the result.
pub type Sender<'a, M> = Robot<'a, M, NoScene, NoPyramid, NoPyramid>;

// The link's state (its frame buffer) is the large variant; without an
// allocator there is nothing to box it in, and a robot holds one state.
#[allow(clippy::large_enum_variant)]
enum State<'a, M: VoxelStorage, R: VoxelSink + SceneSource> {
    Feed {
        own: &'a mut LocalMap<M>,
        received: Option<&'a mut R>,
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
/// [`Machine::poll`] (the link is `ports[0]`).
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
            state: State::Feed { own, received: Some(received), scratch, buffers },
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
            State::Link { endpoint, .. } => {
                let progress = endpoint.step(link, now_ms).map_err(RobotError::Link)?;
                if progress == Progress::Busy {
                    return Ok(Poll::Busy);
                }
            }
            _ => {}
        }
        let io = |_| RobotError::Link(LinkError::Io(embedded_io::ErrorKind::Other));
        match core::mem::replace(&mut self.state, State::Done) {
            State::Feed { .. } => Err(RobotError::Finished),
            State::Link { own, endpoint } => {
                // The exchange is done (the step above said so).
                self.link_ms = now_ms.saturating_sub(self.link_started_ms).min(u64::from(u32::MAX)) as u32;
                let stats = endpoint.stats();
                let peer = endpoint.peer_id();
                if endpoint.peer_takes_map() == Some(false) {
                    self.tell_peer = peer;
                }
                self.state = match endpoint.into_parts() {
                    (_, Some(received)) => State::Align { own, received, stats },
                    // A sender: no received map; the peer tells the result.
                    (_, None) => {
                        let peer = peer.ok_or(RobotError::Link(LinkError::Silent))?;
                        State::Await { voxels: own.len(), stats, awaiter: Awaiter::new(self.fed.me(), peer, now_ms) }
                    }
                };
                Ok(Poll::Busy)
            }
            State::Align { own, received, stats } => {
                let (report, estimate) = self.align(own, received, &stats, meter)?;
                match self.tell_peer {
                    Some(peer) => {
                        let estimate = Estimate { b: peer, ..estimate };
                        self.state = State::Tell { report, teller: Teller::new(estimate, now_ms) };
                        Ok(Poll::Busy)
                    }
                    None => Ok(Poll::Done(report)),
                }
            }
            State::Tell { report, mut teller } => {
                if teller.step(link, now_ms, &self.link_config).map_err(io)? {
                    return Ok(Poll::Done(report));
                }
                self.state = State::Tell { report, teller };
                Ok(Poll::Busy)
            }
            State::Await { voxels, stats, mut awaiter } => {
                match awaiter.step(link, now_ms, &self.link_config).map_err(io)? {
                    Awaited::Busy => {
                        self.state = State::Await { voxels, stats, awaiter };
                        Ok(Poll::Busy)
                    }
                    Awaited::Silent => Err(RobotError::Link(LinkError::Silent)),
                    Awaited::Told(e) => Ok(Poll::Done(self.told(voxels, &stats, &e, meter.peak_stack()))),
                }
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
        let endpoint = Endpoint::new(config, id, u32::from(id), 0, Some((own, scratch)), received, buffers)
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
        let mut report = self.fed.report(own.len(), stats, self.link_ms, meter.peak_stack());
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

impl<'a, M: VoxelStorage> Sender<'a, M> {
    /// A robot that sends its map and is told the result (a board with no
    /// room for a second map): over the caller's buffers, its map
    /// (reconfigured by the set-up), a scratch of one `u32` per voxel, the
    /// link's buffers.
    pub fn sender(
        config: RobotConfig,
        own: &'a mut LocalMap<M>,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
    ) -> Self {
        Robot {
            state: State::Feed { own, received: None, scratch, buffers },
            pyramids: None,
            fed: FeedIn::new(config),
            link_started_ms: 0,
            link_ms: 0,
            tell_peer: None,
            link_config: LinkConfig::default(),
        }
    }
}

impl<M, R, P, Q, F, L, T> Machine<F, L, T> for Robot<'_, M, R, P, Q>
where
    M: VoxelStorage,
    R: VoxelSink + SceneSource,
    P: PyramidStorage,
    Q: PyramidStorage,
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
