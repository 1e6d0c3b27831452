//! Matching on the host: pyramids on the heap, the conventions' error
//! measures and the paper's grid of starts.

use crate::mapping::HostMap;
use cosem_core::matching::{
    CoarseEntry, Pyramid, PyramidError, PyramidParts, PyramidPartsMut, PyramidStorage, VoxelExtra,
};
use nalgebra::{Isometry3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Pyramid storage on the heap.
pub struct HeapPyramidStorage {
    extras: Vec<VoxelExtra>,
    entries: Vec<CoarseEntry>,
    slots: Vec<u32>,
    words: Vec<u32>,
}

impl HeapPyramidStorage {
    /// Room for a map of `voxels` voxels, `entries` coarse entries (and
    /// their index) and `words` footprint words.
    pub fn with_capacity(voxels: usize, entries: usize, words: usize) -> Self {
        HeapPyramidStorage {
            extras: vec![VoxelExtra::EMPTY; voxels],
            entries: vec![CoarseEntry::EMPTY; entries],
            slots: vec![0; 2 * entries],
            words: vec![0; words],
        }
    }
}

impl PyramidStorage for HeapPyramidStorage {
    fn parts(&self) -> PyramidParts<'_> {
        PyramidParts { extras: &self.extras, entries: &self.entries, slots: &self.slots, words: &self.words }
    }
    fn parts_mut(&mut self) -> PyramidPartsMut<'_> {
        PyramidPartsMut {
            extras: &mut self.extras,
            entries: &mut self.entries,
            slots: &mut self.slots,
            words: &mut self.words,
        }
    }
}

/// A map prepared for matching on the host (it borrows the map).
pub type HostPyramid<'m> = Pyramid<'m, HeapPyramidStorage>;

/// Default number of pyramid levels: 0.2 m maps get cells up to 3.2 m.
pub const DEFAULT_LEVELS: usize = 5;

/// Default footprint cell (m) for the coarse search.
pub const FOOTPRINT_CELL: f32 = 1.0;

/// Prepares a map for matching (room for the worst case: no merging at all;
/// a footprint of up to 250 m x 250 m at 1 m).
pub fn prepare(map: &HostMap, levels: usize) -> Result<HostPyramid<'_>, PyramidError> {
    let words = cosem_core::matching::footprint::POOL_LEVELS * 62_500 + 3 * 62_500;
    let coarse = map.len() * levels.saturating_sub(1);
    Pyramid::build(map, levels, FOOTPRINT_CELL, HeapPyramidStorage::with_capacity(map.len(), coarse, words))
}

/// `T_a_b` as an f64 4x4 matrix from the core's isometry.
pub fn to_matrix(t: &Isometry3<f32>) -> Matrix4<f64> {
    t.to_homogeneous().cast::<f64>()
}

/// Translation error (m) and rotation error (degrees) of an estimate:
/// `dT = T_est * inv(T_gt)`.
pub fn errors(est: &Matrix4<f64>, gt: &Matrix4<f64>) -> (f64, f64) {
    let d = est * crate::kitti::rigid_inverse(gt);
    let et = Vector3::new(d[(0, 3)], d[(1, 3)], d[(2, 3)]).norm();
    // atan2 of the antisymmetric part (sin) and the trace (cos): exact near
    // zero, where acos of the trace alone turns a 1e-7 departure from
    // orthonormality (f32 rotations) into a hundredth of a degree.
    let r = d.fixed_view::<3, 3>(0, 0);
    let cos = (r.trace() - 1.0) / 2.0;
    let sin = Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]).norm() / 2.0;
    (et, sin.atan2(cos).to_degrees())
}

/// A perturbation of the paper's grid: `D = Translation(dx, dy, 0) * Rz(dyaw)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Start {
    /// Shift along the model's x (m).
    pub dx: f64,
    /// Shift along the model's y (m).
    pub dy: f64,
    /// Yaw about the model's z (degrees).
    pub dyaw: f64,
}

impl Start {
    /// `T_init = D * T_gt`.
    pub fn apply(&self, gt: &Matrix4<f64>) -> Matrix4<f64> {
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), self.dyaw.to_radians());
        let d =
            Isometry3::from_parts(Translation3::new(self.dx, self.dy, 0.0), UnitQuaternion::from_rotation_matrix(&rz));
        d.to_homogeneous() * gt
    }
}

/// Values of one grid axis, `{-max, ..., max}` by `step`, keeping every
/// `stride`-th counting outward from zero.
fn axis(max: i32, step: i32, stride: usize) -> Vec<f64> {
    let n = max / step;
    (-n..=n).filter(|k| (k.unsigned_abs() as usize) % stride == 0).map(|k| f64::from(k * step)).collect()
}

/// The paper's grid (1331 starts), thinned by `stride` on each axis.
pub fn grid(stride: usize) -> Vec<Start> {
    let stride = stride.max(1);
    let mut out = Vec::new();
    for dx in axis(10, 2, stride) {
        for dy in axis(10, 2, stride) {
            for dyaw in axis(25, 5, stride) {
                out.push(Start { dx, dy, dyaw });
            }
        }
    }
    out
}

/// The 8 corners and the centre of the paper's grid.
pub fn corners() -> Vec<Start> {
    let mut out = vec![Start { dx: 0.0, dy: 0.0, dyaw: 0.0 }];
    for dx in [-10.0, 10.0] {
        for dy in [-10.0, 10.0] {
            for dyaw in [-25.0, 25.0] {
                out.push(Start { dx, dy, dyaw });
            }
        }
    }
    out
}

/// `n` starts of the full grid chosen by a fixed seed (without repetition).
pub fn sample(n: usize, seed: u64) -> Vec<Start> {
    let mut all = grid(1);
    let mut rng = crate::rng::Rng::new(seed);
    for i in (1..all.len()).rev() {
        all.swap(i, rng.below(i as u64 + 1) as usize);
    }
    all.truncate(n.min(all.len()));
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_sizes() {
        assert_eq!(grid(1).len(), 1331);
        // Stride 5: {-10, 0, 10} x {-10, 0, 10} x {-25, 0, 25}.
        assert_eq!(grid(5).len(), 27);
        assert!(grid(5).contains(&Start { dx: 0.0, dy: 0.0, dyaw: 0.0 }));
        assert_eq!(grid(2).len(), 5 * 5 * 5);
    }

    #[test]
    fn errors_of_a_known_offset() {
        let gt = crate::pose::from_xyz_rpy_deg(1.0, 2.0, 0.5, 1.0, 2.0, 30.0);
        let est = Start { dx: 3.0, dy: 4.0, dyaw: 10.0 }.apply(&gt);
        let (et, er) = errors(&est, &gt);
        assert!((et - 5.0).abs() < 1e-9 && (er - 10.0).abs() < 1e-9, "{et} {er}");
    }
}
