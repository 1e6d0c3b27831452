//! Storage for a map and the open-addressing index over it.
//!
//! Voxels live densely, in insertion order, in a caller-provided slice; an
//! index of `u32` slots (0 = empty, otherwise dense position + 1) with linear
//! probing finds them by key. The index has twice as many slots as there are
//! voxels of capacity, so its load factor never passes 0.5 and a probe never
//! runs long. Per voxel of capacity that is 24 bytes of voxel and 8 bytes of
//! index: 32 bytes.

use super::key::VoxelKey;
use super::voxel::SemanticVoxel;

/// Index slots per voxel of capacity.
pub const SLOTS_PER_VOXEL: usize = 2;

/// Bytes per voxel of capacity, index included.
pub const BYTES_PER_VOXEL: usize =
    core::mem::size_of::<SemanticVoxel>() + SLOTS_PER_VOXEL * core::mem::size_of::<u32>();

/// Where a map keeps its voxels and index. [`ArrayStorage`] fixes the
/// capacity at compile time (firmware statics); [`SliceStorage`] borrows
/// buffers the caller owns (e.g. heap vectors sized at run time on a host).
pub trait VoxelStorage {
    /// The voxel buffer; its length is the map's capacity.
    fn voxels(&self) -> &[SemanticVoxel];
    /// The index buffer; at least [`SLOTS_PER_VOXEL`] times the capacity.
    fn slots(&self) -> &[u32];
    /// Both buffers, mutably.
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u32]);
}

/// Storage for `N` voxels, inline. Zero-initialised, so a `static` of it
/// lands in `.bss` on a microcontroller.
pub struct ArrayStorage<const N: usize> {
    voxels: [SemanticVoxel; N],
    slots: [[u32; SLOTS_PER_VOXEL]; N],
}

impl<const N: usize> ArrayStorage<N> {
    /// Empty storage.
    pub const fn new() -> Self {
        ArrayStorage { voxels: [SemanticVoxel::EMPTY; N], slots: [[0; SLOTS_PER_VOXEL]; N] }
    }
}

impl<const N: usize> Default for ArrayStorage<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> VoxelStorage for ArrayStorage<N> {
    fn voxels(&self) -> &[SemanticVoxel] {
        &self.voxels
    }
    fn slots(&self) -> &[u32] {
        self.slots.as_flattened()
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u32]) {
        (&mut self.voxels, self.slots.as_flattened_mut())
    }
}

/// A map may borrow its storage, e.g. a `static` on a microcontroller.
impl<T: VoxelStorage + ?Sized> VoxelStorage for &mut T {
    fn voxels(&self) -> &[SemanticVoxel] {
        (**self).voxels()
    }
    fn slots(&self) -> &[u32] {
        (**self).slots()
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u32]) {
        (**self).parts_mut()
    }
}

/// Storage in buffers the caller owns.
pub struct SliceStorage<'a> {
    /// Voxel buffer (its length is the capacity).
    pub voxels: &'a mut [SemanticVoxel],
    /// Index buffer, at least twice as long as `voxels`.
    pub slots: &'a mut [u32],
}

impl VoxelStorage for SliceStorage<'_> {
    fn voxels(&self) -> &[SemanticVoxel] {
        self.voxels
    }
    fn slots(&self) -> &[u32] {
        self.slots
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u32]) {
        (self.voxels, self.slots)
    }
}

/// Result of a probe: the voxel's dense position, or the empty slot where
/// its key would go.
pub(crate) enum Probe {
    Found(usize),
    Vacant(usize),
}

/// First slot to probe for a hash (multiply-shift: no power-of-two size needed).
fn home(hash: u32, slots: usize) -> usize {
    ((u64::from(hash) * slots as u64) >> 32) as usize
}

/// Finds `key`. `voxels` is the filled prefix. The index always has an empty
/// slot (load factor at most 0.5), so the walk ends; it is bounded anyway.
pub(crate) fn probe(voxels: &[SemanticVoxel], slots: &[u32], key: VoxelKey) -> Probe {
    let n = slots.len();
    if n == 0 {
        return Probe::Vacant(0);
    }
    let mut i = home(key.hash32(), n);
    for _ in 0..n {
        let s = slots.get(i).copied().unwrap_or(0);
        if s == 0 {
            return Probe::Vacant(i);
        }
        if voxels.get((s - 1) as usize).map(|v| v.key) == Some(key) {
            return Probe::Found((s - 1) as usize);
        }
        i += 1;
        if i == n {
            i = 0;
        }
    }
    Probe::Vacant(n)
}

/// Rebuilds the index for the filled prefix `voxels`.
pub(crate) fn rebuild(voxels: &[SemanticVoxel], slots: &mut [u32]) {
    slots.fill(0);
    for (d, v) in voxels.iter().enumerate() {
        if let Probe::Vacant(i) = probe(voxels, slots, v.key) {
            if let Some(s) = slots.get_mut(i) {
                *s = d as u32 + 1;
            }
        }
    }
}
