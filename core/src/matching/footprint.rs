//! A map's semantic footprint: a bird's-eye grid where each cell holds the
//! set of class groups seen in its column (a 5-bit mask, one byte), with
//! max-pooled copies for branch and bound, and the list of occupied cells
//! for when the map is the scene. A storage word holds one cell of four
//! grids (a plane of four grids: byte `h % 4` of plane `h / 4` is grid
//! `h`), so a search over one grid reads a word and shifts it by a fixed
//! amount. Both anchor frames are level (z against gravity), so a column
//! mask is a rotation-invariant description of what stands there.

use crate::map::key::floor_f32;

/// Levels of max-pooling (windows of 1, 2, 4, ... 2^(POOL_LEVELS-1) cells).
pub const POOL_LEVELS: usize = 6;

/// The footprint bit of each class (by class index): classes are merged
/// into groups a segmentation network seldom confuses across, so a column
/// mask survives the network's errors (pole/trunk/sign, car/truck, building/
/// fence): vehicles (1), people (2), structures: building and fence (4),
/// vegetation and trunks (8: a Cityscapes network calls trunks vegetation),
/// poles and traffic signs (16). The ground classes (road, parking,
/// sidewalk, other-ground, terrain) get no bit: ground covers almost every
/// column a sensor saw, so its bits would score the overlap of the two maps'
/// seen areas, which peaks with the two sensors on top of each other
/// whatever the truth. What stands on the ground is not tied to the sensor.
pub const GROUP_BITS: [u32; 19] = [1, 1, 1, 1, 1, 2, 2, 2, 0, 0, 0, 0, 4, 4, 8, 8, 0, 16, 16];

/// Where a footprint lives inside the pyramid storage.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct FootprintInfo {
    /// Cell size (m).
    pub cell: f32,
    /// Grid origin (m), lower corner.
    pub origin: [f32; 2],
    /// Grid size in cells.
    pub width: usize,
    pub height: usize,
    /// Occupied cells listed (after the grids).
    pub occupied: usize,
    /// Grids kept: [`POOL_LEVELS`] for a model, 2 for a scene-only map
    /// (which needs its cells and their 2x2 pooling for the occupied list).
    pub grids: usize,
}

/// Storage words that `grids` grids of `cells` cells take: a plane of
/// `cells` words per four grids.
pub(crate) const fn packed(grids: usize, cells: usize) -> usize {
    grids.div_ceil(4) * cells
}

/// Where grid `h`'s cell `c` is: its word and the byte's shift.
#[inline(always)]
fn place(h: usize, cells: usize, c: usize) -> (usize, u32) {
    ((h / 4) * cells + c, ((h % 4) * 8) as u32)
}

/// Grid `h`'s cell `c` (0 beyond the words).
#[inline(always)]
fn cell_byte(words: &[u32], h: usize, cells: usize, c: usize) -> u32 {
    let (at, shift) = place(h, cells, c);
    words.get(at).map_or(0, |w| (w >> shift) & 0xFF)
}

/// Sets grid `h`'s cell `c`.
fn set_cell_byte(words: &mut [u32], h: usize, cells: usize, c: usize, v: u32) {
    let (at, shift) = place(h, cells, c);
    if let Some(w) = words.get_mut(at) {
        *w = (*w & !(0xFF << shift)) | ((v & 0xFF) << shift);
    }
}

impl FootprintInfo {
    /// u32 words the grids (packed) and the list take.
    pub fn words(&self) -> usize {
        self.list_start() + 3 * self.occupied
    }

    /// Where the occupied cells' list starts (words).
    fn list_start(&self) -> usize {
        packed(self.grids, self.width * self.height)
    }
}

/// Read-only view of a footprint.
#[derive(Clone, Copy)]
pub struct Footprint<'a> {
    pub(crate) info: FootprintInfo,
    pub(crate) words: &'a [u32],
}

impl<'a> Footprint<'a> {
    /// Cell size (m).
    pub fn cell(&self) -> f32 {
        self.info.cell
    }

    /// Whether the max-pooled grids a search bounds with are there (a
    /// model's footprint).
    pub fn has_pooled_grids(&self) -> bool {
        self.info.grids == POOL_LEVELS
    }

    /// The class mask of pooled grid `h` at cell (i, j); 0 outside.
    #[inline]
    pub fn mask(&self, h: usize, i: i32, j: i32) -> u32 {
        let (w, ht) = (self.info.width, self.info.height);
        if h >= self.info.grids {
            return 0;
        }
        // A window that starts below the grid but reaches into it lies within
        // the window starting at 0, whose mask is then an upper bound: what
        // branch and bound needs, without storing a margin below the data.
        let span = 1i32 << h;
        let clamp = |v: i32| if v < 0 && v + span > 0 { 0 } else { v };
        let (i, j) = (clamp(i), clamp(j));
        // Negative values wrap to huge ones and fail the same test.
        let (iu, ju) = (i as usize, j as usize);
        if iu >= w || ju >= ht {
            return 0;
        }
        cell_byte(self.words, h, w * ht, ju * w + iu)
    }

    /// Pooled grid `h` (windows of `2^h` cells), for many lookups.
    #[inline]
    pub fn grid(&self, h: usize) -> Option<Grid<'a>> {
        if h >= self.info.grids {
            return None;
        }
        let (w, ht) = (self.info.width, self.info.height);
        let (start, shift) = place(h, w * ht, 0);
        let words = self.words.get(start..start + w * ht)?;
        Some(Grid { words, shift, width: w as i32, height: ht as i32, span: 1 << h })
    }

    /// Cell index (i, j) of a point, unclamped.
    #[inline]
    pub fn cell_of(&self, x: f32, y: f32) -> (i32, i32) {
        let inv = 1.0 / self.info.cell;
        (floor_f32((x - self.info.origin[0]) * inv) as i32, floor_f32((y - self.info.origin[1]) * inv) as i32)
    }

    /// Occupied cells: (centre x, centre y, mean z, mask).
    pub fn occupied(&self) -> impl Iterator<Item = ([f32; 3], u32)> + 'a {
        let base = self.info.list_start();
        let list = self.words.get(base..base + 3 * self.info.occupied).unwrap_or(&[]);
        list.chunks_exact(3).map(|c| ([f32::from_bits(c[0]), f32::from_bits(c[1]), 0.0], c[2]))
    }

    /// Grid size in cells (width, height).
    pub fn size(&self) -> (usize, usize) {
        (self.info.width, self.info.height)
    }

    /// Number of occupied cells.
    pub fn occupied_len(&self) -> usize {
        self.info.occupied
    }
}

/// One pooled grid of a footprint: [`Footprint::mask`] without the level
/// lookup, for the search's inner loop.
#[derive(Clone, Copy)]
pub struct Grid<'a> {
    /// The plane holding this grid, row-major.
    words: &'a [u32],
    /// This grid's byte in each word (bits).
    shift: u32,
    width: i32,
    height: i32,
    span: i32,
}

impl Grid<'_> {
    /// The plane (row-major), this grid's shift in it, width, height and
    /// window span, for loops that inline [`Grid::mask`].
    #[inline]
    pub(crate) fn parts(&self) -> (&[u32], u32, i32, i32, i32) {
        (self.words, self.shift, self.width, self.height, self.span)
    }

    /// The class mask at cell (i, j); 0 outside. A window that starts below
    /// the grid but reaches into it reads the window at 0 (an upper bound).
    #[inline]
    pub fn mask(&self, i: i32, j: i32) -> u32 {
        // Beyond the grid, or a window that ends before it: nothing.
        if i <= -self.span || j <= -self.span || i >= self.width || j >= self.height {
            return 0;
        }
        let (i, j) = (i.max(0), j.max(0));
        self.words.get((j * self.width + i) as usize).map_or(0, |w| (w >> self.shift) & 0xFF)
    }
}

/// Builds a footprint of a level's entries (`entries()` gives each one's
/// horizontal position and class index, as often as asked; `count` of
/// them) into `words`, with the pooled grids when `pooled` (a model's);
/// the cell size starts at `cell` and doubles until the grids fit. `None`
/// if nothing fits. (Entries, not the pyramid's level type: the pyramid
/// builds footprints, a footprint knows nothing of pyramids.)
pub(crate) fn build<I: Iterator<Item = ([f32; 2], u8)>>(
    entries: impl Fn() -> I,
    count: usize,
    cell: f32,
    pooled: bool,
    words: &mut [u32],
) -> Option<FootprintInfo> {
    let (first, _) = entries().next()?;
    let grids = if pooled { POOL_LEVELS } else { 2 };
    let (mut lo, mut hi) = (first, first);
    for (position, _) in entries() {
        for a in 0..2 {
            lo[a] = lo[a].min(position[a]);
            hi[a] = hi[a].max(position[a]);
        }
    }
    let mut cell = cell;
    for _ in 0..12 {
        let origin = lo;
        let width = (libm::floorf((hi[0] - origin[0]) / cell) as usize) + 1;
        let height = (libm::floorf((hi[1] - origin[1]) / cell) as usize) + 1;
        let grid = width * height;
        // Occupied cells are listed at every other cell on each axis.
        let listed = width.div_ceil(2) * height.div_ceil(2);
        if packed(grids, grid) + 3 * listed.min(count) <= words.len() {
            let mut info = FootprintInfo { cell, origin, width, height, occupied: 0, grids };
            fill(entries(), &mut info, words);
            return Some(info);
        }
        cell *= 2.0;
    }
    None
}

fn fill(entries: impl Iterator<Item = ([f32; 2], u8)>, info: &mut FootprintInfo, words: &mut [u32]) {
    let (w, h) = (info.width, info.height);
    let grid = w * h;
    words.iter_mut().take(packed(info.grids, grid)).for_each(|v| *v = 0);
    let inv = 1.0 / info.cell;
    for (position, class) in entries {
        let Some(&bit) = GROUP_BITS.get(usize::from(class)) else { continue };
        let i = libm::floorf((position[0] - info.origin[0]) * inv) as usize;
        let j = libm::floorf((position[1] - info.origin[1]) * inv) as usize;
        let c = j.min(h - 1) * w + i.min(w - 1);
        set_cell_byte(words, 0, grid, c, cell_byte(words, 0, grid, c) | bit);
    }
    // Max-pooling: level k ORs the 2x2 block of level k-1 at offset 2^(k-1),
    // so cell (i, j) of level k covers [i, i + 2^k) x [j, j + 2^k).
    for k in 1..info.grids {
        let step = 1usize << (k - 1);
        for j in 0..h {
            for i in 0..w {
                let at = |ii: usize, jj: usize| -> u32 {
                    if ii < w && jj < h {
                        cell_byte(words, k - 1, grid, jj * w + ii)
                    } else {
                        0
                    }
                };
                let v = at(i, j) | at(i + step, j) | at(i, j + step) | at(i + step, j + step);
                set_cell_byte(words, k, grid, j * w + i, v);
            }
        }
    }
    // Occupied cells of twice the size (the 2x2 pooled level at even
    // indices), in grid order: the points a scene is scored with. Coarser
    // than the model's grid, they keep the search fast; the error they add
    // stays within a cell, which EM removes.
    let mut n = 0;
    let base = info.list_start();
    for j in (0..h).step_by(2) {
        for i in (0..w).step_by(2) {
            let m = cell_byte(words, 1, grid, j * w + i);
            if m == 0 {
                continue;
            }
            let cx = info.origin[0] + (i as f32 + 1.0) * info.cell;
            let cy = info.origin[1] + (j as f32 + 1.0) * info.cell;
            if let Some(dst) = words.get_mut(base + 3 * n..base + 3 * n + 3) {
                dst[0] = cx.to_bits();
                dst[1] = cy.to_bits();
                dst[2] = m;
                n += 1;
            }
        }
    }
    info.occupied = n;
}
