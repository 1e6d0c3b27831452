//! The prior-free search: every heading and offset of the scene's
//! footprint over the model's, keeping a few distinct best placements.

use super::super::footprint::{Footprint, POOL_LEVELS};
use super::score::{Node, Scorer, SearchScratch, YawCells, STACK};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

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

impl GlobalSearch {
    /// The window a placement it proposes is refined in: its candidates are
    /// exact on the search's lattice, so a few cells (4 m) and two yaw steps
    /// (at least 6 degrees) around one hold its error.
    pub fn refinement_window(&self) -> super::SearchWindow {
        let deg = core::f32::consts::PI / 180.0;
        super::SearchWindow { translation: 4.0, yaw: (2.0 * self.yaw_step).max(6.0 * deg) }
    }
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
    // On a work budget (`SearchScratch::with_work`): the heading order
    // scores every heading's roots, and each heading's roots are scored
    // before the node budget is looked at again; what is left pays for
    // those, or there is no search.
    let per_heading = (roots(bounds.i).count() * roots(bounds.j).count()) as u64;
    let cost = scratch.work().costs().global_node;
    let cap = u64::from(scratch.work().nodes(cost));
    let beyond = per_heading + 4;
    let mut budget = settings.max_evaluations;
    if cost > 0 && cap < n_yaw as u64 * per_heading + beyond {
        scratch.refuse_work();
        return None;
    }
    let lowered = cost > 0 && cap - beyond < u64::from(budget);
    if lowered {
        budget = (cap - beyond) as u32;
    }
    let outcome = search_headings(&scorer, settings, (n_yaw, step, cell, &bounds, budget), &centre, scratch);
    if let Some(o) = &outcome {
        scratch.charge_nodes(o.evaluations, cost);
        if lowered && o.exhausted {
            scratch.refuse_work();
        }
    }
    outcome
}

/// [`search_global_in`]'s branch and bound, heading by heading, within
/// `budget` nodes (and at most a heading's roots and a node's children
/// beyond it).
#[inline(always)]
fn search_headings(
    scorer: &Scorer<'_>,
    settings: &GlobalSearch,
    (n_yaw, step, cell, bounds, budget): (usize, f32, f32, &Bounds, u32),
    centre: &Isometry3<f32>,
    scratch: &mut SearchScratch<'_>,
) -> Option<GlobalSearchOutcome> {
    let points = settings.points.clamp(1, MAX_GLOBAL_POINTS);
    let top = POOL_LEVELS - 1;
    let block = 1i32 << top;
    let roots = |b: (i32, i32)| (b.0..=b.1).step_by(block as usize);
    let mut region = scratch.region();
    let mut cells = YawCells::carve(&mut region, points)?;
    let order = region.take::<[u32; 2]>(n_yaw).ok()?;
    let mut evaluations = 0u32;
    heading_order(scorer, &mut cells, bounds, order, &mut evaluations);
    let r = settings.exclusion.0 / cell;
    let sep =
        Separation { r2: (r * r) as i64, dyaw: libm::floorf(settings.exclusion.1 / step) as i32, turn: n_yaw as i32 };
    let mut kept =
        Kept { nodes: heapless::Vec::new(), capacity: settings.candidates.clamp(1, MAX_GLOBAL_CANDIDATES), sep };
    let mut yaw_roots: heapless::Vec<Node, MAX_YAW_ROOTS> = heapless::Vec::new();
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
                    descend(scorer, &cells, root, bounds, &mut kept, &mut evaluations, budget);
                }
            }
        }
        yaw_roots.sort_unstable_by(|a, b| b.score.cmp(&a.score).then((a.i, a.j).cmp(&(b.i, b.j))));
        for root in yaw_roots.iter() {
            if root.score <= kept.threshold() {
                break;
            }
            descend(scorer, &cells, *root, bounds, &mut kept, &mut evaluations, budget);
        }
        if evaluations >= budget {
            break;
        }
    }
    let candidates = kept.nodes.iter().map(|n| placement(n, step, cell, centre)).collect();
    Some(GlobalSearchOutcome { candidates, evaluations, exhausted: evaluations >= budget })
}
