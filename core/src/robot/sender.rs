//! A robot too small to hold its peer's map (an STM32F405 with 192 KiB of
//! RAM: its own map of 4,096 voxels is 128 KiB): fed like the pair
//! [`Robot`](super::Robot), it builds its map, sends it over the link and
//! takes none (its `Hello` says so), then waits for the peer's result
//! (`T_peer_me` as a [`ShareMessage::Estimate`](crate::wire::share::ShareMessage),
//! resent until acknowledged) and reports the inverse as its own
//! `T_me_peer`, with the peer's status. No pyramids, no matcher: its
//! RAM is its map, the link's buffers and a scratch.

use super::tell::{Awaited, Awaiter};
use super::{FeedIn, Meter, Poll, RobotConfig, RobotError};
use crate::geometry::rows;
use crate::link::{Endpoint, LinkBuffers, LinkConfig, LinkError, LinkStats, Progress};
use crate::map::{LocalMap, VoxelStorage};
use crate::wire::feed::{FeedError, RobotMessage, RobotReport};
use crate::wire::report::MatchReport;
use crate::wire::share::Estimate;
use embedded_io::{Read, ReadReady, Write, WriteReady};

#[allow(clippy::large_enum_variant)]
enum State<'a, M: VoxelStorage> {
    Feed { own: &'a mut LocalMap<M>, scratch: &'a mut [u32], buffers: &'a mut LinkBuffers },
    Link { own: &'a LocalMap<M>, endpoint: Endpoint<'a, M, LocalMap<M>> },
    Await { own: &'a LocalMap<M>, stats: LinkStats, awaiter: Awaiter },
    Done,
}

/// A robot that sends its map and is told the result (see the module
/// documentation), driven by [`SenderRobot::poll`] like the pair robot.
pub struct SenderRobot<'a, M: VoxelStorage> {
    state: State<'a, M>,
    fed: FeedIn,
    link_started_ms: u64,
    link_ms: u32,
    link_config: LinkConfig,
}

impl<'a, M: VoxelStorage> SenderRobot<'a, M> {
    /// A robot over the caller's buffers: its map (reconfigured by the
    /// set-up), a scratch of one `u32` per voxel, the link's buffers.
    pub fn new(
        config: RobotConfig,
        own: &'a mut LocalMap<M>,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
    ) -> Self {
        SenderRobot {
            state: State::Feed { own, scratch, buffers },
            fed: FeedIn::new(config),
            link_started_ms: 0,
            link_ms: 0,
            link_config: LinkConfig::default(),
        }
    }

    /// Does what can be done now: reads the feed, sends its map, waits for
    /// the peer's result, reports. On an error the robot tells its feeder
    /// where and why, best effort, and stops.
    pub fn poll<F, L, T>(&mut self, feed: &mut F, link: &mut L, now_ms: u64, meter: &T) -> Result<Poll, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let r = self.step(feed, link, now_ms, meter);
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

    fn step<F, L, T>(&mut self, feed: &mut F, link: &mut L, now_ms: u64, meter: &T) -> Result<Poll, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let io = |_| RobotError::Link(LinkError::Io(embedded_io::ErrorKind::Other));
        // Waiting states are polled in place (see the pair robot).
        match &mut self.state {
            State::Feed { own, .. } => {
                let ended = self.fed.read(feed, own, None::<&mut LocalMap<M>>, false, now_ms, meter)?;
                if !ended {
                    return Ok(Poll::Busy);
                }
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
            // The feed ended (read above).
            State::Feed { own, scratch, buffers } => {
                let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
                let own: &'a LocalMap<M> = own;
                self.link_config = LinkConfig { silence_ms: setup.silence_ms, ..LinkConfig::default() };
                let id = setup.robot_id;
                let endpoint =
                    Endpoint::new(self.link_config, id, u32::from(id), 0, Some((own, scratch)), None, buffers)
                        .map_err(RobotError::Link)?;
                self.link_started_ms = now_ms;
                self.state = State::Link { own, endpoint };
                Ok(Poll::Busy)
            }
            // The exchange is done (stepped above).
            State::Link { own, endpoint } => {
                self.link_ms = now_ms.saturating_sub(self.link_started_ms).min(u64::from(u32::MAX)) as u32;
                let me = self.fed.setup.map_or(0, |s| s.robot_id);
                let peer = endpoint.peer_id().ok_or(RobotError::Link(LinkError::Silent))?;
                let stats = endpoint.stats();
                self.state = State::Await { own, stats, awaiter: Awaiter::new(me, peer, now_ms) };
                Ok(Poll::Busy)
            }
            State::Await { own, stats, mut awaiter } => {
                match awaiter.step(link, now_ms, &self.link_config).map_err(io)? {
                    Awaited::Busy => {
                        self.state = State::Await { own, stats, awaiter };
                        Ok(Poll::Busy)
                    }
                    Awaited::Silent => Err(RobotError::Link(LinkError::Silent)),
                    Awaited::Told(e) => Ok(Poll::Done(self.report(own.len(), &stats, &e, meter.peak_stack()))),
                }
            }
            State::Done => Err(RobotError::Finished),
        }
    }

    /// The report of a robot told the peer's result `e` (the peer's
    /// `T_peer_me`, reported as `T_me_peer`).
    fn report(&self, map_voxels: usize, stats: &LinkStats, e: &Estimate, peak_stack: u32) -> RobotReport {
        let me = self.fed.setup.map_or(0, |s| s.robot_id);
        let transform = rows(&e.transform().inverse());
        RobotReport {
            result: MatchReport {
                robot_id: me,
                status: e.status,
                transform,
                iterations: 0,
                inliers: 0,
                overlap: 0.0,
                rmse: 0.0,
            },
            points: self.fed.points,
            map_voxels: map_voxels as u32,
            received_voxels: 0,
            bytes_sent: stats.bytes_sent,
            bytes_received: stats.bytes_received,
            retransmissions: stats.retransmissions,
            link_ms: self.link_ms,
            map_instructions: self.fed.map_instructions,
            prepare_instructions: 0,
            locate_instructions: 0,
            match_instructions: 0,
            global: None,
            peak_stack,
            link_bytes_while_matching: 0,
        }
    }
}
