//! Surface normals of a level's entries: the weighted covariance of
//! their neighbourhood, its smallest eigenvector in closed form, fitted by
//! a sorted sweep instead of hash lookups.

use super::*;

/// Weighted moments of a neighbourhood's offsets from its centre entry
/// (centred: better conditioned than absolute positions), the six
/// distinct second moments; entries farther than 1.5 cells are left out.
pub(crate) struct Moments {
    pub(super) centre: [f32; 3],
    pub(super) radius_sq: f32,
    pub(super) sum_w: f32,
    pub(super) m1: [f32; 3],
    pub(super) m2: [f32; 6],
    pub(super) count: u32,
}

impl Moments {
    pub(super) fn new(e: &Entry, resolution: f32) -> Self {
        Self::around(e.position, resolution)
    }

    /// Empty moments about `centre`, of the points within 1.5 cells of it.
    pub(crate) fn around(centre: [f32; 3], resolution: f32) -> Self {
        let r = 1.5 * resolution;
        Moments { centre, radius_sq: r * r, sum_w: 0.0, m1: [0.0; 3], m2: [0.0; 6], count: 0 }
    }

    /// Points taken so far.
    pub(crate) fn count(&self) -> u32 {
        self.count
    }

    #[inline]
    pub(crate) fn add(&mut self, (position, w): ([f32; 3], f32)) {
        let c = self.centre;
        let d = [position[0] - c[0], position[1] - c[1], position[2] - c[2]];
        if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > self.radius_sq {
            return;
        }
        self.sum_w += w;
        for (m, v) in self.m1.iter_mut().zip(d) {
            *m += w * v;
        }
        let wd = [w * d[0], w * d[1], w * d[2]];
        let m2 = &mut self.m2;
        m2[0] += wd[0] * d[0];
        m2[1] += wd[0] * d[1];
        m2[2] += wd[0] * d[2];
        m2[3] += wd[1] * d[1];
        m2[4] += wd[1] * d[2];
        m2[5] += wd[2] * d[2];
        self.count += 1;
    }

    /// The normal: planar when the smallest eigenvalue of the covariance
    /// is under a tenth of the middle one (and at least four entries).
    pub(super) fn normal(&self) -> PackedNormal {
        if self.count < 4 {
            return PackedNormal::NONE;
        }
        let Some((l0, l1, v)) = self.eigen() else { return PackedNormal::NONE };
        if !(l0.is_finite() && l1.is_finite()) || l1 <= 0.0 || l0 > 0.1 * l1 {
            return PackedNormal::NONE;
        }
        PackedNormal::pack(v)
    }

    /// The covariance's two smallest eigenvalues and the smallest one's
    /// eigenvector ([`smallest_eigen`]); `None` with no weight.
    pub(crate) fn eigen(&self) -> Option<(f32, f32, [f32; 3])> {
        let (sum_w, m1, m2) = (self.sum_w, self.m1, self.m2);
        if sum_w <= 0.0 {
            return None;
        }
        let mean = [m1[0] / sum_w, m1[1] / sum_w, m1[2] / sum_w];
        let c = |k: usize, a: usize, b: usize| m2[k] / sum_w - mean[a] * mean[b];
        smallest_eigen(&[c(0, 0, 0), c(1, 0, 1), c(2, 0, 2), c(3, 1, 1), c(4, 1, 2), c(5, 2, 2)])
    }
}

/// Fits the normal of `e`: the weighted covariance of the entries of all
/// classes of `level` within 1.5 cells, gathered by looking up the 27
/// cells around it (the fallback of [`NormalSweep`], with the same result
/// to the bit: the same entries in the same order).
pub(super) fn fit_normal(level: &Level<'_>, e: &Entry) -> PackedNormal {
    let mut m = Moments::new(e, level.resolution);
    for dx in -1..=1 {
        for dy in -1..=1 {
            for dz in -1..=1 {
                let Some(k) = e.key.offset(dx, dy, dz) else { continue };
                for o in level.cell(k) {
                    m.add((o.position, o.weight));
                }
            }
        }
    }
    m.normal()
}

/// [`fit_normal`] for the matcher's tests.
#[cfg(test)]
pub(crate) fn fit_normal_for_tests(level: &Level<'_>, e: &Entry) -> PackedNormal {
    fit_normal(level, e)
}

/// Fits the normals of a level's entries visited in sweep order (x, then
/// y, then z: [`VoxelKey::sweep`]) without a hash lookup: the entries of
/// the 3 x 3 columns around an entry are contiguous in that order, and
/// where each column starts only moves forward from one entry to the next,
/// so nine cursors walk the level once. Nine times cheaper than 27 lookups
/// per entry, which were most of preparing a map on board.
pub(super) struct NormalSweep {
    pub(super) cursors: [usize; 9],
}

impl NormalSweep {
    pub(super) fn new() -> Self {
        NormalSweep { cursors: [0; 9] }
    }

    /// The normal of `e`; `at(r)` is the level's index of the entry of
    /// rank `r` in sweep order, for ranks `0..len`. Calls come in sweep
    /// order.
    #[inline]
    pub(super) fn fit(
        &mut self,
        level: &Level<'_>,
        e: &Entry,
        len: usize,
        at: impl Fn(usize) -> Option<usize>,
    ) -> PackedNormal {
        // Keys compared as (x, y, z) in i32: one cell beyond the i16 range
        // still orders.
        let cell = |r: usize| {
            let i = if r < len { at(r)? } else { return None };
            let k = level.key_at(i)?;
            Some((i, (i32::from(k.x), i32::from(k.y), i32::from(k.z))))
        };
        let mut m = Moments::new(e, level.resolution);
        let (x, y, z) = (i32::from(e.key.x), i32::from(e.key.y), i32::from(e.key.z));
        let mut columns = self.cursors.iter_mut();
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(cursor) = columns.next() else { break };
                let (lo, hi) = ((x + dx, y + dy, z - 1), (x + dx, y + dy, z + 1));
                let mut c = *cursor;
                while cell(c).is_some_and(|(_, k)| k < lo) {
                    c += 1;
                }
                *cursor = c;
                while let Some((i, k)) = cell(c) {
                    if k > hi {
                        break;
                    }
                    if let Some(o) = level.point(i) {
                        m.add(o);
                    }
                    c += 1;
                }
            }
        }
        m.normal()
    }
}

/// Words a [`SweepPoint`] takes.
pub(super) const SWEEP_POINT_WORDS: usize = 6;

/// A level's entry gathered in sweep order for [`fit_gathered`]: its cell
/// as a sweep code (x, y, z of 18 bits each, offset so that one cell beyond
/// the key's range still orders) and its position and weight, read once
/// instead of once per neighbour.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub(super) struct SweepPoint {
    code: [u32; 2],
    position: [f32; 3],
    weight: f32,
}

/// One cell along an axis of [`SweepPoint`]'s code.
const X_STEP: i64 = 1 << 36;
const Y_STEP: i64 = 1 << 18;

impl SweepPoint {
    pub(super) fn new(key: VoxelKey, (position, weight): ([f32; 3], f32)) -> Self {
        let axis = |v: i16| (i64::from(v) + 0x1_0000) as u64;
        let code = (axis(key.x) << 36) | (axis(key.y) << 18) | axis(key.z);
        SweepPoint { code: [(code >> 32) as u32, code as u32], position, weight }
    }

    fn code(&self) -> i64 {
        ((u64::from(self.code[0]) << 32) | u64::from(self.code[1])) as i64
    }
}

/// [`NormalSweep::fit`] over entries gathered in sweep order (`points`):
/// the normal of the entry of rank `r`, with the same entries added in the
/// same order (to the bit), but reading contiguous memory. Calls come in
/// rank order.
pub(super) fn fit_gathered(cursors: &mut [usize; 9], points: &[SweepPoint], r: usize, resolution: f32) -> PackedNormal {
    let Some(e) = points.get(r) else { return PackedNormal::NONE };
    let r = 1.5 * resolution;
    let mut m = Moments { centre: e.position, radius_sq: r * r, sum_w: 0.0, m1: [0.0; 3], m2: [0.0; 6], count: 0 };
    let centre = e.code();
    let mut columns = cursors.iter_mut();
    for dx in -1..=1 {
        for dy in -1..=1 {
            let Some(cursor) = columns.next() else { break };
            let column = centre + dx * X_STEP + dy * Y_STEP;
            let (lo, hi) = (column - 1, column + 1);
            let mut c = *cursor;
            while points.get(c).is_some_and(|p| p.code() < lo) {
                c += 1;
            }
            *cursor = c;
            while let Some(p) = points.get(c) {
                if p.code() > hi {
                    break;
                }
                m.add((p.position, p.weight));
                c += 1;
            }
        }
    }
    m.normal()
}

/// Newton steps for the cubic's smallest root (quadratic convergence from
/// a simple root: about five are taken).
pub(super) const NEWTON_STEPS: usize = 24;

/// The smallest eigenvalue of a symmetric 3x3 matrix (upper triangle
/// `[a00, a01, a02, a11, a12, a22]`), the middle one, and a unit
/// eigenvector of the smallest: the smallest from the trigonometric
/// solution of the characteristic cubic, its eigenvector as the largest
/// cross product of two rows of `A - l0 I`, refined twice through the
/// Rayleigh quotient; the middle one from the remaining quadratic. A few
/// hundred operations, where an iterative decomposition takes thousands:
/// fitting normals is most of preparing a map. `None` for a multiple of
/// the identity or when the eigenvector is not determined.
pub(super) fn smallest_eigen(a: &[f32; 6]) -> Option<(f32, f32, [f32; 3])> {
    let [a00, a01, a02, a11, a12, a22] = *a;
    let p1 = a01 * a01 + a02 * a02 + a12 * a12;
    let q = (a00 + a11 + a22) / 3.0;
    let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
    let p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1;
    let p = libm::sqrtf(p2 / 6.0);
    if p.is_nan() || p <= 0.0 {
        return None;
    }
    // det(B) / 2 with B = (A - qI) / p.
    let det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02);
    let half = (det / (p * p * p) / 2.0).clamp(-1.0, 1.0);
    // The smallest eigenvalue is q + 2 p t, t the smallest root of
    // 4 t^3 - 3 t = half (t = cos(acos(half) / 3 + 2 pi / 3), in [-1, -1/2]).
    // Newton's method from t = -1 climbs to it monotonically (the cubic is
    // increasing and concave there), in f32: libm's cosf and acosf work in
    // f64, which a Cortex-M4F emulates in software. Slow only when the root
    // is double (t = -1/2: the two smallest eigenvalues equal, a
    // neighbourhood that is not planar, refused below); the Rayleigh
    // refinement fixes the rest.
    let mut t = -1.0f32;
    for _ in 0..NEWTON_STEPS {
        let slope = 12.0 * t * t - 3.0;
        if slope <= 0.0 {
            break;
        }
        let step = (4.0 * t * t * t - 3.0 * t - half) / slope;
        t -= step;
        if step.abs() < 1e-7 {
            break;
        }
    }
    let mut l0 = q + 2.0 * p * t.clamp(-1.0, -0.5);
    let cross =
        |u: [f32; 3], v: [f32; 3]| [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    let norm_sq = |v: [f32; 3]| v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let rayleigh = |v: [f32; 3]| {
        let av = [
            a00 * v[0] + a01 * v[1] + a02 * v[2],
            a01 * v[0] + a11 * v[1] + a12 * v[2],
            a02 * v[0] + a12 * v[1] + a22 * v[2],
        ];
        v[0] * av[0] + v[1] * av[1] + v[2] * av[2]
    };
    // The eigenvector from l0, then l0 again from it (its Rayleigh
    // quotient: the cubic's root loses digits in f32 when two eigenvalues
    // are close), twice.
    let mut v = [0.0f32; 3];
    for _ in 0..2 {
        let rows = [[a00 - l0, a01, a02], [a01, a11 - l0, a12], [a02, a12, a22 - l0]];
        let candidates = [cross(rows[0], rows[1]), cross(rows[0], rows[2]), cross(rows[1], rows[2])];
        let best = candidates.iter().copied().max_by(|x, y| norm_sq(*x).total_cmp(&norm_sq(*y)))?;
        let n = libm::sqrtf(norm_sq(best));
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        v = [best[0] / n, best[1] / n, best[2] / n];
        l0 = rayleigh(v);
    }
    // The other two are the roots of x^2 - s x + m = 0 (trace and sum of
    // principal minors less l0's share): the middle one is the smaller.
    let s = a00 + a11 + a22 - l0;
    let minors = a00 * a11 - a01 * a01 + a00 * a22 - a02 * a02 + a11 * a22 - a12 * a12;
    let m = minors - l0 * s;
    let l1 = (s - libm::sqrtf((s * s - 4.0 * m).max(0.0))) / 2.0;
    Some((l0, l1, v))
}
