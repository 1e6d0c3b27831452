//! Building local maps on the host: heap storage sized at run time, and the
//! loop that fuses a range of frames into a map with the core's code.

use crate::kitti::Frame;
use cosem_core::classes::{Class, MovingObjects};
use cosem_core::map::{
    ConfigError, InsertError, Insertion, LocalMap, MapConfig, SemanticVoxel, VoxelStorage, SLOTS_PER_VOXEL,
};

/// Why a map could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The map configuration is invalid.
    #[error("invalid map configuration: {0}")]
    Config(ConfigError),
    /// The map filled up.
    #[error("map is full at {capacity} voxels (frame {frame})")]
    Full {
        /// Capacity of the map.
        capacity: usize,
        /// Frame being fused.
        frame: usize,
    },
    /// A point was rejected.
    #[error("frame {frame}, point {point}: {error}")]
    Point {
        /// Frame.
        frame: usize,
        /// Index of the point in its scan.
        point: usize,
        /// Why.
        error: InsertError,
    },
}

/// Map storage on the heap, with a capacity chosen at run time.
pub struct HeapStorage {
    voxels: Vec<SemanticVoxel>,
    slots: Vec<u32>,
}

impl HeapStorage {
    /// Storage for `capacity` voxels (at least one).
    pub fn with_capacity(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        HeapStorage { voxels: vec![SemanticVoxel::EMPTY; capacity], slots: vec![0; SLOTS_PER_VOXEL * capacity] }
    }
}

impl VoxelStorage for HeapStorage {
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

/// A local map on the host.
pub type HostMap = LocalMap<HeapStorage>;

/// An empty host map.
pub fn new_map(capacity: usize, config: MapConfig) -> Result<HostMap, BuildError> {
    LocalMap::new(HeapStorage::with_capacity(capacity), config).map_err(BuildError::Config)
}

/// Which points go into a map.
#[derive(Clone, Copy, Debug)]
pub struct PointFilter {
    /// Keep only points within this range of their own sensor (m).
    pub max_range: Option<f32>,
    /// What to do with moving objects.
    pub moving: MovingObjects,
}

impl Default for PointFilter {
    fn default() -> Self {
        PointFilter { max_range: None, moving: MovingObjects::Skip }
    }
}

impl PointFilter {
    /// The class a point enters the map with, or `None` if it is left out.
    pub fn keep(&self, range: f32, label: u32) -> Option<Class> {
        if let Some(r) = self.max_range {
            if range > r {
                return None;
            }
        }
        Class::from_semantic_kitti(label, self.moving)
    }
}

/// Counts from building a map.
#[derive(Clone, Copy, Debug, Default)]
pub struct BuildStats {
    /// Points read.
    pub points: usize,
    /// Points with a usable class within range.
    pub kept: usize,
    /// Points dropped by the eviction policy.
    pub dropped: usize,
}

/// Fuses frames (already in the anchor frame) into `map`.
pub fn fuse_frames(map: &mut HostMap, frames: &[Frame], filter: &PointFilter) -> Result<BuildStats, BuildError> {
    let mut stats = BuildStats::default();
    for f in frames {
        for (point, ((p, &r), &l)) in f.points.iter().zip(&f.ranges).zip(&f.labels).enumerate() {
            stats.points += 1;
            let Some(class) = filter.keep(r, l) else { continue };
            stats.kept += 1;
            // A network's probabilities, where given, instead of its argmax.
            let inserted = match f.evidence.as_ref().and_then(|e| e.get(point)).copied().flatten() {
                Some(e) => map.insert_point_evidence(*p, &e),
                None => map.insert_point(*p, class),
            };
            match inserted {
                Ok(Insertion::Dropped) => stats.dropped += 1,
                Ok(_) => {}
                Err(InsertError::Full) => return Err(BuildError::Full { capacity: map.capacity(), frame: f.index }),
                Err(error) => return Err(BuildError::Point { frame: f.index, point, error }),
            }
        }
    }
    Ok(stats)
}

/// Builds a map from frames with a capacity that cannot overflow (one voxel
/// per kept point at most).
pub fn build_map(
    frames: &[Frame],
    config: MapConfig,
    filter: &PointFilter,
) -> Result<(HostMap, BuildStats), BuildError> {
    let upper: usize = frames.iter().map(|f| f.points.len()).sum();
    let mut map = new_map(upper, config)?;
    let stats = fuse_frames(&mut map, frames, filter)?;
    Ok((map, stats))
}
