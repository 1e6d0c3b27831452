//! The boards keep a robot's map storage in memory that is all zeros
//! before it is used as one (`.bss`, or the STM32F405's NOLOAD SRAM
//! section cleared in `main`): that is sound only while an empty storage
//! is all zeros, which this test holds the core to. A storage whose empty
//! value changed (a voxel's empty key, a slot's empty marker) fails here,
//! not on a board.

use cosem_core::map::{VoxelStorage, SLOTS_PER_VOXEL};
use cosem_core::robot::{MapStorage, SmallMapStorage};

/// A storage as all-zero memory, boxed (it is larger than a test's stack).
fn zeroed<T>() -> Box<T> {
    let layout = std::alloc::Layout::new::<T>();
    // SAFETY: the layout is T's; the allocation is all zeros, which every
    // field of the storages below accepts (integers, arrays of integers):
    // the assertions then check those zeros are the empty storage.
    unsafe {
        let p = std::alloc::alloc_zeroed(layout) as *mut T;
        assert!(!p.is_null());
        Box::from_raw(p)
    }
}

fn assert_zeroed_is_empty<S: VoxelStorage>(zeroed: &S, empty: &S) {
    assert_eq!(zeroed.voxels(), empty.voxels(), "an empty voxel is not all zeros");
    assert_eq!(zeroed.slots().len(), empty.slots().len());
    assert!(zeroed.slots().len() >= SLOTS_PER_VOXEL * zeroed.voxels().len());
    assert!(zeroed.slots() == empty.slots(), "an empty slot is not zero");
}

#[test]
fn an_empty_map_storage_is_all_zeros() {
    assert_zeroed_is_empty(&*zeroed::<MapStorage>(), &*Box::new(MapStorage::new()));
    assert_zeroed_is_empty(&*zeroed::<SmallMapStorage>(), &*Box::new(SmallMapStorage::new()));
}
