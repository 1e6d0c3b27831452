//! One robot of a team of N, as a poll-driven step machine like the pair
//! [`Robot`](super::Robot): fed its scans (a set-up, then
//! [`FeedMessage::Team`](crate::wire::feed::FeedMessage::Team), then the
//! points), it builds its map, then meets its peers one per round over a
//! mesh of point-to-point lines (a board's UARTs: `ports[k]` joins the
//! k-th peer in index order). In each round it exchanges maps with that
//! peer and matches the peer's map to its own, with no prior; the rounds
//! follow the circle method, so every pair meets once and the team needs
//! N-1 rounds (N for an odd team). Then, in the same rounds, each robot
//! sends each peer its own estimates ([`crate::wire::share`]), so every
//! robot holds all of them, checks them for consistency
//! ([`crate::team::consistent_set`]) and solves the pose graph
//! ([`crate::team::solve`]): every robot reports the same placement of the
//! whole team in robot 0's frame.
//!
//! Memory: the pair robot's buffers serve every round (one received map,
//! one set of link buffers, one pair of pyramid storages); the team's
//! table of estimates lives in the scratch once the maps have crossed
//! (the scratch orders the robot's own map for the link only).

use super::feed_in::FeedIn;
use super::{Machine, Meter, PhaseMarks, Poll, RobotConfig, RobotError};
use crate::geometry::{from_rows, rows};
use crate::link::{Endpoint, Finished, LinkBuffers, LinkConfig, LinkError, LinkStats, Progress};
use crate::map::{LocalMap, VoxelSink, VoxelStorage};
use crate::matching::search::SearchScratch;
use crate::matching::{MatchStatus, PyramidStorage, SceneSource};
use crate::team::{consistent_set, solve, RelativePose, MAX_ROBOTS};
use crate::wire::feed::{FeedError, PlacedRobot, RobotMessage, RobotReport, TeamEnd};
use crate::wire::frame::{Deframer, MAX_FRAME};
use crate::wire::share::{Estimate, ShareMessage, ESTIMATE_WORDS, NO_EXCHANGE};
use embedded_io::{Read, ReadReady, Write, WriteReady};
use nalgebra::Matrix6;

/// Scratch words the team's table of estimates needs (a robot's scratch,
/// one word per voxel, is far larger).
pub const TABLE_WORDS: usize = MAX_ROBOTS * MAX_ROBOTS * ESTIMATE_WORDS;

/// How long a robot resends its estimates to a peer that has not
/// acknowledged them (ms).
const SHARE_RESEND_MS: u64 = 250;

/// Doublings of the resend wait while the peer says nothing (at most 4 s).
const SHARE_BACKOFF: u8 = 4;

/// Pose-graph iterations.
const SOLVE_ITERATIONS: u32 = 50;

/// The peer robot `me` meets in `round` of a team of `robots` (circle
/// method: robot 0 stays, the others turn; an odd team gets a bye per
/// round), or `None` for a bye.
pub fn peer_in_round(robots: u8, me: u8, round: u8) -> Option<u8> {
    let n = robots + robots % 2;
    if me >= robots || n < 2 {
        return None;
    }
    let m = n - 1;
    // Position on the circle: robot 0 fixed at m; others turn by the round.
    let pos = |r: u8| if r == 0 { m } else { (r - 1 + m - round % m) % m };
    let robot_at = |p: u8| if p == m { 0 } else { (p + round % m) % m + 1 };
    let p = pos(me);
    let partner = if p == m {
        0
    } else if p == 0 {
        m
    } else {
        m - p
    };
    let other = robot_at(partner);
    (other < robots && other != me).then_some(other)
}

/// Rounds a team of `robots` needs.
pub fn rounds(robots: u8) -> u8 {
    (robots + robots % 2).saturating_sub(1)
}

/// The port of peer `peer` on robot `me`: peers in index order, `me`
/// skipped.
pub fn port_of(me: u8, peer: u8) -> usize {
    usize::from(if peer < me { peer } else { peer - 1 })
}

#[allow(clippy::large_enum_variant)]
enum Phase<'a, M: VoxelStorage, R: VoxelSink + SceneSource> {
    Feed {
        own: &'a mut LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
    },
    /// Between rounds: everything free for the next one.
    Ready {
        own: &'a LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
    },
    Link {
        own: &'a LocalMap<M>,
        peer: u8,
        started: u64,
        endpoint: Endpoint<'a, M, R>,
    },
    Share {
        scratch: &'a mut [u32],
        /// The current share round's peer and state.
        with: Option<ShareRound>,
    },
    Done,
}

/// Sharing estimates with one peer.
struct ShareRound {
    peer: u8,
    last_sent: Option<u64>,
    last_heard: u64,
    /// Resends since the peer was last heard: each doubles the wait
    /// before the next (a peer still busy with its maps reads them all
    /// later, so a fixed pace would only pile them up).
    unanswered: u8,
    /// Bit b: the peer holds our estimate of b.
    acked: u8,
    /// The peer said it is finished.
    peer_finished: bool,
    /// We hold all its estimates and it acknowledged all ours (since).
    done_at: Option<u64>,
    ack_due: bool,
    deframer: Deframer,
}

/// One robot of a team (see the module documentation).
pub struct TeamRobot<'a, M: VoxelStorage, R: VoxelSink + SceneSource, P: PyramidStorage, Q: PyramidStorage> {
    phase: Phase<'a, M, R>,
    model: P,
    scene: Q,
    fed: FeedIn,
    round: u8,
    /// Our estimates, by peer index (`None`: not met yet).
    estimates: [Option<Estimate>; MAX_ROBOTS],
    share_started: u64,
    link_config: LinkConfig,
    em_iterations: u32,
}

impl<'a, M: VoxelStorage, R: VoxelSink + SceneSource, P: PyramidStorage, Q: PyramidStorage> TeamRobot<'a, M, R, P, Q> {
    /// A team robot over the caller's buffers, as [`Robot::new`](super::Robot::new);
    /// the scratch must also hold [`TABLE_WORDS`].
    pub fn new(
        config: RobotConfig,
        own: &'a mut LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
        model: P,
        scene: Q,
    ) -> Self {
        TeamRobot {
            phase: Phase::Feed { own, received, scratch, buffers },
            model,
            scene,
            fed: FeedIn::new(config),
            round: 0,
            estimates: [None; MAX_ROBOTS],
            share_started: 0,
            link_config: LinkConfig::default(),
            em_iterations: super::EM_ITERATIONS,
        }
    }

    /// The same robot refining in at most `n` EM iterations (a capacity's
    /// [`em_iterations`](super::Capacity::em_iterations); default
    /// [`super::EM_ITERATIONS`]).
    pub fn with_em_iterations(mut self, n: u32) -> Self {
        self.em_iterations = n;
        self
    }

    fn me(&self) -> u8 {
        self.fed.me()
    }

    fn robots(&self) -> u8 {
        self.fed.team.unwrap_or(0)
    }

    /// One step.
    #[inline(never)]
    fn step<F, L, T>(
        &mut self,
        feed: &mut F,
        ports: &mut [L],
        now_ms: u64,
        meter: &T,
    ) -> Result<Poll<TeamEnd>, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        // Waiting phases are polled in place (see the pair robot); the
        // phase moves out only to change.
        let mut progress = Ok(Progress::Done);
        let me = self.me();
        match &mut self.phase {
            Phase::Feed { own, received, .. } => {
                let ended = self.fed.read(feed, own, Some(&mut **received), true, now_ms, meter)?;
                if !ended {
                    return Ok(Poll::Busy);
                }
            }
            Phase::Link { peer, endpoint, .. } => {
                let port = ports.get_mut(port_of(me, *peer)).ok_or(RobotError::Link(LinkError::Setup))?;
                progress = endpoint.step(port, now_ms);
                if progress == Ok(Progress::Busy) {
                    return Ok(Poll::Busy);
                }
            }
            _ => {}
        }
        match core::mem::replace(&mut self.phase, Phase::Done) {
            // The feed ended (read above).
            Phase::Feed { own, received, scratch, buffers } => {
                let setup = self.fed.setup.ok_or(RobotError::Feed(FeedError::Order))?;
                self.link_config = LinkConfig { silence_ms: setup.silence_ms, ..LinkConfig::default() };
                if ports.len() + 1 < usize::from(self.robots()) {
                    return Err(RobotError::Link(LinkError::Setup));
                }
                self.phase = Phase::Ready { own, received, scratch, buffers };
                Ok(Poll::Busy)
            }
            Phase::Ready { own, received, scratch, buffers } => {
                self.next_round(own, received, scratch, buffers, now_ms)?;
                Ok(Poll::Busy)
            }
            // The exchange ended (stepped above, `progress`).
            Phase::Link { own, peer, started, endpoint } => {
                let stats = endpoint.stats();
                let Finished { scratch: Some(scratch), staging: Some(received), buffers, .. } = endpoint.finish()
                else {
                    return Err(RobotError::Link(LinkError::Setup));
                };
                let link_ms = now_ms.saturating_sub(started).min(u64::from(u32::MAX)) as u32;
                let report = match progress {
                    Ok(_) => self.match_peer(own, received, scratch, peer, &stats, link_ms, meter)?,
                    // The maps never met: no estimate of this peer.
                    Err(_) => self.unmatched(own, peer, &stats, link_ms, meter),
                };
                super::send(feed, &RobotMessage::Matched { peer, report });
                self.round += 1;
                self.phase = Phase::Ready { own, received, scratch, buffers };
                Ok(Poll::Busy)
            }
            Phase::Share { scratch, with } => self.share(feed, ports, scratch, with, now_ms, meter),
            Phase::Done => Err(RobotError::Finished),
        }
    }

    /// Starts the next map round (skipping byes), or the sharing.
    fn next_round(
        &mut self,
        own: &'a LocalMap<M>,
        received: &'a mut R,
        scratch: &'a mut [u32],
        buffers: &'a mut LinkBuffers,
        now_ms: u64,
    ) -> Result<(), RobotError> {
        let (me, n) = (self.me(), self.robots());
        while self.round < rounds(n) && peer_in_round(n, me, self.round).is_none() {
            self.round += 1;
        }
        match peer_in_round(n, me, self.round).filter(|_| self.round < rounds(n)) {
            Some(peer) => {
                let endpoint = Endpoint::new(
                    self.link_config,
                    me,
                    u32::from(me),
                    0,
                    Some((own, scratch)),
                    Some(received),
                    buffers,
                )
                .map_err(RobotError::Link)?;
                self.phase = Phase::Link { own, peer, started: now_ms, endpoint };
            }
            None => {
                // The maps are done with: the scratch holds the team's table.
                let table = scratch.get_mut(..TABLE_WORDS).ok_or(RobotError::Link(LinkError::Setup))?;
                table.fill(0);
                for e in self.estimates.iter().flatten() {
                    put(table, e);
                }
                self.round = 0;
                self.share_started = now_ms;
                self.phase = Phase::Share { scratch, with: None };
            }
        }
        Ok(())
    }

    /// Matches the peer's map to ours; the searches' caches in `scratch`
    /// (it ordered our map for the link, and is idle until the next).
    #[allow(clippy::too_many_arguments)]
    fn match_peer<T: Meter>(
        &mut self,
        own: &LocalMap<M>,
        received: &R,
        scratch: &mut [u32],
        peer: u8,
        stats: &LinkStats,
        link_ms: u32,
        meter: &T,
    ) -> Result<RobotReport, RobotError> {
        let storages = (&mut self.model, &mut self.scene);
        let search = &mut SearchScratch::new(scratch);
        let (result, located, marks) = PhaseMarks::align(own, received, storages, self.em_iterations, search, meter)?;
        let me = self.me();
        if let Some(slot) = self.estimates.get_mut(usize::from(peer)) {
            *slot = Some(result.estimate(me, peer));
        }
        let mut report = self.fed.report(own.len(), stats, link_ms, meter.peak_stack());
        report.result = result.report(me);
        report.received_voxels = received.len() as u32;
        marks.write_to(&mut report);
        report.global = located.as_ref().map(crate::wire::feed::GlobalReport::from);
        Ok(report)
    }

    fn unmatched<T: Meter>(
        &mut self,
        own: &LocalMap<M>,
        peer: u8,
        stats: &LinkStats,
        link_ms: u32,
        meter: &T,
    ) -> RobotReport {
        let me = self.me();
        let none = Estimate::none(me, peer);
        if let Some(slot) = self.estimates.get_mut(usize::from(peer)) {
            *slot = Some(none);
        }
        let mut report = self.fed.report(own.len(), stats, link_ms, meter.peak_stack());
        report.result.status = NO_EXCHANGE;
        report
    }

    /// The sharing rounds: with each peer in turn, send our estimates
    /// until acknowledged, take theirs, acknowledge; then solve.
    #[inline(never)]
    fn share<F, L, T>(
        &mut self,
        feed: &mut F,
        ports: &mut [L],
        scratch: &'a mut [u32],
        with: Option<ShareRound>,
        now_ms: u64,
        meter: &T,
    ) -> Result<Poll<TeamEnd>, RobotError>
    where
        F: Read + Write + ReadReady,
        L: Read + Write + ReadReady + WriteReady,
        T: Meter,
    {
        let (me, n) = (self.me(), self.robots());
        let table = scratch.get_mut(..TABLE_WORDS).ok_or(RobotError::Link(LinkError::Setup))?;
        let mut with = match with {
            Some(w) => w,
            None => {
                while self.round < rounds(n) && peer_in_round(n, me, self.round).is_none() {
                    self.round += 1;
                }
                match peer_in_round(n, me, self.round).filter(|_| self.round < rounds(n)) {
                    Some(peer) => ShareRound {
                        peer,
                        last_sent: None,
                        last_heard: now_ms,
                        unanswered: 0,
                        acked: 0,
                        peer_finished: false,
                        done_at: None,
                        ack_due: true,
                        deframer: Deframer::new(),
                    },
                    None => {
                        let end = self.finish(feed, table, now_ms, meter)?;
                        self.phase = Phase::Done;
                        return Ok(Poll::Done(end));
                    }
                }
            }
        };
        let port = ports.get_mut(port_of(me, with.peer)).ok_or(RobotError::Link(LinkError::Setup))?;
        let over = share_step(&mut with, port, table, me, n, now_ms, &self.link_config)?;
        if over {
            self.round += 1;
            self.phase = Phase::Share { scratch, with: None };
        } else {
            self.phase = Phase::Share { scratch, with: Some(with) };
        }
        Ok(Poll::Busy)
    }

    /// Checks the table's converged estimates for consistency, solves the
    /// pose graph, reports every robot's placement and the end (the
    /// estimates read in place from the table: as `f64` poses, 56 of them
    /// would take 20 KB of a board's stack).
    #[inline(never)]
    fn finish<F: Write, T: Meter>(
        &mut self,
        feed: &mut F,
        table: &[u32],
        now_ms: u64,
        meter: &T,
    ) -> Result<TeamEnd, RobotError> {
        let n = self.robots();
        let t0 = meter.instructions();
        // The converged estimates, as (a, b), in the order a then b.
        let mut candidates: heapless::Vec<(u8, u8), { MAX_ROBOTS * (MAX_ROBOTS - 1) }> = heapless::Vec::new();
        let mut heard = 0u8;
        for a in 0..n {
            let mut all = true;
            for b in (0..n).filter(|&b| b != a) {
                match get(table, a, b) {
                    Some(e) => {
                        if e.status == MatchStatus::Converged.code() {
                            let _ = candidates.push((a, b));
                        }
                    }
                    None => all = false,
                }
            }
            if all {
                heard |= 1 << a;
            }
        }
        let robots = usize::from(n);
        let c = consistent_set(robots, &TableMatches { table, pairs: &candidates }).map_err(RobotError::Team)?;
        let count = candidates.len() as u8;
        // The same list, the kept ones only.
        let mut k = 0;
        candidates.retain(|_| {
            k += 1;
            c.kept & (1 << (k - 1)) != 0
        });
        let kept = TableMatches { table, pairs: &candidates };
        let solution = solve(robots, &kept, SOLVE_ITERATIONS).map_err(RobotError::Team)?;
        let solve_instructions = meter.instructions().saturating_sub(t0);
        for (i, p) in solution.placements.iter().enumerate().take(robots) {
            let Some(p) = p else { continue };
            let cov: [[f32; 6]; 6] = core::array::from_fn(|r| core::array::from_fn(|c| p.covariance[(r, c)] as f32));
            let placed = PlacedRobot {
                index: i as u8,
                anchor: p.anchor,
                transform: rows(&p.pose.cast::<f32>()),
                covariance: Estimate::upper(&cov),
            };
            super::send(feed, &RobotMessage::Placed(placed));
        }
        let end = TeamEnd {
            kept: c.kept,
            candidates: count,
            exhaustive: c.exhaustive,
            heard,
            share_ms: now_ms.saturating_sub(self.share_started).min(u64::from(u32::MAX)) as u32,
            solve_instructions,
            peak_stack: meter.peak_stack(),
        };
        super::send(feed, &RobotMessage::TeamEnd(end));
        Ok(end)
    }
}

impl<M, R, P, Q, F, L, T> Machine<F, L, T> for TeamRobot<'_, M, R, P, Q>
where
    M: VoxelStorage,
    R: VoxelSink + SceneSource,
    P: PyramidStorage,
    Q: PyramidStorage,
    F: Read + Write + ReadReady,
    L: Read + Write + ReadReady + WriteReady,
    T: Meter,
{
    type Report = TeamEnd;

    /// Does what can be done now: reads the feed, exchanges maps with the
    /// round's peer over `ports[port_of(me, peer)]`, matches (one long
    /// step), shares estimates, solves. Every match and the placement go to
    /// the feeder as they come. On an error the robot tells its feeder
    /// where and why, best effort, and stops.
    fn poll(&mut self, feed: &mut F, ports: &mut [L], now_ms: u64, meter: &T) -> Result<Poll<TeamEnd>, RobotError> {
        let r = self.step(feed, ports, now_ms, meter);
        if let Err(e) = &r {
            if *e != RobotError::Finished {
                self.phase = Phase::Done;
                super::send_failure(feed, e);
            }
        }
        r
    }
}

/// Estimates of the table named by `(a, b)`, read in place as the
/// consistency check and the pose graph take them.
struct TableMatches<'t> {
    table: &'t [u32],
    pairs: &'t [(u8, u8)],
}

impl crate::team::Matches for TableMatches<'_> {
    fn count(&self) -> usize {
        self.pairs.len()
    }
    fn get(&self, i: usize) -> Option<RelativePose> {
        let &(a, b) = self.pairs.get(i)?;
        get(self.table, a, b).map(|e| relative_pose(&e))
    }
}

/// The estimate as the pose graph takes it.
pub fn relative_pose(e: &Estimate) -> RelativePose {
    let info = e.information();
    RelativePose {
        a: e.a,
        b: e.b,
        transform: from_rows(&e.transform).cast::<f64>(),
        information: Matrix6::from_fn(|r, c| f64::from(info[r][c])),
    }
}

fn slot(a: u8, b: u8) -> core::ops::Range<usize> {
    let k = (usize::from(a) * MAX_ROBOTS + usize::from(b)) * ESTIMATE_WORDS;
    k..k + ESTIMATE_WORDS
}

fn put(table: &mut [u32], e: &Estimate) {
    if usize::from(e.a) < MAX_ROBOTS && usize::from(e.b) < MAX_ROBOTS {
        if let Some(s) = table.get_mut(slot(e.a, e.b)) {
            s.copy_from_slice(&e.to_words());
        }
    }
}

fn get(table: &[u32], a: u8, b: u8) -> Option<Estimate> {
    if usize::from(a) >= MAX_ROBOTS || usize::from(b) >= MAX_ROBOTS {
        return None;
    }
    Estimate::from_words(table.get(slot(a, b))?).filter(|e| e.a == a && e.b == b)
}

/// Bit b set for every robot b of `n` but `a`.
fn others(n: u8, a: u8) -> u8 {
    let all = if n >= 8 { u8::MAX } else { (1u8 << n) - 1 };
    all & !(1 << a)
}

/// Estimates of `a` held in the table, as bits.
fn held(table: &[u32], n: u8, a: u8) -> u8 {
    (0..n).filter(|&b| b != a && get(table, a, b).is_some()).fold(0, |m, b| m | 1 << b)
}

/// One step of sharing with a peer; `Ok(true)` when this round is over.
fn share_step<L: Read + Write + ReadReady + WriteReady>(
    w: &mut ShareRound,
    port: &mut L,
    table: &mut [u32],
    me: u8,
    n: u8,
    now: u64,
    config: &LinkConfig,
) -> Result<bool, RobotError> {
    let io = |_| RobotError::Link(LinkError::Io(embedded_io::ErrorKind::Other));
    // Read what is there.
    let mut buf = [0u8; 64];
    while port.read_ready().map_err(io)? {
        let k = port.read(&mut buf).map_err(io)?;
        if k == 0 {
            break;
        }
        for &b in buf.get(..k).unwrap_or(&[]) {
            let Ok(Some(payload)) = w.deframer.push(b) else { continue };
            match ShareMessage::decode(payload) {
                Ok(ShareMessage::Estimate(e)) if e.a == w.peer && e.b < n && e.b != e.a => {
                    put(table, &e);
                    w.ack_due = true;
                    w.last_heard = now;
                    w.unanswered = 0;
                }
                Ok(ShareMessage::Ack { from, held, finished }) if from == w.peer => {
                    w.acked |= held;
                    w.peer_finished |= finished;
                    w.last_heard = now;
                    w.unanswered = 0;
                }
                // Another protocol's frame (the map exchange's last
                // words), or a message for someone else: not ours.
                _ => {}
            }
        }
    }
    let mine = others(n, me);
    let theirs = others(n, w.peer);
    let complete = w.acked & mine == mine && held(table, n, w.peer) & theirs == theirs;
    if complete && w.done_at.is_none() {
        w.done_at = Some(now);
        w.ack_due = true;
    }
    // Send: an acknowledgement when due, our estimates when the timer runs.
    let mut frame = [0u8; MAX_FRAME];
    let mut send = |msg: ShareMessage, port: &mut L| -> Result<(), RobotError> {
        let len = msg.to_frame(&mut frame).map_err(|_| RobotError::Link(LinkError::Setup))?;
        port.write_all(frame.get(..len).unwrap_or(&[])).map_err(io)?;
        port.flush().map_err(io)
    };
    let ack = ShareMessage::Ack { from: me, held: held(table, n, w.peer), finished: w.done_at.is_some() };
    let pace = SHARE_RESEND_MS << w.unanswered.min(SHARE_BACKOFF);
    let resend = w.last_sent.is_none_or(|t| now.saturating_sub(t) >= pace);
    if (w.ack_due || resend) && port.write_ready().map_err(io)? {
        if resend && w.acked & mine != mine {
            for b in (0..n).filter(|&b| b != me && w.acked & (1 << b) == 0) {
                if let Some(e) = get(table, me, b) {
                    send(ShareMessage::Estimate(e), port)?;
                }
            }
        }
        send(ack, port)?;
        w.ack_due = false;
        if resend {
            w.last_sent = Some(now);
            w.unanswered = w.unanswered.saturating_add(1);
        }
    }
    // Over when both are finished, or we are and the peer went quiet for a
    // linger time (its last acknowledgement lost), or the peer is gone.
    let over = match w.done_at {
        Some(t) => w.peer_finished || now.saturating_sub(t) > u64::from(config.linger_ms),
        None => now.saturating_sub(w.last_heard) > u64::from(config.silence_ms),
    };
    Ok(over)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pair_meets_once() {
        for n in 2..=8u8 {
            let mut met = [[0u8; 8]; 8];
            for round in 0..rounds(n) {
                for me in 0..n {
                    if let Some(p) = peer_in_round(n, me, round) {
                        assert_eq!(peer_in_round(n, p, round), Some(me), "n {n} round {round} robot {me}");
                        met[usize::from(me)][usize::from(p)] += 1;
                    }
                }
            }
            for a in 0..n {
                for b in 0..n {
                    assert_eq!(met[usize::from(a)][usize::from(b)], u8::from(a != b), "n {n}: {a} met {b}");
                }
            }
        }
    }

    #[test]
    fn ports_skip_the_robot_itself() {
        assert_eq!([0, 1, 3, 4].map(|p| port_of(2, p)), [0, 1, 2, 3]);
    }
}
