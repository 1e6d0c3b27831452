//! Matcher tests on small synthetic structures: the shared maps here, the
//! tests by what they test.

mod agreement;
mod alignment;
mod budget;
mod pyramids;
mod tracking;

use super::*;
use crate::classes::Class;
use crate::geometry::from_xyz_rpy;
use crate::map::{LocalMap, MapConfig, SemanticVoxel, SliceStorage};
use nalgebra::Isometry3;
use proptest::prelude::*;
use std::vec;
use std::vec::Vec;

use crate::matching::VecPyramidStorage as Heap;
use crate::test_util::heap_pyramid;

type Map = LocalMap<crate::test_util::Heap>;

fn new_map() -> Map {
    crate::test_util::map(40_000)
}

fn pyramid<S: crate::map::VoxelStorage>(map: &LocalMap<S>) -> Pyramid<'_, Heap> {
    let n = map.len();
    Pyramid::build(map, 4, 1.0, heap_pyramid(n, 3 * n, 400_000)).unwrap()
}

/// A street's model (0-400) and a scene of its middle (100-300) placed by
/// the returned truth, `T_model_scene` (0.8 m, 0.3 m and 0.03 rad off);
/// with poles, or walls and floor alone.
fn street_pair(poles: bool) -> (Isometry3<f32>, Map, Map) {
    let gt = from_xyz_rpy(0.8, 0.3, 0.0, 0.0, 0.0, 0.03);
    let mut model = new_map();
    crate::test_util::street(&mut model, &Isometry3::identity(), (0, 400), poles);
    let mut scene = new_map();
    crate::test_util::street(&mut scene, &gt.inverse(), (100, 300), poles);
    (gt, model, scene)
}

/// An L-shaped street corner: floor, two walls, poles and a tree.
fn corner(map: &mut Map, t: &Isometry3<f32>) {
    let mut put = |p: [f32; 3], c: Class| {
        let q = crate::geometry::transform_point(t, p);
        map.insert_point(q, c).unwrap();
    };
    for i in 0..150 {
        for j in 0..150 {
            let (x, y) = (i as f32 * 0.1 - 5.0, j as f32 * 0.1 - 5.0);
            put([x, y, 0.0], if y < 2.0 { Class::Road } else { Class::Sidewalk });
        }
    }
    for i in 0..150 {
        for k in 0..40 {
            let (a, z) = (i as f32 * 0.1 - 5.0, k as f32 * 0.1);
            put([a, 10.0, z], Class::Building);
            if a < 4.0 {
                put([10.0, a, z], Class::Fence);
            }
        }
    }
    for (px, py) in [(-3.0f32, 3.0f32), (2.0, -4.0), (6.0, 6.0)] {
        for k in 0..60 {
            for a in 0..8 {
                let ang = a as f32 * core::f32::consts::FRAC_PI_4;
                put([px + 0.1 * libm::cosf(ang), py + 0.1 * libm::sinf(ang), k as f32 * 0.1], Class::Pole);
            }
        }
    }
}

/// The corner as the model, and as a scene whose frame is `gt` in the
/// model's (`T_model_scene`).
fn corner_seen_from(gt: &Isometry3<f32>) -> (Map, Map) {
    let mut model = new_map();
    corner(&mut model, &Isometry3::identity());
    let mut scene = new_map();
    corner(&mut scene, &gt.inverse());
    (model, scene)
}

fn errors(a: &Isometry3<f32>, b: &Isometry3<f32>) -> (f32, f32) {
    let d = a * b.inverse();
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}
