//! What a robot takes from its feed line (set-up, team size, points fused
//! into its map) and the report every role builds from it.

use super::{Meter, RobotConfig, RobotError};
use crate::geometry::{rows, Isometry3};
use crate::link::LinkStats;
use crate::map::{LocalMap, VoxelSink, VoxelStorage};
use crate::wire::feed::{FeedError, FeedMessage, RobotMessage, RobotReport, Setup};
use crate::wire::frame::Deframer;
use crate::wire::report::MatchReport;
use crate::wire::share::NO_EXCHANGE;
use embedded_io::{Read, ReadReady, Write};

/// What a robot took from its feed line: the set-up, the points inserted,
/// and the feed's framing and timing. Shared by the pair robot ([`super::Robot`]) and the
/// team robot ([`super::team`]).
pub(super) struct FeedIn {
    pub(super) config: RobotConfig,
    pub(super) deframer: Deframer,
    pub(super) setup: Option<Setup>,
    /// Robots in the team (a team robot only).
    pub(super) team: Option<u8>,
    pub(super) points: u32,
    pub(super) map_instructions: u64,
    pub(super) last_fed_ms: Option<u64>,
}

impl FeedIn {
    pub(super) fn new(config: RobotConfig) -> Self {
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
    /// robot refuses it. Never inlined: its frame (a feed frame) stays out
    /// of the matcher's stack.
    #[inline(never)]
    pub(super) fn read<F: Read + Write + ReadReady, M: VoxelStorage, R: VoxelSink, T: Meter>(
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
            super::send(feed, &RobotMessage::Ready);
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
                        let config = super::map_config(s.resolution);
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
                        *points += super::insert_points(own, data).map_err(RobotError::Points)?;
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

    /// The one report builder: what every robot reports of its feed, its
    /// map and one exchange (`stats`, `link_ms`), with no match yet (status
    /// [`NO_EXCHANGE`], identity transform); a role fills in its result.
    pub(super) fn report(&self, map_voxels: usize, stats: &LinkStats, link_ms: u32, peak_stack: u32) -> RobotReport {
        RobotReport {
            result: MatchReport {
                robot_id: self.setup.map_or(0, |s| s.robot_id),
                status: NO_EXCHANGE,
                transform: rows(&Isometry3::identity()),
                iterations: 0,
                inliers: 0,
                overlap: 0.0,
                rmse: 0.0,
            },
            points: self.points,
            map_voxels: map_voxels as u32,
            received_voxels: 0,
            bytes_sent: stats.bytes_sent,
            bytes_received: stats.bytes_received,
            retransmissions: stats.retransmissions,
            link_ms,
            map_instructions: self.map_instructions,
            prepare_instructions: 0,
            locate_instructions: 0,
            match_instructions: 0,
            global: None,
            peak_stack,
            link_bytes_while_matching: 0,
        }
    }

    /// The robot's id (0 until the set-up arrived).
    pub(super) fn me(&self) -> u8 {
        self.setup.map_or(0, |s| s.robot_id)
    }
}
