//! The figures of a session, against the truth: wrong `Converged`,
//! availability in meetings, rounds to the first fix, a slip caught, the
//! updates' bytes, the cost of a tracking round.

use super::robot::Robot;
use super::{Record, SessionSpec};
use crate::error::Error;
use crate::evaluation::stats::{median, quantile};
use crate::matching::align::{align, prepare, prepare_scene, DEFAULT_LEVELS};
use cosem_core::geometry::pose_errors;
use cosem_core::matching::{Alignment, MatchStatus};
use cosem_core::session::Kind;
use nalgebra::Isometry3;

/// The conventions' strict thresholds: a correct estimate.
const STRICT: (f64, f64) = (0.5, 1.0);
/// A meeting: rounds with at least this true overlap.
pub const MEETING_OVERLAP: f64 = 0.30;
/// Rounds at a meeting's start left out of its availability.
const SETTLING_ROUNDS: usize = 2;

/// The truth of one robot's estimate of a peer in one round.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// `T_own_peer`: `inv(T_world_odom_own) * T_world_odom_peer` at the
    /// pair of scans (one each, both in the current maps) closest to each
    /// other in the world.
    pub transform: Isometry3<f64>,
    /// The meeting place: where the peer was at its scan of that pair, in
    /// the peer's odometry frame.
    pub place: nalgebra::Point3<f64>,
}

impl Truth {
    /// `(e_t, e_r, e_t_origin)` of an estimate `T_own_peer`: the
    /// conventions' errors, `e_t` with the model frame's origin moved to
    /// the meeting place (metres between where the estimate and the truth
    /// put it), `e_t_origin` at the odometry origin (where a drift's
    /// rotation error counts times the distance to the meeting).
    pub fn errors(&self, estimate: &Isometry3<f64>) -> (f64, f64, f64) {
        let (origin, e_r) = pose_errors(estimate, &self.transform);
        ((estimate * self.place - self.transform * self.place).norm(), e_r, origin)
    }
}

/// The truth of robot `a`'s estimate of robot `b` this round.
pub(super) fn truth(a: &Robot, b: &Robot) -> Option<Truth> {
    let (sa, sb) = (a.scans_in_map(), b.scans_in_map());
    let mut best: Option<(f64, usize, usize)> = None;
    for &ka in &sa {
        for &kb in &sb {
            let d = (a.world_position(ka) - b.world_position(kb)).norm();
            if best.is_none_or(|(bd, _, _)| d < bd) {
                best = Some((d, ka, kb));
            }
        }
    }
    let (_, ka, kb) = best?;
    Some(Truth { transform: a.world_odom(ka).inverse() * b.world_odom(kb), place: b.odometry_position(kb) })
}

/// The cost ratio's denominator (ms): the median of `timed` (from-scratch
/// matches on the maps of tracking rounds), or with none, of three on
/// `last` (the last round's maps of robots 0 and 1).
pub(super) fn cost_denominator(
    timed: &[f64],
    last: (&crate::maps::mapping::HostMap, &crate::maps::mapping::HostMap),
    how: &Alignment,
) -> Result<f64, Error> {
    match median(timed) {
        Some(ms) => Ok(ms),
        None => from_scratch_ms(last.0, last.1, how, 3),
    }
}

/// Median milliseconds of `runs` from-scratch one-shot matches of `a` and
/// `b` (`a` prepared as the model, `b` as the scene, then matched with no
/// prior), in this process.
pub(super) fn from_scratch_ms(
    a: &crate::maps::mapping::HostMap,
    b: &crate::maps::mapping::HostMap,
    how: &Alignment,
    runs: usize,
) -> Result<f64, Error> {
    let mut ms = Vec::new();
    for _ in 0..runs {
        let t = std::time::Instant::now();
        let (pa, pb) = (prepare(a, DEFAULT_LEVELS)?, prepare_scene(b, DEFAULT_LEVELS)?);
        align(*how, None, (&pa, &pb))?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(&ms).unwrap_or(0.0))
}

/// Whether a record is a correct estimate (Converged, within the strict thresholds).
pub(super) fn correct(r: &Record) -> bool {
    converged(r) && r.errors.is_some_and(|(t, a)| t < STRICT.0 && a < STRICT.1)
}

/// Whether a record is Converged and wrong by the conventions' `e_t` at
/// the odometry origin.
fn wrong_at_origin(r: &Record) -> bool {
    converged(r)
        && match (r.origin_error, r.errors) {
            (Some(o), Some((_, a))) => o >= STRICT.0 || a >= STRICT.1,
            _ => false,
        }
}

fn converged(r: &Record) -> bool {
    r.estimate.as_ref().is_some_and(|e| e.status() == MatchStatus::Converged)
}

/// A session's figures.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Summary {
    /// Estimates `Converged` but wrong (outside the strict thresholds, `e_t`
    /// at the meeting place: the peer's place at the closest pair of scans
    /// mapped by the estimate at least 0.5 m from where the truth maps it),
    /// over every round with a truth (a slip's two rounds exempt).
    pub wrong_converged: usize,
    /// The same with the conventions' `e_t` at the odometry origin, where a
    /// rotation error counts times the distance to the meeting: a drift's
    /// lever arm, not a false accept.
    pub wrong_at_origin: usize,
    /// Estimates with a truth.
    pub with_truth: usize,
    /// Correct `Converged` ÷ estimates in meetings, each meeting's first 2
    /// rounds left out (`None`: no such estimate).
    pub availability: Option<f64>,
    /// Estimates in meetings (each meeting's first 2 rounds left out) ...
    pub in_meetings: usize,
    /// ... and of those, the correct Converged ones.
    pub available: usize,
    /// Meetings (maximal runs of rounds of a pair with a true overlap of
    /// at least 0.30).
    pub meetings: usize,
    /// Per meeting, the first correct round after its start (a meeting
    /// never fixed: its length): the largest.
    pub first_fix_rounds: Option<usize>,
    /// An update's bytes ÷ the sender's whole map's, once the copy was
    /// whole once: median, 95th percentile, largest.
    pub update_bytes_ratio: Option<[f64; 3]>,
    /// Voxels an update held back for later rounds (beyond its budget),
    /// over the same updates: median, 95th percentile, largest. How far a
    /// copy lags the map as the sender has it.
    pub update_deferred: Option<[f64; 3]>,
    /// Bytes of every update and answer.
    pub bytes: usize,
    /// Median milliseconds of a tracking round (update applied, maps
    /// prepared, EM from the fix, verdict; the window searched when that
    /// fails).
    pub tracking_ms: Option<f64>,
    /// Median milliseconds of from-scratch matches (both maps prepared,
    /// prior-free) on the maps of every
    /// [`FROM_SCRATCH_EVERY`](super::FROM_SCRATCH_EVERY)th tracking
    /// estimate; with none, of three on the last round's maps of robots 0
    /// and 1.
    pub from_scratch_ms: f64,
    /// `tracking_ms` ÷ `from_scratch_ms`.
    pub tracking_cost_ratio: Option<f64>,
    /// With a slip: the smallest d such that from round s + d on, every
    /// estimate of a pair with the slipped robot is not Converged or correct.
    pub slip_caught_rounds: Option<usize>,
    /// With a line (`--line`): bytes the robots read from their lines.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line_bytes: Option<u64>,
    /// With a line: a pair's round on its line, from the round's start
    /// until both updates were across and answered (ms): median, 95th
    /// percentile, largest.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line_ms: Option<[f64; 3]>,
    /// With a line: the pairs' rounds that took longer on it than the
    /// round's scans take (`every` scans at 10 Hz).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line_late: Option<usize>,
}

impl Summary {
    /// The figures of `records`.
    pub fn of(records: &[Record], spec: &SessionSpec, rounds: usize, from_scratch_ms: f64) -> Summary {
        let n = spec.robots.len();
        let exempt = |r: &Record| {
            spec.slip.is_some_and(|(s, at)| (r.robot == s || r.peer == s) && (at..=at + 1).contains(&r.round))
        };
        let wrong_converged =
            records.iter().filter(|r| converged(r) && r.errors.is_some() && !correct(r) && !exempt(r)).count();
        let wrong_at_origin = records.iter().filter(|r| wrong_at_origin(r) && !exempt(r)).count();
        let (mut in_meetings, mut available, mut meetings, mut first_fix) = (0usize, 0usize, 0usize, None::<usize>);
        for i in 0..n {
            for j in (0..n).filter(|&j| j != i) {
                let pair: Vec<&Record> = records.iter().filter(|r| r.robot == i && r.peer == j).collect();
                for run in meeting_runs(&pair) {
                    meetings += 1;
                    let fixed = run.iter().position(|r| correct(r)).unwrap_or(run.len());
                    first_fix = Some(first_fix.map_or(fixed, |f| f.max(fixed)));
                    for r in run.iter().skip(SETTLING_ROUNDS) {
                        in_meetings += 1;
                        available += usize::from(correct(r));
                    }
                }
            }
        }
        let (update_bytes_ratio, update_deferred) = update_figures(records.iter());
        let tracking: Vec<f64> = records
            .iter()
            .filter(|r| r.estimate.is_some_and(|e| e.kind == Kind::Tracking))
            .map(|r| r.seconds * 1e3)
            .collect();
        let tracking_ms = median(&tracking);
        Summary {
            wrong_converged,
            wrong_at_origin,
            with_truth: records.iter().filter(|r| r.errors.is_some()).count(),
            availability: (in_meetings > 0).then(|| available as f64 / in_meetings as f64),
            in_meetings,
            available,
            meetings,
            first_fix_rounds: first_fix,
            update_bytes_ratio,
            update_deferred,
            bytes: records.iter().map(|r| r.bytes_sent).sum(),
            tracking_ms,
            from_scratch_ms,
            tracking_cost_ratio: tracking_ms.filter(|_| from_scratch_ms > 0.0).map(|t| t / from_scratch_ms),
            slip_caught_rounds: spec.slip.map(|(s, at)| slip_caught(records, s, at, rounds)),
            line_bytes: spec.line.map(|_| records.iter().filter_map(|r| r.line).map(|l| l.bytes).sum()),
            line_ms: spec.line.and_then(|_| line_spread(records)),
            line_late: spec.line.map(|_| {
                let round_ms = (spec.every * 100) as u64;
                records.iter().filter(|r| r.robot > r.peer).filter_map(|r| r.line).filter(|l| l.ms > round_ms).count()
            }),
        }
    }
}

/// Over the updates after a copy's first sync: the bytes ÷ the sender's
/// whole map's, and the voxels held back (each median, p95, largest).
pub(super) fn update_figures<'a>(
    records: impl Iterator<Item = &'a Record> + Clone,
) -> (Option<[f64; 3]>, Option<[f64; 3]>) {
    let spread = |v: Vec<f64>| (!v.is_empty()).then(|| [0.5, 0.95, 1.0].map(|q| quantile(&v, q).unwrap_or(0.0)));
    let synced = records.filter(|r| r.update_ratio.is_some());
    (
        spread(synced.clone().filter_map(|r| r.update_ratio).collect()),
        spread(synced.map(|r| f64::from(r.counts.deferred)).collect()),
    )
}

/// A pair's round on its line (counted once a pair: the record of its
/// higher robot): median, p95, largest (ms).
fn line_spread(records: &[Record]) -> Option<[f64; 3]> {
    let v: Vec<f64> = records.iter().filter(|r| r.robot > r.peer).filter_map(|r| r.line).map(|l| l.ms as f64).collect();
    (!v.is_empty()).then(|| [0.5, 0.95, 1.0].map(|q| quantile(&v, q).unwrap_or(0.0)))
}

/// The meetings of one ordered pair's records (in round order).
fn meeting_runs<'a>(pair: &[&'a Record]) -> Vec<Vec<&'a Record>> {
    let mut runs: Vec<Vec<&Record>> = Vec::new();
    let mut open = false;
    for r in pair {
        let meets = r.overlap_true.is_some_and(|o| o >= MEETING_OVERLAP);
        match (meets, open) {
            (true, true) => runs.last_mut().into_iter().for_each(|run| run.push(r)),
            (true, false) => runs.push(vec![r]),
            _ => {}
        }
        open = meets;
    }
    runs
}

/// The rounds after a slip of robot `s` at round `at` until every estimate
/// of a pair with it is not Converged or correct for good.
fn slip_caught(records: &[Record], s: usize, at: usize, rounds: usize) -> usize {
    let bad_rounds: Vec<usize> = records
        .iter()
        .filter(|r| (r.robot == s || r.peer == s) && r.round >= at && converged(r) && !correct(r))
        .map(|r| r.round)
        .collect();
    bad_rounds.iter().max().map_or(0, |last| (last + 1 - at).min(rounds.saturating_sub(at)))
}
