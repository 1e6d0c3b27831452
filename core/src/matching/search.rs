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

use super::footprint::{Footprint, Grid, POOL_LEVELS};
use super::pyramid::Reach;
use crate::region::{words_for, Region};
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
/// Scene points whose cells are cached per yaw; more are thinned by stride.
pub const MAX_POINTS: usize = 2048;
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
/// Cells as `i16` (a footprint is far narrower; cells beyond are clamped
/// and stay outside the grid at every offset) and the mask (five group
/// bits) beside them, six bytes a point, in words the caller gives
/// ([`SearchScratch`]): the cache is the largest thing a search keeps, and
/// its loop reads one stream.
struct YawCells<'s> {
    yaw: i16,
    len: usize,
    /// Cell i, cell j, mask.
    cells: &'s mut [[i16; 3]],
    /// The most each [`CHUNK`] of cells can add to a score (their class
    /// groups), for scoring that stops once a floor is out of reach.
    most: &'s mut [u16],
    /// The sum of `most`: the most the whole cache can score.
    most_total: u32,
}

impl<'s> YawCells<'s> {
    /// Words a cache of `points` cells takes.
    const fn words(points: usize) -> usize {
        words_for::<[i16; 3]>(points) + words_for::<u16>(points.div_ceil(CHUNK))
    }

    /// The most cells (at most `limit`) a cache in `words` words holds.
    fn fitting(words: usize, limit: usize) -> usize {
        // Six bytes and a sixteenth a cell, less rounding.
        let mut n = limit.min(words.saturating_mul(64) / 97);
        while n > 0 && Self::words(n) > words {
            n -= 1;
        }
        n
    }

    /// A cache of `points` cells carved out of `region`.
    fn carve(region: &mut Region<'s>, points: usize) -> Option<Self> {
        let cells = region.take::<[i16; 3]>(points).ok()?;
        let most = region.take::<u16>(points.div_ceil(CHUNK)).ok()?;
        Some(YawCells { yaw: 0, len: 0, cells, most, most_total: 0 })
    }

    /// Cells it holds at most.
    fn capacity(&self) -> usize {
        self.cells.len()
    }
}

/// Words a search works in, the caller's: the windowed search's cache of
/// scene cells ([`SearchScratch::WINDOWED`] words hold [`MAX_POINTS`] of
/// them; fewer words, fewer cells, thinned by a stride) or the prior-free
/// search's cache and heading order. A robot carves them out of memory
/// that is idle while it searches; [`Matcher::align`](super::Matcher::align)
/// and [`search_global`] take them from the stack.
pub struct SearchScratch<'s> {
    words: &'s mut [u32],
    /// EM's memory of each scene entry's block between iterations
    /// ([`SearchScratch::with_reach`]).
    reach: &'s mut [Reach],
}

impl<'s> SearchScratch<'s> {
    /// Words that hold the windowed search's whole cache.
    pub const WINDOWED: usize = YawCells::words(MAX_POINTS);
    /// Words of a windowed search's cache of `points` cells.
    pub const fn windowed(points: usize) -> usize {
        YawCells::words(points)
    }
    /// Words a prior-free search with `points` cells per candidate and
    /// `headings` headings needs.
    pub const fn global(points: usize, headings: usize) -> usize {
        YawCells::words(points) + words_for::<[u32; 2]>(headings)
    }

    /// Scratch in `words` (any contents).
    pub fn new(words: &'s mut [u32]) -> Self {
        SearchScratch { words, reach: &mut [] }
    }

    /// The same, with room for EM to remember, between its iterations, the
    /// block of model cells each sampled scene entry reached ([`Reach`]:
    /// one per entry, [`MatchSettings::max_scene_entries`] for all of them;
    /// with fewer, the rest are looked up every iteration). The answers are
    /// the same bit for bit, with or without; EM's lookups are fewer.
    ///
    /// [`MatchSettings::max_scene_entries`]: super::MatchSettings::max_scene_entries
    pub fn with_reach(self, reach: &'s mut [Reach]) -> Self {
        SearchScratch { words: self.words, reach }
    }

    /// EM's room to remember blocks, emptied (a new level or new maps).
    pub(crate) fn reach(&mut self) -> &mut [Reach] {
        self.reach.fill(Reach::EMPTY);
        &mut *self.reach
    }

    /// The scene cells a windowed search caches: all of them up to what the
    /// words hold (at most [`MAX_POINTS`]).
    pub fn windowed_points(&self) -> usize {
        YawCells::fitting(self.words.len(), MAX_POINTS)
    }

    fn region(&mut self) -> Region<'_> {
        Region::new(&mut *self.words)
    }
}

/// Cells scored between two checks of the floor.
const CHUNK: usize = 32;

/// Set bits of a class mask: a table for the footprint's five group bits
/// (a Cortex-M4 has no population count instruction), else counted.
#[inline]
fn ones(m: u32) -> u32 {
    const TABLE: [u8; 32] = {
        let mut t = [0u8; 32];
        let mut i = 0;
        while i < 32 {
            t[i] = (i as u32).count_ones() as u8;
            i += 1;
        }
        t
    };
    TABLE.get(m as usize).map_or_else(|| m.count_ones(), |&c| u32::from(c))
}

/// A cell index as the cache keeps it.
fn narrow(v: i32) -> i16 {
    v.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16
}

impl Scorer<'_> {
    /// Fills `out` with the model cell of every (strided) scene point at `yaw`.
    fn cells(&self, yaw: i16, out: &mut YawCells<'_>) {
        let (s, c) = libm::sincosf(f32::from(yaw) * self.step);
        let p = &self.prior;
        // Rz(theta) * [a b; d e] and Rz(theta) * [tx; ty].
        let m = [c * p[0] - s * p[3], c * p[1] - s * p[4], s * p[0] + c * p[3], s * p[1] + c * p[4]];
        let o = [c * p[2] - s * p[5], s * p[2] + c * p[5]];
        out.yaw = yaw;
        out.len = 0;
        out.most.fill(0);
        out.most_total = 0;
        for ((q, mask), slot) in self.scene.occupied().step_by(self.stride).zip(out.cells.iter_mut()) {
            let x = m[0] * q[0] + m[1] * q[1] + o[0];
            let y = m[2] * q[0] + m[3] * q[1] + o[1];
            let (ci, cj) = self.model.cell_of(x, y);
            // Footprint masks are one byte (the five group bits).
            *slot = [narrow(ci), narrow(cj), (mask & 0xFF) as i16];
            if let Some(most) = out.most.get_mut(out.len / CHUNK) {
                let add = if self.semantic { mask.count_ones() } else { 1 };
                *most = most.saturating_add(add as u16);
                out.most_total += add;
            }
            out.len += 1;
        }
    }

    /// Score of a block of translations at the yaw of `cells`.
    #[inline]
    fn score(&self, cells: &YawCells<'_>, i0: i32, j0: i32, h: usize) -> u32 {
        self.score_above(cells, i0, j0, h, 0)
    }

    /// The score if it is above `floor`; otherwise some value at most
    /// `floor` (scoring stops once the cells left cannot lift it above).
    /// Branch and bound discards such a node whatever its exact score.
    #[inline]
    fn score_above(&self, cells: &YawCells<'_>, i0: i32, j0: i32, h: usize, floor: u32) -> u32 {
        let Some(grid) = self.model.grid(h) else { return 0 };
        let points = cells.cells.get(..cells.len).unwrap_or(&[]);
        let mut left = cells.most_total;
        let mut total = 0;
        for (chunk, &most) in points.chunks(CHUNK).zip(cells.most.iter()) {
            total += score_points(chunk, &grid, i0, j0, self.semantic);
            left -= u32::from(most);
            if total + left <= floor {
                return total + left;
            }
        }
        total
    }
}

/// The search's inner loop, kept apart so that its few values stay in
/// registers: for each cached scene cell shifted by `(i0, j0)`, the model
/// grid's mask there ([`Grid::mask`], inlined: one unsigned test per axis
/// for "inside, or a window reaching into the grid from below"), its
/// common class groups counted (bare occupancy unless `semantic`).
#[inline(never)]
fn score_points(points: &[[i16; 3]], grid: &Grid<'_>, i0: i32, j0: i32, semantic: bool) -> u32 {
    let (words, shift, width, height, span) = grid.parts();
    if semantic {
        score_cells::<true>(points, words, shift, (width, height, span), i0, j0)
    } else {
        score_cells::<false>(points, words, shift, (width, height, span), i0, j0)
    }
}

/// [`score_points`] for one kind of score (class groups, or occupancy).
#[inline(always)]
fn score_cells<const SEMANTIC: bool>(
    points: &[[i16; 3]],
    words: &[u32],
    shift: u32,
    (width, height, span): (i32, i32, i32),
    i0: i32,
    j0: i32,
) -> u32 {
    // Valid cells: -span < i < width, i.e. (i + span - 1) below width + span - 1.
    let (ri, rj) = ((width + span - 1) as u32, (height + span - 1) as u32);
    let (si, sj) = (i0 + span - 1, j0 + span - 1);
    let mut total = 0u32;
    for &[ci, cj, mask] in points {
        let (i, j, mask) = (i32::from(ci), i32::from(cj), mask as u32);
        if ((i + si) as u32) >= ri || ((j + sj) as u32) >= rj {
            continue;
        }
        let at = ((j + j0).max(0) * width + (i + i0).max(0)) as usize;
        let Some(&w) = words.get(at) else { continue };
        let m = (w >> shift) & 0xFF;
        total += if SEMANTIC { ones(mask & m) } else { u32::from(m != 0) };
    }
    total
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
/// [`MAX_POINTS`] cells thins the scene's cells by a stride).
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
    let best = branch_and_bound(&scorer, &roots, grid.w, start, &mut cells, &mut evaluations)?;
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
/// within `w` of the prior: the best placement that beats `best`.
#[inline(always)]
fn branch_and_bound(
    scorer: &Scorer<'_>,
    roots: &[Node],
    w: i32,
    mut best: Option<Node>,
    cells: &mut YawCells<'_>,
    evaluations: &mut u32,
) -> Option<Node> {
    let beats = |n: &Node, best: &Option<Node>| best.is_none_or(|b| n.score > b.score);
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
    best
}

/// Settings of the prior-free coarse search ([`search_global`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GlobalSearch {
    /// Yaw step (radians, default 3 degrees): every heading is tried.
    pub yaw_step: f32,
    /// Scene cells scored per candidate at most (default 128, at most
    /// [`MAX_GLOBAL_POINTS`]; more are thinned by a fixed stride, the same
    /// at every level of the search so that its bounds hold). The search
    /// only proposes placements for the matcher to refine and judge: 128
    /// cells found every placement 256 did in the prior-free protocol
    /// (`cosem eval --global`: 360 placements each of five KITTI pairs with
    /// a network's labels at twice the usual severity and three synthetic
    /// streets, all found; no false accept among 90 negatives), at half the
    /// cost of a node: a robot's search with a network's labels took 125-189
    /// M instructions at 256.
    pub points: usize,
    /// Candidates kept: the best placements, each away from the others
    /// ([`GlobalSearch::exclusion`]); default 3, at most
    /// [`MAX_GLOBAL_CANDIDATES`].
    pub candidates: usize,
    /// Placements count as distinct when this far apart in translation (m,
    /// default 4) or in yaw (radians, default 15 degrees).
    pub exclusion: (f32, f32),
    /// Nodes a prior-free alignment may score, over all its searches
    /// (default: no limit, an exhaustive search): a compute budget, such as
    /// a robot's ([`crate::robot::SEARCH_NODES`]). The branch and bound
    /// explores the headings of the best bounds first, so it meets a true
    /// placement early; the rest of an exhaustive search proves it best.
    /// Maps that share nothing prune little: when the budget runs out the
    /// search keeps the best placements found so far
    /// ([`GlobalSearchOutcome::exhausted`]), which the matcher's verdict
    /// judges as any other. A cut search can only miss a placement (a
    /// `NoOverlap` that waits for the next meeting), never make a wrong one
    /// pass.
    pub max_evaluations: u32,
    /// Whether the prior-free alignment searches for the best placement
    /// alone first and refines it, searching again for the few best only
    /// when it fails (default): the cheapest way when the best placement is
    /// usually right, as in a one-shot exchange. Otherwise one search keeps
    /// [`GlobalSearch::candidates`] placements and each is refined in turn:
    /// a session's robot searches every round until it has a fix, mostly on
    /// maps that share nothing (the best placement refused), where the
    /// second search would score most of the first one's nodes again, and
    /// where a meeting starts the right placement is often the second or
    /// third (a junction turned by 90 degrees scores best).
    pub best_alone_first: bool,
}

impl GlobalSearch {
    /// The documented defaults (every heading at 3 degrees, no budget), as
    /// a constant for presets.
    pub const DEFAULT: GlobalSearch = GlobalSearch {
        yaw_step: 3.0 * (core::f32::consts::PI / 180.0),
        points: 128,
        candidates: 3,
        exclusion: (4.0, 15.0 * (core::f32::consts::PI / 180.0)),
        max_evaluations: u32::MAX,
        best_alone_first: true,
    };
}

impl Default for GlobalSearch {
    fn default() -> Self {
        GlobalSearch::DEFAULT
    }
}

/// Most scene cells a prior-free search scores per candidate (its cache is
/// on the stack: 12 bytes each).
pub const MAX_GLOBAL_POINTS: usize = 512;

/// Most candidates a prior-free search keeps.
pub const MAX_GLOBAL_CANDIDATES: usize = 4;

/// One placement the prior-free search found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// `T_model_scene` (x, y, yaw).
    pub transform: Isometry3<f32>,
    /// Its score.
    pub score: u32,
}

/// What the prior-free coarse search found.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalSearchOutcome {
    /// The best distinct placements, best first.
    pub candidates: heapless::Vec<Candidate, MAX_GLOBAL_CANDIDATES>,
    /// Nodes scored.
    pub evaluations: u32,
    /// The search stopped at [`GlobalSearch::max_evaluations`]: the
    /// candidates are the best found until then, not proven best.
    pub exhausted: bool,
}

impl GlobalSearchOutcome {
    /// The best score, and the best of the placements away from it.
    pub fn scores(&self) -> (u32, u32) {
        let s = |k: usize| self.candidates.get(k).map(|c| c.score).unwrap_or(0);
        (s(0), s(1))
    }
}

/// Translation offsets (cells) a search may try, inclusive.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    i: (i32, i32),
    j: (i32, i32),
}

/// How far apart two placements must be to count as distinct.
#[derive(Clone, Copy, Debug)]
struct Separation {
    /// Radius in cells, squared.
    r2: i64,
    /// Yaw steps.
    dyaw: i32,
    /// Yaw steps in a full turn.
    turn: i32,
}

impl Separation {
    fn yaw_near(&self, a: i16, b: i16) -> bool {
        let d = (i32::from(a) - i32::from(b)).abs();
        d.min(self.turn - d) <= self.dyaw
    }

    /// Whether every translation of `node`'s block is near `c`.
    fn covers(&self, c: &Node, node: &Node) -> bool {
        if !self.yaw_near(c.yaw, node.yaw) {
            return false;
        }
        let size = 1i32 << node.h;
        let far = |a: i16, ca: i16| {
            let (a, ca) = (i32::from(a), i32::from(ca));
            i64::from((a - ca).abs().max((a + size - 1 - ca).abs()))
        };
        let (di, dj) = (far(node.i, c.i), far(node.j, c.j));
        di * di + dj * dj <= self.r2
    }

    fn near(&self, a: &Node, b: &Node) -> bool {
        let (di, dj) = (i64::from(a.i) - i64::from(b.i), i64::from(a.j) - i64::from(b.j));
        self.yaw_near(a.yaw, b.yaw) && di * di + dj * dj <= self.r2
    }
}

/// The best distinct leaves found so far, best first.
struct Kept {
    nodes: heapless::Vec<Node, MAX_GLOBAL_CANDIDATES>,
    capacity: usize,
    sep: Separation,
}

impl Kept {
    /// A node must beat this to matter.
    fn threshold(&self) -> u32 {
        if self.nodes.len() < self.capacity {
            0
        } else {
            self.nodes.last().map(|n| n.score).unwrap_or(0)
        }
    }

    /// Whether exploring `node` can change what is kept.
    fn promising(&self, node: &Node) -> bool {
        node.score > self.threshold() && !self.nodes.iter().any(|c| c.score >= node.score && self.sep.covers(c, node))
    }

    /// Keeps a leaf: it replaces the kept ones near it when better, or is
    /// dropped when one near it is better.
    fn offer(&mut self, leaf: Node) {
        if self.nodes.iter().any(|c| c.score >= leaf.score && self.sep.near(c, &leaf)) {
            return;
        }
        let sep = self.sep;
        self.nodes.retain(|c| !sep.near(c, &leaf));
        let at = self.nodes.iter().position(|c| c.score < leaf.score).unwrap_or(self.nodes.len());
        if at < self.capacity {
            if self.nodes.len() == self.capacity {
                self.nodes.pop();
            }
            let _ = self.nodes.insert(at, leaf);
        }
    }
}

/// Branch and bound from `root` (a block at one yaw), offering every leaf
/// within `bounds` that may matter to `kept`.
fn descend(
    scorer: &Scorer<'_>,
    cells: &YawCells<'_>,
    root: Node,
    bounds: &Bounds,
    kept: &mut Kept,
    evaluations: &mut u32,
    budget: u32,
) {
    let mut stack: heapless::Vec<Node, STACK> = heapless::Vec::new();
    let _ = stack.push(root);
    while let Some(node) = stack.pop() {
        if !kept.promising(&node) {
            continue;
        }
        if *evaluations >= budget {
            return;
        }
        if node.h == 0 {
            let (i, j) = (i32::from(node.i), i32::from(node.j));
            if (bounds.i.0..=bounds.i.1).contains(&i) && (bounds.j.0..=bounds.j.1).contains(&j) {
                kept.offer(node);
            }
            continue;
        }
        let half = 1i32 << (node.h - 1);
        let mut children: [Option<Node>; 4] = [None; 4];
        for (c, (di, dj)) in [(0, 0), (half, 0), (0, half), (half, half)].into_iter().enumerate() {
            let (i, j) = (i32::from(node.i) + di, i32::from(node.j) + dj);
            if i > bounds.i.1 || j > bounds.j.1 || i + half <= bounds.i.0 || j + half <= bounds.j.0 {
                continue;
            }
            let score = scorer.score_above(cells, i, j, usize::from(node.h - 1), kept.threshold());
            *evaluations += 1;
            children[c] = Some(Node { yaw: node.yaw, i: i as i16, j: j as i16, h: node.h - 1, score });
        }
        // Push the lowest first so the highest is explored first.
        let mut order = [0usize, 1, 2, 3];
        order.sort_unstable_by_key(|&c| (children[c].map(|n| n.score).unwrap_or(0), core::cmp::Reverse(c)));
        for &c in &order {
            if let Some(n) = children[c] {
                if kept.promising(&n) {
                    let _ = stack.push(n);
                }
            }
        }
    }
}

/// Most headings a prior-free search tries.
const MAX_YAWS: usize = 720;
// The windowed search's words serve any prior-free search too.
const _: () = assert!(SearchScratch::WINDOWED >= SearchScratch::global(MAX_GLOBAL_POINTS, MAX_YAWS));
/// Roots of one heading sorted before descending (more go in grid order).
const MAX_YAW_ROOTS: usize = 256;

/// A node of the lattice as a candidate placement: its heading and
/// offset, after the scene's centre is moved to the origin.
fn placement(n: &Node, step: f32, cell: f32, centre: &Isometry3<f32>) -> Candidate {
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f32::from(n.yaw) * step);
    let shift = Isometry3::from_parts(Translation3::new(f32::from(n.i) * cell, f32::from(n.j) * cell, 0.0), yaw);
    Candidate { transform: shift * centre, score: n.score }
}

/// The centre of the scene's scored cells and their radius about it.
#[inline(always)]
fn scene_centre(scene: &Footprint<'_>, stride: usize) -> ([f32; 2], f32) {
    let (mut c, mut n) = ([0.0f32; 2], 0.0f32);
    for (q, _) in scene.occupied().step_by(stride) {
        c = [c[0] + q[0], c[1] + q[1]];
        n += 1.0;
    }
    let c = [c[0] / n.max(1.0), c[1] / n.max(1.0)];
    let radius = scene
        .occupied()
        .step_by(stride)
        .map(|(q, _)| libm::sqrtf((q[0] - c[0]) * (q[0] - c[0]) + (q[1] - c[1]) * (q[1] - c[1])))
        .fold(0.0f32, f32::max);
    (c, radius)
}

/// Every heading's best root bound, best first (ties to the lower
/// heading): the order headings are searched in.
#[inline(always)]
/// Fills `order` (one entry per heading) with each heading's best bound
/// and the heading, best first (ties toward the lower heading).
fn heading_order(
    scorer: &Scorer<'_>,
    cells: &mut YawCells<'_>,
    bounds: &Bounds,
    order: &mut [[u32; 2]],
    evaluations: &mut u32,
) {
    let top = POOL_LEVELS - 1;
    let block = 1i32 << top;
    let roots = |b: (i32, i32)| (b.0..=b.1).step_by(block as usize);
    for (k, slot) in order.iter_mut().enumerate() {
        scorer.cells(k as i16, cells);
        let mut best_root = 0;
        for i in roots(bounds.i) {
            for j in roots(bounds.j) {
                best_root = best_root.max(scorer.score_above(cells, i, j, top, best_root));
                *evaluations += 1;
            }
        }
        *slot = [best_root, k as u32];
    }
    order.sort_unstable_by(|a, b| b[0].cmp(&a[0]).then(a[1].cmp(&b[1])));
}

/// Searches every heading and every offset at which the scene's footprint
/// lands on the model's for the placements that agree best (class groups by
/// cell when `semantic`, bare occupancy otherwise): with no prior, by branch
/// and bound over the lattice of `settings.yaw_step` by one model cell,
/// headings in the order of their best bound. The scene turns about the
/// centre of its footprint, whose place is searched over the model's
/// footprint and half the scene's radius around it: the frame a map is
/// written in does not matter. Keeps the best `settings.candidates`
/// placements that are distinct from each other, best first.
pub fn search_global(
    model: Footprint<'_>,
    scene: Footprint<'_>,
    settings: &GlobalSearch,
    semantic: bool,
) -> Option<GlobalSearchOutcome> {
    let mut words = [0u32; SearchScratch::global(MAX_GLOBAL_POINTS, MAX_YAWS)];
    search_global_in(model, scene, settings, semantic, &mut SearchScratch::new(&mut words))
}

/// [`search_global`] with its cache and heading order in `scratch`
/// ([`SearchScratch::global`] words; `None` in fewer).
pub fn search_global_in(
    model: Footprint<'_>,
    scene: Footprint<'_>,
    settings: &GlobalSearch,
    semantic: bool,
    scratch: &mut SearchScratch<'_>,
) -> Option<GlobalSearchOutcome> {
    let cell = model.cell();
    let step = settings.yaw_step;
    if !(cell.is_finite() && cell > 0.0 && step.is_finite() && step > 0.0)
        || scene.occupied_len() == 0
        || !model.has_pooled_grids()
    {
        return None;
    }
    let n_yaw = (libm::ceilf(2.0 * core::f32::consts::PI / step) as usize).clamp(1, MAX_YAWS);
    let step = 2.0 * core::f32::consts::PI / n_yaw as f32;
    let points = settings.points.clamp(1, MAX_GLOBAL_POINTS);
    let stride = scene.occupied_len().div_ceil(points);
    let (c, radius) = scene_centre(&scene, stride);
    let centre = Isometry3::from_parts(Translation3::new(-c[0], -c[1], 0.0), UnitQuaternion::identity());
    let scorer = Scorer { model, scene, prior: [1.0, 0.0, -c[0], 0.0, 1.0, -c[1]], step, stride, semantic };
    let margin = libm::ceilf(0.5 * radius / cell) as i32;
    let (oi, oj) = model.cell_of(0.0, 0.0);
    let (w, h) = model.size();
    let bounds =
        Bounds { i: (-oi - margin, w as i32 - 1 - oi + margin), j: (-oj - margin, h as i32 - 1 - oj + margin) };
    if bounds.i.1 - bounds.i.0 > i32::from(i16::MAX) / 2 || bounds.j.1 - bounds.j.0 > i32::from(i16::MAX) / 2 {
        return None;
    }
    let top = POOL_LEVELS - 1;
    let block = 1i32 << top;
    let roots = |b: (i32, i32)| (b.0..=b.1).step_by(block as usize);
    let mut region = scratch.region();
    let mut cells = YawCells::carve(&mut region, points)?;
    let order = region.take::<[u32; 2]>(n_yaw).ok()?;
    let mut evaluations = 0u32;
    heading_order(&scorer, &mut cells, &bounds, order, &mut evaluations);
    let r = settings.exclusion.0 / cell;
    let sep =
        Separation { r2: (r * r) as i64, dyaw: libm::floorf(settings.exclusion.1 / step) as i32, turn: n_yaw as i32 };
    let mut kept =
        Kept { nodes: heapless::Vec::new(), capacity: settings.candidates.clamp(1, MAX_GLOBAL_CANDIDATES), sep };
    let mut yaw_roots: heapless::Vec<Node, MAX_YAW_ROOTS> = heapless::Vec::new();
    let budget = settings.max_evaluations;
    for &[bound, k] in order.iter() {
        if bound <= kept.threshold() || bound == 0 {
            break;
        }
        scorer.cells(k as i16, &mut cells);
        // This heading's roots, best first (in grid order if too many).
        yaw_roots.clear();
        for i in roots(bounds.i) {
            for j in roots(bounds.j) {
                let score = scorer.score_above(&cells, i, j, top, kept.threshold());
                evaluations += 1;
                let root = Node { yaw: k as i16, i: i as i16, j: j as i16, h: top as u8, score };
                if yaw_roots.push(root).is_err() {
                    descend(&scorer, &cells, root, &bounds, &mut kept, &mut evaluations, budget);
                }
            }
        }
        yaw_roots.sort_unstable_by(|a, b| b.score.cmp(&a.score).then((a.i, a.j).cmp(&(b.i, b.j))));
        for root in yaw_roots.iter() {
            if root.score <= kept.threshold() {
                break;
            }
            descend(&scorer, &cells, *root, &bounds, &mut kept, &mut evaluations, budget);
        }
        if evaluations >= budget {
            break;
        }
    }
    let candidates = kept.nodes.iter().map(|n| placement(n, step, cell, &centre)).collect();
    Some(GlobalSearchOutcome { candidates, evaluations, exhausted: evaluations >= budget })
}
