//! Tests of the map stage: sizes, fusion, neighbourhoods, pyramid, fullness.

use super::*;
use crate::classes::Class;
use crate::test_util::{heap_map, Heap};
use proptest::prelude::*;
use std::vec::Vec;

#[test]
fn stored_voxel_fits_the_budget() {
    assert_eq!(core::mem::size_of::<SemanticVoxel>(), 24);
    assert_eq!(core::mem::size_of::<LabelDistribution>(), 8);
    assert_eq!(core::mem::size_of::<VoxelKey>(), 6);
    const { assert!(BYTES_PER_VOXEL <= 32) };
    // Storage for N voxels is exactly N * 32 bytes, index included.
    assert_eq!(core::mem::size_of::<ArrayStorage<8192>>(), 8192 * BYTES_PER_VOXEL);
}

#[test]
fn points_fuse_into_running_mean_and_labels() {
    let mut map = FixedMap::<16>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
    assert_eq!(map.insert_point([0.05, 0.05, 0.05], Class::Road), Ok(Insertion::Created));
    assert_eq!(map.insert_point([0.15, 0.15, 0.15], Class::Road), Ok(Insertion::Fused));
    assert_eq!(map.insert_point([0.10, 0.10, 0.10], Class::Sidewalk), Ok(Insertion::Fused));
    assert_eq!(map.len(), 1);
    let v = map.voxels()[0];
    assert_eq!(v.hits(), 3);
    for c in v.position(0.2) {
        assert!((c - 0.1).abs() < 1e-4, "{c}");
    }
    assert_eq!(v.class(), Some(Class::Road));
    assert!(v.labels.probability(Class::Road) > v.labels.probability(Class::Sidewalk));
    assert!((v.occupancy_logodds() - 2.55).abs() < 0.01);
    assert!(map.get_at([0.19, 0.01, 0.0]).is_some());
    assert!(map.get_at([0.21, 0.01, 0.0]).is_none());
}

#[test]
fn occupancy_is_clamped() {
    let mut map = FixedMap::<4>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
    for _ in 0..20 {
        map.insert_point([1.0, 1.0, 1.0], Class::Building).unwrap();
    }
    assert!((map.voxels()[0].occupancy_logodds() - 3.5).abs() < 1e-3);
}

#[test]
fn bad_points_are_typed_errors_and_change_nothing() {
    let mut map = FixedMap::<4>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
    assert_eq!(map.insert_point([f32::NAN, 0.0, 0.0], Class::Car), Err(InsertError::NonFinite));
    assert_eq!(map.insert_point([0.0, f32::NEG_INFINITY, 0.0], Class::Car), Err(InsertError::NonFinite));
    assert_eq!(map.insert_point([0.0, 0.0, 1e6], Class::Car), Err(InsertError::OutOfRange));
    assert!(map.is_empty());
}

#[test]
fn bad_configs_are_rejected() {
    let bad = |c: MapConfig| FixedMap::<4>::new(ArrayStorage::new(), c).err();
    assert_eq!(bad(MapConfig::with_resolution(0.0)), Some(ConfigError::Resolution));
    assert_eq!(bad(MapConfig::with_resolution(f32::NAN)), Some(ConfigError::Resolution));
    assert_eq!(
        bad(MapConfig { sensor: SensorModel { accuracy: 1.5 }, ..MapConfig::default() }),
        Some(ConfigError::SensorModel)
    );
    assert_eq!(
        bad(MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [f32::NAN; 3] }, ..MapConfig::default() }),
        Some(ConfigError::Anchor)
    );
    let (mut voxels, mut slots) = ([SemanticVoxel::EMPTY; 8], [0u32; 15]);
    let short = SliceStorage { voxels: &mut voxels, slots: &mut slots };
    assert!(matches!(LocalMap::new(short, MapConfig::default()), Err(ConfigError::Storage)));
}

#[test]
fn full_map_rejects_then_keeps_working() {
    let mut map = FixedMap::<3>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
    for i in 0..3 {
        map.insert_point([i as f32, 0.0, 0.0], Class::Pole).unwrap();
    }
    assert_eq!(map.insert_point([9.0, 0.0, 0.0], Class::Pole), Err(InsertError::Full));
    // Existing voxels still fuse.
    assert_eq!(map.insert_point([0.01, 0.01, 0.01], Class::Pole), Ok(Insertion::Fused));
    assert_eq!(map.len(), 3);
}

#[test]
fn eviction_keeps_the_nearest_ball() {
    let config = MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::default() };
    let mut map = heap_map(64, config);
    // A ray of voxels going outward, then one near the anchor.
    for i in 0..200 {
        let _ = map.insert_point([0.1 + 0.2 * i as f32, 0.1, 0.1], Class::Building).unwrap();
    }
    assert!(map.len() <= 64);
    assert!(map.evicted() > 0);
    let r = map.keep_radius().unwrap();
    for v in map.iter() {
        let p = v.position(0.2);
        assert!(p[0] < r + 0.2, "voxel at {} beyond the kept radius {r}", p[0]);
    }
    assert_eq!(map.insert_point([r + 5.0, 0.1, 0.1], Class::Building), Ok(Insertion::Dropped));
    assert_eq!(map.insert_point([0.1, 0.3, 0.1], Class::Building), Ok(Insertion::Created));
}

#[test]
fn neighbourhood_has_the_27_cells() {
    let mut map = heap_map(64, MapConfig::with_resolution(1.0));
    for x in -2..=2 {
        for y in -2..=2 {
            map.insert_point([x as f32 + 0.5, y as f32 + 0.5, 0.5], Class::Road).unwrap();
        }
    }
    let centre = VoxelKey::new(0, 0, 0);
    let n: Vec<_> = map.neighbours(centre).collect();
    assert_eq!(n.len(), 9, "one layer of 3x3 is occupied");
    assert_eq!(n[0].1.key, centre, "the centre comes first");
    assert!(n.iter().all(|(_, v)| (v.key.x - centre.x).abs() <= 1 && (v.key.y - centre.y).abs() <= 1));
    // At the edge of the key range, missing cells are skipped, not wrapped.
    let edge = VoxelKey::new(i16::MAX, 0, 0);
    assert_eq!(map.neighbours(edge).count(), 0);
}

#[test]
fn coarse_level_fuses_children() {
    let mut fine = heap_map(64, MapConfig::with_resolution(0.5));
    fine.insert_point([0.1, 0.1, 0.1], Class::Road).unwrap();
    fine.insert_point([0.6, 0.1, 0.1], Class::Road).unwrap();
    fine.insert_point([0.6, 0.1, 0.1], Class::Road).unwrap();
    fine.insert_point([-0.1, 0.1, 0.1], Class::Sidewalk).unwrap();
    let mut coarse = heap_map(8, MapConfig::default());
    fine.coarsen_into(2, &mut coarse).unwrap();
    assert_eq!(coarse.resolution(), 1.0);
    assert_eq!(coarse.len(), 2);
    let v = coarse.get(VoxelKey::new(0, 0, 0)).unwrap();
    assert_eq!(v.hits(), 3);
    let p = v.position(1.0);
    assert!((p[0] - (0.1 + 0.6 + 0.6) / 3.0).abs() < 1e-3, "{p:?}");
    assert_eq!(v.class(), Some(Class::Road));
    let mut tiny = heap_map(1, MapConfig::default());
    assert_eq!(fine.coarsen_into(2, &mut tiny), Err(CoarsenError::Full));
    assert!(tiny.is_empty());
    assert_eq!(fine.coarsen_into(0, &mut coarse), Err(CoarsenError::Factor));
}

#[test]
fn insert_voxel_rejects_duplicates() {
    let mut map = heap_map(4, MapConfig::default());
    let v = SemanticVoxel::from_parts(VoxelKey::new(1, 2, 3), [0; 3], 100, 1, LabelDistribution::EMPTY);
    map.insert_voxel(v).unwrap();
    assert_eq!(map.insert_voxel(v), Err(InsertError::DuplicateKey));
    assert_eq!(map.get(VoxelKey::new(1, 2, 3)), Some(&v));
}

fn any_coord() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -50.0f32..50.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => prop::num::f32::ANY,
    ]
}

fn any_class() -> impl Strategy<Value = Class> {
    (0u8..19).prop_map(|i| Class::from_index(i).unwrap())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Arbitrary points (NaN, infinities, huge values included) never panic,
    /// never exceed the capacity, and every stored voxel is findable.
    #[test]
    fn capacity_is_never_exceeded(
        points in prop::collection::vec(([any_coord(), any_coord(), any_coord()], any_class()), 0..400),
        capacity in 1usize..40,
        evict in any::<bool>(),
        resolution in 0.05f32..2.0,
    ) {
        let when_full = if evict { FullPolicy::EvictFarthest { anchor: [0.0; 3] } } else { FullPolicy::Reject };
        let mut map = heap_map(capacity, MapConfig { resolution, when_full, ..MapConfig::default() });
        for (p, c) in points {
            let r = map.insert_point(p, c);
            let finite = p.iter().all(|v| v.is_finite());
            if !finite {
                prop_assert_eq!(r, Err(InsertError::NonFinite));
            }
            if r == Err(InsertError::Full) {
                prop_assert!(!evict);
            }
            prop_assert!(map.len() <= capacity);
        }
        for (i, v) in map.iter().enumerate() {
            prop_assert_eq!(map.index_of(v.key), Some(i));
            prop_assert!(v.class().is_some());
        }
    }

    /// The same evidence in any order gives the same distribution (and so the
    /// same argmax) when a voxel sees at most four classes.
    #[test]
    fn fusion_is_order_independent(
        evidence in prop::collection::vec(0usize..4, 1..300),
        classes in prop::sample::subsequence(Class::ALL.to_vec(), 4),
        seed in any::<u64>(),
    ) {
        let mut a = LabelDistribution::EMPTY;
        for &e in &evidence {
            a.observe(classes[e], 34);
        }
        let mut shuffled = evidence.clone();
        let mut s = seed | 1;
        for i in (1..shuffled.len()).rev() {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            shuffled.swap(i, (s % (i as u64 + 1)) as usize);
        }
        let mut b = LabelDistribution::EMPTY;
        for &e in &shuffled {
            b.observe(classes[e], 34);
        }
        prop_assert_eq!(a.argmax(), b.argmax());
        // Ties aside, the majority class wins.
        let mut counts = [0usize; 4];
        for &e in &evidence { counts[e] += 1; }
        let best = *counts.iter().max().unwrap();
        if counts.iter().filter(|&&c| c == best).count() == 1 {
            let winner = counts.iter().position(|&c| c == best).unwrap();
            prop_assert_eq!(a.argmax(), Some(classes[winner]));
        }
    }

    /// Also with more classes than slots, identical evidence gives the same
    /// argmax whatever its order when one class holds more than 5/9 of it
    /// (the Misra–Gries bound for four slots).
    #[test]
    fn majority_survives_any_order(
        minority in prop::collection::vec(0u8..19, 0..40),
        seed in any::<u64>(),
    ) {
        let mut evidence: Vec<u8> = minority.iter().copied().filter(|&c| c != Class::Vegetation.index()).collect();
        // v > 5/9 (v + m)  <=>  v > 1.25 m.
        let majority = evidence.len() * 5 / 4 + 1;
        evidence.extend(core::iter::repeat_n(Class::Vegetation.index(), majority));
        let mut s = seed | 1;
        for i in (1..evidence.len()).rev() {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            evidence.swap(i, (s % (i as u64 + 1)) as usize);
        }
        let mut d = LabelDistribution::EMPTY;
        for &c in &evidence {
            d.observe(Class::from_index(c).unwrap(), 34);
        }
        prop_assert_eq!(d.argmax(), Some(Class::Vegetation));
    }

    /// A coarser level never has more voxels than the finer one, and keeps
    /// every hit.
    #[test]
    fn coarser_level_is_not_larger(
        points in prop::collection::vec([-20.0f32..20.0, -20.0f32..20.0, -3.0f32..3.0], 1..300),
        factor in 1u16..5,
    ) {
        let mut fine = heap_map(400, MapConfig::default());
        for p in &points {
            fine.insert_point(*p, Class::Building).unwrap();
        }
        let mut coarse = heap_map(400, MapConfig::default());
        fine.coarsen_into(factor, &mut coarse).unwrap();
        prop_assert!(coarse.len() <= fine.len());
        let hits = |m: &LocalMap<Heap>| m.iter().map(|v| u32::from(v.hits())).sum::<u32>();
        prop_assert_eq!(hits(&coarse), hits(&fine));
        for v in fine.iter() {
            prop_assert!(coarse.get(v.key.coarsen(factor)).is_some());
        }
    }
}

#[test]
fn overlap_under_identity_and_shift() {
    let mut a = heap_map(1000, MapConfig::default());
    for i in 0..100 {
        a.insert_point([i as f32 * 0.2 + 0.1, 0.1, 0.1], Class::Building).unwrap();
    }
    let id = crate::geometry::Isometry3::identity();
    assert_eq!(overlap(&a, &a, &id), 1.0);
    let far = crate::geometry::from_xyz_rpy(0.0, 5.0, 0.0, 0.0, 0.0, 0.0);
    assert_eq!(overlap(&a, &a, &far), 0.0);
    let mut b = heap_map(1000, MapConfig::default());
    for i in 0..100 {
        b.insert_point([i as f32 * 0.2 + 0.1, 0.1, 0.1], Class::Road).unwrap();
    }
    assert_eq!(overlap(&a, &b, &id), 0.0, "different classes do not overlap");
}

/// A full map evicts exactly an eighth of its capacity, the farthest
/// voxels (ties at one distance included: a shell of a lattice), and
/// keeps 7/8 of it.
#[test]
fn eviction_removes_exactly_the_farthest_eighth() {
    let config = MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::default() };
    let mut map = heap_map(400, config);
    // A 20 x 20 plane of voxels around the anchor: many equal distances.
    for i in 0..20 {
        for j in 0..20 {
            map.insert_point([0.2 * i as f32 - 1.9, 0.2 * j as f32 - 1.9, 0.1], Class::Road).unwrap();
        }
    }
    assert_eq!(map.len(), 400);
    let far_before: Vec<f32> = {
        let mut d: Vec<f32> =
            map.iter().map(|v| v.key.center(0.2)).map(|c| (c[0] * c[0] + c[1] * c[1]).sqrt()).collect();
        d.sort_by(|a, b| a.total_cmp(b));
        d
    };
    // One more voxel fills it past capacity: 50 of 400 go.
    assert_eq!(map.insert_point([0.05, 0.05, 0.3], Class::Pole), Ok(Insertion::Created));
    assert_eq!(map.evicted(), 50);
    assert_eq!(map.len(), 351);
    // Every kept voxel is at most as far as the 350th nearest before.
    let limit = far_before[349];
    for v in map.iter() {
        let c = v.key.center(0.2);
        assert!((c[0] * c[0] + c[1] * c[1]).sqrt() <= limit + 1e-5);
    }
}

/// A map that keeps driving stays a ball around the robot: after a cut,
/// moving the anchor keeps the cut's radius around the new point, so what
/// the sensor sees beyond it is dropped, not fused and evicted again at the
/// next cut; the next cut sets the radius anew, larger where the ground
/// ahead holds less.
#[test]
fn a_moving_map_keeps_its_ball_around_the_robot() {
    let config = MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::default() };
    let mut map = heap_map(64, config);
    // A dense line along x, out to 20 m: the map fills and cuts.
    for i in 0..100 {
        let _ = map.insert_point([0.1 + 0.2 * i as f32, 0.1, 0.1], Class::Road).unwrap();
    }
    let r = map.keep_radius().expect("a cut was made");
    // The robot moves 1 m along y: the ball moves with it.
    map.move_anchor([0.0, 1.0, 0.0]).unwrap();
    assert_eq!(map.keep_radius(), Some(r), "the radius outlives the move");
    let before = map.len();
    let far = [0.1, 1.0 + r + 0.5, 0.1];
    assert_eq!(map.insert_point(far, Class::Pole), Ok(Insertion::Dropped), "beyond the ball");
    let near = [0.1, 1.0 + 0.5 * r, 0.1];
    assert_eq!(map.insert_point(near, Class::Pole), Ok(Insertion::Created), "inside the ball");
    assert_eq!(map.len(), before + 1);
    // Sparse ground ahead: a cut far out grows the radius again.
    map.move_anchor([0.0, 40.0, 0.0]).unwrap();
    for i in 0..80 {
        let _ = map.insert_point([0.1, 40.0 + 0.05 * r * i as f32, 0.1], Class::Road).unwrap();
    }
    let grown = map.keep_radius().expect("cut again");
    assert!(grown > r && grown.is_finite(), "{grown} after {r}");
    for v in map.iter() {
        let p = v.position(0.2);
        let d = ((p[0] - 0.0).powi(2) + (p[1] - 40.0).powi(2)).sqrt();
        assert!(d < grown + 0.4, "voxel {d} m from the robot, beyond the ball {grown}");
    }
}

/// `nearest` picks exactly the voxels a map of that many kept around the
/// point would hold (ties included), ascending, and all of a small map.
#[test]
fn the_nearest_part_of_a_map_is_exactly_that_many() {
    let mut map = heap_map(400, MapConfig::default());
    for i in 0..20 {
        for j in 0..20 {
            map.insert_point([0.2 * i as f32 - 1.9, 0.2 * j as f32 - 1.9, 0.1], Class::Road).unwrap();
        }
    }
    let at = [0.5, -0.3, 0.1];
    let d = |i: u32| {
        let c = map.voxel(i as usize).unwrap().key.center(0.2);
        ((c[0] - at[0]).powi(2) + (c[1] - at[1]).powi(2) + (c[2] - at[2]).powi(2)).sqrt()
    };
    let mut out = std::vec![0u32; 400];
    for most in [1, 37, 200, 399] {
        let n = map.nearest(at, most, &mut out);
        assert_eq!(n, most);
        let picked = &out[..n];
        assert!(picked.windows(2).all(|w| w[0] < w[1]), "ascending, none twice");
        let farthest_in = picked.iter().map(|&i| d(i)).fold(0.0f32, f32::max);
        let nearest_out = (0..400u32).filter(|i| !picked.contains(i)).map(d).fold(f32::INFINITY, f32::min);
        assert!(farthest_in <= nearest_out + 1e-5, "{most}: {farthest_in} > {nearest_out}");
    }
    assert_eq!(map.nearest(at, 1000, &mut out), 400, "a map that fits goes whole");
    assert_eq!(map.nearest(at, 400, &mut out[..10]), 10, "never beyond the output");
}

/// 16-bit index slots: the same map as with 32-bit ones (same voxels in the
/// same order, same lookups), and a capacity they cannot address refused.
#[test]
fn sixteen_bit_slots_index_like_thirty_two_bit_ones() {
    let config = MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::default() };
    let mut narrow = LocalMap::new(ArrayStorage::<300, u16>::new(), config).unwrap();
    let mut wide = LocalMap::new(ArrayStorage::<300, u32>::new(), config).unwrap();
    let mut seed = 3u32;
    for _ in 0..5000 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let p = [(seed >> 8) as f32 / 16_777_216.0 * 12.0 - 6.0, (seed >> 4 & 0xFF) as f32 * 0.05 - 6.0, 0.1];
        assert_eq!(narrow.insert_point(p, Class::Road), wide.insert_point(p, Class::Road));
    }
    assert!(narrow.evicted() > 0);
    assert_eq!(narrow.voxels(), wide.voxels());
    for v in wide.iter() {
        assert_eq!(narrow.get(v.key), Some(v));
    }
    let mut voxels = std::vec![SemanticVoxel::EMPTY; 65_535];
    let mut slots = std::vec![0u16; 2 * 65_535];
    let too_many = SliceStorage { voxels: &mut voxels, slots: &mut slots };
    assert!(matches!(LocalMap::new(too_many, MapConfig::default()), Err(ConfigError::Storage)));
    let ok = SliceStorage { voxels: &mut voxels[..65_534], slots: &mut slots };
    assert!(LocalMap::new(ok, MapConfig::default()).is_ok());
}

/// The memo gives what it remembers for: the same class and confidence as
/// [`class_and_confidence`], through repeats and colliding slots.
#[test]
fn the_class_memo_answers_as_the_posterior_does() {
    use crate::map::labels::LabelDistribution;
    use crate::map::{class_and_confidence, ClassMemo};
    let mut memo = ClassMemo::default();
    let mut next = crate::test_util::draws(0x9e37_79b9_7f4a_7c15u64);
    let mut seen = std::vec::Vec::new();
    for _ in 0..5_000 {
        // Half of them a distribution seen before.
        let labels = if !seen.is_empty() && next(2) == 0 {
            seen[next(seen.len() as u64) as usize]
        } else {
            let mut d = LabelDistribution::default();
            for _ in 0..1 + next(6) {
                d.observe(Class::from_index(next(19) as u8).unwrap(), 1 + next(200) as u16);
            }
            seen.push(d);
            d
        };
        let v = SemanticVoxel::from_parts(VoxelKey::new(0, 0, 0), [0; 3], 0, 1, labels);
        assert_eq!(memo.of(&v), class_and_confidence(&v), "{labels:?}");
    }
}
