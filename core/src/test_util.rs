//! Helpers shared by the core's tests (compiled for tests only).

use crate::map::{LocalMap, MapConfig, SemanticVoxel, VoxelStorage};
use std::vec;
use std::vec::Vec;

/// Map storage on the heap, as a host would provide it (inline storage of
/// large maps would not fit a test thread's stack).
pub struct Heap {
    /// Voxel buffer.
    pub voxels: Vec<SemanticVoxel>,
    /// Index slots.
    pub slots: Vec<u32>,
}

impl VoxelStorage for Heap {
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

/// An empty heap map of `capacity` voxels (at least one) with `config`.
pub fn heap_map(capacity: usize, config: MapConfig) -> LocalMap<Heap> {
    let n = capacity.max(1);
    LocalMap::new(Heap { voxels: vec![SemanticVoxel::EMPTY; n], slots: vec![0; 2 * n] }, config).unwrap()
}

/// An empty heap map with the default configuration.
pub fn map(capacity: usize) -> LocalMap<Heap> {
    heap_map(capacity, MapConfig::default())
}

/// Pyramid storage on the heap.
pub struct HeapPyramid {
    extras: Vec<crate::matching::VoxelExtra>,
    entries: Vec<crate::matching::CoarseEntry>,
    slots: Vec<u32>,
    words: Vec<u32>,
}

impl HeapPyramid {
    /// Storage for maps of up to `voxels` voxels, `entries` coarse entries
    /// and `words` footprint words.
    pub fn new(voxels: usize, entries: usize, words: usize) -> Self {
        HeapPyramid {
            extras: vec![crate::matching::VoxelExtra::EMPTY; voxels],
            entries: vec![crate::matching::CoarseEntry::EMPTY; entries],
            slots: vec![0; 2 * entries],
            words: vec![0; words],
        }
    }
}

impl crate::matching::PyramidStorage for HeapPyramid {
    fn parts(&self) -> crate::matching::PyramidParts<'_> {
        crate::matching::PyramidParts {
            extras: &self.extras,
            entries: &self.entries,
            slots: &self.slots,
            words: &self.words,
        }
    }
    fn parts_mut(&mut self) -> crate::matching::PyramidPartsMut<'_> {
        crate::matching::PyramidPartsMut {
            extras: &mut self.extras,
            entries: &mut self.entries,
            slots: &mut self.slots,
            words: &mut self.words,
        }
    }
}

#[test]
fn selftest_converges_and_encodes_consistently() {
    use crate::selftest::*;
    let config = MapConfig::with_resolution(RESOLUTION);
    let (mut a, mut b, mut r) =
        (heap_map(MAP_VOXELS, config), heap_map(MAP_VOXELS, config), heap_map(MAP_VOXELS, config));
    let mut scratch = vec![0u32; MAP_VOXELS];
    let mut chunk = [0u8; 240];
    let pa = HeapPyramid::new(MAP_VOXELS, PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let pb = HeapPyramid::new(MAP_VOXELS, PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let mut calls = 0;
    let report = run(&mut a, &mut b, &mut r, &mut scratch, &mut chunk, pa, pb, |_| calls += 1).unwrap();
    assert_eq!(calls, 2);
    std::println!("{report:?}");
    assert!(report.wire_ok);
    assert!(report.voxels[0] > 800 && report.voxels[1] > 800, "{:?}", report.voxels);
    assert_eq!(report.result.status, crate::matching::MatchStatus::Converged);
    let d = report.result.transform * report.truth.inverse();
    assert!(d.translation.vector.norm() < 0.05 && d.rotation.angle().to_degrees() < 0.2, "{d:?}");
}
