//! Simulation, for tests and hosts (feature `sim`; never in a board's
//! build): the one fault model of a byte stream ([`Fault`], and [`Lossy`]
//! over any port), a seeded lossy serial line ([`SimLine`]), a scripted feed line
//! ([`ScriptPort`]), and the one driver that runs any number of robots
//! ([`Machine`]s) over such lines in virtual time ([`run`]). The core's
//! tests, the host's twin of a board run, its team run and its link
//! benchmark all run robots through [`run`], so a host computes exactly
//! what the boards compute.

mod fault;
mod line;

pub use fault::{Damaged, Fault, FaultError, Lossy, Mix, MixError, SimRng};
pub use line::{OutputFull, ScriptPort, SimConfig, SimLine, SimPort};

use crate::robot::{Machine, Poll, RobotError};
use alloc::vec::Vec;
use core::cell::RefCell;

/// Bytes a robot may tell its feeder in a simulation (reports, a team's
/// matches and placements).
pub const FEED_OUT: usize = 16384;

/// Bytes each direction of a simulated line buffers.
pub const LINE_BYTES: usize = 65536;

/// A robot's feed line in a simulation.
pub type Feeder<'f> = ScriptPort<'f, FEED_OUT>;

/// One end of a simulated line between robots.
pub type Port<'l> = SimPort<'l, LINE_BYTES>;

/// A robot the simulation can drive: any [`Machine`] over a scripted feed
/// and simulated ports, measuring nothing.
pub type SimRobot<'r, 'f, R> = dyn for<'l> Machine<Feeder<'f>, Port<'l>, (), Report = R> + 'r;

/// A line between robots `a` and `b` (side 0 is `a`'s end).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wire {
    /// One robot's index.
    pub a: usize,
    /// The other's.
    pub b: usize,
    /// What the line does to bytes, and how fast.
    pub line: SimConfig,
}

impl Wire {
    /// A clean line of `baud` (8N1) between robots `a` and `b`.
    pub fn clean(a: usize, b: usize, baud: u32, seed: u64) -> Self {
        Wire { a, b, line: SimConfig::clean(baud, seed) }
    }

    /// Clean lines between every two of `robots` (a team's mesh), in the
    /// order (0,1), (0,2) ... (1,2) ..., seeded 1, 2, 3 ...
    pub fn mesh(robots: usize, baud: u32) -> Vec<Wire> {
        let pairs = (0..robots).flat_map(|a| (a + 1..robots).map(move |b| (a, b)));
        pairs.enumerate().map(|(k, (a, b))| Wire::clean(a, b, baud, k as u64 + 1)).collect()
    }
}

/// How one robot of a simulation ended.
#[derive(Clone, Debug, PartialEq)]
pub struct Ended<R> {
    /// Its report or its error; `None`: still busy at the time limit.
    pub result: Option<Result<R, RobotError>>,
    /// When it ended (ms of virtual time).
    pub at_ms: u64,
    /// Everything it told its feeder (framed robot messages).
    pub told: Vec<u8>,
}

/// Runs `robots` to their ends, robot `i` fed `feeds[i]` (framed feed
/// messages, 64 bytes per read as a UART delivers them) and joined to its
/// peers by `wires`: robot `i`'s ports are its wires in the order of the
/// peers' indices (a pair robot's one port, a team robot's mesh as
/// [`crate::robot::team::port_of`] numbers it). Virtual time: one
/// millisecond per round, every line ticked, each busy robot polled once.
/// Stops after `limit_ms`. Deterministic: the same robots, feeds and
/// wires give the same results.
pub fn run<'f, R>(
    robots: &mut [&mut SimRobot<'_, 'f, R>],
    feeds: &[&'f [u8]],
    wires: &[Wire],
    limit_ms: u64,
) -> Vec<Ended<R>> {
    let lines: Vec<RefCell<SimLine<LINE_BYTES>>> = wires.iter().map(|w| RefCell::new(SimLine::new(w.line))).collect();
    // Each robot's ports, by the peer's index.
    let mut ends: Vec<Vec<(usize, Port<'_>)>> = robots.iter().map(|_| Vec::new()).collect();
    for (w, line) in wires.iter().zip(&lines) {
        let (pa, pb) = SimLine::ports(line);
        if let Some(e) = ends.get_mut(w.a) {
            e.push((w.b, pa));
        }
        if let Some(e) = ends.get_mut(w.b) {
            e.push((w.a, pb));
        }
    }
    let mut ports: Vec<Vec<Port<'_>>> = ends
        .into_iter()
        .map(|mut e| {
            e.sort_by_key(|&(peer, _)| peer);
            e.into_iter().map(|(_, p)| p).collect()
        })
        .collect();
    let mut feeders: Vec<Feeder<'f>> =
        (0..robots.len()).map(|i| ScriptPort::new(feeds.get(i).copied().unwrap_or(&[]), 64)).collect();
    let mut out: Vec<Ended<R>> = robots.iter().map(|_| Ended { result: None, at_ms: 0, told: Vec::new() }).collect();
    let mut now = 0u64;
    while out.iter().any(|o| o.result.is_none()) && now <= limit_ms {
        for line in &lines {
            line.borrow_mut().tick(now);
        }
        for (((robot, feeder), ports), ended) in robots.iter_mut().zip(&mut feeders).zip(&mut ports).zip(&mut out) {
            if ended.result.is_some() {
                continue;
            }
            match robot.poll(feeder, ports, now, &()) {
                Ok(Poll::Busy) => continue,
                Ok(Poll::Done(r)) => ended.result = Some(Ok(r)),
                Err(e) => ended.result = Some(Err(e)),
            }
            ended.at_ms = now;
        }
        now += 1;
    }
    for (ended, feeder) in out.iter_mut().zip(&feeders) {
        ended.told = feeder.output.to_vec();
        if ended.result.is_none() {
            ended.at_ms = now;
        }
    }
    out
}

#[cfg(test)]
mod tests;
