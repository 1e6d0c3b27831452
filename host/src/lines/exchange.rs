//! Two maps exchanged over a simulated line, by the core's link endpoints
//! in the core's simulation ([`cosem_core::sim::run`]): what `cosem bench
//! link` measures and what a team on the host sends between its robots.

use crate::error::Error;
use crate::maps::mapping::{new_map, HostMap};
use cosem_core::link::{Endpoint, LinkBuffers, LinkConfig, LinkStats, Progress};
use cosem_core::map::VecStorage;
use cosem_core::robot::{Machine, Poll, RobotError};
use cosem_core::sim::{self, SimConfig, SimRobot, Wire};
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// One simulated exchange of two maps, both ways at once.
pub struct SimExchange {
    /// What each side received: B's map at A, then A's map at B.
    pub received: [HostMap; 2],
    /// Each side's link figures.
    pub stats: [LinkStats; 2],
    /// Simulated seconds until A's map, then B's, was through (`None`: never).
    pub through_s: [Option<f64>; 2],
    /// Simulated seconds until both ends were over (closing included).
    pub over_s: f64,
    /// Both maps arrived whole (digest checked) and both ends ended well.
    pub delivered: bool,
}

/// A link endpoint as a machine of the simulation: it only exchanges, and
/// reports when the peer's map was through here (ms).
struct Exchanger<'a> {
    endpoint: Endpoint<'a, VecStorage, HostMap>,
    through_ms: Option<u64>,
}

impl<F, L: Read + Write + ReadReady + WriteReady, T> Machine<F, L, T> for Exchanger<'_> {
    type Report = Option<u64>;

    fn poll(
        &mut self,
        _feed: &mut F,
        ports: &mut [L],
        now_ms: u64,
        _meter: &T,
    ) -> Result<Poll<Option<u64>>, RobotError> {
        let link = ports.first_mut().ok_or(RobotError::Link(cosem_core::link::LinkError::Setup))?;
        let progress = self.endpoint.step(link, now_ms).map_err(RobotError::Link)?;
        if self.through_ms.is_none() && self.endpoint.received() {
            self.through_ms = Some(now_ms);
        }
        Ok(match progress {
            Progress::Busy => Poll::Busy,
            Progress::Done => Poll::Done(self.through_ms),
        })
    }
}

/// Maps `ma` and `mb` exchanged over the simulated `line` (at once, or one
/// after the other on a half-duplex one), in simulated time, by the core's
/// link endpoints (robot ids 0 and 1).
pub fn simulate_exchange(ma: &HostMap, mb: &HostMap, line: SimConfig) -> Result<SimExchange, Error> {
    let (mut s0, mut s1) = (vec![0u32; ma.len()], vec![0u32; mb.len()]);
    let (mut st0, mut st1) = (new_map(mb.len(), *ma.config())?, new_map(ma.len(), *ma.config())?);
    let lc = LinkConfig { half_duplex: line.half_duplex, ..LinkConfig::default() };
    let setup = |e| Error::Invalid(format!("link set-up: {e}"));
    let (mut b0, mut b1) = (Box::new(LinkBuffers::new()), Box::new(LinkBuffers::new()));
    let e0 = Endpoint::new(lc, 0, 1, 0, Some((ma, &mut s0)), Some(&mut st0), &mut *b0).map_err(setup)?;
    let e1 = Endpoint::new(lc, 1, 2, 0, Some((mb, &mut s1)), Some(&mut st1), &mut *b1).map_err(setup)?;
    let mut x0 = Exchanger { endpoint: e0, through_ms: None };
    let mut x1 = Exchanger { endpoint: e1, through_ms: None };
    let wire = Wire { a: 0, b: 1, line };
    let out = sim::run(&mut [&mut x0 as &mut SimRobot<'_, '_, Option<u64>>, &mut x1], &[], &[wire], 3_600_000);
    let stats = [x0.endpoint.stats(), x1.endpoint.stats()];
    let through_ms = [x1.through_ms, x0.through_ms];
    // Both ended (well or not) one millisecond after their last poll.
    let over_ms = out.iter().map(|o| o.at_ms + u64::from(o.result.is_some())).max().unwrap_or(0);
    let ended_well = out.iter().all(|o| matches!(o.result, Some(Ok(_))));
    let whole = st1.len() == ma.len() && st0.len() == mb.len();
    Ok(SimExchange {
        received: [st0, st1],
        stats,
        through_s: through_ms.map(|t| t.map(|ms| ms as f64 / 1e3)),
        over_s: over_ms as f64 / 1e3,
        delivered: ended_well && whole,
    })
}
