//! Where pyramids keep their buffers: the storage trait, storages of
//! compile-time size (model, scene, split with a copied level 0), on the
//! heap (feature `alloc`), and the capacity a map's pyramid needs.

use super::*;

/// Room for a model's level 0 copied out of its map: `V` points and two
/// 16-bit index slots each (the map's index, copied), 22 bytes per voxel.
/// A model storage with this room ([`SplitStorage`]) lets the map's memory
/// go to other uses once the model is built (a board overlays it).
pub struct CopiedLevel<const V: usize> {
    points: [ModelPoint; V],
    slots: [[u16; 2]; V],
}

impl<const V: usize> CopiedLevel<V> {
    /// Empty room.
    pub const fn new() -> Self {
        CopiedLevel { points: [ModelPoint::EMPTY; V], slots: [[0; 2]; V] }
    }
}

impl<const V: usize> Default for CopiedLevel<V> {
    fn default() -> Self {
        Self::new()
    }
}

/// Where a copied level 0 goes: its points and index slots.
pub trait CopiedRoom {
    /// The points and slots.
    fn room(&self) -> (&[ModelPoint], &[u16]);
    /// The points and slots, mutably.
    fn room_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]);
}

impl<const V: usize> CopiedRoom for CopiedLevel<V> {
    fn room(&self) -> (&[ModelPoint], &[u16]) {
        (&self.points, self.slots.as_flattened())
    }
    fn room_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        (&mut self.points, self.slots.as_flattened_mut())
    }
}

impl<T: CopiedRoom + ?Sized> CopiedRoom for &mut T {
    fn room(&self) -> (&[ModelPoint], &[u16]) {
        (**self).room()
    }
    fn room_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        (**self).room_mut()
    }
}

/// Room for a copied level 0 in buffers the caller owns (e.g. carved out
/// of a robot's memory, [`crate::region`]).
pub struct CopiedSlices<'a> {
    /// One point per voxel.
    pub points: &'a mut [ModelPoint],
    /// The map's index slots (two per voxel of its capacity).
    pub slots: &'a mut [u16],
}

impl CopiedRoom for CopiedSlices<'_> {
    fn room(&self) -> (&[ModelPoint], &[u16]) {
        (self.points, self.slots)
    }
    fn room_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        (self.points, self.slots)
    }
}

/// A model's storage in two parts that may live apart: room for the copied
/// level 0 (`level0`) and everything else (`rest`: coarse entries, normals,
/// index, footprint; its extras unused). While the map is copied only
/// `level0` is touched, so `rest` may overlay the map's memory.
pub struct SplitStorage<L, S> {
    /// Room for the copied level 0.
    pub level0: L,
    /// The coarse levels and footprint.
    pub rest: S,
}

impl<L: CopiedRoom, S: PyramidStorage> PyramidStorage for SplitStorage<L, S> {
    fn parts(&self) -> PyramidParts<'_> {
        let (points, point_slots) = self.level0.room();
        PyramidParts { points, point_slots, ..self.rest.parts() }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        let (points, point_slots) = self.level0.room_mut();
        PyramidPartsMut { points, point_slots, ..self.rest.parts_mut() }
    }
    fn copied_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        self.level0.room_mut()
    }
}

/// A pyramid's buffers, read-only.
pub struct PyramidParts<'a> {
    /// One per voxel of the map (at least the map's length) when level 0 is
    /// the map; none when it is copied or a scene.
    pub extras: &'a [VoxelExtra],
    /// Entries of all coarse levels.
    pub entries: &'a [CoarseEntry],
    /// Normals of the coarse entries, one per entry (a model's; a scene's
    /// storage has none).
    pub normals: &'a [PackedNormal],
    /// Index slots of the coarse levels: at least two per entry.
    pub slots: &'a [u32],
    /// Footprint words.
    pub words: &'a [u32],
    /// A copied level 0's points ([`Pyramid::build_model`]; may be empty).
    pub points: &'a [ModelPoint],
    /// A copied level 0's index slots.
    pub point_slots: &'a [u16],
}

/// A pyramid's buffers, mutable.
pub struct PyramidPartsMut<'a> {
    /// One per voxel of the map (at least the map's length) when level 0 is
    /// the map; none when it is copied or a scene.
    pub extras: &'a mut [VoxelExtra],
    /// Entries of all coarse levels.
    pub entries: &'a mut [CoarseEntry],
    /// Normals of the coarse entries, one per entry (a model's).
    pub normals: &'a mut [PackedNormal],
    /// Index slots of the coarse levels: at least two per entry.
    pub slots: &'a mut [u32],
    /// Footprint words.
    pub words: &'a mut [u32],
    /// A copied level 0's points.
    pub points: &'a mut [ModelPoint],
    /// A copied level 0's index slots.
    pub point_slots: &'a mut [u16],
}

/// Buffers the caller owns are a storage as they are (e.g. carved out of a
/// robot's memory, [`crate::region`]).
impl PyramidStorage for PyramidPartsMut<'_> {
    fn parts(&self) -> PyramidParts<'_> {
        PyramidParts {
            extras: self.extras,
            entries: self.entries,
            normals: self.normals,
            slots: self.slots,
            words: self.words,
            points: self.points,
            point_slots: self.point_slots,
        }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        PyramidPartsMut {
            extras: self.extras,
            entries: self.entries,
            normals: self.normals,
            slots: self.slots,
            words: self.words,
            points: self.points,
            point_slots: self.point_slots,
        }
    }
}

/// Where a pyramid keeps its buffers.
pub trait PyramidStorage {
    /// The buffers.
    fn parts(&self) -> PyramidParts<'_>;
    /// The buffers, mutably.
    fn parts_mut(&mut self) -> PyramidPartsMut<'_>;
    /// Only the room for a copied level 0 ([`Pyramid::build_model`]): all
    /// that is touched while the map is copied, so the other parts may lie
    /// over the map's memory. None by default.
    fn copied_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        (&mut [], &mut [])
    }
}

/// A pyramid may borrow its storage, e.g. a `static` on a microcontroller.
impl<T: PyramidStorage + ?Sized> PyramidStorage for &mut T {
    fn parts(&self) -> PyramidParts<'_> {
        (**self).parts()
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        (**self).parts_mut()
    }
    fn copied_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        (**self).copied_mut()
    }
}

/// Pyramid storage of compile-time size: extras for `V` voxels, `E` coarse
/// entries with a normal and one index word each (two 16-bit slots: `E`
/// must stay under [`NARROW_LIMIT`]), `W` footprint words. Bytes:
/// `6 V + 20 E + 4 W`.
pub struct ArrayPyramidStorage<const V: usize, const E: usize, const W: usize> {
    extras: [VoxelExtra; V],
    entries: [CoarseEntry; E],
    normals: [PackedNormal; E],
    slots: [u32; E],
    words: [u32; W],
}

impl<const V: usize, const E: usize, const W: usize> ArrayPyramidStorage<V, E, W> {
    /// Empty storage.
    pub const fn new() -> Self {
        ArrayPyramidStorage {
            extras: [VoxelExtra::EMPTY; V],
            entries: [CoarseEntry::EMPTY; E],
            normals: [PackedNormal([0, 0]); E],
            slots: [0; E],
            words: [0; W],
        }
    }
}

impl<const V: usize, const E: usize, const W: usize> Default for ArrayPyramidStorage<V, E, W> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const V: usize, const E: usize, const W: usize> PyramidStorage for ArrayPyramidStorage<V, E, W> {
    fn parts(&self) -> PyramidParts<'_> {
        PyramidParts {
            extras: &self.extras,
            entries: &self.entries,
            normals: &self.normals,
            slots: &self.slots,
            words: &self.words,
            points: &[],
            point_slots: &[],
        }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        PyramidPartsMut {
            extras: &mut self.extras,
            entries: &mut self.entries,
            normals: &mut self.normals,
            slots: &mut self.slots,
            words: &mut self.words,
            points: &mut [],
            point_slots: &mut [],
        }
    }
}

/// Storage of a scene's pyramid ([`Role::Scene`], e.g. of a
/// [`SceneMap`]) of compile-time size: `E` coarse entries and `W` footprint
/// words, no extras, normals or index slots. Bytes: `12 E + 4 W`.
pub struct ArraySceneStorage<const E: usize, const W: usize> {
    entries: [CoarseEntry; E],
    words: [u32; W],
}

impl<const E: usize, const W: usize> ArraySceneStorage<E, W> {
    /// Empty storage.
    pub const fn new() -> Self {
        ArraySceneStorage { entries: [CoarseEntry::EMPTY; E], words: [0; W] }
    }
}

impl<const E: usize, const W: usize> Default for ArraySceneStorage<E, W> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const E: usize, const W: usize> PyramidStorage for ArraySceneStorage<E, W> {
    fn parts(&self) -> PyramidParts<'_> {
        PyramidParts {
            extras: &[],
            entries: &self.entries,
            normals: &[],
            slots: &[],
            words: &self.words,
            points: &[],
            point_slots: &[],
        }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        PyramidPartsMut {
            extras: &mut [],
            entries: &mut self.entries,
            normals: &mut [],
            slots: &mut [],
            words: &mut self.words,
            points: &mut [],
            point_slots: &mut [],
        }
    }
}

/// Most footprint cells a [`PyramidCapacity`] plans for: a 250 m square at
/// 1 m. A larger map's footprint gets coarser cells instead of more memory.
pub const MAX_FOOTPRINT_CELLS: usize = 62_500;

/// The buffer sizes a pyramid of one map needs: what a storage sized at run
/// time allocates (and what compile-time capacities must cover).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PyramidCapacity {
    /// [`VoxelExtra`]s: one per voxel.
    pub voxels: usize,
    /// Coarse entries.
    pub entries: usize,
    /// Index words of the coarse levels: one per entry for a model (two
    /// 16-bit slots; two words from [`NARROW_LIMIT`] entries on), none for
    /// a scene (nothing looks a scene's cell up).
    pub slots: usize,
    /// Footprint words.
    pub words: usize,
}

impl PyramidCapacity {
    /// Room to prepare `map` with `levels` levels and a footprint of
    /// `footprint_cell` metres for `role`, whatever the map holds: coarse
    /// levels as large as the map (no merging at all), a footprint grid over
    /// the map's bounds (at most [`MAX_FOOTPRINT_CELLS`] cells; beyond that
    /// the build doubles the cell until it fits).
    pub fn for_map<V: VoxelStorage>(map: &LocalMap<V>, levels: usize, footprint_cell: f32, role: Role) -> Self {
        Self::of(map.len(), map.bounds(), levels, footprint_cell, role)
    }

    /// Room to prepare `scene` ([`Pyramid::build_scene`]), as
    /// [`PyramidCapacity::for_map`]: no extras (the scene's points hold
    /// what they would).
    pub fn for_scene<S: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>>(
        scene: &SceneMap<S>,
        levels: usize,
        footprint_cell: f32,
    ) -> Self {
        let len = crate::map::VoxelSink::len(scene);
        PyramidCapacity { voxels: 0, ..Self::of(len, scene.bounds(), levels, footprint_cell, Role::Scene) }
    }

    fn of(len: usize, bounds: Option<([f32; 3], [f32; 3])>, levels: usize, footprint_cell: f32, role: Role) -> Self {
        let grids = match role {
            Role::Model => footprint::POOL_LEVELS,
            Role::Scene => 2,
        };
        let cells = match bounds {
            Some((lo, hi)) if footprint_cell.is_finite() && footprint_cell > 0.0 => {
                // One cell of margin per axis: the grid spans the voxels' means.
                let side = |a: usize| (libm::floorf((hi[a] - lo[a]) / footprint_cell) as usize).saturating_add(2);
                side(0).saturating_mul(side(1)).min(MAX_FOOTPRINT_CELLS)
            }
            _ => 0,
        };
        let listed = cells.min(len);
        let entries = len.saturating_mul(levels.saturating_sub(1));
        // A model's words hold level 0's sweep order while normals are
        // fitted and, beside it, its entries gathered in that order (one
        // word and six per voxel: the faster sort and the faster fit); a
        // scene's hold the merge's hash table while its coarse levels are
        // built (two per entry of a level). Slots of 16 bits, two to a
        // word, below NARROW_LIMIT entries.
        let per_entry = if entries < NARROW_LIMIT { 1 } else { 2 };
        let scratch = match role {
            Role::Model => (1 + super::normals::SWEEP_POINT_WORDS) * len,
            Role::Scene => per_entry * len,
        };
        PyramidCapacity {
            voxels: len,
            entries,
            slots: match role {
                Role::Model => per_entry * entries,
                Role::Scene => 0,
            },
            words: (footprint::packed(grids, cells) + 3 * listed).max(scratch),
        }
    }

    /// Normals of coarse entries: one per entry for a model (a storage with
    /// index slots), none for a scene.
    pub fn normals(&self) -> usize {
        if self.slots > 0 {
            self.entries
        } else {
            0
        }
    }

    /// Bytes of storage this takes.
    pub fn bytes(&self) -> usize {
        self.voxels * core::mem::size_of::<VoxelExtra>()
            + self.entries * core::mem::size_of::<CoarseEntry>()
            + self.normals() * core::mem::size_of::<PackedNormal>()
            + self.slots * core::mem::size_of::<u32>()
            + self.words * core::mem::size_of::<u32>()
    }
}

/// Pyramid storage on the heap, sized at run time (feature `alloc`).
#[cfg(any(test, feature = "alloc"))]
pub struct VecPyramidStorage {
    extras: alloc::vec::Vec<VoxelExtra>,
    entries: alloc::vec::Vec<CoarseEntry>,
    normals: alloc::vec::Vec<PackedNormal>,
    slots: alloc::vec::Vec<u32>,
    words: alloc::vec::Vec<u32>,
}

#[cfg(any(test, feature = "alloc"))]
impl VecPyramidStorage {
    /// Storage of the given capacity.
    pub fn new(capacity: PyramidCapacity) -> Self {
        VecPyramidStorage {
            extras: alloc::vec![VoxelExtra::EMPTY; capacity.voxels],
            entries: alloc::vec![CoarseEntry::EMPTY; capacity.entries],
            normals: alloc::vec![PackedNormal::NONE; capacity.normals()],
            slots: alloc::vec![0; capacity.slots],
            words: alloc::vec![0; capacity.words],
        }
    }
}

#[cfg(any(test, feature = "alloc"))]
impl PyramidStorage for VecPyramidStorage {
    fn parts(&self) -> PyramidParts<'_> {
        PyramidParts {
            extras: &self.extras,
            entries: &self.entries,
            normals: &self.normals,
            slots: &self.slots,
            words: &self.words,
            points: &[],
            point_slots: &[],
        }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        PyramidPartsMut {
            extras: &mut self.extras,
            entries: &mut self.entries,
            normals: &mut self.normals,
            slots: &mut self.slots,
            words: &mut self.words,
            points: &mut [],
            point_slots: &mut [],
        }
    }
}

/// A pyramid on the heap over a map of any storage (feature `alloc`).
#[cfg(any(test, feature = "alloc"))]
pub type VecPyramid<'m> = Pyramid<'m, VecPyramidStorage>;

#[cfg(any(test, feature = "alloc"))]
impl<'m> Pyramid<'m, VecPyramidStorage> {
    /// Prepares `map` in storage sized for it ([`PyramidCapacity::for_map`]).
    pub fn build_vec<V: VoxelStorage>(
        map: &'m LocalMap<V>,
        levels: usize,
        footprint_cell: f32,
        role: Role,
    ) -> Result<Self, PyramidError> {
        let storage = VecPyramidStorage::new(PyramidCapacity::for_map(map, levels, footprint_cell, role));
        Self::build_as(map, levels, footprint_cell, role, storage)
    }

    /// Prepares `map` for tracking only ([`Pyramid::build_tracked`]) in
    /// storage sized for it.
    pub fn build_vec_tracked<V: VoxelStorage>(map: &'m LocalMap<V>, role: Role) -> Result<Self, PyramidError> {
        let levels = Self::tracked_levels(map.resolution(), role);
        let storage = VecPyramidStorage::new(PyramidCapacity::for_map(map, levels, f32::NAN, role));
        Self::build_tracked(map, role, storage)
    }

    /// Prepares `map` as a model for tracking with level 0's normals left
    /// to fit ([`Pyramid::build_tracked_lazy`]) in storage sized for it.
    pub fn build_vec_tracked_lazy<V: VoxelStorage>(map: &'m LocalMap<V>) -> Result<Self, PyramidError> {
        let levels = Self::tracked_levels(map.resolution(), Role::Model);
        let storage = VecPyramidStorage::new(PyramidCapacity::for_map(map, levels, f32::NAN, Role::Model));
        Self::build_tracked_lazy(map, storage)
    }
}
