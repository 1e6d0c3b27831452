//! Coarse search: the best (x, y, yaw) within a window around the prior, by
//! branch and bound over the footprints (as Cartographer's fast correlative
//! scan matcher does for 2D scans).
//!
//! The score of a candidate is the number of (cell, class) pairs of the
//! scene's footprint that land on a model cell holding the same class:
//! `sum popcount(scene_mask & model_mask)`. A node of the search covers a
//! block of `2^h x 2^h` translations at one yaw; scoring it against the model
//! grid max-pooled over `2^h` cells bounds every translation in the block, so
//! whole blocks are discarded once a better leaf is known. The answer is the
//! exact optimum of the score over the window's lattice, found in a
//! deterministic order (ties go to the candidate nearest the prior).

use super::footprint::{Footprint, POOL_LEVELS};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// The region around the prior that the coarse search covers.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SearchWindow {
    /// Half-width of the translation window in x and y (m).
    pub translation: f32,
    /// Half-width of the yaw window (radians).
    pub yaw: f32,
}

const MAX_ROOTS: usize = 1024;
/// Scene points whose cells are cached per yaw; more are thinned by stride.
const MAX_POINTS: usize = 2048;
const STACK: usize = 4 * POOL_LEVELS + 4;

#[derive(Clone, Copy, Debug)]
struct Node {
    yaw: i16,
    i: i16,
    j: i16,
    h: u8,
    score: u32,
}

/// What the coarse search found.
#[derive(Clone, Copy, Debug)]
pub struct SearchOutcome {
    /// `Translation(x, y, 0) * Rz(yaw) * prior`.
    pub transform: Isometry3<f32>,
    /// Its score.
    pub score: u32,
    /// The score of the prior itself.
    pub prior_score: u32,
    /// Nodes scored.
    pub evaluations: u32,
}

struct Scorer<'a> {
    model: Footprint<'a>,
    scene: Footprint<'a>,
    /// Top two rows of the prior: [a b tx; d e ty].
    prior: [f32; 6],
    step: f32,
    stride: usize,
    /// Score classes (semantic methods) or bare occupancy (geometric).
    semantic: bool,
}

/// Scene points' model cells at one yaw and zero translation, with masks.
struct YawCells {
    yaw: i16,
    len: usize,
    cells: [(i32, i32, u32); MAX_POINTS],
}

impl Scorer<'_> {
    /// Fills `out` with the model cell of every (strided) scene point at `yaw`.
    fn cells(&self, yaw: i16, out: &mut YawCells) {
        let (s, c) = libm::sincosf(f32::from(yaw) * self.step);
        let p = &self.prior;
        // Rz(theta) * [a b; d e] and Rz(theta) * [tx; ty].
        let m = [c * p[0] - s * p[3], c * p[1] - s * p[4], s * p[0] + c * p[3], s * p[1] + c * p[4]];
        let o = [c * p[2] - s * p[5], s * p[2] + c * p[5]];
        out.yaw = yaw;
        out.len = 0;
        for ((q, mask), slot) in self.scene.occupied().step_by(self.stride).zip(out.cells.iter_mut()) {
            let x = m[0] * q[0] + m[1] * q[1] + o[0];
            let y = m[2] * q[0] + m[3] * q[1] + o[1];
            let (ci, cj) = self.model.cell_of(x, y);
            *slot = (ci, cj, mask);
            out.len += 1;
        }
    }

    /// Score of a block of translations at the yaw of `cells`.
    fn score(&self, cells: &YawCells, i0: i32, j0: i32, h: usize) -> u32 {
        let mut total = 0u32;
        if self.semantic {
            for &(ci, cj, mask) in cells.cells.iter().take(cells.len) {
                total += (mask & self.model.mask(h, ci + i0, cj + j0)).count_ones();
            }
        } else {
            for &(ci, cj, _) in cells.cells.iter().take(cells.len) {
                total += u32::from(self.model.mask(h, ci + i0, cj + j0) != 0);
            }
        }
        total
    }
}

/// Searches `window` around `prior` (a `T_model_scene`) for the placement of
/// the scene's footprint that best agrees with the model's: class by class
/// when `semantic`, by bare occupancy otherwise.
pub fn search(
    model: Footprint<'_>,
    scene: Footprint<'_>,
    prior: &Isometry3<f32>,
    window: &SearchWindow,
    semantic: bool,
) -> Option<SearchOutcome> {
    let cell = model.cell();
    let usable = |v: f32| v.is_finite() && v >= 0.0;
    if !(usable(cell) && cell > 0.0 && usable(window.translation) && usable(window.yaw))
        || scene.occupied_len() == 0
        || !model.has_pooled_grids()
    {
        return None;
    }
    let r = prior.rotation.to_rotation_matrix();
    let rm = r.matrix();
    let t = prior.translation.vector;
    let p = [rm[(0, 0)], rm[(0, 1)], t.x, rm[(1, 0)], rm[(1, 1)], t.y];
    // Yaw step: one cell of arc at the farthest scene cell, within [0.25, 3] degrees.
    let mut r_max = 0.0f32;
    for (q, _) in scene.occupied() {
        let x = p[0] * q[0] + p[1] * q[1] + p[2];
        let y = p[3] * q[0] + p[4] * q[1] + p[5];
        r_max = r_max.max(libm::sqrtf(x * x + y * y));
    }
    let deg = core::f32::consts::PI / 180.0;
    // One cell of arc at the farthest scene cell, between 1 and 3 degrees:
    // the scene's cells are two model cells wide, so finer steps add nothing.
    let mut step = (cell / r_max.max(cell)).clamp(1.0 * deg, 3.0 * deg);
    let w = libm::ceilf(window.translation / cell) as i32;
    let block = 1i32 << (POOL_LEVELS - 1);
    let blocks = ((2 * w + 1) + block - 1) / block;
    let mut n_yaw = libm::ceilf(window.yaw / step) as i32;
    while ((2 * n_yaw + 1) * blocks * blocks) as usize > MAX_ROOTS {
        step *= 1.5;
        n_yaw = libm::ceilf(window.yaw / step) as i32;
    }
    let stride = scene.occupied_len().div_ceil(MAX_POINTS);
    let scorer = Scorer { model, scene, prior: p, step, stride, semantic };
    let mut cells = YawCells { yaw: 0, len: 0, cells: [(0, 0, 0); MAX_POINTS] };
    let mut evaluations = 0u32;
    let mut roots: heapless::Vec<Node, MAX_ROOTS> = heapless::Vec::new();
    for k in -n_yaw..=n_yaw {
        scorer.cells(k as i16, &mut cells);
        for a in 0..blocks {
            for b in 0..blocks {
                let (i, j) = (-w + a * block, -w + b * block);
                let score = scorer.score(&cells, i, j, POOL_LEVELS - 1);
                evaluations += 1;
                let node = Node { yaw: k as i16, i: i as i16, j: j as i16, h: (POOL_LEVELS - 1) as u8, score };
                if roots.push(node).is_err() {
                    break;
                }
            }
        }
    }
    // Best first; ties toward the prior's yaw.
    roots.sort_unstable_by(|x, y| {
        y.score
            .cmp(&x.score)
            .then(x.yaw.unsigned_abs().cmp(&y.yaw.unsigned_abs()))
            .then(x.yaw.cmp(&y.yaw))
            .then((x.i, x.j).cmp(&(y.i, y.j)))
    });
    let mut best: Option<Node> = None;
    scorer.cells(0, &mut cells);
    let prior_score = scorer.score(&cells, 0, 0, 0);
    evaluations += 1;
    // The prior itself is a candidate: nothing worse than it is accepted.
    if w >= 0 {
        best = Some(Node { yaw: 0, i: 0, j: 0, h: 0, score: prior_score });
    }
    let beats = |n: &Node, best: &Option<Node>| best.is_none_or(|b| n.score > b.score);
    for root in roots.iter() {
        if !beats(root, &best) {
            break;
        }
        if cells.yaw != root.yaw {
            scorer.cells(root.yaw, &mut cells);
        }
        let mut stack: heapless::Vec<Node, STACK> = heapless::Vec::new();
        let _ = stack.push(*root);
        while let Some(node) = stack.pop() {
            if !beats(&node, &best) {
                continue;
            }
            if node.h == 0 {
                if i32::from(node.i).abs() <= w && i32::from(node.j).abs() <= w {
                    best = Some(node);
                }
                continue;
            }
            let half = 1i32 << (node.h - 1);
            let mut children: [Option<Node>; 4] = [None; 4];
            for (c, (di, dj)) in [(0, 0), (half, 0), (0, half), (half, half)].into_iter().enumerate() {
                let (i, j) = (i32::from(node.i) + di, i32::from(node.j) + dj);
                if i > w || j > w {
                    continue;
                }
                let score = scorer.score(&cells, i, j, usize::from(node.h - 1));
                evaluations += 1;
                children[c] = Some(Node { yaw: node.yaw, i: i as i16, j: j as i16, h: node.h - 1, score });
            }
            // Push the lowest first so the highest is explored first.
            let mut order = [0usize, 1, 2, 3];
            order.sort_unstable_by_key(|&c| (children[c].map(|n| n.score).unwrap_or(0), core::cmp::Reverse(c)));
            for &c in &order {
                if let Some(n) = children[c] {
                    if beats(&n, &best) {
                        let _ = stack.push(n);
                    }
                }
            }
        }
    }
    let best = best?;
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f32::from(best.yaw) * step);
    let shift = Isometry3::from_parts(Translation3::new(f32::from(best.i) * cell, f32::from(best.j) * cell, 0.0), yaw);
    Some(SearchOutcome { transform: shift * prior, score: best.score, prior_score, evaluations })
}
