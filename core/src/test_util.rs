//! Helpers shared by the core's tests (compiled for tests only).

use crate::map::{vec_map, MapConfig, VecMap};
use crate::matching::{PyramidCapacity, VecPyramidStorage};
use std::vec;

/// Map storage on the heap (inline storage of large maps would not fit a
/// test thread's stack).
pub type Heap = crate::map::VecStorage;

/// An empty heap map of `capacity` voxels (at least one) with `config`.
pub fn heap_map(capacity: usize, config: MapConfig) -> VecMap {
    vec_map(capacity, config).unwrap()
}

/// An empty heap map with the default configuration.
pub fn map(capacity: usize) -> VecMap {
    heap_map(capacity, MapConfig::default())
}

/// Pyramid storage on the heap for maps of up to `voxels` voxels, `entries`
/// coarse entries and `words` footprint words.
pub fn heap_pyramid(voxels: usize, entries: usize, words: usize) -> VecPyramidStorage {
    VecPyramidStorage::new(PyramidCapacity { voxels, entries, slots: 2 * entries, words })
}

/// A straight street seen from `t` (`T_map_street`), inserted into `map`:
/// its two walls from `x0` to `x1` (tenths of a metre), and with `poles`
/// poles at uneven spacing. No floor: where one meets a wall, the edge's
/// voxels (not planar) are matched point to point and hold the street
/// along it by their grid. So without poles nothing holds a match along
/// the street where it does not end, nor up; with them, everything does.
pub fn street(map: &mut VecMap, t: &crate::geometry::Isometry3<f32>, (x0, x1): (i32, i32), poles: bool) {
    use crate::classes::Class;
    let mut put = |p: [f32; 3], c: Class| {
        map.insert_point(crate::geometry::transform_point(t, p), c).unwrap();
    };
    for i in x0..x1 {
        let x = i as f32 * 0.1;
        for k in 0..40 {
            put([x, 5.0, k as f32 * 0.1], Class::Building);
            put([x, -5.0, k as f32 * 0.1], Class::Vegetation);
        }
    }
    for px in [12.0f32, 17.5, 21.0, 26.5].iter().filter(|_| poles) {
        for k in 0..60 {
            put([*px, 3.5, k as f32 * 0.1], Class::Pole);
        }
    }
}

#[test]
fn selftest_converges_and_encodes_consistently() {
    use crate::selftest::*;
    let config = MapConfig::with_resolution(RESOLUTION);
    let (mut a, mut b, mut r) =
        (heap_map(MAP_VOXELS, config), heap_map(MAP_VOXELS, config), heap_map(MAP_VOXELS, config));
    let mut scratch = vec![0u32; MAP_VOXELS];
    let mut chunk = [0u8; 240];
    let pa = heap_pyramid(MAP_VOXELS, PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let pb = heap_pyramid(MAP_VOXELS, PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let mut calls = 0;
    let report = run(&mut a, &mut b, &mut r, &mut scratch, &mut chunk, pa, pb, |_| calls += 1).unwrap();
    assert_eq!(calls, 2);
    std::println!("{report:?}");
    assert!(report.wire_ok);
    assert!(report.voxels[0] > 800 && report.voxels[1] > 800, "{:?}", report.voxels);
    assert_eq!(report.result.status, crate::matching::MatchStatus::Converged);
    let d = report.result.transform * report.truth.inverse();
    assert!(d.translation.vector.norm() < 0.05 && d.rotation.angle().to_degrees() < 0.2, "{d:?}");
}

/// A seeded xorshift draw below `n` for each call: the tests' random
/// cases, the same on every run.
pub fn draws(seed: u64) -> impl FnMut(u64) -> u64 {
    let mut state = seed;
    move |n| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state % n
    }
}
