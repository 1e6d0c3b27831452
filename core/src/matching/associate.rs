//! E-step: data association through the voxel hash, and the accumulation of
//! the weighted normal equations in the same pass (so no correspondence
//! buffer is needed).
//!
//! Each scene entry, moved by the current transform, looks at the model
//! entries of the 27 cells around it and takes the one of highest weight
//! `exp(-d^2 / 2 sigma^2) * s`, where `s` is the semantic compatibility of the
//! method. The Gaussian weight is also the Welsch robust kernel of the
//! least-squares M-step: far pairs fade out instead of pulling.

use super::footprint::GROUP_BITS;
use super::pyramid::{normal_of, Entry, Level, PackedNormal, Reach};
use super::settings::{Cost, Method};
use crate::classes::NUM_CLASSES;
use crate::map::VoxelKey;
use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};

/// `exp(x)` for `x <= 0`, to about 1e-4 relative: a weight, not a
/// probability to report. Plain arithmetic, so every platform rounds alike.
#[inline]
pub fn exp_weight(x: f32) -> f32 {
    if x.is_nan() || x <= -80.0 {
        return 0.0;
    }
    // exp(x) = 2^k * exp(r), |r| <= ln2/2, with a degree-5 polynomial.
    let k = libm::roundf(x * core::f32::consts::LOG2_E);
    let r = x - k * core::f32::consts::LN_2;
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0)))));
    p * f32::from_bits(((k as i32 + 127) as u32) << 23)
}

/// Probability that two entries carry the same class, each distribution
/// taken as its top class with its probability and the rest spread evenly.
pub fn compatibility(method: Method, a: &Entry, b: &Entry) -> f32 {
    match method {
        Method::Geometric => 1.0,
        Method::CosemHard => {
            if a.class == b.class && a.class != u8::MAX {
                1.0
            } else {
                0.0
            }
        }
        Method::Cosem => {
            let others = (NUM_CLASSES - 1) as f32;
            let pa = f32::from(a.confidence) / 255.0;
            let pb = f32::from(b.confidence) / 255.0;
            let (qa, qb) = ((1.0 - pa) / others, (1.0 - pb) / others);
            if a.class == b.class {
                pa * pb + others * qa * qb
            } else {
                pa * qb + pb * qa + (others - 1.0) * qa * qb
            }
        }
    }
}

/// Slots of [`Sampling`]: one per class and one for entries without one.
const SAMPLING_SLOTS: usize = NUM_CLASSES + 1;

/// Which scene entries an E-step uses: every `stride[c]`-th entry of class
/// `c`, in level order. A class-balanced thinning: the budget is shared
/// equally among the classes present (water-filling), so rare classes such
/// as poles, trunks and signs, which pin the direction along a street, keep
/// all their entries while road and building are thinned.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sampling {
    stride: [u32; SAMPLING_SLOTS],
}

fn sampling_slot(class: u8) -> usize {
    usize::from(class).min(SAMPLING_SLOTS - 1)
}

impl Sampling {
    /// About `budget` entries of `level`, shared equally among classes.
    pub fn balanced(level: &Level<'_>, budget: usize) -> Self {
        let mut count = [0usize; SAMPLING_SLOTS];
        for i in 0..level.len() {
            if let Some(class) = level.class_at(i) {
                count[sampling_slot(class)] += 1;
            }
        }
        let mut order = [0usize; SAMPLING_SLOTS];
        for (i, o) in order.iter_mut().enumerate() {
            *o = i;
        }
        order.sort_unstable_by_key(|&i| (count[i], i));
        let mut left = budget.max(1);
        let mut classes = count.iter().filter(|&&c| c > 0).count();
        let mut stride = [1u32; SAMPLING_SLOTS];
        for &i in &order {
            let c = count[i];
            if c == 0 {
                continue;
            }
            let share = (left / classes.max(1)).max(1);
            let st = c.div_ceil(share).max(1);
            stride[i] = st as u32;
            left = left.saturating_sub(c.div_ceil(st));
            classes -= 1;
        }
        Sampling { stride }
    }
}

/// Sums of one E-step.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Normal {
    /// `sum w J^T J` over the sampled entries: what the M-step solves.
    pub h: Matrix6<f32>,
    /// The same, each entry counted `stride` times: an estimate of the sum
    /// over all entries, for the information matrix.
    pub h_all: Matrix6<f32>,
    /// `sum w J^T r`.
    pub g: Vector6<f32>,
    /// `sum w`.
    pub sum_w: f32,
    /// `sum w r^2`.
    pub sum_wr2: f32,
    /// `sum w |q|^2`: lever arm of the rotation.
    pub sum_wq2: f32,
    /// Associated scene entries.
    pub pairs: u32,
}

impl Normal {
    /// The pairs' RMS distance from the model frame's origin (weighted):
    /// the lever arm that makes a rotation comparable with a translation.
    pub fn lever(&self) -> f32 {
        if self.sum_w > 0.0 {
            libm::sqrtf(self.sum_wq2 / self.sum_w)
        } else {
            0.0
        }
    }

    fn new() -> Self {
        Normal {
            h: Matrix6::zeros(),
            h_all: Matrix6::zeros(),
            g: Vector6::zeros(),
            sum_w: 0.0,
            sum_wr2: 0.0,
            sum_wq2: 0.0,
            pairs: 0,
        }
    }

    fn add_row(&mut self, j: &Vector6<f32>, r: f32, w: f32, scale: Option<f32>) {
        // Upper triangle only; mirrored by `finish`.
        for a in 0..6 {
            let wa = w * j[a];
            self.g[a] += wa * r;
            for b in a..6 {
                self.h[(a, b)] += wa * j[b];
            }
        }
        if let Some(scale) = scale {
            for a in 0..6 {
                let wa = w * j[a] * scale;
                for b in a..6 {
                    self.h_all[(a, b)] += wa * j[b];
                }
            }
        }
        self.sum_wr2 += w * r * r;
    }

    fn finish(&mut self) {
        for a in 0..6 {
            for b in 0..a {
                self.h[(a, b)] = self.h[(b, a)];
                self.h_all[(a, b)] = self.h_all[(b, a)];
            }
        }
    }
}

/// A block's cell and side in one word (never `u64::MAX`).
fn block_code(key: VoxelKey, side: [i32; 3]) -> u64 {
    let axis = |v: i16| u64::from(v as u16);
    let sides = side.iter().enumerate().fold(0u64, |acc, (i, &d)| acc | (u64::from(d > 0) << i));
    axis(key.x) | (axis(key.y) << 16) | (axis(key.z) << 32) | (sides << 48)
}

/// The model entry a moved scene entry associates with, its weight,
/// squared distance and index in the level. It looks at the 2x2x2 block
/// of cells on `q`'s side of its cell, which holds every model entry
/// within half a cell of `q` (and some farther ones, up to `radius`); with
/// `reach`, the block the last E-step found for this entry, looked up
/// again only when it moved.
#[inline]
fn best_match(
    model: &Level<'_>,
    s: &Entry,
    q: &Point3<f32>,
    (sigma, radius, method): (f32, f32, Method),
    reach: Option<&mut Reach>,
) -> Option<(Entry, f32, f32, u32)> {
    let cell = model.locate_with_fraction([q.x, q.y, q.z])?;
    let (key, f) = (cell.key, cell.fraction);
    let step = |v: f32| if v < 0.5 { -1 } else { 1 };
    let (sx, sy, sz) = (step(f[0]), step(f[1]), step(f[2]));
    let block = [(0, 0, 0), (sx, 0, 0), (0, sy, 0), (0, 0, sz), (sx, sy, 0), (sx, 0, sz), (0, sy, sz), (sx, sy, sz)];
    let look = |(dx, dy, dz): (i32, i32, i32)| {
        key.offset(dx, dy, dz).map_or((0, 0), |k| {
            let (a, b) = model.cell_run(k);
            (a as u32, b as u32)
        })
    };
    let runs = match reach {
        Some(r) => {
            let code = block_code(key, [sx, sy, sz]);
            if r.block != code {
                *r = Reach { block: code, runs: block.map(look) };
            }
            r.runs
        }
        None => block.map(look),
    };
    let inv_two_sigma_sq = 0.5 / (sigma * sigma);
    let radius_sq = radius * radius;
    let mut best: Option<(Entry, f32, f32, u32)> = None;
    for (a, b) in runs {
        for i in a..b {
            let Some(m) = model.entry(i as usize) else { break };
            let d = [q.x - m.position[0], q.y - m.position[1], q.z - m.position[2]];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            if d2 > radius_sq {
                continue;
            }
            let c = compatibility(method, s, &m);
            if c <= 0.0 {
                continue;
            }
            let w = exp_weight(-d2 * inv_two_sigma_sq) * c;
            if best.is_none_or(|(_, bw, _, _)| w > bw) {
                best = Some((m, w, d2, i));
            }
        }
    }
    best
}

/// How one E-step associates.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pass {
    /// Gaussian width (m).
    pub sigma: f32,
    /// Largest association distance (m).
    pub radius: f32,
    /// Semantic compatibility.
    pub method: Method,
    /// Residual.
    pub cost: Cost,
    /// Which scene entries take part.
    pub sampling: Sampling,
    /// Also sum the information over all entries (`Normal::h_all`).
    pub information: bool,
}

/// One E-step at one level: associates every scene entry and accumulates the
/// normal equations of the M-step at the transform `t`.
///
/// `reach`: the blocks of the last E-step at this level, one per entry taken
/// in order (fewer: the rest looked up every time), kept for the next.
/// `memo`: the normals fitted so far of a model whose normals are fitted as
/// they are read ([`normal_of`]).
pub(crate) fn accumulate(
    model: &Level<'_>,
    scene: &Level<'_>,
    t: &Isometry3<f32>,
    pass: &Pass,
    (reach, memo): (&mut [Reach], &mut [PackedNormal]),
) -> Normal {
    let Pass { sigma, radius, method, cost, sampling, information } = *pass;
    let mut n = Normal::new();
    let mut reach = reach.iter_mut();
    // Countdown per class: an entry is used when its class's reaches zero.
    let mut skip = [0u32; SAMPLING_SLOTS];
    for i in 0..scene.len() {
        let Some(class) = scene.class_at(i) else { continue };
        let k = sampling_slot(class);
        if skip[k] > 0 {
            skip[k] -= 1;
            continue;
        }
        let stride = sampling.stride[k];
        skip[k] = stride - 1;
        let Some(s) = scene.entry(i) else { continue };
        let scale = information.then_some(stride as f32);
        let q = t * Point3::new(s.position[0], s.position[1], s.position[2]);
        let Some((m, w, _, index)) = best_match(model, &s, &q, (sigma, radius, method), reach.next()) else {
            continue;
        };
        if w.is_nan() || w <= 0.0 {
            continue;
        }
        n.pairs += 1;
        n.sum_w += w;
        n.sum_wq2 += w * q.coords.norm_squared();
        let mp = Vector3::new(m.position[0], m.position[1], m.position[2]);
        let diff = q.coords - mp;
        let normal = if cost == Cost::PointToPlane { normal_of(model, &m, index, memo) } else { None };
        if let Some(nm) = normal {
            let nv = Vector3::new(nm[0], nm[1], nm[2]);
            let r = nv.dot(&diff);
            let qxn = q.coords.cross(&nv);
            let j = Vector6::new(nv.x, nv.y, nv.z, qxn.x, qxn.y, qxn.z);
            n.add_row(&j, r, w, scale);
        } else {
            for k in 0..3 {
                let mut e = Vector3::zeros();
                e[k] = 1.0;
                let qxe = q.coords.cross(&e);
                let j = Vector6::new(e.x, e.y, e.z, qxe.x, qxe.y, qxe.z);
                n.add_row(&j, diff[k], w, scale);
            }
        }
    }
    n.finish();
    n
}

/// Agreement of the two finest levels under `t`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Agreement {
    /// Scene entries with a model entry within one cell.
    pub inliers: u32,
    /// Fraction of the scene entries with a class that have a same-class
    /// model entry within one cell (entries of an unknown class can neither
    /// agree nor disagree: they count on neither side).
    pub overlap: f32,
    /// RMS distance of the inlier pairs.
    pub rmse: f32,
    /// Of the scene's standing entries (classes with a footprint group: not
    /// ground) that the model saw around (an entry of `cover` within one of
    /// its cells), the fraction with a model entry of the same group within
    /// one cell of the finest level.
    pub agreement: f32,
    /// Fraction of the scene's standing entries that the model saw around.
    pub coverage: f32,
}

/// The final pass over the scene entries of the finest level (one in
/// `stride`): the agreement (inliers, the conventions' overlap, RMSE). The
/// 2x2x2 block
/// around a moved entry holds every model entry within half a cell; the other
/// 19 cells of its neighbourhood are read only when that block does not
/// settle the agreement.
pub(crate) fn agreement(
    model: &Level<'_>,
    cover: Option<&Level<'_>>,
    scene: &Level<'_>,
    t: &Isometry3<f32>,
    stride: usize,
) -> Agreement {
    let res = model.resolution();
    let res_sq = res * res;
    let stride = stride.max(1);
    let (mut inliers, mut same, mut sum_d2, mut classed) = (0u32, 0u32, 0.0f32, 0u32);
    let (mut standing, mut covered, mut agreeing) = (0u32, 0u32, 0u32);
    let group = |c: u8| GROUP_BITS.get(usize::from(c)).copied().unwrap_or(0);
    let empty_around = cover.and_then(|c| EmptyAround::new(model, c));
    for s in (0..scene.len()).step_by(stride).filter_map(|i| scene.entry(i)) {
        let known = s.class != u8::MAX;
        classed += u32::from(known);
        let q = t * Point3::new(s.position[0], s.position[1], s.position[2]);
        let g = group(s.class);
        let seen_around = g != 0 && cover.is_some_and(|c| near_any(c, [q.x, q.y, q.z]));
        standing += u32::from(g != 0);
        covered += u32::from(seen_around);
        let Some(cell) = model.locate_with_fraction([q.x, q.y, q.z]) else { continue };
        if empty_around.as_ref().is_some_and(|e| e.holds(cell.key)) {
            // No model entry within one cell: not an inlier, no agreement.
            continue;
        }
        let (nearest, same_class, same_group) = nearest_within_a_cell(model, &cell, &q, (known, s.class, g));
        if nearest <= res_sq {
            inliers += 1;
            sum_d2 += nearest;
            if same_class {
                same += 1;
            }
        }
        agreeing += u32::from(seen_around && same_group);
    }
    // Inliers are counted for the whole scene: the subset's count times the stride.
    Agreement {
        inliers: inliers.saturating_mul(stride as u32),
        overlap: same as f32 / classed.max(1) as f32,
        rmse: if inliers > 0 { libm::sqrtf(sum_d2 / inliers as f32) } else { 0.0 },
        agreement: agreeing as f32 / covered.max(1) as f32,
        coverage: covered as f32 / standing.max(1) as f32,
    }
}

/// Around a moved scene entry `q` in `cell` of the finest level: the
/// nearest model entry's squared distance within one cell, and whether a
/// model entry there has the entry's class (`known` and `class`) and its
/// footprint group (`g`, 0 for none). The 2x2x2 block on `q`'s side first;
/// the other 19 cells only when the block does not settle it.
fn nearest_within_a_cell(
    model: &Level<'_>,
    cell: &crate::map::CellPoint,
    q: &Point3<f32>,
    (known, class, g): (bool, u8, u32),
) -> (f32, bool, bool) {
    let res_sq = model.resolution() * model.resolution();
    let group = |c: u8| GROUP_BITS.get(usize::from(c)).copied().unwrap_or(0);
    let f = cell.fraction;
    let side = |v: f32| if v < 0.5 { -1 } else { 1 };
    let (sx, sy, sz) = (side(f[0]), side(f[1]), side(f[2]));
    let in_block = |dx: i32, dy: i32, dz: i32| (dx == 0 || dx == sx) && (dy == 0 || dy == sy) && (dz == 0 || dz == sz);
    // (nearest squared distance within one cell, a same-class entry
    // there, a same-group entry there)
    let mut found = (f32::INFINITY, false, false);
    let visit = |found: &mut (f32, bool, bool), dx: i32, dy: i32, dz: i32| {
        let Some(k) = cell.key.offset(dx, dy, dz) else { return };
        for m in model.cell(k) {
            let d = [q.x - m.position[0], q.y - m.position[1], q.z - m.position[2]];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            if d2 <= res_sq {
                found.0 = found.0.min(d2);
                found.1 |= known && m.class == class;
                found.2 |= g != 0 && group(m.class) == g;
            }
        }
    };
    for (dx, dy, dz) in
        [(0, 0, 0), (sx, 0, 0), (0, sy, 0), (0, 0, sz), (sx, sy, 0), (sx, 0, sz), (0, sy, sz), (sx, sy, sz)]
    {
        visit(&mut found, dx, dy, dz);
    }
    // Settled: the nearest is within half a cell (so nothing outside the
    // block is nearer) and a same-class entry was found (an entry of an
    // unknown class looks for none: its nearest is all it needs).
    if !((found.1 || !known) && (found.2 || g == 0) && found.0 <= 0.25 * res_sq) {
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if !in_block(dx, dy, dz) {
                        visit(&mut found, dx, dy, dz);
                    }
                }
            }
        }
    }
    found
}

/// Whether the 27 cells of the finest level around a cell are all empty,
/// read from a coarser level of the same pyramid (the cover): a coarse cell
/// holds an entry wherever a finer entry lies under it, so when every
/// coarse cell under those 27 is empty, so are they. One to eight lookups
/// instead of 27 for a scene entry that no model entry is near (in a
/// tracking round about as many as those that are: where the maps do not
/// overlap), with the same answer.
struct EmptyAround<'l> {
    coarse: &'l Level<'l>,
    /// Finest cells to a coarse cell along an axis.
    factor: i32,
}

impl<'l> EmptyAround<'l> {
    /// `None` unless `coarse` is a level of `fine`'s pyramid whose cells
    /// are a power of two of `fine`'s (the pyramid's levels are).
    fn new(fine: &Level<'_>, coarse: &'l Level<'l>) -> Option<Self> {
        let ratio = coarse.resolution() / fine.resolution();
        let factor = libm::roundf(ratio) as i32;
        let exact = factor >= 1 && (ratio - factor as f32).abs() < 1e-3 && (factor & (factor - 1)) == 0;
        exact.then_some(EmptyAround { coarse, factor })
    }

    /// Every cell within one of `key` (finest level) is empty.
    fn holds(&self, key: VoxelKey) -> bool {
        let span = |v: i16| {
            let v = i32::from(v);
            ((v - 1).div_euclid(self.factor), (v + 1).div_euclid(self.factor))
        };
        let ((x0, x1), (y0, y1), (z0, z1)) = (span(key.x), span(key.y), span(key.z));
        for x in x0..=x1 {
            for y in y0..=y1 {
                for z in z0..=z1 {
                    let (Ok(x), Ok(y), Ok(z)) = (i16::try_from(x), i16::try_from(y), i16::try_from(z)) else {
                        // Beyond the keys' range: nothing lies there.
                        continue;
                    };
                    if self.coarse.cell(VoxelKey::new(x, y, z)).next().is_some() {
                        return false;
                    }
                }
            }
        }
        true
    }
}

/// [`Agreement::agreement`] alone, to the bit, for ranking placements
/// (the look-alike check's dozen passes): ground entries and entries the
/// model did not see around are skipped before any lookup of the finest
/// level, and each search stops at the first same-group entry.
pub(crate) fn standing_agreement(
    model: &Level<'_>,
    cover: Option<&Level<'_>>,
    scene: &Level<'_>,
    t: &Isometry3<f32>,
    stride: usize,
) -> f32 {
    let Some(cover) = cover else { return 0.0 };
    let res_sq = model.resolution() * model.resolution();
    let group = |c: u8| GROUP_BITS.get(usize::from(c)).copied().unwrap_or(0);
    let (mut covered, mut agreeing) = (0u32, 0u32);
    for i in (0..scene.len()).step_by(stride.max(1)) {
        let g = scene.class_at(i).map_or(0, group);
        if g == 0 {
            continue;
        }
        let Some(s) = scene.entry(i) else { continue };
        let q = t * Point3::new(s.position[0], s.position[1], s.position[2]);
        if !near_any(cover, [q.x, q.y, q.z]) {
            continue;
        }
        covered += 1;
        let Some(key) = model.locate([q.x, q.y, q.z]) else { continue };
        let near_same_group = |dx: i32, dy: i32, dz: i32| {
            key.offset(dx, dy, dz).is_some_and(|k| {
                model.cell(k).any(|m| {
                    let d = [q.x - m.position[0], q.y - m.position[1], q.z - m.position[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= res_sq && group(m.class) == g
                })
            })
        };
        let found = (-1..=1).any(|dx| (-1..=1).any(|dy| (-1..=1).any(|dz| near_same_group(dx, dy, dz))));
        agreeing += u32::from(found);
    }
    agreeing as f32 / covered.max(1) as f32
}

/// Whether `level` has an entry in the cell of `p` or one of its 26
/// neighbours.
fn near_any(level: &Level<'_>, p: [f32; 3]) -> bool {
    let Some(key) = level.locate(p) else { return false };
    for dx in -1..=1 {
        for dy in -1..=1 {
            for dz in -1..=1 {
                if key.offset(dx, dy, dz).is_some_and(|k| level.cell(k).next().is_some()) {
                    return true;
                }
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    #[test]
    fn fast_exp_is_close() {
        let mut x = 0.0f32;
        while x > -30.0 {
            let (a, b) = (super::exp_weight(x), libm::expf(x));
            assert!((a - b).abs() <= 2e-4 * b, "{x}: {a} vs {b}");
            x -= 0.37;
        }
        assert_eq!(super::exp_weight(-100.0), 0.0);
        assert_eq!(super::exp_weight(f32::NAN), 0.0);
    }
}
