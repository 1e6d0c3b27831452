//! Storage for a map and the open-addressing index over it.
//!
//! Voxels live densely, in insertion order, in a caller-provided slice; an
//! index of slots (0 = empty, otherwise dense position + 1) with linear
//! probing finds them by key. The index has twice as many slots as there are
//! voxels of capacity, so its load factor never passes 0.5 and a probe never
//! runs long. Slots are `u32`, or `u16` for maps of fewer than 65,535 voxels
//! (a robot's: half the index). Per voxel of capacity that is 24 bytes of
//! voxel and 8 (or 4) bytes of index: 32 (or 28) bytes.

use super::key::VoxelKey;
use super::voxel::SemanticVoxel;

/// Index slots per voxel of capacity.
pub const SLOTS_PER_VOXEL: usize = 2;

/// Bytes per voxel of capacity with `u32` slots, index included.
pub const BYTES_PER_VOXEL: usize =
    core::mem::size_of::<SemanticVoxel>() + SLOTS_PER_VOXEL * core::mem::size_of::<u32>();

/// The integer of an index slot: `u32`, or `u16` for a map of at most
/// [`SlotInt::MAX`] - 1 voxels.
pub trait SlotInt: Copy + Default + PartialEq + sealed::Sealed {
    /// An empty slot.
    const ZERO: Self;
    /// The largest value a slot holds (dense position + 1).
    const MAX: u32;
    /// The slot's value.
    fn get(self) -> u32;
    /// A slot holding `v` (at most [`SlotInt::MAX`]; callers check capacity).
    fn of(v: u32) -> Self;
    /// A map's index, as the pyramid keeps it.
    fn index(slots: &[Self]) -> MapIndex<'_>;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for u16 {}
    impl Sealed for u32 {}
}

impl SlotInt for u32 {
    const ZERO: Self = 0;
    const MAX: u32 = u32::MAX;
    #[inline]
    fn get(self) -> u32 {
        self
    }
    #[inline]
    fn of(v: u32) -> Self {
        v
    }
    fn index(slots: &[Self]) -> MapIndex<'_> {
        MapIndex::Wide(slots)
    }
}

impl SlotInt for u16 {
    const ZERO: Self = 0;
    const MAX: u32 = u16::MAX as u32;
    #[inline]
    fn get(self) -> u32 {
        u32::from(self)
    }
    #[inline]
    fn of(v: u32) -> Self {
        v as u16
    }
    fn index(slots: &[Self]) -> MapIndex<'_> {
        MapIndex::Narrow(slots)
    }
}

/// A map's index slots of either width.
#[derive(Clone, Copy, Debug)]
pub enum MapIndex<'a> {
    /// `u32` slots.
    Wide(&'a [u32]),
    /// `u16` slots.
    Narrow(&'a [u16]),
}

/// Where a map keeps its voxels and index. [`ArrayStorage`] fixes the
/// capacity at compile time (firmware statics); [`SliceStorage`] borrows
/// buffers the caller owns (e.g. heap vectors sized at run time on a host).
pub trait VoxelStorage {
    /// The slot integer (`u32`, or `u16` for small maps).
    type Slot: SlotInt;
    /// The voxel buffer; its length is the map's capacity.
    fn voxels(&self) -> &[SemanticVoxel];
    /// The index buffer; at least [`SLOTS_PER_VOXEL`] times the capacity.
    fn slots(&self) -> &[Self::Slot];
    /// Both buffers, mutably.
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [Self::Slot]);
}

/// Storage for `N` voxels, inline, with slots of `T` (`u32` by default;
/// `u16` takes 4 bytes per voxel less for up to 65,534 voxels).
/// Zero-initialised, so a `static` of it lands in `.bss` on a
/// microcontroller.
pub struct ArrayStorage<const N: usize, T: SlotInt = u32> {
    voxels: [SemanticVoxel; N],
    slots: [[T; SLOTS_PER_VOXEL]; N],
}

impl<const N: usize, T: SlotInt> ArrayStorage<N, T> {
    /// Empty storage.
    pub const fn new() -> Self {
        ArrayStorage { voxels: [SemanticVoxel::EMPTY; N], slots: [[T::ZERO; SLOTS_PER_VOXEL]; N] }
    }
}

impl<const N: usize, T: SlotInt> Default for ArrayStorage<N, T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, T: SlotInt> VoxelStorage for ArrayStorage<N, T> {
    type Slot = T;
    fn voxels(&self) -> &[SemanticVoxel] {
        &self.voxels
    }
    fn slots(&self) -> &[T] {
        self.slots.as_flattened()
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [T]) {
        (&mut self.voxels, self.slots.as_flattened_mut())
    }
}

/// A map may borrow its storage, e.g. a `static` on a microcontroller.
impl<S: VoxelStorage + ?Sized> VoxelStorage for &mut S {
    type Slot = S::Slot;
    fn voxels(&self) -> &[SemanticVoxel] {
        (**self).voxels()
    }
    fn slots(&self) -> &[S::Slot] {
        (**self).slots()
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [S::Slot]) {
        (**self).parts_mut()
    }
}

/// Storage in buffers the caller owns, with slots of `T` (`u32` by default).
pub struct SliceStorage<'a, T: SlotInt = u32> {
    /// Voxel buffer (its length is the capacity).
    pub voxels: &'a mut [SemanticVoxel],
    /// Index buffer, at least twice as long as `voxels`.
    pub slots: &'a mut [T],
}

impl<T: SlotInt> VoxelStorage for SliceStorage<'_, T> {
    type Slot = T;
    fn voxels(&self) -> &[SemanticVoxel] {
        self.voxels
    }
    fn slots(&self) -> &[T] {
        self.slots
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [T]) {
        (self.voxels, self.slots)
    }
}

/// Storage in words the caller owns: `voxels` voxels at the start of
/// `words`, the words after them kept with them (a robot's: what follows
/// its map is handed on whole with what the map leaves, see
/// [`CopiedBase::compact`](crate::matching::CopiedBase::compact)), and
/// 16-bit index slots.
pub struct WordStorage<'a> {
    words: &'a mut [u32],
    voxels: usize,
    slots: &'a mut [u16],
}

impl<'a> WordStorage<'a> {
    /// `voxels` voxels at the start of `words` (any contents: the map
    /// clears its index), indexed by `slots`; `None` when `words` holds
    /// fewer.
    pub fn new(words: &'a mut [u32], voxels: usize, slots: &'a mut [u16]) -> Option<Self> {
        (words.len() >= crate::region::words_for::<SemanticVoxel>(voxels)).then_some(WordStorage {
            words,
            voxels,
            slots,
        })
    }

    /// The words (the voxels first), the capacity in voxels and the slots.
    pub fn into_parts(self) -> (&'a mut [u32], usize, &'a mut [u16]) {
        (self.words, self.voxels, self.slots)
    }

    fn voxel_words(&self) -> usize {
        crate::region::words_for::<SemanticVoxel>(self.voxels)
    }
}

impl VoxelStorage for WordStorage<'_> {
    type Slot = u16;
    fn voxels(&self) -> &[SemanticVoxel] {
        let words = self.words.get(..self.voxel_words()).unwrap_or(&[]);
        bytemuck::try_cast_slice(words).unwrap_or(&[])
    }
    fn slots(&self) -> &[u16] {
        self.slots
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u16]) {
        let n = self.voxel_words();
        let words = match self.words.get_mut(..n) {
            Some(w) => w,
            None => &mut [],
        };
        (bytemuck::try_cast_slice_mut(words).unwrap_or(&mut []), self.slots)
    }
}

/// Storage on the heap, sized at run time (feature `alloc`): what a host
/// gives a map whose size it learns from its data.
#[cfg(any(test, feature = "alloc"))]
#[derive(Clone)]
pub struct VecStorage {
    voxels: alloc::vec::Vec<SemanticVoxel>,
    slots: alloc::vec::Vec<u32>,
}

#[cfg(any(test, feature = "alloc"))]
impl VecStorage {
    /// Storage for `capacity` voxels (at least one).
    pub fn with_capacity(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        VecStorage {
            voxels: alloc::vec![SemanticVoxel::EMPTY; capacity],
            slots: alloc::vec![0; SLOTS_PER_VOXEL * capacity],
        }
    }
}

#[cfg(any(test, feature = "alloc"))]
impl VoxelStorage for VecStorage {
    type Slot = u32;
    fn voxels(&self) -> &[SemanticVoxel] {
        &self.voxels
    }
    fn slots(&self) -> &[u32] {
        &self.slots
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [u32]) {
        (&mut self.voxels, &mut self.slots)
    }
}

/// Where a walk of an open-addressing index ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Slot {
    /// A slot whose value the caller recognised.
    Found {
        /// Slot position.
        slot: usize,
        /// Its value (never 0).
        value: u32,
    },
    /// The first empty slot on the walk: where the key would go.
    Vacant(usize),
    /// Every slot is taken and none matched (or there are no slots).
    Full,
}

/// First slot to probe for a hash (multiply-shift: no power-of-two size needed).
#[inline]
fn home(hash: u32, slots: usize) -> usize {
    ((u64::from(hash) * slots as u64) >> 32) as usize
}

/// The one linear-probing walk of every open-addressing index of the crate
/// (a map's voxels, a pyramid's coarse cells and its merge table): slots hold
/// 0 for empty or a caller-defined nonzero value; from `hash`'s home slot the
/// walk visits slots in order (wrapping) until `is_match(value)` or an empty
/// slot. Bounded by the slot count, so a full table cannot loop.
#[inline]
pub(crate) fn walk<T: SlotInt>(slots: &[T], hash: u32, is_match: impl FnMut(u32) -> bool) -> Slot {
    walk_by(slots.len(), |i| slots.get(i).map_or(0, |s| s.get()), hash, is_match)
}

/// [`walk`] over `n` slots read by `get` (e.g. two 16-bit slots to a word).
#[inline]
pub(crate) fn walk_by(n: usize, get: impl Fn(usize) -> u32, hash: u32, mut is_match: impl FnMut(u32) -> bool) -> Slot {
    if n == 0 {
        return Slot::Full;
    }
    let mut i = home(hash, n);
    for _ in 0..n {
        let value = get(i);
        if value == 0 {
            return Slot::Vacant(i);
        }
        if is_match(value) {
            return Slot::Found { slot: i, value };
        }
        i += 1;
        if i == n {
            i = 0;
        }
    }
    Slot::Full
}

/// Result of a probe: the voxel's dense position, or the empty slot where
/// its key would go.
pub(crate) enum Probe {
    Found(usize),
    Vacant(usize),
}

/// Finds `key`. `voxels` is the filled prefix; slots hold the dense
/// position plus one. The index always has an empty slot (load factor at
/// most 0.5); a full one answers `Vacant(slots.len())`, a slot no write
/// reaches.
#[inline]
pub(crate) fn probe<T: SlotInt>(voxels: &[SemanticVoxel], slots: &[T], key: VoxelKey) -> Probe {
    probe_keys(slots, key, |i| voxels.get(i).map(|v| v.key))
}

/// [`probe`] over entries whose keys `key_at` gives (by dense position).
#[inline]
pub(crate) fn probe_keys<T: SlotInt>(slots: &[T], key: VoxelKey, key_at: impl Fn(usize) -> Option<VoxelKey>) -> Probe {
    let at_key = |s: u32| key_at((s - 1) as usize) == Some(key);
    match walk(slots, key.hash32(), at_key) {
        Slot::Found { value, .. } => Probe::Found((value - 1) as usize),
        Slot::Vacant(i) => Probe::Vacant(i),
        Slot::Full => Probe::Vacant(slots.len()),
    }
}

/// [`probe`] in an index of either width.
#[inline]
pub(crate) fn probe_index(voxels: &[SemanticVoxel], index: MapIndex<'_>, key: VoxelKey) -> Probe {
    match index {
        MapIndex::Wide(s) => probe(voxels, s, key),
        MapIndex::Narrow(s) => probe(voxels, s, key),
    }
}

/// Rebuilds the index for the filled prefix `voxels`.
pub(crate) fn rebuild<T: SlotInt>(voxels: &[SemanticVoxel], slots: &mut [T]) {
    slots.fill(T::ZERO);
    for (d, v) in voxels.iter().enumerate() {
        if let Probe::Vacant(i) = probe(voxels, slots, v.key) {
            if let Some(s) = slots.get_mut(i) {
                *s = T::of(d as u32 + 1);
            }
        }
    }
}
