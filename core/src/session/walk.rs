//! How far a robot's odometry turns its scans from its own map: a measure
//! of its heading walk that the robot can take itself, with no truth.
//!
//! Why: an estimate of a peer is judged against the truth at one pair of
//! scans, while the two maps it matches average many scans each. Under a
//! heading walk of 2 degrees per 100 m a scan's heading strays half a
//! degree from its map's (town, root mean square), and a right match of
//! the maps is more than a degree off the truth at the scans: 89 wrong
//! `Converged` on the town's five seeds (docs/session.md). The estimates'
//! own steps do not show it (they move with the maps' averaged frames); a
//! scan registered to the map before it is fused does, about a scan's own
//! stray ([`ScanFit`], [`OdometryWalk`]).

use crate::map::{LocalMap, VoxelStorage};
use crate::matching::pyramid::Moments;

/// A scan's points are taken one in this many ([`ScanFit::add`]): a
/// few hundred point-to-plane pairs a scan, enough to fix a heading to a
/// few hundredths of a degree.
///
/// Why 16: on the town (seeds 1-5) one point in 16 of a LiDAR's scan gives
/// the same verdicts as one in 8 at every drift measured and the same
/// benchmark, at half the cost; one in 32 withholds right fixes at 1%,1
/// (docs/session.md). A scan of few points (a camera's view) is taken
/// more densely ([`walk_stride`]): one in 16 of it gave no turn at all.
pub const WALK_STRIDE: u32 = 16;
/// A scan with fewer points than [`WALK_STRIDE`] times this is taken one
/// point in fewer ([`walk_stride`]): at least about this many of its
/// points are tried.
///
/// Why: a scan labelled from a camera keeps only the points in the
/// camera's view, 3,000-4,500 of the town's, and one in 16 of them gave
/// 4-24 pairs, under [`WALK_MIN_PAIRS`]: such a robot had no figure for
/// most of a session, or all of it (town seed 2, camera labels), and
/// reported `Converged` a degree off at 1 degree per 100 m that the
/// limit would have withheld (docs/session.md). A LiDAR's scan keeps
/// 26,000-33,000 there, 16 times this and more: one point in 16 of it,
/// as before.
pub const WALK_POINTS: usize = 1600;
/// A scan's turn known no better than this (its standard deviation,
/// degrees; [`ScanFit::turn`]) is passed over ([`OdometryWalk::push`]).
///
/// Why: the figure is read against a limit of 0.25 for a pair (about
/// 0.18 a robot, [`WALK_LIMIT_DEG`]), and a turn this uncertain says
/// little of a walk that size. Such fits are the ones whose one step
/// breaks: a narrow view of one facade, where the turn and the sideways
/// shift look alike. On the town a LiDAR's scans fit to 0.04 at the
/// most; a camera's view to 0.03 at the median but 0.34 at the 99th
/// percentile, with turns of 2 and 43 degrees among them, which took
/// the figure to 6 degrees.
pub const WALK_MAX_SD_DEG: f32 = 0.1;

/// The stride to take a scan of `points` points at ([`ScanFit::with_stride`]):
/// one in [`WALK_STRIDE`], or in fewer for a scan of fewer than
/// [`WALK_STRIDE`] times [`WALK_POINTS`] points, every point for one of
/// fewer than twice [`WALK_POINTS`].
pub fn walk_stride(points: usize) -> u32 {
    (points / WALK_POINTS).clamp(1, WALK_STRIDE as usize) as u32
}

/// A scan thinned to a point a voxel (a board's feed: the voxel's mean, a
/// few thousand points a scan) is taken one point in this many.
///
/// Why 2: on the boards' twin (town seeds 1-3) one point in two gives the
/// same verdicts as every point at 0.5 and 1.5 degrees per 100 m, as many
/// fixes held back at 1 degree, at about 5e6 instructions a scan on an
/// mps2-an386 instead of 1e7 (docs/session.md "On the boards").
pub const BOARD_WALK_STRIDE: u32 = 2;
/// A scan with fewer pairs than this gives no heading ([`ScanFit::yaw`]):
/// a scan in the open, or one the map has not seen before.
pub const WALK_MIN_PAIRS: u32 = 50;
/// A pair whose point lies farther than this (m) from its plane is left
/// out: a point on something that moved, or on the far side of a thin
/// wall, not the odometry's turn.
pub const WALK_GATE_M: f32 = 0.3;
/// A voxel is a plane's point once this many points fell in it: a voxel of
/// one or two points is where the scans' noise, not a surface, is.
pub const WALK_MIN_HITS: u16 = 3;
/// Scans the figure is taken over ([`OdometryWalk::rms`]): five seconds
/// of a 10 Hz LiDAR.
pub const WALK_SCANS: usize = 48;
/// Scans an [`OdometryWalk`] needs before it gives a figure.
pub const WALK_MIN_SCANS: usize = 8;
/// An estimate is not reported `Converged` while the two robots' walk
/// together ([`pair_walk`]) is more than this (degrees): a scan's heading
/// then strays from its map's by about a degree, and a right match of the
/// maps is more than a degree off the truth at the scans.
///
/// Why this value: on the town (2 robots, five seeds, true labels) the
/// pair's figure is about 0.11 at a heading walk of 0.5 degrees per
/// 100 m, 0.20 at 1 and 0.28 at 1.5. Every wrong `Converged` there came at
/// 0.19 and more (`e_r` 1.01-1.35 degrees, the estimates right against
/// the maps' own truth), none at 1 degree per 100 m, 20 at 1.5, 89 at 2
/// (docs/session.md).
pub const WALK_LIMIT_DEG: f32 = 0.25;

/// The two robots' walk together (degrees): the root sum of squares of
/// their figures ([`OdometryWalk::excess`]), of the one known when the
/// other is not, `None` when neither is.
pub fn pair_walk(own: Option<f32>, peer: Option<f32>) -> Option<f32> {
    match (own, peer) {
        (None, None) => None,
        (a, b) => {
            let (a, b) = (a.unwrap_or(0.0), b.unwrap_or(0.0));
            Some(libm::sqrtf(a * a + b * b))
        }
    }
}

/// The point-to-plane normal equations of one scan against the map before
/// it is fused, in a turn about the sensor's vertical axis and a
/// horizontal shift: their solution is how far the odometry turned the
/// scan from the map ([`ScanFit::yaw`]).
///
/// A plane is a voxel's mean with the normal of the voxel means around it
/// (the 27 cells, within 1.5 cells), planar and not level: a level plane
/// says nothing of a turn. One Gauss-Newton step from where the odometry
/// put the scan: the turn is a fraction of a degree, the shift
/// centimetres, where the terms are linear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanFit {
    centre: [f32; 3],
    /// Upper triangle of `JᵀJ`: (yaw, yaw), (yaw, x), (yaw, y), (x, x),
    /// (x, y), (y, y).
    h: [f32; 6],
    g: [f32; 3],
    /// Sum of the squared residuals.
    rr: f32,
    pairs: u32,
    seen: u32,
    stride: u32,
}

impl ScanFit {
    /// An empty fit of a scan taken at `centre` (the sensor, map frame),
    /// of its raw points: one in [`WALK_STRIDE`] is taken.
    pub fn new(centre: [f32; 3]) -> Self {
        Self::with_stride(centre, WALK_STRIDE)
    }

    /// An empty fit that takes one point in `stride` (at least 1): a scan
    /// thinned to a point a voxel, as a board is fed, takes more of its
    /// points ([`BOARD_WALK_STRIDE`]).
    pub fn with_stride(centre: [f32; 3], stride: u32) -> Self {
        ScanFit { centre, h: [0.0; 6], g: [0.0; 3], rr: 0.0, pairs: 0, seen: 0, stride: stride.max(1) }
    }

    /// Pairs taken so far.
    pub fn pairs(&self) -> u32 {
        self.pairs
    }

    /// Takes point `p` (map frame) of the scan, one in its stride's
    /// calls ([`ScanFit::with_stride`]): its pair with the plane of the voxel it falls in, if that
    /// voxel has one. A point that is not finite is passed over.
    pub fn add<S: VoxelStorage>(&mut self, map: &LocalMap<S>, p: [f32; 3]) {
        let take = self.seen.is_multiple_of(self.stride);
        self.seen = self.seen.wrapping_add(1);
        if !take || !p.iter().all(|v| v.is_finite()) {
            return;
        }
        let Some((q, n)) = plane_at(map, p) else { return };
        let r = n[0] * (p[0] - q[0]) + n[1] * (p[1] - q[1]) + n[2] * (p[2] - q[2]);
        if r.is_nan() || r.abs() > WALK_GATE_M {
            return;
        }
        let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
        let j = [n[1] * dx - n[0] * dy, n[0], n[1]];
        let h = &mut self.h;
        h[0] += j[0] * j[0];
        h[1] += j[0] * j[1];
        h[2] += j[0] * j[2];
        h[3] += j[1] * j[1];
        h[4] += j[1] * j[2];
        h[5] += j[2] * j[2];
        for (g, ji) in self.g.iter_mut().zip(j) {
            *g += ji * r;
        }
        self.rr += r * r;
        self.pairs += 1;
    }

    /// The turn (degrees, counter-clockwise about the vertical) that
    /// brings the scan onto the map, less the sign: how far the odometry
    /// turned the scan from the map. `None` with fewer than
    /// [`WALK_MIN_PAIRS`] pairs, or when they do not hold the turn.
    pub fn yaw(&self) -> Option<f32> {
        self.turn().map(|t| t.0)
    }

    /// [`ScanFit::yaw`] and its variance (degrees squared): the residuals'
    /// variance after the fit times the turn's entry of the normal
    /// equations' inverse. What the map's and the scan's own noise would
    /// turn a scan by, which [`OdometryWalk::excess`] takes out.
    pub fn turn(&self) -> Option<(f32, f32)> {
        if self.pairs < WALK_MIN_PAIRS {
            return None;
        }
        let [a, b, c, d, e, f] = self.h;
        // The adjugate of the symmetric [[a b c] [b d e] [c e f]].
        let (c00, c01, c02) = (d * f - e * e, c * e - b * f, b * e - c * d);
        let (c11, c12, c22) = (a * f - c * c, b * c - a * e, a * d - b * b);
        let det = a * c00 + b * c01 + c * c02;
        if !(det.is_finite() && det > 1e-9 * a.max(1.0) * d.max(1.0) * f.max(1.0)) {
            return None;
        }
        let g = self.g;
        let x = [
            (c00 * g[0] + c01 * g[1] + c02 * g[2]) / det,
            (c01 * g[0] + c11 * g[1] + c12 * g[2]) / det,
            (c02 * g[0] + c12 * g[1] + c22 * g[2]) / det,
        ];
        let explained = x[0] * g[0] + x[1] * g[1] + x[2] * g[2];
        let sigma_sq = (self.rr - explained).max(0.0) / (self.pairs - 3) as f32;
        let variance = sigma_sq * c00 / det * (180.0 / core::f32::consts::PI) * (180.0 / core::f32::consts::PI);
        let yaw = x[0].to_degrees();
        (yaw.is_finite() && variance.is_finite()).then_some((yaw, variance))
    }
}

/// The plane at `p`: the mean of the voxel it falls in (of at least
/// [`WALK_MIN_HITS`] points) and the normal of the voxel means around it,
/// planar (the smallest eigenvalue under a tenth of the middle one) and
/// not level (its horizontal part at least half).
fn plane_at<S: VoxelStorage>(map: &LocalMap<S>, p: [f32; 3]) -> Option<([f32; 3], [f32; 3])> {
    let v = map.get_at(p)?;
    if v.hits() < WALK_MIN_HITS {
        return None;
    }
    let res = map.resolution();
    let q = v.position(res);
    let mut moments = Moments::around(q, res);
    for (_, o) in map.neighbours(v.key) {
        moments.add((o.position(res), 1.0));
    }
    if moments.count() < 6 {
        return None;
    }
    let (l0, l1, n) = moments.eigen()?;
    let planar = l0.is_finite() && l1.is_finite() && l1 > 0.0 && l0 < 0.1 * l1;
    let upright = n[0] * n[0] + n[1] * n[1] >= 0.25;
    (planar && upright).then_some((q, n))
}

/// A robot's figure of its odometry's heading walk: the root mean square of
/// the turns ([`ScanFit::yaw`]) of its last [`WALK_SCANS`] scans against
/// its map. Over a floor of a few hundredths of a degree (the map's own
/// noise), it grows with the walk (docs/session.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometryWalk {
    turns: [f32; WALK_SCANS],
    variances: [f32; WALK_SCANS],
    len: usize,
    next: usize,
}

impl Default for OdometryWalk {
    fn default() -> Self {
        Self::new()
    }
}

impl OdometryWalk {
    /// No scans yet.
    pub const fn new() -> Self {
        OdometryWalk { turns: [0.0; WALK_SCANS], variances: [0.0; WALK_SCANS], len: 0, next: 0 }
    }

    /// Takes a scan's turn and its variance ([`ScanFit::turn`]; a scan
    /// with none, or with one known no better than [`WALK_MAX_SD_DEG`], is
    /// passed over).
    pub fn push(&mut self, turn: Option<(f32, f32)>) {
        let known = |v: f32| (0.0..=WALK_MAX_SD_DEG * WALK_MAX_SD_DEG).contains(&v);
        let Some((t, v)) = turn.filter(|(t, v)| t.is_finite() && known(*v)) else { return };
        if let (Some(slot), Some(var)) = (self.turns.get_mut(self.next), self.variances.get_mut(self.next)) {
            (*slot, *var) = (t, v);
        }
        self.next = (self.next + 1) % WALK_SCANS;
        self.len = (self.len + 1).min(WALK_SCANS);
    }

    /// The root mean square of the last scans' turns (degrees), once
    /// [`WALK_MIN_SCANS`] scans gave one.
    pub fn rms(&self) -> Option<f32> {
        if self.len < WALK_MIN_SCANS {
            return None;
        }
        let turns = self.turns.get(..self.len)?;
        let sum: f32 = turns.iter().map(|t| t * t).sum();
        Some(libm::sqrtf(sum / self.len as f32))
    }

    /// The root mean square of the last scans' turns beyond what their
    /// fits' own noise explains (degrees): the mean square less the mean
    /// variance, once [`WALK_MIN_SCANS`] scans gave one.
    pub fn excess(&self) -> Option<f32> {
        let rms = self.rms()?;
        let variances = self.variances.get(..self.len)?;
        let noise: f32 = variances.iter().sum::<f32>() / self.len as f32;
        Some(libm::sqrtf((rms * rms - noise).max(0.0)))
    }
}
