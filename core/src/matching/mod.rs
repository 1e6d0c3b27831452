//! Layer 6: EM map matching.
//!
//! - [`pyramid`]: the search structure, a semantic resolution pyramid with
//!   a hash index per level and per-entry normals (one-off preparation);
//! - [`footprint`], [`search`](mod@search): a bird's-eye class-group grid
//!   per map and a branch-and-bound search over it: of the prior's window,
//!   which puts EM in its basin from starts 10 m and 25 degrees off, or of
//!   every heading and offset when there is no prior;
//! - [`global`]: prior-free alignment: the search's few best placements,
//!   refined until one passes the verdict;
//! - [`associate`]: the E-step, nearest-voxel association with Gaussian and
//!   semantic weights;
//! - [`solve`](mod@solve): the M-step, damped Gauss-Newton on SE(3) or 4-DoF;
//! - [`em`]: [`Matcher`], the coarse-to-fine driver with annealing;
//! - [`work`](mod@work): a round's work budget, charged step by step;
//! - [`settings`], [`result`]: plain data in and out.
//!
//! ```
//! use cosem_core::classes::Class;
//! use cosem_core::geometry::from_xyz_rpy;
//! use cosem_core::map::{ArrayStorage, FixedMap, MapConfig};
//! use cosem_core::matching::{ArrayPyramidStorage, Matcher, MatchSettings, Pyramid};
//!
//! // A corner of two walls and a floor, seen by both robots.
//! let mut map = FixedMap::<2048>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
//! for i in 0..30 {
//!     for j in 0..12 {
//!         let (a, b) = (i as f32 * 0.2, j as f32 * 0.2);
//!         map.insert_point([a, b, 0.0], Class::Road).unwrap();
//!         map.insert_point([a, 0.0, b + 0.2], Class::Building).unwrap();
//!         map.insert_point([0.0, a, b + 0.2], Class::Fence).unwrap();
//!     }
//! }
//! let model = Pyramid::build(&map, 3, 1.0, ArrayPyramidStorage::<2048, 2048, 4096>::new()).unwrap();
//! let scene = Pyramid::build(&map, 3, 1.0, ArrayPyramidStorage::<2048, 2048, 4096>::new()).unwrap();
//! let start = from_xyz_rpy(0.3, -0.2, 0.0, 0.0, 0.0, 0.05);
//! // A 6 m corner is too small for the coarse search (1 m cells, a few
//! // dozen footprint cells): EM alone, from a prior this close.
//! let settings = MatchSettings { search: None, ..MatchSettings::default() };
//! let result = Matcher::new(settings).align(&model, &scene, &start).unwrap();
//! assert!(result.transform.translation.vector.norm() < 0.02);
//! ```

pub mod align;
pub mod associate;
pub mod em;
pub mod footprint;
pub mod global;
pub mod pyramid;
pub mod result;
pub mod search;
pub mod settings;
pub mod solve;
pub mod work;

pub use align::{align_prepared, Alignment};
pub use em::{MatchError, Matcher, TrackStop};
pub use footprint::Footprint;
pub use pyramid::{
    ArrayPyramidStorage, ArraySceneStorage, CoarseEntry, CopiedBase, CopiedLevel, CopiedRoom, CopiedSlices, Entry,
    Level, ModelPoint, PackedNormal, Pyramid, PyramidCapacity, PyramidError, PyramidParts, PyramidPartsMut,
    PyramidStorage, Reach, Role, SceneSource, SplitStorage, VoxelExtra, COVER_RESOLUTION, MAX_FOOTPRINT_CELLS,
    MAX_LEVELS,
};
#[cfg(any(test, feature = "alloc"))]
pub use pyramid::{VecPyramid, VecPyramidStorage};
pub use result::{MatchResult, MatchStatus};
pub use search::{SearchOutcome, SearchWindow};
pub use settings::{Cost, Dof, MatchSettings, Method};
pub use work::{Work, WorkCosts};

#[cfg(test)]
mod tests;
