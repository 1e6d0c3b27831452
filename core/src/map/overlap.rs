//! How much two maps agree under a transform.

use super::key::VoxelKey;
use super::local_map::LocalMap;
use super::table::VoxelStorage;
use crate::geometry::{transform_point, Isometry3};

/// The conventions' overlap: the fraction of `scene` voxels that, moved by
/// `t_model_scene`, have a `model` voxel of the same class whose mean lies
/// within one model voxel size. Voxels of an unknown class (geometry kept
/// without labels) have no class to share: they count on neither side. 0
/// for a scene without a labelled voxel.
pub fn overlap<A: VoxelStorage, B: VoxelStorage>(
    model: &LocalMap<A>,
    scene: &LocalMap<B>,
    t_model_scene: &Isometry3<f32>,
) -> f32 {
    let res = model.resolution();
    let inv = 1.0 / res;
    let (mut hits, mut classed) = (0usize, 0usize);
    for v in scene.iter() {
        let Some(class) = v.class() else { continue };
        classed += 1;
        let p = transform_point(t_model_scene, v.position(scene.resolution()));
        let Ok(cell) = VoxelKey::locate(p, inv) else { continue };
        let found = model.neighbours(cell.key).any(|(_, m)| {
            let q = m.position(res);
            let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
            m.class() == Some(class) && d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= res * res
        });
        if found {
            hits += 1;
        }
    }
    if classed == 0 {
        return 0.0;
    }
    hits as f32 / classed as f32
}
