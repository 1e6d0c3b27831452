//! Layer 2: building a robot's local semantic map.
//!
//! - [`key`]: voxel keys and hashing;
//! - [`labels`]: compact label distributions and the Bayes sensor model;
//! - [`voxel`]: the 24-byte stored voxel;
//! - [`table`]: storage (compile-time or caller-provided) and the index;
//! - [`local_map`]: [`LocalMap`], which fuses points, finds neighbours and
//!   builds coarser levels;
//! - [`overlap`](mod@overlap): how much two maps agree under a transform;
//! - [`scene`]: a received map kept as only what matching it as a scene
//!   reads ([`SceneMap`], 8 bytes per voxel), and [`VoxelSink`], where a
//!   decoder puts voxels.

pub mod key;
pub mod labels;
pub mod local_map;
pub mod overlap;
pub mod scene;
pub mod table;
pub mod voxel;

pub use key::{CellPoint, KeyError, VoxelKey};

/// The voxel sizes of a robot's map (m): what a robot is fed, builds,
/// sends and matches. Finer, the matcher's pyramid (at most
/// `matching::MAX_LEVELS` levels) no longer reaches the coarse search's
/// 1 m cells; coarser, a scan leaves no structure to match. (A map's own
/// storage takes 1 mm to 1 km: its coarse levels are coarser.)
pub const VOXEL_SIZES: core::ops::RangeInclusive<f32> = 0.02..=10.0;
pub use labels::{LabelDistribution, LabelError, SensorModel, LABEL_SLOTS, SCORE_UNITS_PER_NAT};
pub use local_map::{CoarsenError, ConfigError, FullPolicy, InsertError, Insertion, LocalMap, MapConfig, Neighbours};
pub use overlap::overlap;
pub use scene::{class_and_confidence, ClassMemo, SceneMap, ScenePoint, VoxelSink};
pub use table::{
    ArrayStorage, MapIndex, SliceStorage, SlotInt, VoxelStorage, WordStorage, BYTES_PER_VOXEL, SLOTS_PER_VOXEL,
};
pub use voxel::SemanticVoxel;

#[cfg(any(test, feature = "alloc"))]
pub use table::VecStorage;

/// A map on the heap, its capacity chosen at run time (feature `alloc`).
#[cfg(any(test, feature = "alloc"))]
pub type VecMap = LocalMap<VecStorage>;

/// An empty heap map of `capacity` voxels (at least one) (feature `alloc`).
#[cfg(any(test, feature = "alloc"))]
pub fn vec_map(capacity: usize, config: MapConfig) -> Result<VecMap, ConfigError> {
    LocalMap::new(VecStorage::with_capacity(capacity), config)
}

/// A map whose capacity is fixed at compile time: `N` voxels, `32 * N` bytes.
pub type FixedMap<const N: usize> = LocalMap<ArrayStorage<N>>;

#[cfg(test)]
mod tests;
