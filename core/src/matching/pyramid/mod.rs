//! The matcher's search structure: a semantic resolution pyramid.
//!
//! Level 0 is the map itself: its voxels and hash index, plus a 6-byte
//! [`VoxelExtra`] per voxel (packed normal, class, confidence), so preparing
//! a map does not copy it; or, for a model whose storage has room for it
//! ([`Pyramid::build_model`]), a copy of what matching reads of it (18-byte
//! [`ModelPoint`]s and the map's index), after which the map's memory may
//! serve other uses. Level `l >= 1` groups the entries of level `l - 1`
//! by (cell twice as large, class) into 12-byte [`CoarseEntry`]s: a pole
//! stays a pole at 3.2 m instead of dissolving into the building next to it,
//! which is what lets the coarse levels associate semantically. Entries of
//! one coarse cell are contiguous and an open-addressing index finds a
//! cell's run; each entry of a model has a surface normal fitted to its
//! neighbourhood at its own level. The matcher reads every level through
//! [`Level`], which decodes entries into the plain [`Entry`] form.
//!
//! A scene ([`Role::Scene`]) is read less: the matcher walks its entries
//! and never looks its cells up nor reads its normals, so a scene's pyramid
//! fits no normals and indexes no coarse level, and its level 0 may be a
//! [`SceneMap`] (a received map kept as 8 bytes per voxel,
//! [`Pyramid::build_scene`]) instead of a map.
//!
//! Building a pyramid is the one-off per-map preparation; matching only reads
//! it. Nothing allocates: the extras, coarse entries, normals, index slots
//! and footprint words live in a [`PyramidStorage`] the caller provides. A
//! map's coarse levels take about 0.4 entries per voxel (0.5 m maps, 3
//! levels), so a model's pyramid costs about 6 + 0.4 * 20 = 14 bytes per
//! voxel besides the map and its footprint.

use super::footprint::{self, Footprint, FootprintInfo};
use crate::map::key::sort_indices_by_code;
use crate::map::table::{probe_index, probe_keys, walk, walk_by, MapIndex, Probe, Slot};
use crate::map::voxel::mean_position;
use crate::map::{
    class_and_confidence, CellPoint, ClassMemo, LocalMap, SceneMap, ScenePoint, SemanticVoxel, VoxelKey, VoxelStorage,
    WordStorage,
};
use crate::region::Region;
use core::mem::size_of;

mod index;
mod lazy;
mod normals;
mod storage;

pub use storage::*;

pub use index::Reach;
pub use index::NARROW_LIMIT;
use index::*;
pub(crate) use lazy::normal_of;
use lazy::Prep;
pub(crate) use normals::Moments;
/// Writes into `words` the indices `0..len` sorted by their keys' sweep
/// order ([`VoxelKey::sweep`]; [`sort_indices_by_code`] on the keys in
/// offset binary, x then y then z: the same order in 48 bits); false when
/// `words` is too short.
fn sweep_permutation(words: &mut [u32], len: usize, key: impl Fn(usize) -> Option<VoxelKey>) -> bool {
    let Some(order) = words.get_mut(..len).filter(|_| len < u32::MAX as usize) else { return false };
    for (i, w) in order.iter_mut().enumerate() {
        *w = i as u32;
    }
    let code = |i: u32| {
        key(i as usize).map_or(u64::MAX, |k| {
            let [x, y, z] = [k.x, k.y, k.z].map(|v| u64::from(v as u16 ^ 0x8000));
            (x << 32) | (y << 16) | z
        })
    };
    sort_indices_by_code(words, len, len, code)
}

/// A map base's per-voxel extras (class, confidence; each normal `normal`
/// until fitted) written into `extras`; a scene or copied base has none.
fn base_extras<'e>(
    base: &Base<'_>,
    extras: &'e mut [VoxelExtra],
    normal: PackedNormal,
) -> Result<&'e [VoxelExtra], PyramidError> {
    match base {
        Base::Map { voxels, .. } => {
            let extras = extras.get_mut(..voxels.len()).ok_or(PyramidError::Full)?;
            let mut memo = ClassMemo::default();
            for (x, v) in extras.iter_mut().zip(voxels.iter()) {
                let (class, confidence) = memo.of(v);
                *x = VoxelExtra { normal, class, confidence };
            }
            Ok(extras)
        }
        Base::Scene { .. } | Base::Copied { .. } => Ok(&[]),
    }
}

#[cfg(test)]
pub(crate) use normals::fit_normal_for_tests;
use normals::*;

/// Most levels a pyramid has.
pub const MAX_LEVELS: usize = 8;

/// A model's cover is its first level of cells at least this large (m): it
/// says where the model saw anything (the verdict's coverage).
pub const COVER_RESOLUTION: f32 = 1.5;

/// Level 0's cells to a cover cell along an axis: the least power of two
/// (at most `2^(MAX_LEVELS - 1)`) that makes them [`COVER_RESOLUTION`] wide,
/// the cells of the whole pyramid's cover.
fn cover_factor(resolution: f32) -> u16 {
    let mut f = 1u16;
    while f < (1 << (MAX_LEVELS - 1)) && resolution * f32::from(f) < COVER_RESOLUTION {
        f *= 2;
    }
    f
}

/// A unit surface normal in 32 bits (octahedral mapping, 16 bits per
/// coordinate: about 0.003 degrees), or none where the neighbourhood is not
/// planar.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct PackedNormal([i16; 2]);

fn sign(v: f32) -> f32 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

impl PackedNormal {
    /// No normal.
    pub const NONE: PackedNormal = PackedNormal([i16::MIN, i16::MIN]);

    /// Packs a direction (normalised here); `NONE` for a zero or non-finite one.
    pub fn pack(n: [f32; 3]) -> Self {
        let s = n[0].abs() + n[1].abs() + n[2].abs();
        if !(s.is_finite() && s > 0.0) {
            return Self::NONE;
        }
        let (mut x, mut y) = (n[0] / s, n[1] / s);
        if n[2] < 0.0 {
            let (ax, ay) = (x.abs(), y.abs());
            x = (1.0 - ay) * sign(x);
            y = (1.0 - ax) * sign(y);
        }
        let q = |v: f32| libm::roundf(v.clamp(-1.0, 1.0) * 32767.0) as i16;
        PackedNormal([q(x), q(y)])
    }

    /// The unit normal, if any.
    #[inline]
    pub fn unpack(self) -> Option<[f32; 3]> {
        if self == Self::NONE {
            return None;
        }
        let (mut x, mut y) = (f32::from(self.0[0]) / 32767.0, f32::from(self.0[1]) / 32767.0);
        let z = 1.0 - x.abs() - y.abs();
        if z < 0.0 {
            let (ax, ay) = (x.abs(), y.abs());
            x = (1.0 - ay) * sign(x);
            y = (1.0 - ax) * sign(y);
        }
        let norm = libm::sqrtf(x * x + y * y + z * z);
        Some([x / norm, y / norm, z / norm])
    }
}

/// One point of a pyramid level as the matcher sees it: a voxel at level 0,
/// the mean of the voxels of one class in one cell above.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Entry {
    /// Mean position (m, map frame).
    pub position: [f32; 3],
    /// Surface normal of the neighbourhood.
    pub normal: PackedNormal,
    /// Number of level-0 voxels merged into the entry.
    pub weight: f32,
    /// Cell at this level.
    pub key: VoxelKey,
    /// Class index (0..19; `u8::MAX` without one).
    pub class: u8,
    /// Probability of that class, in 1/255.
    pub confidence: u8,
}

impl Entry {
    /// Whether the entry has a planar neighbourhood (a usable normal).
    pub fn is_planar(&self) -> bool {
        self.normal != PackedNormal::NONE
    }
}

/// What level 0 adds to each voxel of the map: 6 bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VoxelExtra {
    normal: PackedNormal,
    class: u8,
    confidence: u8,
}

impl VoxelExtra {
    /// Zeroed (a `static` of them lands in `.bss`).
    pub const EMPTY: VoxelExtra = VoxelExtra { normal: PackedNormal([0, 0]), class: 0, confidence: 0 };
}

impl Default for VoxelExtra {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// A model's level 0 copied out of its map ([`Pyramid::build_model`]): one
/// voxel's cell, mean, normal, class and confidence in 18 bytes, the 24-byte
/// voxel and its 6-byte extra less what matching never reads (occupancy,
/// hit count, label distribution).
#[derive(Clone, Copy, Debug, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct ModelPoint {
    key: VoxelKey,
    mean: [u16; 3],
    normal: PackedNormal,
    class: u8,
    confidence: u8,
}

impl ModelPoint {
    /// A voxel's point: its cell, mean, class and confidence (no normal
    /// yet).
    fn of(v: &SemanticVoxel) -> Self {
        let (class, confidence) = class_and_confidence(v);
        ModelPoint { key: v.key, mean: v.mean_raw(), normal: PackedNormal::NONE, class, confidence }
    }

    /// Zeroed (a `static` of them lands in `.bss`).
    pub const EMPTY: ModelPoint =
        ModelPoint { key: VoxelKey::new(0, 0, 0), mean: [0; 3], normal: PackedNormal([0, 0]), class: 0, confidence: 0 };

    #[inline]
    fn position(&self, resolution: f32) -> [f32; 3] {
        mean_position(self.key, self.mean, resolution)
    }
}

impl Default for ModelPoint {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// A stored entry of a coarse level: 12 bytes. The position is kept as an
/// 8-bit fraction of the cell (1/256 of a cell: 8 mm at 2 m; a running mean
/// of its entries, each step rounded, stays within about a step of the
/// exact one: coarse levels only guide EM to level 0), the weight (level-0
/// voxels merged) exactly to 127 and then in steps of 2^(1/16) (4.4%) up to
/// about 31,000. A model's entries have their normals beside them (a
/// storage's `normals`), a scene's none: the matcher reads no scene normal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct CoarseEntry {
    key: VoxelKey,
    fraction: [u8; 3],
    class: u8,
    confidence: u8,
    weight: u8,
}

/// Weights coded above the exact range: `WEIGHT_STEPS[k]` = 128 * 2^(k/16).
const WEIGHT_STEPS: [f32; 128] = {
    let mut t = [128.0f32; 128];
    let mut k = 1;
    while k < 128 {
        // 2^(1/16)
        t[k] = t[k - 1] * 1.044_273_8;
        k += 1;
    }
    t
};

/// A weight's code: exact to 127, then the nearest step of [`WEIGHT_STEPS`]
/// (saturating).
fn encode_weight(w: f32) -> u8 {
    if w.is_nan() || w <= 0.0 {
        return 0;
    }
    if w < 127.5 {
        return libm::roundf(w) as u8;
    }
    let k = libm::roundf(16.0 * libm::log2f(w / 128.0)).clamp(0.0, 127.0);
    128 + k as u8
}

#[inline]
fn decode_weight(c: u8) -> f32 {
    if c < 128 {
        f32::from(c)
    } else {
        WEIGHT_STEPS.get(usize::from(c - 128)).copied().unwrap_or(0.0)
    }
}

impl CoarseEntry {
    /// Zeroed (a `static` of them lands in `.bss`).
    pub const EMPTY: CoarseEntry =
        CoarseEntry { key: VoxelKey::new(0, 0, 0), fraction: [0; 3], class: 0, confidence: 0, weight: 0 };

    fn order(&self) -> (u64, u8) {
        (self.key.sweep(), self.class)
    }

    #[inline]
    fn position(&self, resolution: f32) -> [f32; 3] {
        let c = self.key.corner(resolution);
        let f = self.fraction.map(|q| (f32::from(q) + 0.5) * (1.0 / 256.0));
        [c[0] + f[0] * resolution, c[1] + f[1] * resolution, c[2] + f[2] * resolution]
    }

    fn set_position(&mut self, p: [f32; 3], resolution: f32) {
        let c = self.key.corner(resolution);
        let inv = 1.0 / resolution;
        for a in 0..3 {
            let q = libm::floorf((p[a] - c[a]) * inv * 256.0);
            self.fraction[a] = if q >= 0.0 { q.min(255.0) as u8 } else { 0 };
        }
    }

    /// Level-0 voxels merged into it.
    #[inline]
    fn weight(&self) -> f32 {
        decode_weight(self.weight)
    }

    fn set_weight(&mut self, w: f32) {
        self.weight = encode_weight(w);
    }
}

impl Default for CoarseEntry {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// A map that can be prepared as the scene of a match: a [`LocalMap`] or a
/// [`SceneMap`] (what a robot receives its peer's map into).
pub trait SceneSource {
    /// The map prepared as a scene ([`Role::Scene`]) in `storage`.
    fn prepare_scene<S: PyramidStorage>(
        &self,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Pyramid<'_, S>, PyramidError>;
}

impl<V: VoxelStorage> SceneSource for LocalMap<V> {
    fn prepare_scene<S: PyramidStorage>(
        &self,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Pyramid<'_, S>, PyramidError> {
        Pyramid::build_as(self, levels, footprint_cell, Role::Scene, storage)
    }
}

impl<P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> SceneSource for SceneMap<P> {
    fn prepare_scene<S: PyramidStorage>(
        &self,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Pyramid<'_, S>, PyramidError> {
        Pyramid::build_scene(self, levels, footprint_cell, storage)
    }
}

/// Why a pyramid could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PyramidError {
    /// The map has no voxel.
    EmptyMap,
    /// Zero levels, or more than [`MAX_LEVELS`].
    Levels,
    /// The storage is too small: fewer extras than voxels, too few coarse
    /// entries, or fewer than two index slots per entry.
    Full,
}

impl core::fmt::Display for PyramidError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            PyramidError::EmptyMap => "the map has no voxel",
            PyramidError::Levels => "level count must be 1 to 8",
            PyramidError::Full => "pyramid storage too small",
        })
    }
}

impl core::error::Error for PyramidError {}

/// How a pyramid will be matched, which decides its footprint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Role {
    /// As model or scene: the max-pooled footprint grids the coarse search
    /// bounds with, and the list of occupied cells.
    Model,
    /// Only as scene: the occupied cells alone (a third of the footprint
    /// words). Matched as a model, such a pyramid gets no coarse search.
    Scene,
}

#[derive(Clone, Copy, Debug, Default)]
struct LevelInfo {
    start: usize,
    len: usize,
    slot_start: usize,
    slot_len: usize,
    resolution: f32,
    /// Index slots of 16 bits, two to a word (see [`NARROW_LIMIT`]).
    narrow: bool,
}

/// What a pyramid's level 0 is.
#[derive(Clone, Copy)]
enum Base<'m> {
    /// A map's voxels and index (the pyramid adds their extras).
    Map { voxels: &'m [SemanticVoxel], index: MapIndex<'m> },
    /// A scene's points (they hold what the extras would, but normals).
    Scene { points: &'m [ScenePoint] },
    /// A model's level 0 copied into the storage's `points` (`len` of
    /// them) and `point_slots` (`slots` of them, the map's index).
    Copied { len: usize, slots: usize },
}

impl<'m> Base<'m> {
    fn len(&self) -> usize {
        match self {
            Base::Map { voxels, .. } => voxels.len(),
            Base::Scene { points } => points.len(),
            Base::Copied { len, .. } => *len,
        }
    }

    /// Level 0 over this base, with a map's `extras` or a copy's `points`
    /// and `point_slots` (each only as long as the base needs).
    fn level0<'a>(self, extras: &'a [VoxelExtra], points: &'a [ModelPoint], point_slots: &'a [u16]) -> LevelData<'a>
    where
        'm: 'a,
    {
        match self {
            Base::Map { voxels, index } => LevelData::Voxels { voxels, index, extras },
            Base::Scene { points } => LevelData::Points { points },
            Base::Copied { len, slots } => LevelData::Copied {
                points: points.get(..len).unwrap_or(&[]),
                index: point_slots.get(..slots).unwrap_or(&[]),
            },
        }
    }
}

/// A map prepared for matching. It borrows the map: level 0 is the map.
pub struct Pyramid<'m, S: PyramidStorage> {
    base: Base<'m>,
    role: Role,
    storage: S,
    levels: [LevelInfo; MAX_LEVELS],
    count: usize,
    footprint: Option<FootprintInfo>,
    /// Prepared only for tracking from a fix ([`Pyramid::build_tracked`]).
    tracked: bool,
    /// Level 0's normals fitted as tracking reads them
    /// ([`Pyramid::build_tracked_lazy`]).
    lazy: bool,
}

#[derive(Clone, Copy)]
enum LevelData<'a> {
    /// Level 0: the map's voxels and index, and the extras.
    Voxels { voxels: &'a [SemanticVoxel], index: MapIndex<'a>, extras: &'a [VoxelExtra] },
    /// Level 0 of a scene: its points, in arrival order, without an index.
    Points { points: &'a [ScenePoint] },
    /// Level 0 copied out of a model's map: its points in the map's order
    /// and the map's index.
    Copied { points: &'a [ModelPoint], index: &'a [u16] },
    /// A coarse level: sorted entries, their normals (none for a scene) and
    /// their index (`narrow`: 16-bit slots, two to a word).
    Coarse { entries: &'a [CoarseEntry], normals: &'a [PackedNormal], slots: &'a [u32], narrow: bool },
}

/// One level of a pyramid, read-only.
#[derive(Clone, Copy)]
pub struct Level<'a> {
    data: LevelData<'a>,
    resolution: f32,
    inv_resolution: f32,
}

/// The entries of one cell of a level (one per class present; at most one
/// at level 0).
pub struct Cell<'a> {
    level: Level<'a>,
    next: usize,
    end: usize,
}

impl Iterator for Cell<'_> {
    type Item = Entry;
    #[inline]
    fn next(&mut self) -> Option<Entry> {
        if self.next >= self.end {
            return None;
        }
        self.next += 1;
        self.level.entry(self.next - 1)
    }
}

impl<'a> Level<'a> {
    fn new(data: LevelData<'a>, resolution: f32) -> Self {
        Level { data, resolution, inv_resolution: 1.0 / resolution }
    }

    /// Cell size (m).
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        match self.data {
            LevelData::Voxels { voxels, .. } => voxels.len(),
            LevelData::Points { points } => points.len(),
            LevelData::Copied { points, .. } => points.len(),
            LevelData::Coarse { entries, .. } => entries.len(),
        }
    }

    /// Whether the level has no entry.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entry `i`, decoded (`0..len()`; level 0 in the map's order, coarse
    /// levels sorted by cell).
    #[inline]
    pub fn entry(&self, i: usize) -> Option<Entry> {
        match self.data {
            LevelData::Voxels { voxels, extras, .. } => {
                let (v, x) = (voxels.get(i)?, extras.get(i)?);
                Some(Entry {
                    position: v.position(self.resolution),
                    normal: x.normal,
                    weight: 1.0,
                    key: v.key,
                    class: x.class,
                    confidence: x.confidence,
                })
            }
            LevelData::Points { points } => {
                let p = points.get(i)?;
                Some(Entry {
                    position: p.position(self.resolution),
                    normal: PackedNormal::NONE,
                    weight: 1.0,
                    key: p.key,
                    class: p.class(),
                    confidence: p.confidence(),
                })
            }
            LevelData::Copied { points, .. } => {
                let p = points.get(i)?;
                Some(Entry {
                    position: p.position(self.resolution),
                    normal: p.normal,
                    weight: 1.0,
                    key: p.key,
                    class: p.class,
                    confidence: p.confidence,
                })
            }
            LevelData::Coarse { entries, normals, .. } => {
                let c = entries.get(i)?;
                Some(Entry {
                    position: c.position(self.resolution),
                    normal: normals.get(i).copied().unwrap_or(PackedNormal::NONE),
                    weight: c.weight(),
                    key: c.key,
                    class: c.class,
                    confidence: c.confidence,
                })
            }
        }
    }

    /// Position and weight of entry `i` (all a neighbourhood's moments
    /// need: cheaper than decoding the whole entry).
    #[inline]
    pub fn point(&self, i: usize) -> Option<([f32; 3], f32)> {
        match self.data {
            LevelData::Voxels { voxels, .. } => voxels.get(i).map(|v| (v.position(self.resolution), 1.0)),
            LevelData::Points { points } => points.get(i).map(|p| (p.position(self.resolution), 1.0)),
            LevelData::Copied { points, .. } => points.get(i).map(|p| (p.position(self.resolution), 1.0)),
            LevelData::Coarse { entries, .. } => entries.get(i).map(|c| (c.position(self.resolution), c.weight())),
        }
    }

    /// Cell of entry `i` (cheaper than decoding it).
    #[inline]
    pub fn key_at(&self, i: usize) -> Option<VoxelKey> {
        match self.data {
            LevelData::Voxels { voxels, .. } => voxels.get(i).map(|v| v.key),
            LevelData::Points { points } => points.get(i).map(|p| p.key),
            LevelData::Copied { points, .. } => points.get(i).map(|p| p.key),
            LevelData::Coarse { entries, .. } => entries.get(i).map(|c| c.key),
        }
    }

    /// Class of entry `i` (cheaper than decoding it).
    #[inline]
    pub fn class_at(&self, i: usize) -> Option<u8> {
        match self.data {
            LevelData::Voxels { extras, .. } => extras.get(i).map(|x| x.class),
            LevelData::Points { points } => points.get(i).map(|p| p.class()),
            LevelData::Copied { points, .. } => points.get(i).map(|p| p.class),
            LevelData::Coarse { entries, .. } => entries.get(i).map(|c| c.class),
        }
    }

    /// All entries, decoded, in order.
    pub fn iter(&self) -> impl Iterator<Item = Entry> + 'a {
        let level = *self;
        (0..self.len()).filter_map(move |i| level.entry(i))
    }

    /// The entries of one cell (one per class present). A scene's levels
    /// ([`Role::Scene`]) have no index: nothing is found there.
    #[inline]
    pub fn cell(&self, key: VoxelKey) -> Cell<'a> {
        let (next, end) = self.cell_run(key);
        Cell { level: *self, next, end }
    }

    /// The run of entries (`start..end`) in the cell `key`; empty when
    /// nothing is there.
    pub(crate) fn cell_run(&self, key: VoxelKey) -> (usize, usize) {
        match self.data {
            LevelData::Voxels { voxels, index, .. } => match probe_index(voxels, index, key) {
                Probe::Found(i) => (i, i + 1),
                Probe::Vacant(_) => (0, 0),
            },
            LevelData::Points { .. } => (0, 0),
            LevelData::Copied { points, index } => match probe_keys(index, key, |i| points.get(i).map(|p| p.key)) {
                Probe::Found(i) => (i, i + 1),
                Probe::Vacant(_) => (0, 0),
            },
            LevelData::Coarse { entries, slots, narrow, .. } => coarse_run(entries, slots, narrow, key),
        }
    }

    /// The cell holding point `p`.
    pub fn locate(&self, p: [f32; 3]) -> Option<VoxelKey> {
        VoxelKey::locate(p, self.inv_resolution).ok().map(|c| c.key)
    }

    /// The cell holding point `p` and where in it `p` lies.
    pub fn locate_with_fraction(&self, p: [f32; 3]) -> Option<CellPoint> {
        VoxelKey::locate(p, self.inv_resolution).ok()
    }
}

/// A map's level 0 copied out of it (its points and index), for
/// [`Pyramid::build_copied`]: what is left to know of the map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CopiedBase {
    len: usize,
    slots: usize,
    resolution: f32,
}

impl CopiedBase {
    /// Copies `map`'s level 0 into `points` and its index into `slots`
    /// (the first half of [`Pyramid::build_model`]); `None` when the map
    /// is empty or the room does not hold them.
    pub fn copy<V: VoxelStorage>(map: &LocalMap<V>, points: &mut [ModelPoint], slots: &mut [u16]) -> Option<Self> {
        let len = map.len();
        let index = map.index_slots();
        let index_len = match index {
            MapIndex::Wide(s) => s.len(),
            MapIndex::Narrow(s) => s.len(),
        };
        let (points, slots) = (points.get_mut(..len)?, slots.get_mut(..index_len)?);
        if len == 0 || !copy_index(index, slots) {
            return None;
        }
        for (p, v) in points.iter_mut().zip(map.voxels()) {
            *p = ModelPoint::of(v);
        }
        Some(CopiedBase { len, slots: index_len, resolution: map.resolution() })
    }

    /// Turns `map`'s voxels into model points where they lie (a point is
    /// smaller than a voxel, so point `i` is written over bytes of voxels
    /// `..=i` only, each read before), keeping its index as the level's
    /// index: the map's memory holds its level 0 with no room for a copy.
    /// Gives back the level (room for the map's capacity of points, the
    /// first `len` written) and the words after it, whole: what the points
    /// leave of the voxels' words and the words the storage kept after
    /// them; `None` when the map is empty.
    pub fn compact(map: LocalMap<WordStorage<'_>>) -> Option<(Self, CopiedSlices<'_>, &mut [u32])> {
        const { assert!(size_of::<ModelPoint>() <= size_of::<SemanticVoxel>()) };
        let (len, resolution) = (map.len(), map.resolution());
        if len == 0 {
            return None;
        }
        let (words, capacity, slots) = map.into_storage().into_parts();
        {
            let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut *words);
            let (vs, ps) = (size_of::<SemanticVoxel>(), size_of::<ModelPoint>());
            for i in 0..len {
                let v: SemanticVoxel = bytemuck::pod_read_unaligned(bytes.get(i * vs..(i + 1) * vs)?);
                bytes.get_mut(i * ps..(i + 1) * ps)?.copy_from_slice(bytemuck::bytes_of(&ModelPoint::of(&v)));
            }
        }
        let mut region = Region::new(words);
        let points = region.take::<ModelPoint>(capacity).ok()?;
        let copied = CopiedBase { len, slots: slots.len(), resolution };
        Some((copied, CopiedSlices { points, slots }, region.into_words()))
    }
}

/// Normals fitted per chunk, so no buffer of the level's size is needed.
const NORMAL_CHUNK: usize = 256;

impl<'m, S: PyramidStorage> Pyramid<'m, S> {
    /// Prepares `map` for matching as model or scene ([`Role::Model`]) with
    /// `levels` levels (level `l` has cells `2^l` times the map's
    /// resolution) and a footprint of cells of `footprint_cell` metres
    /// (doubled until it fits the storage's words; no footprint, and so no
    /// coarse search, when the storage has none).
    pub fn build<V: VoxelStorage>(
        map: &'m LocalMap<V>,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Self, PyramidError> {
        Self::build_as(map, levels, footprint_cell, Role::Model, storage)
    }

    /// As [`Pyramid::build`], for the given [`Role`]. A scene
    /// ([`Role::Scene`]) gets no normals and no index of its coarse levels
    /// (the matcher reads neither of a scene), so it needs no index slots,
    /// and its footprint words double as the scratch of the coarse merge.
    pub fn build_as<V: VoxelStorage>(
        map: &'m LocalMap<V>,
        levels: usize,
        footprint_cell: f32,
        role: Role,
        storage: S,
    ) -> Result<Self, PyramidError> {
        let base = Base::Map { voxels: map.voxels(), index: map.index_slots() };
        Self::build_base(base, map.resolution(), (levels, footprint_cell), role, Prep::Whole, storage)
    }

    /// Prepares `map` only for tracking from a fix ([`Matcher::track_in`],
    /// which reads level 0 of both maps and a model's cover alone): as a
    /// model ([`Role::Model`]), level 0 with its normals and the cover
    /// ([`Pyramid::tracked_levels`]), merged from level 0 at once (its cells
    /// the power of two of level 0's that is at least [`COVER_RESOLUTION`],
    /// the whole pyramid's cover: the same cells, which is all that is read
    /// of it); as a scene, level 0 alone; no footprint either way. Tracking from it
    /// gives what it gives from the whole pyramid, bit for bit, at about
    /// half a model's preparation and a quarter of a scene's; anything
    /// else refuses it ([`MatchError::TrackingOnly`]). A robot that keeps
    /// driving prepares its maps this way every round it holds a fix.
    ///
    /// [`Matcher::track_in`]: crate::matching::Matcher::track_in
    /// [`MatchError::TrackingOnly`]: crate::matching::MatchError::TrackingOnly
    pub fn build_tracked<V: VoxelStorage>(map: &'m LocalMap<V>, role: Role, storage: S) -> Result<Self, PyramidError> {
        let base = Base::Map { voxels: map.voxels(), index: map.index_slots() };
        let levels = Self::tracked_levels(map.resolution(), role);
        Self::build_base(base, map.resolution(), (levels, f32::NAN), role, Prep::Tracked, storage)
    }

    /// Levels of a pyramid prepared for tracking ([`Pyramid::build_tracked`]):
    /// a model's two, level 0 and its cover (one, when level 0's cells are
    /// at least [`COVER_RESOLUTION`]); a scene's one.
    pub fn tracked_levels(resolution: f32, role: Role) -> usize {
        if role == Role::Model && cover_factor(resolution) > 1 {
            2
        } else {
            1
        }
    }

    /// Prepared only for tracking from a fix ([`Pyramid::build_tracked`]).
    pub fn is_tracked(&self) -> bool {
        self.tracked
    }

    /// Prepares `map` as a model ([`Role::Model`]) like [`Pyramid::build`],
    /// copying level 0 into the storage's room for it
    /// ([`PyramidStorage::copied_mut`], e.g. a [`SplitStorage`]) when the
    /// room holds the map's voxels and index: then the pyramid reads nothing
    /// of the map after the copy, and the storage's other parts are reached
    /// only after it, so they may lie over the map's memory (a board reuses
    /// its map's memory for both pyramids this way). Without the room, level
    /// 0 is the map. The same levels, normals and footprint either way.
    pub fn build_model<V: VoxelStorage>(
        map: &'m LocalMap<V>,
        levels: usize,
        footprint_cell: f32,
        mut storage: S,
    ) -> Result<Self, PyramidError> {
        let (points, slots) = storage.copied_mut();
        match CopiedBase::copy(map, points, slots) {
            // The map is not read from here on.
            Some(copied) => Self::build_copied(copied, levels, footprint_cell, storage),
            None => Self::build_as(map, levels, footprint_cell, Role::Model, storage),
        }
    }

    /// The second half of [`Pyramid::build_model`]: a model over a level 0
    /// copied into `storage`'s room for it ([`CopiedBase::copy`]), with no
    /// map in sight: the map's memory may already serve the other parts of
    /// `storage`, handed over by ownership.
    pub fn build_copied(
        copied: CopiedBase,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Self, PyramidError> {
        let base = Base::Copied { len: copied.len, slots: copied.slots };
        Self::build_base(base, copied.resolution, (levels, footprint_cell), Role::Model, Prep::Whole, storage)
    }

    /// Prepares a received [`SceneMap`] as a scene ([`Role::Scene`]): the
    /// same levels, entries and footprint as [`Pyramid::build_as`] gives a
    /// [`LocalMap`] holding the same voxels in the same order, with no
    /// extras in the storage (the scene's points hold them).
    pub fn build_scene<P: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>>(
        scene: &'m SceneMap<P>,
        levels: usize,
        footprint_cell: f32,
        storage: S,
    ) -> Result<Self, PyramidError> {
        let base = Base::Scene { points: scene.points() };
        Self::build_base(base, scene.resolution(), (levels, footprint_cell), Role::Scene, Prep::Whole, storage)
    }

    /// The pyramid over `base`: `levels` levels and a footprint of cells of
    /// `footprint_cell` (m); as far as `prep` says (tracked: normals at
    /// level 0 only).
    fn build_base(
        base: Base<'m>,
        resolution: f32,
        (levels, footprint_cell): (usize, f32),
        role: Role,
        prep: Prep,
        mut storage: S,
    ) -> Result<Self, PyramidError> {
        let tracked = prep != Prep::Whole;
        if base.len() == 0 {
            return Err(PyramidError::EmptyMap);
        }
        if levels == 0 || levels > MAX_LEVELS {
            return Err(PyramidError::Levels);
        }
        let model = role == Role::Model;
        let lazy = model && prep == Prep::Lazy;
        let mut info = [LevelInfo::default(); MAX_LEVELS];
        info[0] = LevelInfo { start: 0, len: base.len(), slot_start: 0, slot_len: 0, resolution, narrow: false };
        {
            let PyramidPartsMut { extras, entries, normals, slots, words, points, point_slots } = storage.parts_mut();
            // 32-bit slots address entries with 27 bits; 16-bit ones (fewer
            // entries than NARROW_LIMIT) take one word per entry, not two.
            let narrow = entries.len() < NARROW_LIMIT;
            let words_per_entry = if narrow { 1 } else { 2 };
            if entries.len() >= (1 << (32 - RUN_BITS)) - 1
                || (model && levels > 1 && slots.len() < words_per_entry * entries.len())
                || (model && normals.len() < entries.len())
            {
                return Err(PyramidError::Full);
            }
            // A lazy model's normals stay unfitted for EM; others are fitted below.
            let unfitted = if lazy { PackedNormal::UNFIT } else { PackedNormal::NONE };
            let extras = base_extras(&base, extras, unfitted)?;
            let level0 = base.level0(extras, points, point_slots);
            // Coarse levels: each merged from the one below, then indexed
            // (a model's).
            let (mut start, mut slot_start) = (0usize, 0usize);
            for l in 1..levels {
                let prev = info[l - 1];
                let (done, rest) = entries.split_at_mut(start);
                let src = if l == 1 {
                    Level::new(level0, resolution)
                } else {
                    let e = done.get(prev.start..prev.start + prev.len).ok_or(PyramidError::Full)?;
                    Level::new(LevelData::Coarse { entries: e, normals: &[], slots: &[], narrow }, prev.resolution)
                };
                let table = if model { slots.get_mut(slot_start..) } else { Some(&mut *words) };
                let table = table.ok_or(PyramidError::Full)?;
                // A tracked model's one coarse level is its cover.
                let factor = if tracked { cover_factor(resolution) } else { 2 };
                let len = merge_level(&src, rest, table, narrow, factor)?;
                let slot_len = if model {
                    let level_slots = table.get_mut(..words_per_entry * len).ok_or(PyramidError::Full)?;
                    index_level(rest.get(..len).ok_or(PyramidError::Full)?, level_slots, narrow);
                    words_per_entry * len
                } else {
                    0
                };
                info[l] = LevelInfo {
                    start,
                    len,
                    slot_start,
                    slot_len,
                    resolution: prev.resolution * f32::from(factor),
                    narrow,
                };
                start += len;
                slot_start += slot_len;
            }
        }
        let mut pyramid = Pyramid { base, role, storage, levels: info, count: levels, footprint: None, tracked, lazy };
        // Normals (a model's), level by level: fitted against the read-only
        // level, then written. Coarse levels are sorted in sweep order;
        // level 0 (the map, in insertion order) is visited through a
        // permutation sorted in the footprint's words (built after), or,
        // where they are too few, through hash lookups (the same normals).
        if model && !lazy {
            pyramid.fit_normals()?;
        }
        if footprint_cell.is_finite() && footprint_cell > 0.0 {
            let PyramidPartsMut { extras, words, points, point_slots, .. } = pyramid.storage.parts_mut();
            let level0 = Level::new(base.level0(extras, points, point_slots), resolution);
            let entries = || level0.iter().map(|e| ([e.position[0], e.position[1]], e.class));
            pyramid.footprint = footprint::build(entries, level0.len(), footprint_cell, model, words);
        }
        Ok(pyramid)
    }

    /// Fits the normals of a model's levels (see [`NormalSweep`]). Never
    /// inlined: its frame stays out of the matcher's.
    #[inline(never)]
    fn fit_normals(&mut self) -> Result<(), PyramidError> {
        let base = self.base;
        // A tracked model's coarse levels serve its cover alone: no normals.
        let fitted = if self.tracked { 1 } else { self.count };
        for l in 0..fitted {
            let li = self.levels[l];
            let permuted = l == 0 && {
                let PyramidPartsMut { words, points, .. } = self.storage.parts_mut();
                let points: &[ModelPoint] = points;
                let key = |i: usize| match base {
                    Base::Map { voxels, .. } => voxels.get(i).map(|v| v.key),
                    Base::Copied { .. } => points.get(i).map(|p| p.key),
                    Base::Scene { points } => points.get(i).map(|p| p.key),
                };
                sweep_permutation(words, li.len, key)
            };
            if permuted && self.fit_gathered(li.len)? {
                continue;
            }
            let mut sweep = NormalSweep::new();
            for chunk_start in (0..li.len).step_by(NORMAL_CHUNK) {
                // (index, normal); an index of u32::MAX writes nothing.
                let mut normals = [(u32::MAX, PackedNormal::NONE); NORMAL_CHUNK];
                let n = (li.len - chunk_start).min(NORMAL_CHUNK);
                {
                    let level = self.level(l).ok_or(PyramidError::Levels)?;
                    let order = self.storage.parts().words;
                    let at = |r: usize| {
                        if permuted {
                            order.get(r).map(|&i| i as usize)
                        } else {
                            Some(r)
                        }
                    };
                    for (k, nm) in normals.iter_mut().enumerate().take(n) {
                        let rank = chunk_start + k;
                        let Some(i) = at(rank) else { continue };
                        if let Some(e) = level.entry(i) {
                            let normal = if l == 0 && !permuted {
                                fit_normal(&level, &e)
                            } else {
                                sweep.fit(&level, &e, li.len, at)
                            };
                            *nm = (i as u32, normal);
                        }
                    }
                }
                let parts = self.storage.parts_mut();
                for &(i, normal) in normals.iter().take(n).filter(|(i, _)| *i != u32::MAX) {
                    let slot = match (l, base) {
                        (0, Base::Copied { .. }) => parts.points.get_mut(i as usize).map(|p| &mut p.normal),
                        (0, _) => parts.extras.get_mut(i as usize).map(|x| &mut x.normal),
                        _ => parts.normals.get_mut(li.start + i as usize),
                    };
                    *slot.ok_or(PyramidError::Full)? = normal;
                }
            }
        }
        Ok(())
    }

    /// Fits level 0's normals from its entries gathered in sweep order
    /// ([`fit_gathered`]) into the words after its sweep order (which the
    /// words' first `len` hold); `false`, fitting nothing, when they have no
    /// room for them. Three times faster than reading each neighbour from
    /// the level, with the same normals.
    fn fit_gathered(&mut self, len: usize) -> Result<bool, PyramidError> {
        let base = self.base;
        let resolution = self.levels[0].resolution;
        let PyramidPartsMut { extras, words, points, point_slots, .. } = self.storage.parts_mut();
        let Some((order, rest)) = words.split_at_mut_checked(len) else { return Ok(false) };
        let Some(room) = rest.get_mut(..len.saturating_mul(SWEEP_POINT_WORDS)) else { return Ok(false) };
        let Ok(gathered) = bytemuck::try_cast_slice_mut::<u32, SweepPoint>(room) else { return Ok(false) };
        {
            let level = Level::new(base.level0(extras, points, point_slots), resolution);
            for (g, &i) in gathered.iter_mut().zip(order.iter()) {
                let i = i as usize;
                let (Some(key), Some(point)) = (level.key_at(i), level.point(i)) else {
                    return Err(PyramidError::Full);
                };
                *g = SweepPoint::new(key, point);
            }
        }
        let mut cursors = [0usize; 9];
        for (r, &i) in order.iter().enumerate() {
            let normal = fit_gathered(&mut cursors, gathered, r, resolution);
            let slot = match base {
                Base::Copied { .. } => points.get_mut(i as usize).map(|p| &mut p.normal),
                _ => extras.get_mut(i as usize).map(|x| &mut x.normal),
            };
            *slot.ok_or(PyramidError::Full)? = normal;
        }
        Ok(true)
    }

    /// The footprint, if the storage had room for one.
    pub fn footprint(&self) -> Option<Footprint<'_>> {
        let info = self.footprint?;
        let words = self.storage.parts().words;
        Some(Footprint { info, words: words.get(..info.words())? })
    }

    /// How the pyramid was prepared.
    pub fn role(&self) -> Role {
        self.role
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.count
    }

    /// Level `l` (0 is the finest).
    pub fn level(&self, l: usize) -> Option<Level<'_>> {
        let li = self.levels.get(..self.count)?.get(l)?;
        let parts = self.storage.parts();
        let data = if l == 0 {
            let extras = match self.base {
                Base::Map { .. } => parts.extras.get(..li.len)?,
                Base::Scene { .. } | Base::Copied { .. } => &[],
            };
            self.base.level0(extras, parts.points, parts.point_slots)
        } else {
            LevelData::Coarse {
                entries: parts.entries.get(li.start..li.start + li.len)?,
                normals: match self.role {
                    Role::Model if !self.tracked => parts.normals.get(li.start..li.start + li.len)?,
                    _ => &[],
                },
                slots: parts.slots.get(li.slot_start..li.slot_start + li.slot_len)?,
                narrow: li.narrow,
            }
        };
        Some(Level::new(data, li.resolution))
    }

    /// Entries of the coarse levels, all together (what the storage must hold).
    pub fn coarse_entries(&self) -> usize {
        self.levels[1..self.count].iter().map(|l| l.len).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::{smallest_eigen, sweep_permutation};
    use crate::map::VoxelKey;
    use nalgebra::{Matrix3, SymmetricEigen};

    /// The sweep permutation is the keys' sweep order whether each index
    /// is sorted beside its key (two words an index) or not (one).
    #[test]
    fn the_sweep_permutation_is_the_same_with_or_without_room_beside_it() {
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 16) as i16
        };
        let mut keys: std::vec::Vec<VoxelKey> =
            (0..3000).map(|_| VoxelKey::new(next(), next() % 40, next() % 9)).collect();
        keys.extend([VoxelKey::new(i16::MIN, i16::MAX, -1), VoxelKey::new(i16::MAX, i16::MIN, 0)]);
        keys.sort_by_key(|k| k.sweep());
        keys.dedup();
        keys.reverse();
        let key = |i: usize| keys.get(i).copied();
        let (mut one, mut two) = (std::vec![0u32; keys.len()], std::vec![0u32; 2 * keys.len()]);
        assert!(sweep_permutation(&mut one, keys.len(), key) && sweep_permutation(&mut two, keys.len(), key));
        assert_eq!(one[..], two[..keys.len()]);
        assert!(one.windows(2).all(|w| keys[w[0] as usize].sweep() < keys[w[1] as usize].sweep()));
        assert!(!sweep_permutation(&mut one[..10], keys.len(), key), "too short");
    }

    /// The closed form agrees with nalgebra's iterative decomposition on
    /// the covariances normals come from: planes with noise, lines, blobs,
    /// at any orientation (eigenvector up to sign).
    #[test]
    fn smallest_eigenpair_matches_the_iterative_decomposition() {
        let mut seed = 12345u32;
        let mut rnd = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        for case in 0..2000 {
            let spread = [1.0, [1.0, 0.3, 1e-3][case % 3], [1e-4, 1e-2, 0.5][case / 3 % 3]];
            let r = nalgebra::Rotation3::from_euler_angles(rnd() * 6.0, rnd() * 6.0, rnd() * 6.0).into_inner();
            let d = Matrix3::from_diagonal(&nalgebra::Vector3::new(spread[0], spread[1], spread[2]));
            let m = r * d * r.transpose() * 0.04;
            let packed = [m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 1)], m[(1, 2)], m[(2, 2)]];
            let eig = SymmetricEigen::new(m);
            let mut order = [0usize, 1, 2];
            order.sort_unstable_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
            let (l0, l1) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
            let (c0, c1, v) = smallest_eigen(&packed).expect("an eigenvector");
            let scale = eig.eigenvalues.amax();
            // The smallest to 1e-5 of the largest; the middle one (only
            // compared with a tenth of it) to 1e-3: two equal large ones (a
            // round patch of plane) make the cubic's angle ill-conditioned.
            assert!(
                (c0 - l0).abs() < 1e-5 * scale && (c1 - l1).abs() < 1e-3 * scale,
                "case {case}: {c0} {c1} vs {l0} {l1}"
            );
            if l0 < 0.1 * l1 {
                let w = eig.eigenvectors.column(order[0]);
                let dot = (v[0] * w[0] + v[1] * w[1] + v[2] * w[2]).abs();
                assert!(dot > 1.0 - 1e-4, "case {case}: {v:?} vs {w:?}");
            }
        }
        // A diagonal matrix, and an isotropic one (no single smallest).
        let (l0, l1, v) = smallest_eigen(&[3.0, 0.0, 0.0, 2.0, 0.0, 1.0]).unwrap();
        assert!((l0 - 1.0).abs() < 1e-5 && (l1 - 2.0).abs() < 1e-5 && v[2].abs() > 0.9999, "{l0} {l1} {v:?}");
        assert!(smallest_eigen(&[1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).is_none());
    }
}
