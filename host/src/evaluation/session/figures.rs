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
    /// The same with each robot's `T_world_odom` as its map holds it about
    /// its scan of the pair ([`local_world_odom`]): what one rigid
    /// transform between the two maps can be right about. The odometry's
    /// heading walks from scan to scan, and a map's voxels there average
    /// the scans that saw them; `transform` carries the walk at one scan
    /// of each robot, which no match of the maps can see.
    pub local: Isometry3<f64>,
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

    /// `(e_t, e_r)` of an estimate against [`Truth::local`], `e_t` at the
    /// meeting place as in [`Truth::errors`].
    pub fn local_errors(&self, estimate: &Isometry3<f64>) -> (f64, f64) {
        let (_, e_r) = pose_errors(estimate, &self.local);
        ((estimate * self.place - self.local * self.place).norm(), e_r)
    }
}

/// A scan whose `T_world_odom` moves the pair's scan's place by more than
/// this (m) from where that scan's own puts it, or turns by more than
/// [`LOCAL_JUMP_DEG`], is left out of [`local_world_odom`]'s average: a
/// slip, not the walk of the heading.
const LOCAL_JUMP_M: f64 = 1.0;
/// See [`LOCAL_JUMP_M`].
const LOCAL_JUMP_DEG: f64 = 3.0;

/// `T_world_odom` about scan `k0` of `scans` (each `(T_world_odom, true
/// world position)`) as a map holds it there: the heading (about the
/// vertical) and the translation averaged over the scans within `reach`
/// (m; the session's crop: the scans that saw the place) of scan `k0` in
/// the world, leaving out a jump ([`LOCAL_JUMP_M`]) at `place` (scan
/// `k0`'s place in the odometry frame). Averaging the rotation's heading
/// and the translation apart is the average of the frames' maps of a
/// point to first order in the heading's spread (hundredths of a radian).
pub(super) fn local_world_odom(
    scans: &[(Isometry3<f64>, nalgebra::Vector3<f64>)],
    k0: usize,
    place: &nalgebra::Point3<f64>,
    reach: f64,
) -> Option<Isometry3<f64>> {
    let (base, at) = scans.get(k0)?;
    let (mut yaw, mut t, mut n) = (0.0, nalgebra::Vector3::zeros(), 0.0);
    for (w, p) in scans {
        let d = base.inverse() * w;
        let jump = (w * place - base * place).norm() > LOCAL_JUMP_M || d.rotation.angle() > LOCAL_JUMP_DEG.to_radians();
        if (p - at).norm() > reach || jump {
            continue;
        }
        yaw += d.rotation.euler_angles().2;
        t += w.translation.vector;
        n += 1.0;
    }
    // Scan k0 itself is always counted, so n >= 1.
    let rotation = base.rotation * nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, yaw / n);
    Some(Isometry3::from_parts(nalgebra::Translation3::from(t / n), rotation))
}

/// The truth of robot `a`'s estimate of robot `b` this round; `reach`:
/// the session's crop ([`Truth::local`]).
pub(super) fn truth(a: &Robot, b: &Robot, reach: f64) -> Option<Truth> {
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
    let local = |r: &Robot, ks: &[usize], k0: usize| {
        let scans: Vec<_> = ks.iter().map(|&k| (r.world_odom(k), r.world_position(k))).collect();
        let at = ks.iter().position(|&k| k == k0)?;
        local_world_odom(&scans, at, &r.odometry_position(k0), reach)
    };
    Some(Truth {
        transform: a.world_odom(ka).inverse() * b.world_odom(kb),
        place: b.odometry_position(kb),
        local: local(a, &sa, ka)?.inverse() * local(b, &sb, kb)?,
    })
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
    /// The same against the truth as the two maps hold it about the
    /// closest pair of scans ([`Truth::local`]): the estimator's own wrong
    /// answers. What `wrong_converged` counts beyond these is the
    /// odometry's heading walk at the pair's two scans, which no match of
    /// the maps sees.
    pub wrong_converged_local: usize,
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
        let wrong_converged_local = records
            .iter()
            .filter(|r| {
                converged(r) && r.local_errors.is_some_and(|(t, a)| t >= STRICT.0 || a >= STRICT.1) && !exempt(r)
            })
            .count();
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
            wrong_converged_local,
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

    /// A robot driving along x, 1 m a scan, whose odometry frame's heading
    /// walks `yaw_deg[k]` at scan k (the frame turned about the world's
    /// origin), and its scans' true places.
    fn walk(yaw_deg: &[f64]) -> Vec<(Isometry3<f64>, Vector3<f64>)> {
        yaw_deg
            .iter()
            .enumerate()
            .map(|(k, y)| {
                let frame = Isometry3::from_parts(
                    Translation3::new(3.0, -2.0, 0.0),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), y.to_radians()),
                );
                (frame, Vector3::new(k as f64, 0.0, 0.0))
            })
            .collect()
    }

    fn heading_deg(t: &Isometry3<f64>) -> f64 {
        t.rotation.euler_angles().2.to_degrees()
    }

    #[test]
    fn the_local_frame_averages_the_heading_walk_of_the_scans_that_saw_the_place() {
        // The heading jitters by 0.5 degree about 10 degrees from scan to
        // scan: the pair's scan (k0 = 20) sits at the top of the jitter.
        let yaw: Vec<f64> = (0..41).map(|k| 10.0 + if k % 2 == 0 { 0.5 } else { -0.5 }).collect();
        let scans = walk(&yaw);
        let place = Point3::new(20.0, 0.0, 0.0);
        let local = local_world_odom(&scans, 20, &place, 25.0).unwrap();
        assert!((heading_deg(&scans[20].0) - 10.5).abs() < 1e-9);
        // 41 scans within reach, 21 at +0.5 and 20 at -0.5.
        assert!((heading_deg(&local) - (10.0 + 0.5 / 41.0)).abs() < 1e-6, "{}", heading_deg(&local));
        // Only the scans within reach count: 5 m takes scans 15-25, 5 at
        // +0.5 and 6 at -0.5.
        let near = local_world_odom(&scans, 20, &place, 5.0).unwrap();
        assert!((heading_deg(&near) - (10.0 - 0.5 / 11.0)).abs() < 1e-6, "{}", heading_deg(&near));
    }

    #[test]
    fn a_slip_is_left_out_of_the_local_frame() {
        // A steady heading, then a 10-degree slip from scan 25 on.
        let yaw: Vec<f64> = (0..41).map(|k| if k < 25 { 2.0 } else { 12.0 }).collect();
        let scans = walk(&yaw);
        let local = local_world_odom(&scans, 20, &Point3::new(20.0, 0.0, 0.0), 25.0).unwrap();
        assert!((heading_deg(&local) - 2.0).abs() < 1e-9, "{}", heading_deg(&local));
        assert!(local_world_odom(&scans, 41, &Point3::origin(), 25.0).is_none());
    }
}
