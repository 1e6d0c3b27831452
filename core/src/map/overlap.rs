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
    // The model's cells' extent: a scene voxel more than a cell outside it
    // has no neighbour to look up (maps that do not meet, most of a robot
    // team's pairs, cost one pass, not 27 lookups a voxel).
    let within = VoxelKey::extent(model.iter().map(|v| v.key));
    let (mut hits, mut classed) = (0usize, 0usize);
    for v in scene.iter() {
        let Some(class) = v.class() else { continue };
        classed += 1;
        let p = transform_point(t_model_scene, v.position(scene.resolution()));
        let Ok(cell) = VoxelKey::locate(p, inv) else { continue };
        if !within.is_some_and(|(lo, hi)| near_extent(cell.key, lo, hi)) {
            continue;
        }
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

/// Whether `key`'s 27-neighbourhood can hold a cell inside `lo..=hi`.
fn near_extent(key: VoxelKey, lo: VoxelKey, hi: VoxelKey) -> bool {
    [key.x, key.y, key.z]
        .into_iter()
        .zip([lo.x, lo.y, lo.z].into_iter().zip([hi.x, hi.y, hi.z]))
        .all(|(k, (l, h))| (i32::from(l) - 1..=i32::from(h) + 1).contains(&i32::from(k)))
}
