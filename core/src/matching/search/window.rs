//! The search of a window around a prior: every heading and offset within
//! it, branch and bound from the coarsest pooled level down.

use super::super::footprint::{Footprint, POOL_LEVELS};
use super::score::{Node, Scorer, SearchScratch, YawCells, STACK};
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

/// Roots (top-level blocks at each heading) of a windowed search, on the
/// stack: the matcher's windows (15 m and 30 degrees with a prior, 4 m and
/// 6 degrees around a prior-free candidate) need at most 61 at cells of
/// 1 m or more; a wider window coarsens its heading step to fit.
const MAX_ROOTS: usize = 128;

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

/// Searches `window` around `prior` (a `T_model_scene`) for the placement of
/// the scene's footprint that best agrees with the model's: class by class
/// when `semantic`, by bare occupancy otherwise; its cache of scene cells on
/// the stack.
pub fn search(
    model: Footprint<'_>,
    scene: Footprint<'_>,
    prior: &Isometry3<f32>,
    window: &SearchWindow,
    semantic: bool,
) -> Option<SearchOutcome> {
    let mut words = [0u32; SearchScratch::WINDOWED];
    search_in(model, scene, prior, window, semantic, &mut SearchScratch::new(&mut words))
}

/// [`search`] with its cache in `scratch` (a cache smaller than
/// [`MAX_POINTS`](super::MAX_POINTS) cells thins the scene's cells by a stride).
pub fn search_in(
    model: Footprint<'_>,
    scene: Footprint<'_>,
    prior: &Isometry3<f32>,
    window: &SearchWindow,
    semantic: bool,
    scratch: &mut SearchScratch<'_>,
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
    let grid = WindowGrid::of(cell, &scene, &p, window);
    // The nodes the work budget pays for: at least the roots and the prior,
    // else no search at all.
    let cost = scratch.work().costs().window_node;
    let cap = scratch.work().nodes(cost);
    if u64::from(cap) <= grid.roots() {
        scratch.refuse_work();
        return None;
    }
    let points = scratch.windowed_points();
    let mut region = scratch.region();
    let mut cells = YawCells::carve(&mut region, points).filter(|c| c.capacity() > 0)?;
    let stride = scene.occupied_len().div_ceil(cells.capacity());
    let scorer = Scorer { model, scene, prior: p, step: grid.step, stride, semantic };
    let mut evaluations = 0u32;
    let roots = window_roots(&scorer, &grid, &mut cells, &mut evaluations);
    scorer.cells(0, &mut cells);
    let prior_score = scorer.score(&cells, 0, 0, 0);
    evaluations += 1;
    // The prior itself is a candidate: nothing worse than it is accepted.
    let start = (grid.w >= 0).then_some(Node { yaw: 0, i: 0, j: 0, h: 0, score: prior_score });
    let (best, cut) = branch_and_bound(&scorer, &roots, (grid.w, cap), start, &mut cells, &mut evaluations);
    scratch.charge_nodes(evaluations, cost);
    if cut {
        scratch.refuse_work();
    }
    let best = best?;
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f32::from(best.yaw) * grid.step);
    let shift = Isometry3::from_parts(Translation3::new(f32::from(best.i) * cell, f32::from(best.j) * cell, 0.0), yaw);
    Some(SearchOutcome { transform: shift * prior, score: best.score, prior_score, evaluations })
}

/// The window's grid: the yaw step, the half-widths in cells and headings,
/// and the blocks of the coarsest pooled level covering it.
struct WindowGrid {
    step: f32,
    w: i32,
    block: i32,
    blocks: i32,
    n_yaw: i32,
}

impl WindowGrid {
    #[inline(always)]
    fn of(cell: f32, scene: &Footprint<'_>, p: &[f32; 6], window: &SearchWindow) -> WindowGrid {
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
        WindowGrid { step, w, block, blocks, n_yaw }
    }

    /// Nodes the roots and the prior take: scored before the branch and
    /// bound starts.
    fn roots(&self) -> u64 {
        let n = u64::from((2 * self.n_yaw + 1).unsigned_abs()) * u64::from(self.blocks.unsigned_abs()).pow(2);
        n.min(MAX_ROOTS as u64) + 1
    }
}

/// Every heading's blocks of the coarsest level, scored, best first (ties
/// toward the prior's yaw).
#[inline(always)]
fn window_roots(
    scorer: &Scorer<'_>,
    g: &WindowGrid,
    cells: &mut YawCells<'_>,
    evaluations: &mut u32,
) -> heapless::Vec<Node, MAX_ROOTS> {
    let mut roots: heapless::Vec<Node, MAX_ROOTS> = heapless::Vec::new();
    for k in -g.n_yaw..=g.n_yaw {
        scorer.cells(k as i16, cells);
        for a in 0..g.blocks {
            for b in 0..g.blocks {
                let (i, j) = (-g.w + a * g.block, -g.w + b * g.block);
                let score = scorer.score(cells, i, j, POOL_LEVELS - 1);
                *evaluations += 1;
                let node = Node { yaw: k as i16, i: i as i16, j: j as i16, h: (POOL_LEVELS - 1) as u8, score };
                if roots.push(node).is_err() {
                    break;
                }
            }
        }
    }
    roots.sort_unstable_by(|x, y| {
        y.score
            .cmp(&x.score)
            .then(x.yaw.unsigned_abs().cmp(&y.yaw.unsigned_abs()))
            .then(x.yaw.cmp(&y.yaw))
            .then((x.i, x.j).cmp(&(y.i, y.j)))
    });
    roots
}

/// Branch and bound from the roots (best first) down to single cells
/// within `w` of the prior: the best placement that beats `best`, and
/// whether it stopped short of scoring more than `cap` nodes in all (the
/// best found so far: a work budget's, [`SearchScratch::with_work`]).
#[inline(always)]
fn branch_and_bound(
    scorer: &Scorer<'_>,
    roots: &[Node],
    (w, cap): (i32, u32),
    mut best: Option<Node>,
    cells: &mut YawCells<'_>,
    evaluations: &mut u32,
) -> (Option<Node>, bool) {
    let beats = |n: &Node, best: &Option<Node>| best.is_none_or(|b| n.score > b.score);
    // A node's children are four nodes more.
    let last = cap.saturating_sub(4);
    for root in roots.iter() {
        if !beats(root, &best) {
            break;
        }
        if cells.yaw != root.yaw {
            scorer.cells(root.yaw, cells);
        }
        let mut stack: heapless::Vec<Node, STACK> = heapless::Vec::new();
        let _ = stack.push(*root);
        while let Some(node) = stack.pop() {
            if !beats(&node, &best) {
                continue;
            }
            if node.h > 0 && *evaluations > last {
                return (best, true);
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
                let floor = best.map_or(0, |b| b.score);
                let score = scorer.score_above(cells, i, j, usize::from(node.h - 1), floor);
                *evaluations += 1;
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
    (best, false)
}
