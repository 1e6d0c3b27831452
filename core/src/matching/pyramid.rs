//! The matcher's search structure: a semantic resolution pyramid.
//!
//! Level 0 holds one [`Entry`] per voxel of the map. Level `l` groups the
//! entries of level `l - 1` by (cell twice as large, class): a pole stays a
//! pole at 3.2 m instead of dissolving into the building next to it, which is
//! what lets the coarse levels associate semantically. Entries of one cell are
//! contiguous and an open-addressing index finds a cell's run; each entry
//! carries a surface normal fitted to its neighbourhood at its own level.
//!
//! Building a pyramid is the one-off per-map preparation; matching only reads
//! it. Nothing allocates: entries and index slots live in a
//! [`PyramidStorage`] the caller provides.

use super::footprint::{self, Footprint, FootprintInfo};
use crate::classes::NUM_CLASSES;
use crate::map::{CellPoint, LocalMap, VoxelKey, VoxelStorage};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// Most levels a pyramid has.
pub const MAX_LEVELS: usize = 8;

/// One point of a pyramid level: the mean of the voxels of one class in one cell.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Entry {
    /// Mean position (m, map frame).
    pub position: [f32; 3],
    /// Unit surface normal of the neighbourhood; zero where it is not planar.
    pub normal: [f32; 3],
    /// Number of level-0 voxels merged into the entry.
    pub weight: f32,
    /// Cell at this level.
    pub key: VoxelKey,
    /// Class index (0..19).
    pub class: u8,
    /// Probability of that class, in 1/255.
    pub confidence: u8,
}

impl Entry {
    /// Whether the entry has a planar neighbourhood (a usable normal).
    pub fn is_planar(&self) -> bool {
        self.normal != [0.0; 3]
    }

    fn order(&self) -> (u64, u8) {
        (self.key.packed(), self.class)
    }
}

/// Where a pyramid keeps its entries, index and footprint.
pub trait PyramidStorage {
    /// Entry buffer, index slot buffer, footprint words.
    fn parts(&self) -> (&[Entry], &[u32], &[u32]);
    /// All three, mutably.
    fn parts_mut(&mut self) -> (&mut [Entry], &mut [u32], &mut [u32]);
}

/// A pyramid may borrow its storage, e.g. a `static` on a microcontroller.
impl<T: PyramidStorage + ?Sized> PyramidStorage for &mut T {
    fn parts(&self) -> (&[Entry], &[u32], &[u32]) {
        (**self).parts()
    }
    fn parts_mut(&mut self) -> (&mut [Entry], &mut [u32], &mut [u32]) {
        (**self).parts_mut()
    }
}

/// Pyramid storage of compile-time size: `E` entries, `2 * E` index slots,
/// `W` footprint words.
pub struct ArrayPyramidStorage<const E: usize, const W: usize> {
    entries: [Entry; E],
    slots: [[u32; 2]; E],
    words: [u32; W],
}

impl<const E: usize, const W: usize> ArrayPyramidStorage<E, W> {
    /// Empty storage.
    pub const fn new() -> Self {
        const ZERO: Entry = Entry {
            position: [0.0; 3],
            normal: [0.0; 3],
            weight: 0.0,
            key: VoxelKey::new(0, 0, 0),
            class: 0,
            confidence: 0,
        };
        ArrayPyramidStorage { entries: [ZERO; E], slots: [[0; 2]; E], words: [0; W] }
    }
}

impl<const E: usize, const W: usize> Default for ArrayPyramidStorage<E, W> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const E: usize, const W: usize> PyramidStorage for ArrayPyramidStorage<E, W> {
    fn parts(&self) -> (&[Entry], &[u32], &[u32]) {
        (&self.entries, self.slots.as_flattened(), &self.words)
    }
    fn parts_mut(&mut self) -> (&mut [Entry], &mut [u32], &mut [u32]) {
        (&mut self.entries, self.slots.as_flattened_mut(), &mut self.words)
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
    /// The storage is too small for the entries (or has fewer than two index
    /// slots per entry).
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

#[derive(Clone, Copy, Debug, Default)]
struct LevelInfo {
    start: usize,
    len: usize,
    slot_start: usize,
    slot_len: usize,
    resolution: f32,
}

/// A map prepared for matching.
pub struct Pyramid<S: PyramidStorage> {
    storage: S,
    levels: [LevelInfo; MAX_LEVELS],
    count: usize,
    footprint: Option<FootprintInfo>,
}

/// One level of a pyramid, read-only.
#[derive(Clone, Copy)]
pub struct Level<'a> {
    entries: &'a [Entry],
    slots: &'a [u32],
    resolution: f32,
    inv_resolution: f32,
}

fn home(hash: u32, n: usize) -> usize {
    ((u64::from(hash) * n as u64) >> 32) as usize
}

impl<'a> Level<'a> {
    /// Cell size (m).
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// The entries, sorted by cell.
    pub fn entries(&self) -> &'a [Entry] {
        self.entries
    }

    /// The entries of one cell (one per class present).
    #[inline]
    pub fn cell(&self, key: VoxelKey) -> &'a [Entry] {
        let n = self.slots.len();
        if n == 0 {
            return &[];
        }
        let mut i = home(key.hash32(), n);
        for _ in 0..n {
            let s = self.slots.get(i).copied().unwrap_or(0);
            if s == 0 {
                return &[];
            }
            // A slot holds (first entry + 1) << 5 | entries in the cell.
            let first = ((s >> RUN_BITS) - 1) as usize;
            let len = (s & RUN_MASK) as usize;
            if let Some(run) = self.entries.get(first..first + len) {
                if run.first().map(|e| e.key) == Some(key) {
                    return run;
                }
            }
            i += 1;
            if i == n {
                i = 0;
            }
        }
        &[]
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

/// Bits of a slot holding the number of entries of its cell.
const RUN_BITS: u32 = 5;
const RUN_MASK: u32 = (1 << RUN_BITS) - 1;

/// Builds the index of one level over its (sorted) entries.
fn index_level(entries: &[Entry], slots: &mut [u32]) {
    slots.fill(0);
    let n = slots.len();
    if n == 0 {
        return;
    }
    let mut i = 0;
    while let Some(e) = entries.get(i) {
        let run = entries.get(i..).unwrap_or(&[]).iter().take_while(|o| o.key == e.key).count().max(1);
        // One entry per class: a run never exceeds the class count (< 32).
        let value = ((i as u32 + 1) << RUN_BITS) | (run as u32 & RUN_MASK);
        let mut s = home(e.key.hash32(), n);
        i += run;
        for _ in 0..n {
            match slots.get_mut(s) {
                Some(slot) if *slot == 0 => {
                    *slot = value;
                    break;
                }
                _ => {
                    s += 1;
                    if s == n {
                        s = 0;
                    }
                }
            }
        }
    }
}

/// Fits normals for `entries`: the weighted covariance of the entries of all
/// classes of `level` within 1.5 cells; planar when the smallest eigenvalue
/// is under a tenth of the middle one.
fn fit_normals(level: &Level<'_>, entries: &[Entry], out: &mut [[f32; 3]]) {
    let r = level.resolution;
    let radius_sq = (1.5 * r) * (1.5 * r);
    for (e, n) in entries.iter().zip(out.iter_mut()) {
        *n = [0.0; 3];
        let mut sum_w = 0.0f32;
        let mut mean = Vector3::zeros();
        let mut second = Matrix3::zeros();
        let mut count = 0;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(k) = e.key.offset(dx, dy, dz) else { continue };
                    for o in level.cell(k) {
                        let d = [
                            o.position[0] - e.position[0],
                            o.position[1] - e.position[1],
                            o.position[2] - e.position[2],
                        ];
                        if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > radius_sq {
                            continue;
                        }
                        let p = Vector3::new(o.position[0], o.position[1], o.position[2]);
                        sum_w += o.weight;
                        mean += p * o.weight;
                        second += p * p.transpose() * o.weight;
                        count += 1;
                    }
                }
            }
        }
        if count < 4 || sum_w <= 0.0 {
            continue;
        }
        mean /= sum_w;
        let cov = second / sum_w - mean * mean.transpose();
        let eig = SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_unstable_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let (l0, l1) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
        if !(l0.is_finite() && l1.is_finite()) || l1 <= 0.0 || l0 > 0.1 * l1 {
            continue;
        }
        let v = eig.eigenvectors.column(order[0]);
        let norm = v.norm();
        if norm > 0.0 && norm.is_finite() {
            *n = [v[0] / norm, v[1] / norm, v[2] / norm];
        }
    }
}

impl<S: PyramidStorage> Pyramid<S> {
    /// Prepares `map` for matching with `levels` levels (level `l` has cells
    /// `2^l` times the map's resolution) and a footprint of cells of
    /// `footprint_cell` metres (doubled until it fits the storage's words; no
    /// footprint, and so no coarse search, when the storage has none).
    pub fn build<V: VoxelStorage>(
        map: &LocalMap<V>,
        levels: usize,
        footprint_cell: f32,
        mut storage: S,
    ) -> Result<Self, PyramidError> {
        if map.is_empty() {
            return Err(PyramidError::EmptyMap);
        }
        if levels == 0 || levels > MAX_LEVELS {
            return Err(PyramidError::Levels);
        }
        let (entries, slots, _) = storage.parts_mut();
        // Slots address entries with 27 bits.
        if entries.len() < map.len() || entries.len() >= (1 << (32 - RUN_BITS)) - 1 {
            return Err(PyramidError::Full);
        }
        // Level 0: one entry per voxel.
        for (e, v) in entries.iter_mut().zip(map.iter()) {
            let class = v.class();
            let p = class.map(|c| v.labels.probability(c)).unwrap_or(1.0 / NUM_CLASSES as f32);
            *e = Entry {
                position: v.position(map.resolution()),
                normal: [0.0; 3],
                weight: 1.0,
                key: v.key,
                class: class.map(|c| c.index()).unwrap_or(u8::MAX),
                confidence: (p * 255.0 + 0.5) as u8,
            };
        }
        let mut info = [LevelInfo::default(); MAX_LEVELS];
        let n0 = map.len();
        entries.get_mut(..n0).ok_or(PyramidError::Full)?.sort_unstable_by_key(Entry::order);
        info[0] = LevelInfo { start: 0, len: n0, resolution: map.resolution(), ..LevelInfo::default() };
        for l in 1..levels {
            let prev = info[l - 1];
            let start = prev.start + prev.len;
            // Copy the finer level with coarsened keys, sort, merge runs in place.
            let end = start.checked_add(prev.len).ok_or(PyramidError::Full)?;
            if end > entries.len() {
                return Err(PyramidError::Full);
            }
            let (done, rest) = entries.split_at_mut(start);
            let src = done.get(prev.start..prev.start + prev.len).ok_or(PyramidError::Full)?;
            let work = rest.get_mut(..prev.len).ok_or(PyramidError::Full)?;
            for (w, s) in work.iter_mut().zip(src) {
                *w = Entry { key: s.key.coarsen(2), ..*s };
            }
            work.sort_unstable_by_key(Entry::order);
            let mut out = 0usize;
            for i in 0..work.len() {
                let e = work[i];
                if out > 0 && work[out - 1].order() == e.order() {
                    let acc = &mut work[out - 1];
                    let w = acc.weight + e.weight;
                    for a in 0..3 {
                        acc.position[a] += (e.position[a] - acc.position[a]) * (e.weight / w);
                    }
                    let conf = (f32::from(acc.confidence) * acc.weight + f32::from(e.confidence) * e.weight) / w;
                    acc.confidence = (conf + 0.5) as u8;
                    acc.weight = w;
                } else {
                    work[out] = e;
                    out += 1;
                }
            }
            info[l] = LevelInfo { start, len: out, resolution: prev.resolution * 2.0, ..LevelInfo::default() };
        }
        // Index slots: twice the entries of each level.
        let total_slots: usize = info[..levels].iter().map(|i| 2 * i.len).sum();
        if slots.len() < total_slots {
            return Err(PyramidError::Full);
        }
        let mut slot_start = 0;
        for li in info[..levels].iter_mut() {
            li.slot_start = slot_start;
            li.slot_len = 2 * li.len;
            slot_start += li.slot_len;
            let e = entries.get(li.start..li.start + li.len).ok_or(PyramidError::Full)?;
            let s = slots.get_mut(li.slot_start..li.slot_start + li.slot_len).ok_or(PyramidError::Full)?;
            index_level(e, s);
        }
        let mut pyramid = Pyramid { storage, levels: info, count: levels, footprint: None };
        // Normals, level by level: computed against the read-only level, then written.
        for l in 0..levels {
            let li = pyramid.levels[l];
            for chunk_start in (0..li.len).step_by(256) {
                let mut normals = [[0.0f32; 3]; 256];
                let n = (li.len - chunk_start).min(256);
                {
                    // Neighbours are looked up in the whole level; the entries
                    // are fitted in chunks so the normals need no big buffer.
                    let level = pyramid.level(l).ok_or(PyramidError::Levels)?;
                    let chunk = level.entries.get(chunk_start..chunk_start + n).unwrap_or(&[]);
                    fit_normals(&level, chunk, &mut normals[..n]);
                }
                let (entries, _, _) = pyramid.storage.parts_mut();
                if let Some(dst) = entries.get_mut(li.start + chunk_start..li.start + chunk_start + n) {
                    for (e, nm) in dst.iter_mut().zip(normals.iter()) {
                        e.normal = *nm;
                    }
                }
            }
        }
        if footprint_cell.is_finite() && footprint_cell > 0.0 {
            let (entries, _, words) = pyramid.storage.parts_mut();
            let n0 = pyramid.levels[0].len;
            pyramid.footprint = footprint::build(entries.get(..n0).unwrap_or(&[]), footprint_cell, words);
        }
        Ok(pyramid)
    }

    /// The footprint, if the storage had room for one.
    pub fn footprint(&self) -> Option<Footprint<'_>> {
        let info = self.footprint?;
        let (_, _, words) = self.storage.parts();
        Some(Footprint { info, words: words.get(..info.words())? })
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.count
    }

    /// Level `l` (0 is the finest).
    pub fn level(&self, l: usize) -> Option<Level<'_>> {
        let li = self.levels.get(..self.count)?.get(l)?;
        let (entries, slots, _) = self.storage.parts();
        Some(Level {
            entries: entries.get(li.start..li.start + li.len)?,
            slots: slots.get(li.slot_start..li.slot_start + li.slot_len)?,
            resolution: li.resolution,
            inv_resolution: 1.0 / li.resolution,
        })
    }

    /// Entries used in the storage, all levels together.
    pub fn entry_count(&self) -> usize {
        self.levels[..self.count].iter().map(|l| l.len).sum()
    }
}
