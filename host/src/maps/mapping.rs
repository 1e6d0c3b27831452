//! Building local maps on the host: heap storage sized at run time, and the
//! loop that fuses a range of frames into a map with the core's code.

use crate::knobs::Knob;
use crate::sources::kitti::Frame;
use cosem_core::classes::{Class, MovingObjects};
use cosem_core::map::{ConfigError, InsertError, Insertion, LabelDistribution, MapConfig};

/// Why a map could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// A voxel size outside a robot map's ([`cosem_core::map::VOXEL_SIZES`]).
    #[error(
        "voxel size {size} m: a robot's map has voxels of {lo} to {hi} m (finer, the matcher's pyramid cannot reach its coarse search's cells; coarser, a scan leaves nothing to match)",
        size = .0,
        lo = cosem_core::map::VOXEL_SIZES.start(),
        hi = cosem_core::map::VOXEL_SIZES.end()
    )]
    Voxel(f32),
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
    /// No point entered the map: what the frames held and why each point
    /// stayed out.
    #[error("the map is empty: {0}")]
    Empty(String),
}

impl crate::error::LayerError for BuildError {}

/// A local map on the host: the core's map on heap storage sized at run
/// time.
pub type HostMap = cosem_core::map::VecMap;

/// An empty host map.
pub fn new_map(capacity: usize, config: MapConfig) -> Result<HostMap, BuildError> {
    if cosem_core::pipeline::Setting::Voxel.check(f64::from(config.resolution)).is_err() {
        return Err(BuildError::Voxel(config.resolution));
    }
    cosem_core::map::vec_map(capacity, config).map_err(BuildError::Config)
}

/// What becomes of unlabelled points (SemanticKITTI id 0): a camera's
/// labels leave so every point outside its view, about three in four of a
/// scan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Unlabeled {
    /// Left out of the map (the conventions' default).
    #[default]
    Drop,
    /// Kept as geometry of an unknown class: a voxel with no label evidence,
    /// which the matcher takes as uniform over the classes (and which a
    /// labelled point in the same voxel later labels).
    Geometry,
}

impl Unlabeled {
    /// The names it is read from (the command line's, Python's).
    pub const NAMES: &'static [&'static str] = &["drop", "geometry"];
}

impl std::str::FromStr for Unlabeled {
    type Err = String;
    /// What to do with unlabelled points: drop or geometry.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "drop" => Ok(Unlabeled::Drop),
            "geometry" => Ok(Unlabeled::Geometry),
            _ => Err(format!("`{s}`: expected drop or geometry")),
        }
    }
}

/// Which points go into a map.
#[derive(Clone, Copy, Debug)]
pub struct PointFilter {
    /// Keep only points within this range of their own sensor (m).
    pub max_range: Option<f32>,
    /// What to do with moving objects.
    pub moving: MovingObjects,
    /// What to do with unlabelled points.
    pub unlabeled: Unlabeled,
}

impl Default for PointFilter {
    fn default() -> Self {
        PointFilter { max_range: None, moving: MovingObjects::Skip, unlabeled: Unlabeled::Drop }
    }
}

impl PointFilter {
    /// How a point enters the map: `Some(Some(class))` with a class,
    /// `Some(None)` as geometry of an unknown class, `None` not at all.
    pub fn keep(&self, range: f32, label: u32) -> Option<Option<Class>> {
        if let Some(r) = self.max_range {
            if range > r {
                return None;
            }
        }
        match Class::from_semantic_kitti(label, self.moving) {
            Some(class) => Some(Some(class)),
            None if label & 0xFFFF == 0 && self.unlabeled == Unlabeled::Geometry => Some(None),
            None => None,
        }
    }
}

/// Counts from building a map.
#[derive(Clone, Copy, Debug, Default)]
pub struct BuildStats {
    /// Points read.
    pub points: usize,
    /// Points with a usable class within range.
    pub kept: usize,
    /// Unlabelled points kept as geometry of an unknown class
    /// ([`Unlabeled::Geometry`]).
    pub unknown_class: usize,
    /// Points dropped by the eviction policy.
    pub dropped: usize,
    /// Points beyond the map's key range (32,768 voxels from the anchor on
    /// an axis: 6.5 km at 0.2 m), left out: an outlier far away must not
    /// cost the whole map.
    pub out_of_range: usize,
    /// Points farther from their sensor than the filter's range.
    pub beyond_max_range: usize,
    /// Points of moving objects, left out by the filter.
    pub moving: usize,
    /// Points whose SemanticKITTI id has no class (unlabeled, outlier,
    /// other-structure, other-object).
    pub no_class: usize,
    /// Points whose id is not a SemanticKITTI id, and the first such id.
    pub unknown_ids: usize,
    /// The first id not known to SemanticKITTI.
    pub first_unknown_id: Option<u16>,
}

/// SemanticKITTI's ids that name no class (unlabeled, outlier,
/// other-structure, other-object).
const CLASSLESS_IDS: [u32; 4] = [0, 1, 52, 99];

impl BuildStats {
    /// Counts why a point with `range` and `label` stayed out of the map.
    fn count_left_out(&mut self, filter: &PointFilter, range: f32, label: u32) {
        let id = label & 0xFFFF;
        if filter.max_range.is_some_and(|r| range > r) {
            self.beyond_max_range += 1;
        } else if (252..=259).contains(&id) {
            self.moving += 1;
        } else if CLASSLESS_IDS.contains(&id) {
            self.no_class += 1;
        } else {
            self.unknown_ids += 1;
            self.first_unknown_id.get_or_insert(id as u16);
        }
    }

    /// What a user should know about the points left out of a map of
    /// `voxel` metres that is not empty.
    pub fn warnings(&self, voxel: f32) -> Vec<String> {
        let mut out = Vec::new();
        if self.unknown_ids > 0 {
            out.push(format!(
                "{} points have label ids that are not SemanticKITTI's (the first: {}) and were left out; a class table ({}) maps a user's ids",
                self.unknown_ids,
                self.first_unknown_id.unwrap_or_default(),
                Knob::Classes,
            ));
        }
        if self.out_of_range > 0 {
            out.push(format!(
                "{} points lie beyond the map's key range ({:.0} m from the anchor at {voxel} m voxels) and were left out; {} drops far points by design",
                self.out_of_range,
                32_767.0 * voxel,
                Knob::MaxRange,
            ));
        }
        out
    }

    /// Why a map built from these points is empty.
    pub fn why_empty(&self) -> String {
        if self.points == 0 {
            return "the scans hold no points".into();
        }
        let mut why = Vec::new();
        if self.unknown_ids > 0 {
            why.push(format!(
                "{} have label ids that are not SemanticKITTI's (the first: {}; give a class table with {})",
                self.unknown_ids,
                self.first_unknown_id.unwrap_or_default(),
                Knob::Classes,
            ));
        }
        if self.no_class > 0 {
            why.push(format!("{} are unlabeled or of no class (ids 0, 1, 52, 99)", self.no_class));
        }
        if self.moving > 0 {
            why.push(format!("{} are moving objects ({} keeps them)", self.moving, Knob::KeepMoving));
        }
        if self.beyond_max_range > 0 {
            why.push(format!("{} lie beyond {}", self.beyond_max_range, Knob::MaxRange));
        }
        if self.out_of_range > 0 {
            why.push(format!("{} lie beyond the map's key range", self.out_of_range));
        }
        if self.dropped > 0 {
            why.push(format!("{} were dropped by the map's eviction", self.dropped));
        }
        format!("of {} points, {}", self.points, why.join("; "))
    }
}

/// How far the odometry turned scan `f` (in the anchor frame, the
/// sensor at `at`) from `map`, before it is fused: the points the map
/// would take, registered to it ([`cosem_core::session::ScanFit`]). What a
/// robot's [`cosem_core::session::OdometryWalk`] is fed, scan by scan.
pub fn scan_turn(map: &HostMap, f: &Frame, filter: &PointFilter, at: [f32; 3]) -> Option<(f32, f32)> {
    // A scan that keeps few points (a camera's view) is taken more densely.
    let kept = f.ranges.iter().zip(&f.labels).filter(|&(&r, &l)| filter.keep(r, l).is_some()).count();
    let mut fit = cosem_core::session::ScanFit::with_stride(at, cosem_core::session::walk_stride(kept));
    for ((p, &range), &label) in f.points.iter().zip(&f.ranges).zip(&f.labels) {
        if filter.keep(range, label).is_some() {
            fit.add(map, *p);
        }
    }
    fit.turn()
}

/// Fuses frames (already in the anchor frame) into `map`.
pub fn fuse_frames(map: &mut HostMap, frames: &[Frame], filter: &PointFilter) -> Result<BuildStats, BuildError> {
    let mut stats = BuildStats::default();
    for f in frames {
        for (point, ((p, &r), &l)) in f.points.iter().zip(&f.ranges).zip(&f.labels).enumerate() {
            stats.points += 1;
            let Some(class) = filter.keep(r, l) else {
                stats.count_left_out(filter, r, l);
                continue;
            };
            // A network's probabilities, where given, instead of its argmax.
            let inserted = match (class, f.evidence.as_ref().and_then(|e| e.get(point)).copied().flatten()) {
                (None, _) => {
                    stats.unknown_class += 1;
                    map.insert_point_evidence(*p, &LabelDistribution::EMPTY)
                }
                (Some(_), Some(e)) => {
                    stats.kept += 1;
                    map.insert_point_evidence(*p, &e)
                }
                (Some(class), None) => {
                    stats.kept += 1;
                    map.insert_point(*p, class)
                }
            };
            match inserted {
                Ok(Insertion::Dropped) => stats.dropped += 1,
                Ok(_) => {}
                Err(InsertError::OutOfRange) => stats.out_of_range += 1,
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
    if map.is_empty() {
        return Err(BuildError::Empty(stats.why_empty()));
    }
    Ok((map, stats))
}

/// A class histogram of a map, largest first (ties by class index).
pub fn class_histogram(map: &HostMap) -> Vec<(Class, usize)> {
    let mut counts = [0usize; cosem_core::classes::NUM_CLASSES];
    for v in map.iter() {
        if let Some(c) = v.class() {
            if let Some(n) = counts.get_mut(usize::from(c.index())) {
                *n += 1;
            }
        }
    }
    let mut h: Vec<_> = Class::ALL.iter().map(|c| (*c, counts[usize::from(c.index())])).collect();
    h.retain(|(_, n)| *n > 0);
    h.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    h
}
