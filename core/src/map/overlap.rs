//! How much two maps agree under a transform.

use super::key::VoxelKey;
use super::local_map::LocalMap;
use super::table::VoxelStorage;
use crate::geometry::{transform_point, Isometry3};

/// The conventions' overlap: the fraction of `scene` voxels that, moved by
/// `t_model_scene`, have a `model` voxel of the same class whose mean lies
/// within one model voxel size. 0 for an empty scene.
pub fn overlap<A: VoxelStorage, B: VoxelStorage>(
    model: &LocalMap<A>,
    scene: &LocalMap<B>,
    t_model_scene: &Isometry3<f32>,
) -> f32 {
    if scene.is_empty() {
        return 0.0;
    }
    let res = model.resolution();
    let inv = 1.0 / res;
    let mut hits = 0usize;
    for v in scene.iter() {
        let p = transform_point(t_model_scene, v.position(scene.resolution()));
        let Ok(cell) = VoxelKey::locate(p, inv) else { continue };
        let class = v.class();
        let found = model.neighbours(cell.key).any(|(_, m)| {
            let q = m.position(res);
            let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
            m.class() == class && d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= res * res
        });
        if found {
            hits += 1;
        }
    }
    hits as f32 / scene.len() as f32
}
