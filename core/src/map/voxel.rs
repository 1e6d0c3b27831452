//! The stored voxel: 24 bytes of position, occupancy, hit count and labels.

use super::key::VoxelKey;
use super::labels::LabelDistribution;
use crate::classes::Class;

/// Occupancy log-odds are stored in units of 1/1024.
pub const LOGODDS_UNITS: f32 = 1024.0;
/// Sub-voxel positions are stored in units of 1/65536 of the voxel.
pub const POSITION_UNITS: f32 = 65536.0;

/// One occupied cell of a local map.
///
/// The position is the running mean of the points that fell in the cell,
/// kept as a 16-bit fraction of the cell per axis (1/65536 of a voxel, 3 µm
/// at 0.2 m): the matcher aligns means, not cell centres, which is what makes
/// sub-voxel accuracy possible.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct SemanticVoxel {
    /// The cell.
    pub key: VoxelKey,
    mean: [u16; 3],
    occupancy: i16,
    hits: u16,
    /// Fused label evidence.
    pub labels: LabelDistribution,
}

impl SemanticVoxel {
    /// An all-zero voxel, used to fill storage.
    pub const EMPTY: SemanticVoxel = SemanticVoxel {
        key: VoxelKey::new(0, 0, 0),
        mean: [0; 3],
        occupancy: 0,
        hits: 0,
        labels: LabelDistribution::EMPTY,
    };

    /// A voxel from its stored fields (decoders); `mean` is in 1/65536 of the
    /// cell, `occupancy` in 1/1024 of a log-odds unit.
    pub fn from_parts(key: VoxelKey, mean: [u16; 3], occupancy: i16, hits: u16, labels: LabelDistribution) -> Self {
        SemanticVoxel { key, mean, occupancy, hits, labels }
    }

    /// A fresh voxel holding one point at `fraction` of the cell.
    pub(crate) fn first_hit(key: VoxelKey, fraction: [f32; 3], occupancy: i16) -> Self {
        let mut v = SemanticVoxel { key, hits: 1, occupancy, ..SemanticVoxel::EMPTY };
        for (m, f) in v.mean.iter_mut().zip(fraction) {
            *m = quantise_fraction(f);
        }
        v
    }

    /// Folds one more point into the running mean and the occupancy.
    pub(crate) fn add_hit(&mut self, fraction: [f32; 3], hit_units: i16, max_units: i16) {
        self.hits = self.hits.saturating_add(1);
        let n = f32::from(self.hits);
        for (m, f) in self.mean.iter_mut().zip(fraction) {
            let old = dequantise_fraction(*m);
            *m = quantise_fraction(old + (f - old) / n);
        }
        self.occupancy = self.occupancy.saturating_add(hit_units).min(max_units);
    }

    /// Folds a whole voxel (its points and labels) into this one; `fraction`
    /// is the other voxel's mean expressed in this voxel's cell.
    pub(crate) fn absorb(&mut self, other: &SemanticVoxel, fraction: [f32; 3]) {
        let n0 = f32::from(self.hits);
        let n1 = f32::from(other.hits);
        let total = n0 + n1;
        if total > 0.0 {
            for (m, f) in self.mean.iter_mut().zip(fraction) {
                let old = dequantise_fraction(*m);
                *m = quantise_fraction(old + (f - old) * (n1 / total));
            }
        }
        self.hits = self.hits.saturating_add(other.hits);
        self.occupancy = self.occupancy.max(other.occupancy);
        self.labels.merge(&other.labels);
    }

    /// The mean as a fraction of the cell, each axis in `(0, 1)`.
    pub fn mean_fraction(&self) -> [f32; 3] {
        [dequantise_fraction(self.mean[0]), dequantise_fraction(self.mean[1]), dequantise_fraction(self.mean[2])]
    }

    /// The stored mean, in 1/65536 of the cell.
    pub fn mean_raw(&self) -> [u16; 3] {
        self.mean
    }

    /// Mean position of the voxel's points, in metres in the map frame.
    pub fn position(&self, resolution: f32) -> [f32; 3] {
        mean_position(self.key, self.mean, resolution)
    }

    /// Number of points fused into the voxel (saturates at 65535).
    pub fn hits(&self) -> u16 {
        self.hits
    }

    /// Occupancy log-odds.
    pub fn occupancy_logodds(&self) -> f32 {
        f32::from(self.occupancy) / LOGODDS_UNITS
    }

    /// The stored occupancy, in 1/1024 of a log-odds unit.
    pub fn occupancy_raw(&self) -> i16 {
        self.occupancy
    }

    /// Occupancy probability.
    pub fn occupancy_probability(&self) -> f32 {
        1.0 / (1.0 + libm::expf(-self.occupancy_logodds()))
    }

    /// The voxel's label: its most probable class.
    pub fn class(&self) -> Option<Class> {
        self.labels.argmax()
    }
}

/// The position (m) of a mean stored as 1/65536 of `key`'s cell per axis:
/// one formula for map voxels, scene points and pyramid entries, so each
/// gives the same bits for the same mean.
#[inline]
pub(crate) fn mean_position(key: VoxelKey, mean: [u16; 3], resolution: f32) -> [f32; 3] {
    let c = key.corner(resolution);
    let f = mean.map(dequantise_fraction);
    [c[0] + f[0] * resolution, c[1] + f[1] * resolution, c[2] + f[2] * resolution]
}

pub(crate) fn quantise_fraction(f: f32) -> u16 {
    let q = libm::floorf(f * POSITION_UNITS);
    if q.is_nan() || q < 0.0 {
        0
    } else if q >= 65535.0 {
        65535
    } else {
        q as u16
    }
}

pub(crate) fn dequantise_fraction(q: u16) -> f32 {
    (f32::from(q) + 0.5) / POSITION_UNITS
}
