//! A session's updates over simulated serial lines (`cosem session
//! --line`): every two robots trade their round's two updates over one
//! full-duplex [`SimLine`] of the fault and baud rate asked for, each side
//! a [`Courier`] (the boards' transport: frames with parity and CRC-32,
//! resends, the answer riding the acknowledgements), in virtual time. What
//! arrives is what was sent; it reaches the receiver's copy in the round
//! by whose end it is across (each round is `every` scans at 10 Hz), and
//! until then the receiver estimates on the copy it held. A line busy with
//! a round's updates takes no new ones: what changed meanwhile goes in the
//! next update, written when the line is free.

use super::{Applied, Link, UpdateCounts};
use crate::error::Error;
use crate::maps::mapping::HostMap;
use cosem_core::link::courier::{Courier, CourierConfig, CourierError, Event};
use cosem_core::sim::{Fault, SimConfig, SimLine, LINE_BYTES};
use std::cell::RefCell;
use std::time::Instant;

/// The line between every two robots of a session.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionLine {
    /// What the line does to bytes (the one fault model).
    pub fault: Fault,
    /// Bits a second (8N1: ten a byte).
    pub baud: u32,
}

/// Virtual milliseconds a pair's round may take on its line before the
/// session gives up on it (a line that carries nothing).
const GIVE_UP_MS: u64 = 600_000;

/// What a pair's round on its line gave: each side's answer from its
/// peer, the bytes each side read, and the milliseconds since the round's
/// start.
type Traded = ([Vec<u8>; 2], [u64; 2], u64);

/// One pair's line: the simulated wire and each end's courier.
pub(super) struct PairLine {
    wire: Box<RefCell<SimLine<LINE_BYTES>>>,
    ends: [Courier; 2],
    inputs: [Vec<u8>; 2],
    /// The line's virtual clock (ms).
    now: u64,
    round: u16,
    /// A trade not across yet.
    pending: Option<OnTheLine>,
}

/// A pair's trade still on the line: what it delivers once across (at
/// `done_ms`), and each receiver's copy as it was before, which the
/// receiver estimates on until then (`[a to b, b to a]`).
struct OnTheLine {
    done_ms: u64,
    delivered: [Delivered; 2],
    before: [HostMap; 2],
}

/// What one update cost on its line, for the robot that received it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LineCost {
    /// Bytes that robot read from the line this round (the update's
    /// frames, resends and the peer's acknowledgements of its own).
    pub bytes: u64,
    /// Milliseconds from the round's start (its first scan) until both of
    /// the pair's updates were across and answered: a line slower than
    /// the rounds falls behind, and this grows.
    pub ms: u64,
}

/// What became of one update: for the robot that received it.
pub(super) struct Delivered {
    pub bytes: usize,
    pub ratio: Option<f64>,
    /// `None`: still on the line.
    pub applied: Option<Applied>,
    pub counts: UpdateCounts,
    /// Seconds the receiver took to apply and answer it.
    pub applying: f64,
    pub line: Option<LineCost>,
}

impl Delivered {
    /// Nothing this round: an update still on the line.
    pub(super) fn on_the_line() -> Self {
        Delivered { bytes: 0, ratio: None, applied: None, counts: UpdateCounts::default(), applying: 0.0, line: None }
    }
}

impl PairLine {
    /// The copy the receiver of direction `dir` (0: a to b) estimates on
    /// while an update to it is on the line.
    pub(super) fn before(&self, dir: usize) -> Option<&HostMap> {
        self.pending.as_ref().and_then(|p| p.before.get(dir))
    }

    /// The line of robots `a` and `b` (`a < b`), seeded by the session's
    /// seed and the pair.
    pub(super) fn new(line: SessionLine, (a, b): (usize, usize), seed: u64) -> Result<Self, Error> {
        let mut config = SimConfig::clean(line.baud, seed.wrapping_mul(31).wrapping_add((a * 3 + b) as u64));
        (config.error_rate, config.mix) = (line.fault.rate, line.fault.mix);
        let courier = || Courier::new(CourierConfig::default()).map_err(|e| Error::Invalid(format!("courier: {e}")));
        Ok(PairLine {
            wire: Box::new(RefCell::new(SimLine::new(config))),
            ends: [courier()?, courier()?],
            inputs: [vec![0; CourierConfig::MAX_MESSAGE], vec![0; CourierConfig::MAX_MESSAGE]],
            now: 0,
            round: 0,
            pending: None,
        })
    }

    /// Trades `out[0]` (side 0's update) and `out[1]` from `start_ms` on
    /// (or when the last trade ended, if later): `deliver(side, bytes)`
    /// takes what reached `side` and gives its answer. Each side's answer
    /// from the peer, the bytes each side read, and the milliseconds
    /// since `start_ms`.
    fn trade(
        &mut self,
        out: [&[u8]; 2],
        start_ms: u64,
        mut deliver: impl FnMut(usize, &[u8]) -> Result<Vec<u8>, Error>,
    ) -> Result<Traded, Error> {
        let fail = |e: CourierError| Error::Invalid(format!("the line: {e}"));
        // A line still busy with an earlier round starts this one late.
        self.now = self.now.max(start_ms);
        let start = self.now;
        let before = [self.ends[0].stats().bytes_received, self.ends[1].stats().bytes_received];
        for (end, o) in self.ends.iter_mut().zip(out) {
            end.start(self.round, o.len(), self.now).map_err(fail)?;
        }
        let (mut p0, mut p1) = SimLine::ports(&self.wire);
        let mut done = [false; 2];
        while !(done[0] && done[1]) {
            if self.now - start > GIVE_UP_MS {
                return Err(Error::Invalid(format!("the line: round {} not across in {GIVE_UP_MS} ms", self.round)));
            }
            self.wire.borrow_mut().tick(self.now);
            for (side, port) in [(0usize, &mut p0), (1, &mut p1)] {
                if done[side] {
                    // Answers the peer's resends of this round still.
                    self.ends[side].step(port, &[], &mut self.inputs[side], self.now).map_err(fail)?;
                    continue;
                }
                match self.ends[side].step(port, out[side], &mut self.inputs[side], self.now).map_err(fail)? {
                    Event::Busy => {}
                    Event::Delivered(n) => {
                        let got = self.inputs[side]
                            .get(..n)
                            .ok_or_else(|| Error::Invalid(format!("the line: a message of {n} bytes")))?;
                        let answer = deliver(side, got)?;
                        self.ends[side].reply(&answer).map_err(fail)?;
                        self.ends[side].send_answer(port).map_err(fail)?;
                    }
                    Event::Done => done[side] = true,
                }
            }
            self.now += 1;
        }
        let answers = [0, 1].map(|s| self.ends[s].answer().map(<[u8]>::to_vec).unwrap_or_default());
        let read = [0, 1].map(|s| self.ends[s].stats().bytes_received - before[s]);
        self.round = self.round.wrapping_add(1);
        Ok((answers, read, self.now - start_ms))
    }
}

/// Robots `a` and `b`'s round `[start_ms, end_ms)` on their line: with the
/// line free, this round's updates written (from `maps`, each measured
/// against `whole`) and traded; what reaches each receiver by the round's
/// end (`[a to b, b to a]`; `None`: still on the line).
pub(super) fn pair_round(
    line: &mut PairLine,
    [ab, ba]: [&mut Link; 2],
    maps: [&HostMap; 2],
    whole: [usize; 2],
    (start_ms, end_ms): (u64, u64),
    words: &mut [u32],
) -> Result<[Option<Delivered>; 2], Error> {
    if line.pending.is_none() {
        let before = [ab.copy.map().clone(), ba.copy.map().clone()];
        let delivered = trade_pair(line, [ab, ba], maps, whole, start_ms, words)?;
        let done_ms = start_ms + delivered[0].line.map_or(0, |l| l.ms);
        line.pending = Some(OnTheLine { done_ms, delivered, before });
    }
    match line.pending.take() {
        Some(p) if p.done_ms <= end_ms => {
            let [x, y] = p.delivered;
            Ok([Some(x), Some(y)])
        }
        still => {
            line.pending = still;
            Ok([None, None])
        }
    }
}

/// Robots `a` and `b`'s round over their line: each one's update written
/// (from `maps`, each measured against `whole`), traded, applied to the
/// other's copy and answered; what became of each, `[a to b, b to a]`.
fn trade_pair(
    line: &mut PairLine,
    links: [&mut Link; 2],
    maps: [&crate::maps::mapping::HostMap; 2],
    whole: [usize; 2],
    start_ms: u64,
    words: &mut [u32],
) -> Result<[Delivered; 2], Error> {
    let [ab, ba] = links;
    let mut out = [Vec::new(), Vec::new()];
    for ((link, map), o) in [&mut *ab, &mut *ba].into_iter().zip(maps).zip(&mut out) {
        o.resize(CourierConfig::MAX_MESSAGE, 0);
        let n = link.write(map, words, o)?;
        o.truncate(n);
    }
    // Side 0 is robot a: it receives b's update into its copy (`ba`).
    let mut applied = [Applied::Applied; 2];
    let mut applying = [0.0; 2];
    let (answers, read, ms) = line.trade([&out[0], &out[1]], start_ms, |side, got| {
        let link = if side == 0 { &mut *ba } else { &mut *ab };
        let t = Instant::now();
        let (done, answer) = link.receive(got, words);
        (applied[side], applying[side]) = (done, t.elapsed().as_secs_f64());
        Ok(answer)
    })?;
    // Direction 0 is a to b: b (side 1) received it, a (side 0) heard the answer.
    let heard = |dir: usize, link: &mut Link| -> Result<Delivered, Error> {
        let (sender, receiver) = (dir, 1 - dir);
        let (bytes, ratio) = link.answered(&answers[sender], out[sender].len(), whole[sender], applied[receiver])?;
        Ok(Delivered {
            bytes,
            ratio,
            applied: Some(applied[receiver]),
            counts: link.publisher.counts(),
            applying: applying[receiver],
            line: Some(LineCost { bytes: read[receiver], ms }),
        })
    };
    Ok([heard(0, ab)?, heard(1, ba)?])
}
