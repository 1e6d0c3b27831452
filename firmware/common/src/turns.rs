//! Memory that takes turns. A pair robot's link buffers and Morton scratch
//! are used only while the maps are exchanged, its pyramid storages only
//! from preparing on: the core's robot drops its link endpoint (and with
//! it every borrow of the link's memory) before it prepares. A board keeps
//! both in one `union` static, so the larger turn sets the RAM, not their
//! sum.
//!
//! The link's turn is borrowed as usual when the robot is built; the
//! pyramids' turn is handed over as [`Later`]: a storage that reaches its
//! memory only when the pyramid is built, after the link's turn is over.

use cosem_core::matching::{PyramidParts, PyramidPartsMut, PyramidStorage};

/// A pyramid storage reached through a pointer only when used.
pub struct Later<T: 'static>(*mut T);

impl<T: 'static> Later<T> {
    /// The storage at `ptr`.
    ///
    /// # Safety
    /// `ptr` is valid for reads and writes for the program's life, every bit
    /// pattern is a valid `T` (pyramid storages are plain integers), and
    /// from the first use of this storage on nothing else touches `*ptr`
    /// (the memory's other turn is over).
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
}
