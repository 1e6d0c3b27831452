//! `LocalMap`: fusing labelled points into a fixed-capacity voxel map.

use super::key::{KeyError, VoxelKey};
use super::labels::{LabelDistribution, SensorModel};
use super::table::{self, MapIndex, Probe, SlotInt, VoxelStorage, SLOTS_PER_VOXEL};
use super::voxel::{quantise_fraction, SemanticVoxel, LOGODDS_UNITS};
use crate::classes::Class;

/// What a full map does with a point that would need a new voxel.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FullPolicy {
    /// Refuse it with [`InsertError::Full`] (default): the caller decides.
    #[default]
    Reject,
    /// Keep the voxels nearest to `anchor` (usually the anchor frame's origin):
    /// evict the farthest eighth of the capacity at once, then drop every later
    /// point at or beyond the distance where eviction cut, so that the map
    /// stays a consistent ball around the anchor instead of a patchwork, also
    /// as the anchor moves ([`LocalMap::move_anchor`]).
    EvictFarthest {
        /// Point whose neighbourhood is kept, in map coordinates.
        anchor: [f32; 3],
    },
}

/// How a map fuses points.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MapConfig {
    /// Voxel edge length in metres (default 0.2, the paper's).
    pub resolution: f32,
    /// Label sensor model for Bayes fusion.
    pub sensor: SensorModel,
    /// Log-odds added by a hit (default 0.85, OctoMap's `p_hit` = 0.7).
    pub hit_logodds: f32,
    /// Upper clamp of the occupancy log-odds (default 3.5, OctoMap's 0.97).
    pub max_logodds: f32,
    /// Behaviour when the capacity is reached.
    pub when_full: FullPolicy,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            resolution: 0.2,
            sensor: SensorModel::default(),
            hit_logodds: 0.85,
            max_logodds: 3.5,
            when_full: FullPolicy::Reject,
        }
    }
}

impl MapConfig {
    /// The default configuration at another resolution.
    pub fn with_resolution(resolution: f32) -> Self {
        MapConfig { resolution, ..MapConfig::default() }
    }
}

/// A voxel size a map (or a scene) accepts: finite, in [1 mm, 1 km].
pub(crate) fn check_resolution(r: f32) -> Result<(), ConfigError> {
    if r.is_finite() && (1e-3..=1e3).contains(&r) {
        Ok(())
    } else {
        Err(ConfigError::Resolution)
    }
}

/// Why a map could not be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// The resolution is not a positive finite number in [1 mm, 1 km].
    Resolution,
    /// The sensor model's accuracy is not in `(1/19, 1)`.
    SensorModel,
    /// The occupancy parameters are not finite, positive and below 30.
    Occupancy,
    /// The eviction anchor is not finite.
    Anchor,
    /// The storage has no voxels, more than `u32::MAX - 1`, or too few index slots.
    Storage,
}

/// Why a point or voxel was not inserted. The map is unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum InsertError {
    /// A coordinate was NaN or infinite.
    NonFinite,
    /// The voxel index is outside the key range.
    OutOfRange,
    /// The map is full and its policy is [`FullPolicy::Reject`].
    Full,
    /// [`LocalMap::insert_voxel`]: the map already holds this key.
    DuplicateKey,
    /// A [`SceneMap`](super::SceneMap) was given a voxel holding more than
    /// a received one does (a mean off the quarter-cell grid, a confidence
    /// off the encoding's levels): it would be kept altered.
    Inexact,
}

impl From<KeyError> for InsertError {
    fn from(e: KeyError) -> Self {
        match e {
            KeyError::NonFinite => InsertError::NonFinite,
            KeyError::OutOfRange => InsertError::OutOfRange,
        }
    }
}

impl core::fmt::Display for InsertError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            InsertError::NonFinite => "coordinate is NaN or infinite",
            InsertError::OutOfRange => "voxel index out of the 16-bit key range",
            InsertError::Full => "map is full",
            InsertError::DuplicateKey => "voxel key already in the map",
            InsertError::Inexact => {
                "voxel holds more than a received scene keeps (mean or confidence off the encoding's steps)"
            }
        })
    }
}

impl core::error::Error for InsertError {}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ConfigError::Resolution => "resolution must be a finite number in [0.001, 1000] m",
            ConfigError::SensorModel => "label accuracy must be in (1/19, 1)",
            ConfigError::Occupancy => "occupancy log-odds must be finite, positive and below 30",
            ConfigError::Anchor => "eviction anchor is not finite",
            ConfigError::Storage => "storage has no voxels, too many, or too few index slots",
        })
    }
}

impl core::error::Error for ConfigError {}

/// Why a coarser level could not be built. The output map is left empty.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoarsenError {
    /// The factor is zero or the coarse resolution is not valid.
    Factor,
    /// The output map's capacity is too small.
    Full,
}

impl core::fmt::Display for CoarsenError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            CoarsenError::Factor => "coarsening factor is zero or gives an invalid resolution",
            CoarsenError::Full => "the coarse map's capacity is too small",
        })
    }
}

impl core::error::Error for CoarsenError {}

/// What happened to an inserted point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Insertion {
    /// It started a new voxel.
    Created,
    /// It was fused into an existing voxel.
    Fused,
    /// [`FullPolicy::EvictFarthest`] dropped it: it lies beyond the kept ball.
    Dropped,
}

/// A robot's local semantic map: voxels of one resolution in its anchor frame.
///
/// Capacity is fixed by the storage; nothing allocates. Voxels are kept in
/// insertion order, so iteration, and everything built on it, is
/// deterministic.
#[derive(Clone)]
pub struct LocalMap<S: VoxelStorage> {
    storage: S,
    len: usize,
    config: MapConfig,
    inv_resolution: f32,
    evidence: u16,
    hit_units: i16,
    max_units: i16,
    /// Squared radius beyond which points are dropped, after an eviction.
    keep_radius_sq: f32,
    evicted: usize,
    /// Where the last cut was made about, if any.
    last_cut: Option<[f32; 3]>,
}

fn dist_sq(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// The 27 offsets of a neighbourhood, the centre first.
const NEIGHBOUR_OFFSETS: [[i8; 3]; 27] = {
    let mut out = [[0i8; 3]; 27];
    let mut i = 1;
    let mut dx = -1;
    while dx <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dz = -1;
            while dz <= 1 {
                if !(dx == 0 && dy == 0 && dz == 0) {
                    out[i] = [dx, dy, dz];
                    i += 1;
                }
                dz += 1;
            }
            dy += 1;
        }
        dx += 1;
    }
    out
};

/// Where a histogram's top `target` counts start: the bin at which the
/// counts from the top reach `target`, and the count above that bin.
fn cut_from_top(hist: &[usize], target: usize) -> (usize, usize) {
    let mut above = 0;
    for (b, &here) in hist.iter().enumerate().rev() {
        if above + here >= target {
            return (b, above);
        }
        above += here;
    }
    (0, above)
}

/// Which `keep` voxels of a map lie nearest a point, exactly, without a
/// list of distances: a 256-bin histogram of distances finds the bin where
/// the cut falls, a second histogram within that bin narrows it, and of
/// the voxels tied in the last sub-bin the first inserted stay.
struct NearestCut {
    anchor: [f32; 3],
    resolution: f32,
    width: f32,
    cut: usize,
    lo: f32,
    sub_w: f32,
    sub: usize,
    keep_tied: usize,
    /// Distances at or beyond this are cut.
    radius: f32,
}

impl NearestCut {
    const BINS: usize = 256;

    fn new(voxels: &[SemanticVoxel], resolution: f32, anchor: [f32; 3], keep: usize) -> Self {
        let distance = |v: &SemanticVoxel| libm::sqrtf(dist_sq(v.key.center(resolution), anchor));
        let max_d = voxels.iter().map(distance).fold(0.0f32, f32::max);
        // Bin `b` holds distances in [b w, (b + 1) w), w = max_d / (BINS - 1).
        let width = if max_d > 0.0 { max_d / (Self::BINS as f32 - 1.0) } else { 0.0 };
        let mut c =
            NearestCut { anchor, resolution, width, cut: 0, lo: 0.0, sub_w: 0.0, sub: 0, keep_tied: 0, radius: 0.0 };
        let target = voxels.len().saturating_sub(keep);
        if target == 0 {
            // Nothing is cut.
            (c.cut, c.keep_tied, c.radius) = (Self::BINS, usize::MAX, f32::INFINITY);
            return c;
        }
        // The coarse cut: bins above `cut` go whole.
        let mut hist = [0usize; Self::BINS];
        for v in voxels {
            if let Some(h) = hist.get_mut(c.bin(distance(v))) {
                *h += 1;
            }
        }
        let (cut, above) = cut_from_top(&hist, target);
        // The fine cut within bin `cut`: sub-bins above `sub` go whole.
        (c.cut, c.lo, c.sub_w) = (cut, cut as f32 * width, width / Self::BINS as f32);
        let mut fine = [0usize; Self::BINS];
        for v in voxels {
            let d = distance(v);
            if c.bin(d) == cut {
                if let Some(h) = fine.get_mut(c.sub_bin(d)) {
                    *h += 1;
                }
            }
        }
        let need = target - above;
        let (sub, above_sub) = cut_from_top(&fine, need);
        c.sub = sub;
        c.keep_tied = fine.get(sub).copied().unwrap_or(0).saturating_sub(need - above_sub);
        c.radius = c.lo + sub as f32 * c.sub_w;
        c
    }

    fn bin_in(d: f32, lo: f32, w: f32) -> usize {
        if w <= 0.0 {
            0
        } else {
            (((d - lo) / w) as usize).min(Self::BINS - 1)
        }
    }

    fn bin(&self, d: f32) -> usize {
        Self::bin_in(d, 0.0, self.width)
    }

    fn sub_bin(&self, d: f32) -> usize {
        Self::bin_in(d, self.lo, self.sub_w)
    }

    /// Whether `v` stays; `tied` counts the voxels of the last sub-bin seen
    /// so far (the voxels visited in the map's order).
    fn keeps(&self, v: &SemanticVoxel, tied: &mut usize) -> bool {
        let d = libm::sqrtf(dist_sq(v.key.center(self.resolution), self.anchor));
        let (b, sb) = (self.bin(d), self.sub_bin(d));
        b < self.cut
            || (b == self.cut && sb < self.sub)
            || (b == self.cut && sb == self.sub && {
                *tied += 1;
                *tied <= self.keep_tied
            })
    }
}

impl<S: VoxelStorage> LocalMap<S> {
    /// An empty map over `storage`.
    pub fn new(mut storage: S, config: MapConfig) -> Result<Self, ConfigError> {
        let capacity = storage.voxels().len();
        if capacity == 0
            || capacity >= <S::Slot as SlotInt>::MAX as usize
            || storage.slots().len() < SLOTS_PER_VOXEL * capacity
        {
            return Err(ConfigError::Storage);
        }
        let mut map = LocalMap {
            storage: {
                storage.parts_mut().1.fill(<S::Slot as SlotInt>::ZERO);
                storage
            },
            len: 0,
            config,
            inv_resolution: 1.0,
            evidence: 1,
            hit_units: 0,
            max_units: 0,
            keep_radius_sq: f32::INFINITY,
            evicted: 0,
            last_cut: None,
        };
        map.set_config(config)?;
        Ok(map)
    }

    /// Empties the map and gives it another configuration (e.g. a robot's
    /// map, whose storage is a static, once its set-up names the voxel
    /// size). On an invalid configuration the map is left as it was.
    pub fn reset(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        self.set_config(config)?;
        self.clear();
        Ok(())
    }

    fn set_config(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        check_resolution(config.resolution)?;
        if !config.sensor.is_valid() {
            return Err(ConfigError::SensorModel);
        }
        let ok = |v: f32| v.is_finite() && v > 0.0 && v < 30.0;
        if !ok(config.hit_logodds) || !ok(config.max_logodds) {
            return Err(ConfigError::Occupancy);
        }
        if let FullPolicy::EvictFarthest { anchor } = config.when_full {
            if !anchor.iter().all(|v| v.is_finite()) {
                return Err(ConfigError::Anchor);
            }
        }
        self.config = config;
        self.inv_resolution = 1.0 / config.resolution;
        self.evidence = config.sensor.evidence_units();
        self.hit_units = libm::roundf(config.hit_logodds * LOGODDS_UNITS) as i16;
        self.max_units = libm::roundf(config.max_logodds * LOGODDS_UNITS) as i16;
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }

    /// Voxel edge length in metres.
    pub fn resolution(&self) -> f32 {
        self.config.resolution
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the map has no voxel.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Ends the map and gives its storage back (e.g. for a robot's next
    /// stage to carve other buffers out of).
    pub fn into_storage(self) -> S {
        self.storage
    }

    /// Maximum number of voxels.
    pub fn capacity(&self) -> usize {
        self.storage.voxels().len()
    }

    /// Voxels removed so far by [`FullPolicy::EvictFarthest`].
    pub fn evicted(&self) -> usize {
        self.evicted
    }

    /// The radius beyond which points are now dropped, once eviction started.
    pub fn keep_radius(&self) -> Option<f32> {
        if self.keep_radius_sq.is_finite() {
            Some(libm::sqrtf(self.keep_radius_sq))
        } else {
            None
        }
    }

    /// Removes every voxel (keeps configuration and storage).
    pub fn clear(&mut self) {
        self.storage.parts_mut().1.fill(<S::Slot as SlotInt>::ZERO);
        self.len = 0;
        self.keep_radius_sq = f32::INFINITY;
        self.evicted = 0;
        self.last_cut = None;
    }

    /// The voxels, in insertion order.
    pub fn voxels(&self) -> &[SemanticVoxel] {
        self.storage.voxels().get(..self.len).unwrap_or(&[])
    }

    /// The hash index over [`LocalMap::voxels`] (read by the matcher's level 0).
    pub(crate) fn index_slots(&self) -> MapIndex<'_> {
        <S::Slot as SlotInt>::index(self.storage.slots())
    }

    /// Iterates over the voxels in insertion order.
    pub fn iter(&self) -> core::slice::Iter<'_, SemanticVoxel> {
        self.voxels().iter()
    }

    /// The voxel at a dense position (`0..len()`).
    pub fn voxel(&self, index: usize) -> Option<&SemanticVoxel> {
        self.voxels().get(index)
    }

    /// Dense position of the voxel with this key.
    pub fn index_of(&self, key: VoxelKey) -> Option<usize> {
        match table::probe(self.voxels(), self.storage.slots(), key) {
            Probe::Found(i) => Some(i),
            Probe::Vacant(_) => None,
        }
    }

    /// The voxel with this key.
    pub fn get(&self, key: VoxelKey) -> Option<&SemanticVoxel> {
        self.index_of(key).and_then(|i| self.voxel(i))
    }

    /// The voxel holding point `p`, if any.
    pub fn get_at(&self, p: [f32; 3]) -> Option<&SemanticVoxel> {
        VoxelKey::locate(p, self.inv_resolution).ok().and_then(|c| self.get(c.key))
    }

    /// The occupied voxels among the 27 cells around `key` (itself included,
    /// first), in a fixed order.
    pub fn neighbours(&self, key: VoxelKey) -> Neighbours<'_, S> {
        Neighbours { map: self, key, next: 0 }
    }

    /// Fuses one labelled point (map coordinates, metres): updates the
    /// voxel's running mean, occupancy and label distribution.
    pub fn insert_point(&mut self, p: [f32; 3], class: Class) -> Result<Insertion, InsertError> {
        let evidence = self.evidence;
        self.insert_with(p, |labels| labels.observe(class, evidence))
    }

    /// Fuses a point whose label evidence is given directly, in score units
    /// per class (e.g. from a segmentation network's class probabilities).
    pub fn insert_point_evidence(
        &mut self,
        p: [f32; 3],
        evidence: &LabelDistribution,
    ) -> Result<Insertion, InsertError> {
        self.insert_with(p, |labels| labels.merge(evidence))
    }

    fn insert_with(
        &mut self,
        p: [f32; 3],
        fuse: impl FnOnce(&mut LabelDistribution),
    ) -> Result<Insertion, InsertError> {
        let cell = VoxelKey::locate(p, self.inv_resolution)?;
        if let FullPolicy::EvictFarthest { anchor } = self.config.when_full {
            if dist_sq(p, anchor) >= self.keep_radius_sq {
                return Ok(Insertion::Dropped);
            }
        }
        let len = self.len;
        let (voxels, slots) = self.storage.parts_mut();
        let filled = voxels.get_mut(..len).unwrap_or(&mut []);
        let slot = match table::probe(filled, slots, cell.key) {
            Probe::Found(i) => {
                if let Some(v) = filled.get_mut(i) {
                    v.add_hit(cell.fraction, self.hit_units, self.max_units);
                    fuse(&mut v.labels);
                }
                return Ok(Insertion::Fused);
            }
            Probe::Vacant(slot) => slot,
        };
        let slot = if self.len < self.capacity() {
            slot
        } else {
            match self.config.when_full {
                FullPolicy::Reject => return Err(InsertError::Full),
                FullPolicy::EvictFarthest { anchor } => {
                    self.evict_farthest(anchor);
                    if dist_sq(p, anchor) >= self.keep_radius_sq || self.len >= self.capacity() {
                        return Ok(Insertion::Dropped);
                    }
                    match table::probe(self.voxels(), self.storage.slots(), cell.key) {
                        Probe::Vacant(s) => s,
                        Probe::Found(_) => return Ok(Insertion::Dropped),
                    }
                }
            }
        };
        let mut voxel = SemanticVoxel::first_hit(cell.key, cell.fraction, self.hit_units.min(self.max_units));
        fuse(&mut voxel.labels);
        self.push_at(slot, voxel);
        Ok(Insertion::Created)
    }

    fn push_at(&mut self, slot: usize, voxel: SemanticVoxel) {
        let len = self.len;
        let (voxels, slots) = self.storage.parts_mut();
        if let (Some(v), Some(s)) = (voxels.get_mut(len), slots.get_mut(slot)) {
            *v = voxel;
            *s = <S::Slot as SlotInt>::of(len as u32 + 1);
            self.len += 1;
        }
    }

    /// Adds a whole voxel as it is (map decoders). Rejects a key already present.
    pub fn insert_voxel(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        match table::probe(self.voxels(), self.storage.slots(), voxel.key) {
            Probe::Found(_) => Err(InsertError::DuplicateKey),
            Probe::Vacant(_) if self.len >= self.capacity() => Err(InsertError::Full),
            Probe::Vacant(slot) => {
                self.push_at(slot, voxel);
                Ok(())
            }
        }
    }

    /// Adds a whole voxel, or replaces the one of its key (a peer's map
    /// kept up to date by updates).
    pub fn upsert_voxel(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        match table::probe(self.voxels(), self.storage.slots(), voxel.key) {
            Probe::Found(i) => {
                if let Some(v) = self.storage.parts_mut().0.get_mut(i) {
                    *v = voxel;
                }
                Ok(())
            }
            Probe::Vacant(_) if self.len >= self.capacity() => Err(InsertError::Full),
            Probe::Vacant(slot) => {
                self.push_at(slot, voxel);
                Ok(())
            }
        }
    }

    /// Keeps the voxels `keep` says, in their order, and returns how many
    /// went (the index rebuilt once; removals by key of a peer's update).
    pub fn retain(&mut self, mut keep: impl FnMut(&SemanticVoxel) -> bool) -> usize {
        let len = self.len;
        let (voxels, slots) = self.storage.parts_mut();
        let mut kept = 0;
        for i in 0..len {
            let Some(v) = voxels.get(i).copied() else { break };
            if keep(&v) {
                if let Some(dst) = voxels.get_mut(kept) {
                    *dst = v;
                }
                kept += 1;
            }
        }
        if kept < len {
            self.len = kept;
            table::rebuild(voxels.get(..kept).unwrap_or(&[]), slots);
        }
        len - kept
    }

    /// Moves the point whose neighbourhood a full map keeps
    /// ([`FullPolicy::EvictFarthest`]) to where the robot is now: a robot
    /// that keeps driving evicts what is farthest from itself, not from
    /// where it started. The radius of the last cut moves with it: the map
    /// stays a ball of that radius around the robot, and a point beyond it
    /// is dropped, not fused only to be evicted at the next cut. (Opening
    /// the ball at every move let each scan fill the map with what the
    /// sensor saw farthest away, which the next cut evicted again: on the
    /// town, a sixth of the voxels a robot published to its peers lived
    /// four rounds or less.) The radius follows each cut, so a map that
    /// drives into sparser ground grows its ball again. Nothing changes
    /// under [`FullPolicy::Reject`]; a point that is not finite is refused.
    pub fn move_anchor(&mut self, anchor: [f32; 3]) -> Result<(), ConfigError> {
        if !anchor.iter().all(|v| v.is_finite()) {
            return Err(ConfigError::Anchor);
        }
        if let FullPolicy::EvictFarthest { .. } = self.config.when_full {
            self.config.when_full = FullPolicy::EvictFarthest { anchor };
        }
        Ok(())
    }

    /// Removes the eighth of the capacity farthest from `anchor`, exactly
    /// ([`NearestCut`]); of the voxels tied at the cut the latest inserted
    /// go. Later points at or beyond the cut radius are dropped, until the
    /// next cut sets another. (A small board's map keeps exactly 7/8 of its
    /// capacity.)
    fn evict_farthest(&mut self, anchor: [f32; 3]) {
        let target = (self.capacity() / 8).max(1).min(self.len);
        let res = self.config.resolution;
        let cut = NearestCut::new(self.voxels(), res, anchor, self.len - target);
        let len = self.len;
        let (voxels, slots) = self.storage.parts_mut();
        let (mut kept, mut tied) = (0, 0);
        for i in 0..len {
            let Some(v) = voxels.get(i).copied() else { break };
            if cut.keeps(&v, &mut tied) {
                if let Some(dst) = voxels.get_mut(kept) {
                    *dst = v;
                }
                kept += 1;
            }
        }
        self.evicted += len - kept;
        self.len = kept;
        table::rebuild(voxels.get(..kept).unwrap_or(&[]), slots);
        self.keep_radius_sq = cut.radius * cut.radius;
        self.last_cut = Some(anchor);
    }

    /// The point the last eviction cut about ([`FullPolicy::EvictFarthest`]),
    /// if any: where the robot was when its map last evicted, which may be
    /// a scan or two behind [`LocalMap::keep_centre`].
    pub fn last_cut_centre(&self) -> Option<[f32; 3]> {
        self.last_cut
    }

    /// Where the map keeps what it holds: the anchor a full map evicts
    /// around (where the robot is), or the middle of its bounds for a map
    /// with none (the origin when empty). What is sent of it to a peer
    /// that holds less is the part nearest this ([`LocalMap::nearest`]).
    pub fn keep_centre(&self) -> [f32; 3] {
        match (self.config.when_full, self.bounds()) {
            (FullPolicy::EvictFarthest { anchor }, _) => anchor,
            (FullPolicy::Reject, Some((lo, hi))) => [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k])),
            (FullPolicy::Reject, None) => [0.0; 3],
        }
    }

    /// The indices of the `most` voxels nearest `anchor` (all of them when
    /// the map holds no more), written to the start of `out`, ascending;
    /// returns how many. The same cut a full map evicts by: what a map of
    /// `most` voxels kept around `anchor` would hold, e.g. the part of a
    /// robot's map that fits a smaller peer.
    pub fn nearest(&self, anchor: [f32; 3], most: usize, out: &mut [u32]) -> usize {
        let keep = most.min(self.len).min(out.len());
        if keep == self.len {
            // All of it (a map that fits its peer, every round): no cut to find.
            for (i, o) in out.iter_mut().take(keep).enumerate() {
                *o = i as u32;
            }
            return keep;
        }
        let cut = NearestCut::new(self.voxels(), self.config.resolution, anchor, keep);
        let (mut n, mut tied) = (0, 0);
        for (i, v) in self.voxels().iter().enumerate() {
            if cut.keeps(v, &mut tied) {
                if let Some(o) = out.get_mut(n) {
                    *o = i as u32;
                    n += 1;
                }
            }
        }
        n
    }

    /// Builds the level `factor` times coarser into `out` (cleared first; its
    /// resolution becomes `factor * resolution()`, its other settings stay).
    /// Each coarse voxel fuses its children: hit-weighted mean position,
    /// summed hits, the highest occupancy and the fused label evidence.
    /// Nothing allocates; on error `out` is left empty.
    pub fn coarsen_into<T: VoxelStorage>(&self, factor: u16, out: &mut LocalMap<T>) -> Result<(), CoarsenError> {
        if factor == 0 {
            return Err(CoarsenError::Factor);
        }
        out.clear();
        let config = MapConfig { resolution: self.config.resolution * f32::from(factor), ..out.config };
        out.set_config(config).map_err(|_| CoarsenError::Factor)?;
        let f = f32::from(factor);
        for v in self.iter() {
            let ck = v.key.coarsen(factor);
            let fine = v.mean_fraction();
            let rel =
                |fk: i16, ckv: i16, fr: f32| ((i32::from(fk) - i32::from(ckv) * i32::from(factor)) as f32 + fr) / f;
            let fraction = [rel(v.key.x, ck.x, fine[0]), rel(v.key.y, ck.y, fine[1]), rel(v.key.z, ck.z, fine[2])];
            let len = out.len;
            let (voxels, slots) = out.storage.parts_mut();
            let filled = voxels.get_mut(..len).unwrap_or(&mut []);
            match table::probe(filled, slots, ck) {
                Probe::Found(i) => {
                    if let Some(c) = filled.get_mut(i) {
                        c.absorb(v, fraction);
                    }
                }
                Probe::Vacant(slot) => {
                    if out.len >= out.capacity() {
                        out.clear();
                        return Err(CoarsenError::Full);
                    }
                    let mean = fraction.map(quantise_fraction);
                    out.push_at(slot, SemanticVoxel::from_parts(ck, mean, v.occupancy_raw(), v.hits(), v.labels));
                }
            }
        }
        Ok(())
    }

    /// Axis-aligned bounds of the occupied cells (min corner, max corner), in metres.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        VoxelKey::bounds(self.iter().map(|v| v.key), self.config.resolution)
    }
}

/// Iterator over the occupied cells of a 27-neighbourhood.
pub struct Neighbours<'a, S: VoxelStorage> {
    map: &'a LocalMap<S>,
    key: VoxelKey,
    next: usize,
}

impl<'a, S: VoxelStorage> Iterator for Neighbours<'a, S> {
    type Item = (usize, &'a SemanticVoxel);

    fn next(&mut self) -> Option<Self::Item> {
        while let Some(o) = NEIGHBOUR_OFFSETS.get(self.next) {
            self.next += 1;
            let Some(k) = self.key.offset(i32::from(o[0]), i32::from(o[1]), i32::from(o[2])) else { continue };
            if let Some(i) = self.map.index_of(k) {
                if let Some(v) = self.map.voxel(i) {
                    return Some((i, v));
                }
            }
        }
        None
    }
}
