//! Memory that takes turns. A pair robot uses each of its large buffers in
//! one stretch of its run only, so a board keeps two of them in one `union`
//! static each, and the larger turn sets the RAM, not the sum:
//!
//! - the link's buffers and Morton scratch (while the maps are exchanged)
//!   then the model's level 0 copied out of the robot's map (from
//!   preparing on): the core's robot drops its link endpoint, and with it
//!   every borrow of the link's memory, before it prepares;
//! - the robot's own map (mapping, exchange) then the model's coarse
//!   levels and footprint and the scene's pyramid: the core's `align`
//!   builds the model first, with a copied level 0
//!   (`cosem_core::matching::Pyramid::build_model`), which reads the map
//!   for the last time before it reaches the rest of its storage, and the
//!   robot reads only the map's length (a field of the `LocalMap`, not of
//!   its storage) after that.
//!
//! Every such buffer is reached through [`Later`]: a pointer, never a Rust
//! reference that would outlive its turn, turned into slices only for the
//! duration of one access.

use cosem_core::map::{SemanticVoxel, VoxelStorage};
use cosem_core::matching::{CopiedRoom, ModelPoint, PyramidParts, PyramidPartsMut, PyramidStorage};

/// A storage reached through a pointer only when used.
pub struct Later<T: 'static>(*mut T);

impl<T: 'static> Later<T> {
    /// The storage at `ptr`.
    ///
    /// # Safety
    /// `ptr` is valid for reads and writes for the program's life, every bit
    /// pattern is a valid `T` (the storages are plain integers), and while
    /// this storage is in use nothing else touches `*ptr` (the memory's
    /// other turn is over, or has not begun).
    pub const unsafe fn new(ptr: *mut T) -> Self {
        Later(ptr)
    }
}

impl<T: PyramidStorage + 'static> PyramidStorage for Later<T> {
    fn parts(&self) -> PyramidParts<'_> {
        // SAFETY: `new`'s contract: valid, and this storage's alone now;
        // the borrow of `self` bounds the parts' lifetime.
        unsafe { (*self.0).parts() }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        // SAFETY: as above; `&mut self` makes the parts exclusive.
        unsafe { (*self.0).parts_mut() }
    }
    fn copied_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        // SAFETY: as above.
        unsafe { (*self.0).copied_mut() }
    }
}

impl<T: CopiedRoom + 'static> CopiedRoom for Later<T> {
    fn room(&self) -> (&[ModelPoint], &[u16]) {
        // SAFETY: as for `PyramidStorage::parts`.
        unsafe { (*self.0).room() }
    }
    fn room_mut(&mut self) -> (&mut [ModelPoint], &mut [u16]) {
        // SAFETY: as for `PyramidStorage::parts_mut`.
        unsafe { (*self.0).room_mut() }
    }
}

impl<T: VoxelStorage + 'static> VoxelStorage for Later<T> {
    type Slot = T::Slot;
    fn voxels(&self) -> &[SemanticVoxel] {
        // SAFETY: as for `PyramidStorage::parts`.
        unsafe { (*self.0).voxels() }
    }
    fn slots(&self) -> &[Self::Slot] {
        // SAFETY: as above.
        unsafe { (*self.0).slots() }
    }
    fn parts_mut(&mut self) -> (&mut [SemanticVoxel], &mut [Self::Slot]) {
        // SAFETY: as for `PyramidStorage::parts_mut`.
        unsafe { (*self.0).parts_mut() }
    }
}
