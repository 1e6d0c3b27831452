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
