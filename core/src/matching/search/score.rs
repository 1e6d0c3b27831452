//! The coarse searches' scorer: a scene footprint's cells at one heading,
//! cached in the caller's words ([`SearchScratch`]), scored against the
//! model's pooled grids by their common class groups.

use super::super::footprint::{Footprint, Grid, POOL_LEVELS};
use super::super::pyramid::{PackedNormal, Reach};
use super::super::work::Work;
use crate::region::{words_for, Region};

/// Scene points whose cells are cached per yaw; more are thinned by stride.
pub const MAX_POINTS: usize = 2048;
pub(super) const STACK: usize = 4 * POOL_LEVELS + 4;

#[derive(Clone, Copy, Debug)]
pub(super) struct Node {
    pub(super) yaw: i16,
    pub(super) i: i16,
    pub(super) j: i16,
    pub(super) h: u8,
    pub(super) score: u32,
}

pub(super) struct Scorer<'a> {
    pub(super) model: Footprint<'a>,
    pub(super) scene: Footprint<'a>,
    /// Top two rows of the prior: [a b tx; d e ty].
    pub(super) prior: [f32; 6],
    pub(super) step: f32,
    pub(super) stride: usize,
    /// Score classes (semantic methods) or bare occupancy (geometric).
    pub(super) semantic: bool,
}

/// Scene points' model cells at one yaw and zero translation, with masks.
/// Cells as `i16` (a footprint is far narrower; cells beyond are clamped
/// and stay outside the grid at every offset) and the mask (five group
/// bits) beside them, six bytes a point, in words the caller gives
/// ([`SearchScratch`]): the cache is the largest thing a search keeps, and
/// its loop reads one stream.
pub(super) struct YawCells<'s> {
    pub(super) yaw: i16,
    pub(super) len: usize,
    /// Cell i, cell j, mask.
    pub(super) cells: &'s mut [[i16; 3]],
    /// The most each [`CHUNK`] of cells can add to a score (their class
    /// groups), for scoring that stops once a floor is out of reach.
    pub(super) most: &'s mut [u16],
    /// The sum of `most`: the most the whole cache can score.
    pub(super) most_total: u32,
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
    pub(super) fn carve(region: &mut Region<'s>, points: usize) -> Option<Self> {
        let cells = region.take::<[i16; 3]>(points).ok()?;
        let most = region.take::<u16>(points.div_ceil(CHUNK)).ok()?;
        Some(YawCells { yaw: 0, len: 0, cells, most, most_total: 0 })
    }

    /// Cells it holds at most.
    pub(super) fn capacity(&self) -> usize {
        self.cells.len()
    }
}

/// Words a search works in, the caller's: the windowed search's cache of
/// scene cells ([`SearchScratch::WINDOWED`] words hold [`MAX_POINTS`] of
/// them; fewer words, fewer cells, thinned by a stride) or the prior-free
/// search's cache and heading order. A robot carves them out of memory
/// that is idle while it searches; [`Matcher::align`](crate::matching::Matcher::align)
/// and [`search_global`](super::search_global) take them from the stack.
pub struct SearchScratch<'s> {
    words: &'s mut [u32],
    /// EM's memory of each scene entry's block between iterations
    /// ([`SearchScratch::with_reach`]).
    reach: &'s mut [Reach],
    /// The normals EM fitted of a model that leaves them to it
    /// ([`SearchScratch::with_normals`]).
    normals: &'s mut [PackedNormal],
    /// What the searches and EM may still spend ([`SearchScratch::with_work`]):
    /// the caller's meter (a reference: a robot's stack holds scratches).
    work: Option<&'s mut Work>,
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
        SearchScratch { words, reach: &mut [], normals: &mut [], work: None }
    }

    /// The same, with room for EM to remember, between its iterations, the
    /// block of model cells each sampled scene entry reached ([`Reach`]:
    /// one per entry, [`MatchSettings::max_scene_entries`] for all of them;
    /// with fewer, the rest are looked up every iteration). The answers are
    /// the same bit for bit, with or without; EM's lookups are fewer.
    ///
    /// [`MatchSettings::max_scene_entries`]: crate::matching::MatchSettings::max_scene_entries
    pub fn with_reach(self, reach: &'s mut [Reach]) -> Self {
        SearchScratch { reach, ..self }
    }

    /// The same, with room for EM to keep the normals it fits of a model
    /// prepared without them ([`Pyramid::build_tracked_lazy`]): one per
    /// model entry for all of them; with fewer, the rest are fitted each
    /// time they are read. The answers are the same bit for bit.
    ///
    /// [`Pyramid::build_tracked_lazy`]: crate::matching::Pyramid::build_tracked_lazy
    pub fn with_normals(self, normals: &'s mut [PackedNormal]) -> Self {
        SearchScratch { normals, ..self }
    }

    /// The same, on a work budget: every search node, EM iteration and
    /// placement judged with this scratch is charged to `work`, and a step
    /// it cannot pay for is not taken ([`Work`]). Without one, nothing is
    /// refused.
    pub fn with_work(self, work: &'s mut Work) -> Self {
        SearchScratch { work: Some(work), ..self }
    }

    /// The work meter, as spent so far ([`Work::UNBOUNDED`] without one).
    pub fn work(&self) -> &Work {
        match &self.work {
            Some(w) => w,
            None => &Work::UNBOUNDED,
        }
    }

    /// Takes a step of `cost` from the meter, if it allows it (always
    /// without one).
    pub(crate) fn take_work(&mut self, cost: u32) -> bool {
        self.work.as_deref_mut().is_none_or(|w| w.take(cost))
    }

    /// Charges a search's `nodes`, `cost` each, to the meter.
    pub(crate) fn charge_nodes(&mut self, nodes: u32, cost: u32) {
        if let Some(w) = self.work.as_deref_mut() {
            w.charge_nodes(nodes, cost);
        }
    }

    /// Marks the meter's round cut short.
    pub(crate) fn refuse_work(&mut self) {
        if let Some(w) = self.work.as_deref_mut() {
            w.refuse();
        }
    }

    /// Empties EM's room to remember blocks (a new level or new maps), and
    /// to keep the normals it fits for a model that leaves them to it
    /// (`lazy`).
    pub(crate) fn clear_em_room(&mut self, lazy: bool) {
        self.reach.fill(Reach::EMPTY);
        if lazy {
            self.normals.fill(PackedNormal::UNFIT);
        }
    }

    /// EM's room, as its iterations since [`SearchScratch::clear_em_room`]
    /// filled it.
    pub(crate) fn em_room(&mut self, lazy: bool) -> (&mut [Reach], &mut [PackedNormal]) {
        let normals: &mut [PackedNormal] = if lazy { &mut *self.normals } else { &mut [] };
        (&mut *self.reach, normals)
    }

    /// The scene cells a windowed search caches: all of them up to what the
    /// words hold (at most [`MAX_POINTS`]).
    pub fn windowed_points(&self) -> usize {
        YawCells::fitting(self.words.len(), MAX_POINTS)
    }

    pub(super) fn region(&mut self) -> Region<'_> {
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
    pub(super) fn cells(&self, yaw: i16, out: &mut YawCells<'_>) {
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
    pub(super) fn score(&self, cells: &YawCells<'_>, i0: i32, j0: i32, h: usize) -> u32 {
        self.score_above(cells, i0, j0, h, 0)
    }

    /// The score if it is above `floor`; otherwise some value at most
    /// `floor` (scoring stops once the cells left cannot lift it above).
    /// Branch and bound discards such a node whatever its exact score.
    #[inline]
    pub(super) fn score_above(&self, cells: &YawCells<'_>, i0: i32, j0: i32, h: usize, floor: u32) -> u32 {
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
