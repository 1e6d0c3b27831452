//! Matcher tests on small synthetic structures.

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

#[test]
fn converges_from_far_starts_to_the_truth() {
    let gt = from_xyz_rpy(1.5, -0.7, 0.05, 0.0, 0.0, 0.2);
    let (model, scene) = corner_seen_from(&gt);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    for (dx, dy, dyaw) in [(0.0, 0.0, 0.0), (6.0, -6.0, 20.0), (-6.0, 6.0, -20.0)] {
        let d = from_xyz_rpy(dx, dy, 0.0, 0.0, 0.0, f32::to_radians(dyaw));
        let r = Matcher::default().align(&pm, &ps, &(d * gt)).unwrap();
        let (et, er) = errors(&r.transform, &gt);
        assert_eq!(r.status, MatchStatus::Converged, "start {dx} {dy} {dyaw}: {r:?}");
        assert!(et < 0.05 && er < 0.2, "start {dx} {dy} {dyaw}: e_t {et} e_r {er}");
        assert!(r.overlap > 0.9 && r.inliers > 1000 && r.rmse < 0.15, "{r:?}");
        assert!(r.min_eigenvalue > 0.0 && r.degeneracy > 0.002, "{r:?}");
    }
}

/// `corner` seen by a camera looking along -x: points with `x > 0` (in the
/// corner's frame) are kept as geometry of an unknown class, the rest labelled.
fn corner_with_unknown(map: &mut Map, t: &Isometry3<f32>) {
    let mut labelled = new_map();
    corner(&mut labelled, &Isometry3::identity());
    for v in labelled.iter() {
        let p = v.position(labelled.resolution());
        let q = crate::geometry::transform_point(t, p);
        if p[0] > 0.0 {
            map.insert_point_evidence(q, &crate::map::LabelDistribution::EMPTY).unwrap();
        } else if let Some(c) = v.class() {
            map.insert_point(q, c).unwrap();
        }
    }
}

#[test]
fn unknown_class_voxels_align_but_stay_out_of_the_overlap() {
    let gt = from_xyz_rpy(1.5, -0.7, 0.05, 0.0, 0.0, 0.2);
    let mut model = new_map();
    corner_with_unknown(&mut model, &Isometry3::identity());
    let mut scene = new_map();
    corner_with_unknown(&mut scene, &gt.inverse());
    let unknown = scene.iter().filter(|v| v.class().is_none()).count();
    assert!(unknown > scene.len() / 3, "{unknown} of {}", scene.len());
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    for method in [Method::Cosem, Method::CosemHard, Method::Geometric] {
        let settings = MatchSettings { method, ..MatchSettings::default() };
        let d = from_xyz_rpy(4.0, -4.0, 0.0, 0.0, 0.0, f32::to_radians(15.0));
        let r = Matcher::new(settings).align(&pm, &ps, &(d * gt)).unwrap();
        let (et, er) = errors(&r.transform, &gt);
        assert_eq!(r.status, MatchStatus::Converged, "{method:?}: {r:?}");
        assert!(et < 0.05 && er < 0.2, "{method:?}: e_t {et} e_r {er}");
        // The overlap is over the labelled voxels: they all agree here
        // (counting the unknown ones as disagreeing would halve it).
        assert!(r.overlap > 0.9, "{method:?}: {r:?}");
        let whole = crate::map::overlap(&model, &scene, &r.transform);
        assert!((whole - r.overlap).abs() < 0.05, "{whole} vs {}", r.overlap);
    }
    // A scene of unknown voxels alone has no overlap to show.
    let mut blank = new_map();
    for v in scene.iter() {
        blank.insert_point_evidence(v.position(scene.resolution()), &crate::map::LabelDistribution::EMPTY).unwrap();
    }
    assert_eq!(crate::map::overlap(&model, &blank, &gt), 0.0);
}

#[test]
fn self_match_is_identity_and_bit_for_bit_repeatable() {
    let mut m = new_map();
    corner(&mut m, &Isometry3::identity());
    let (a, b) = (pyramid(&m), pyramid(&m));
    let r1 = Matcher::default().align(&a, &b, &Isometry3::identity()).unwrap();
    let r2 = Matcher::default().align(&a, &b, &Isometry3::identity()).unwrap();
    assert_eq!(r1.status, MatchStatus::Converged);
    let (et, er) = errors(&r1.transform, &Isometry3::identity());
    assert!(et < 1e-3 && er < 1e-3, "{et} {er}");
    assert_eq!(r1, r2);
    let bits = |r: &MatchResult| {
        let v = r.transform.translation.vector;
        let q = r.transform.rotation.coords;
        [v.x, v.y, v.z, q.x, q.y, q.z, q.w].map(f32::to_bits)
    };
    assert_eq!(bits(&r1), bits(&r2));
}

#[test]
fn flat_road_alone_is_degenerate() {
    let mut m = new_map();
    for i in 0..200 {
        for j in 0..100 {
            m.insert_point([i as f32 * 0.1, j as f32 * 0.1, 0.0], Class::Road).unwrap();
        }
    }
    let p = pyramid(&m);
    let r = Matcher::default().align(&p, &p, &from_xyz_rpy(0.3, 0.2, 0.0, 0.0, 0.0, 0.02)).unwrap();
    assert_eq!(r.status, MatchStatus::Degenerate, "{r:?}");
    assert!(r.degeneracy < 1e-3);
}

#[test]
fn far_apart_maps_do_not_match() {
    let mut model = new_map();
    corner(&mut model, &Isometry3::identity());
    let mut scene = new_map();
    corner(&mut scene, &from_xyz_rpy(80.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    let r = Matcher::default().align(&pyramid(&model), &pyramid(&scene), &Isometry3::identity()).unwrap();
    assert_eq!(r.status, MatchStatus::NoOverlap, "{r:?}");
}

#[test]
fn four_dof_keeps_roll_and_pitch_of_the_start() {
    let gt = from_xyz_rpy(1.0, 0.5, 0.0, 0.0, 0.0, 0.1);
    let (model, scene) = corner_seen_from(&gt);
    let settings = MatchSettings { dof: Dof::Four, ..MatchSettings::default() };
    let r = Matcher::new(settings)
        .align(&pyramid(&model), &pyramid(&scene), &from_xyz_rpy(2.0, 0.0, 0.0, 0.0, 0.0, 0.3))
        .unwrap();
    let (roll, pitch, _) = r.transform.rotation.euler_angles();
    assert!(roll.abs() < 1e-6 && pitch.abs() < 1e-6, "{roll} {pitch}");
    let (et, er) = errors(&r.transform, &gt);
    assert!(et < 0.05 && er < 0.2, "{et} {er}");
}

#[test]
fn invalid_inputs_are_errors() {
    let mut m = new_map();
    corner(&mut m, &Isometry3::identity());
    let p = pyramid(&m);
    let mut bad = Isometry3::identity();
    bad.translation.vector.x = f32::NAN;
    assert_eq!(Matcher::default().align(&p, &p, &bad), Err(MatchError::NonFiniteInit));
    let zero = MatchSettings { max_iterations: 0, ..MatchSettings::default() };
    assert_eq!(Matcher::new(zero).align(&p, &p, &Isometry3::identity()), Err(MatchError::Settings));
    // A pyramid of another resolution.
    let mut coarse = LocalMap::new(crate::map::ArrayStorage::<4096>::new(), MapConfig::with_resolution(0.5)).unwrap();
    coarse.insert_point([0.0; 3], Class::Road).unwrap();
    let pc = pyramid(&coarse);
    assert_eq!(Matcher::default().align(&p, &pc, &Isometry3::identity()), Err(MatchError::ResolutionMismatch));
    // Too little storage is a typed error.
    let tiny = heap_pyramid(m.len(), 10, 0);
    assert!(matches!(Pyramid::build(&m, 4, 1.0, tiny), Err(PyramidError::Full)));
}

fn small_map(points: &[([f32; 3], u8)]) -> (Vec<SemanticVoxel>, Vec<u32>) {
    (vec![SemanticVoxel::EMPTY; points.len().max(1)], vec![0; 2 * points.len().max(1)])
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Arbitrary maps and priors never panic and never give a non-finite
    /// transform.
    #[test]
    fn arbitrary_maps_and_priors_are_safe(
        a in prop::collection::vec(([-15.0f32..15.0, -15.0f32..15.0, -2.0f32..4.0], 0u8..19), 1..300),
        b in prop::collection::vec(([-15.0f32..15.0, -15.0f32..15.0, -2.0f32..4.0], 0u8..19), 1..300),
        t in [-40.0f32..40.0, -40.0f32..40.0, -5.0f32..5.0, -3.2f32..3.2, -3.2f32..3.2, -3.2f32..3.2],
        method in 0u8..3,
        four in any::<bool>(),
    ) {
        let (mut va, mut sa) = small_map(&a);
        let (mut vb, mut sb) = small_map(&b);
        let mut ma = LocalMap::new(SliceStorage { voxels: &mut va, slots: &mut sa }, MapConfig::default()).unwrap();
        let mut mb = LocalMap::new(SliceStorage { voxels: &mut vb, slots: &mut sb }, MapConfig::default()).unwrap();
        for (p, c) in &a { ma.insert_point(*p, Class::from_index(*c).unwrap()).unwrap(); }
        for (p, c) in &b { mb.insert_point(*p, Class::from_index(*c).unwrap()).unwrap(); }
        let settings = MatchSettings {
            method: [Method::Cosem, Method::CosemHard, Method::Geometric][method as usize],
            dof: if four { Dof::Four } else { Dof::Six },
            ..MatchSettings::default()
        };
        let init = from_xyz_rpy(t[0], t[1], t[2], t[3], t[4], t[5]);
        let r = Matcher::new(settings).align(&pyramid(&ma), &pyramid(&mb), &init).unwrap();
        let v = r.transform.translation.vector;
        let q = r.transform.rotation.coords;
        prop_assert!(v.iter().chain(q.iter()).all(|x| x.is_finite()), "{:?}", r);
        prop_assert!(r.overlap.is_finite() && r.rmse.is_finite() && r.degeneracy.is_finite());
        prop_assert!(r.iterations <= settings.max_iterations);
    }
}

#[test]
fn packed_normals_round_trip() {
    let mut seed = 7u32;
    let mut next = || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (seed >> 8) as f32 / (1 << 24) as f32 * 2.0 - 1.0
    };
    for _ in 0..10_000 {
        let v = [next(), next(), next()];
        let n = libm::sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if n < 1e-3 {
            continue;
        }
        let u = [v[0] / n, v[1] / n, v[2] / n];
        let back = PackedNormal::pack(v).unpack().unwrap();
        let d = [u[0] - back[0], u[1] - back[1], u[2] - back[2]];
        // Within 0.01 degrees (1.7e-4 rad).
        assert!(libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) < 1.7e-4, "{u:?} -> {back:?}");
    }
    for axis in [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]] {
        assert_eq!(PackedNormal::pack(axis).unpack(), Some(axis));
    }
    assert_eq!(PackedNormal::pack([0.0; 3]), PackedNormal::NONE);
    assert_eq!(PackedNormal::pack([f32::NAN, 0.0, 1.0]), PackedNormal::NONE);
    assert_eq!(PackedNormal::NONE.unpack(), None);
}

#[test]
fn storage_sizes() {
    assert_eq!(core::mem::size_of::<VoxelExtra>(), 6);
    assert_eq!(core::mem::size_of::<CoarseEntry>(), 12);
    assert_eq!(core::mem::size_of::<super::ModelPoint>(), 18);
    assert_eq!(core::mem::size_of::<super::CopiedLevel<8>>(), 8 * 22);
}

/// A model whose level 0 is copied out of the map (what a robot does to
/// reuse its map's memory) is the model whose level 0 is the map, to the
/// bit: the same levels, normals, cells and footprint, so the same match
/// with a prior and without. A room too small (or none) falls back to the
/// map.
#[test]
fn copied_model_matches_like_the_map_model() {
    use super::{CopiedLevel, SplitStorage};
    let mut m = new_map();
    corner(&mut m, &Isometry3::identity());
    let n = m.len();
    // The room holds the map's index: two slots per voxel of capacity (the
    // map's 32-bit slots hold values that fit 16 bits).
    assert_eq!(m.capacity(), 40_000);
    let t = from_xyz_rpy(1.2, -0.7, 0.0, 0.0, 0.0, 0.3);
    let mut scene_map = new_map();
    corner(&mut scene_map, &t.inverse());
    let scene = pyramid(&scene_map);
    let as_map = Pyramid::build(&m, 4, 1.0, heap_pyramid(n, 3 * n, 400_000)).unwrap();
    let mut room = std::boxed::Box::new(CopiedLevel::<40_000>::new());
    let copied =
        Pyramid::build_model(&m, 4, 1.0, SplitStorage { level0: &mut *room, rest: heap_pyramid(0, 3 * n, 400_000) })
            .unwrap();
    for l in 0..4 {
        let (a, b) = (as_map.level(l).unwrap(), copied.level(l).unwrap());
        assert_eq!(a.len(), b.len(), "level {l}");
        for (i, e) in a.iter().enumerate() {
            assert_eq!(Some(e), b.entry(i), "level {l} entry {i}");
            let (x, y): (Vec<Entry>, Vec<Entry>) = (a.cell(e.key).collect(), b.cell(e.key).collect());
            assert_eq!(x, y, "level {l}");
        }
        assert!(b.cell(crate::map::VoxelKey::new(i16::MAX, 0, 0)).next().is_none());
    }
    assert!(as_map.level(0).unwrap().iter().filter(|e| e.is_planar()).count() > n / 4);
    let (fa, fb) = (as_map.footprint().unwrap(), copied.footprint().unwrap());
    assert_eq!((fa.cell(), fa.has_pooled_grids()), (fb.cell(), fb.has_pooled_grids()));
    let start = from_xyz_rpy(1.0, -0.5, 0.0, 0.0, 0.0, 0.25);
    let a = Matcher::default().align(&as_map, &scene, &start).unwrap();
    let b = Matcher::default().align(&copied, &scene, &start).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.status, MatchStatus::Converged);
    let search = crate::matching::search::GlobalSearch::default();
    let ga = crate::matching::global::align_searched(&Matcher::default(), &as_map, &scene, &search, || {}).unwrap();
    let gb = crate::matching::global::align_searched(&Matcher::default(), &copied, &scene, &search, || {}).unwrap();
    assert_eq!(ga.0, gb.0);
    // Room for fewer points than the map: level 0 stays the map.
    let mut small = std::boxed::Box::new(CopiedLevel::<16>::new());
    let fallback =
        Pyramid::build_model(&m, 4, 1.0, SplitStorage { level0: &mut *small, rest: heap_pyramid(n, 3 * n, 400_000) })
            .unwrap();
    assert_eq!(Matcher::default().align(&fallback, &scene, &start).unwrap(), a);
}

#[test]
fn scene_role_pyramid_matches_like_a_model() {
    // A scene prepared as scene only gives the same answer as one prepared
    // for both roles; as a model it has no pooled grids, so no coarse search.
    let mut m = new_map();
    corner(&mut m, &Isometry3::identity());
    let full = pyramid(&m);
    let scene = Pyramid::build_as(&m, 4, 1.0, Role::Scene, heap_pyramid(m.len(), 3 * m.len(), 400_000)).unwrap();
    assert!(full.footprint().unwrap().has_pooled_grids());
    assert!(!scene.footprint().unwrap().has_pooled_grids());
    let start = from_xyz_rpy(0.4, -0.3, 0.0, 0.0, 0.0, 0.08);
    let a = Matcher::default().align(&full, &full, &start).unwrap();
    let b = Matcher::default().align(&full, &scene, &start).unwrap();
    assert_eq!(a.transform, b.transform);
}

/// The normal sweep (sorted cursors) gives the 27-lookup fit's normals to
/// the bit at every level, with room for level 0's permutation and its
/// entries gathered in sweep order, with room for the permutation alone
/// (read from the level), and without room (which falls back to lookups),
/// on a map that spans negative and positive cells on every axis.
#[test]
fn swept_normals_equal_looked_up_normals() {
    let mut m = new_map();
    corner(&mut m, &from_xyz_rpy(-2.5, 1.3, -0.7, 0.1, -0.05, 0.7));
    let mut seed = 7u32;
    let mut rnd = || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5
    };
    for k in 0..3000 {
        let p = [rnd() * 16.0, rnd() * 16.0, rnd() * 3.0];
        m.insert_point(p, [Class::Vegetation, Class::Terrain, Class::Car][k % 3]).unwrap();
    }
    let n = m.len();
    let roomy = Pyramid::build(&m, 3, 1.0, heap_pyramid(n, 3 * n, 400_000)).unwrap();
    let tight = Pyramid::build(&m, 3, 0.0, heap_pyramid(n, 3 * n, 0)).unwrap();
    let sorted = Pyramid::build(&m, 3, 0.0, heap_pyramid(n, 3 * n, 2 * n)).unwrap();
    let mut planar = 0;
    for l in 0..3 {
        let (a, b, c) = (roomy.level(l).unwrap(), tight.level(l).unwrap(), sorted.level(l).unwrap());
        assert_eq!(a.len(), b.len());
        for i in 0..a.len() {
            let e = a.entry(i).unwrap();
            assert_eq!(e.normal, b.entry(i).unwrap().normal, "level {l} entry {i}");
            assert_eq!(e.normal, c.entry(i).unwrap().normal, "level {l} entry {i}");
            assert_eq!(e.normal, super::pyramid::fit_normal_for_tests(&a, &e), "level {l} entry {i}");
            planar += usize::from(e.is_planar());
        }
    }
    assert!(planar > n / 2, "{planar} planar of {n}");
}

/// Two maps of one corner, the second seen 0.3 m, -0.2 m and 0.05 rad
/// away.
fn corners_apart() -> (Map, Map) {
    let mut a = new_map();
    corner(&mut a, &Isometry3::identity());
    let mut b = new_map();
    corner(&mut b, &from_xyz_rpy(0.3, -0.2, 0.0, 0.0, 0.0, 0.05));
    (a, b)
}

/// Placements in the plane, `(x, y, yaw)`, numbered.
fn placements(xy_yaw: &[(f32, f32, f32)]) -> impl Iterator<Item = (usize, Isometry3<f32>)> + '_ {
    xy_yaw.iter().map(|&(x, y, yaw)| from_xyz_rpy(x, y, 0.0, 0.0, 0.0, yaw)).enumerate()
}

/// The look-alike check's agreement-only pass gives the full pass's
/// agreement to the bit, aligned, shifted and far off.
#[test]
fn standing_agreement_equals_the_full_pass() {
    use super::associate::{agreement, standing_agreement};
    let (a, b) = corners_apart();
    let (pa, pb) = (pyramid(&a), pyramid(&b));
    let (m0, c0) = (pa.level(0).unwrap(), pb.level(0).unwrap());
    let cover = pa.level(2);
    let mut seen = 0;
    for (i, t) in
        placements(&[(0.0, 0.0, 0.0), (0.3, -0.2, 0.05), (1.0, 0.5, -0.1), (-2.0, 3.0, 0.4), (40.0, 0.0, 0.0)])
    {
        for stride in [1, 3] {
            let full = agreement(&m0, cover.as_ref(), &c0, &t, stride).agreement;
            assert_eq!(standing_agreement(&m0, cover.as_ref(), &c0, &t, stride), full, "case {i} stride {stride}");
            seen += usize::from(full > 0.0);
        }
        assert_eq!(standing_agreement(&m0, None, &c0, &t, 1), agreement(&m0, None, &c0, &t, 1).agreement);
    }
    assert!(seen >= 4, "{seen}");
}

/// The agreement pass skips a scene entry whose neighbourhood a coarser
/// level (the cover) says is empty, with the same inliers, overlap and
/// RMSE as looking up all 27 cells: aligned, partly overlapping (half the
/// scene's entries skipped) and far off, with covers two and four cells
/// wide.
#[test]
fn skipping_where_the_cover_is_empty_changes_no_agreement() {
    use super::associate::agreement;
    let (a, b) = corners_apart();
    let (pa, pb) = (pyramid(&a), pyramid(&b));
    let (m0, c0) = (pa.level(0).unwrap(), pb.level(0).unwrap());
    let mut matched = 0;
    for (i, t) in placements(&[(0.0, 0.0, 0.0), (0.3, -0.2, 0.05), (4.0, 1.5, 0.3), (-6.0, 3.0, 0.4), (40.0, 0.0, 0.0)])
    {
        for stride in [1, 3] {
            let every = agreement(&m0, None, &c0, &t, stride);
            for l in [1, 2] {
                let skipping = agreement(&m0, pa.level(l).as_ref(), &c0, &t, stride);
                assert_eq!(skipping.inliers, every.inliers, "case {i} stride {stride} cover level {l}");
                assert_eq!(skipping.overlap.to_bits(), every.overlap.to_bits(), "case {i} stride {stride} level {l}");
                assert_eq!(skipping.rmse.to_bits(), every.rmse.to_bits(), "case {i} stride {stride} level {l}");
            }
            matched += usize::from(every.inliers > 0);
        }
    }
    assert!(matched >= 6, "{matched}");
}

/// A received map kept as a [`crate::map::SceneMap`] (what a robot holds)
/// prepares into the same scene as the same voxels in a `LocalMap`, to the
/// bit: the same levels and footprint, so the same match, with a prior and
/// without; and a scene-only pyramid is refused as a model.
#[test]
fn scene_map_matches_like_the_local_map_it_holds() {
    use crate::map::{SceneMap, ScenePoint, VoxelSink};
    let mut model = new_map();
    corner(&mut model, &Isometry3::identity());
    let t = from_xyz_rpy(1.2, -0.7, 0.0, 0.0, 0.0, 0.3);
    let mut fine = new_map();
    corner(&mut fine, &t.inverse());
    // What a robot receives: the map through the link's encoding (a file's).
    let mut file = Vec::new();
    let header = crate::wire::mapfile::header_of(&fine, None, None);
    let mut chunk = vec![0u8; crate::wire::mapfile::FILE_CHUNK];
    crate::wire::mapfile::write(&fine, &header, &mut vec![0; fine.len()], &mut chunk, |b| {
        file.extend_from_slice(b);
        true
    })
    .unwrap();
    let mut m = new_map();
    crate::wire::mapfile::read_into(&file, &mut m).unwrap();
    assert_eq!(m.len(), fine.len());
    let mut scene = SceneMap::new(vec![ScenePoint::EMPTY; m.len()], m.resolution()).unwrap();
    // A voxel finer than the encoding's steps is refused, not rounded.
    assert_eq!(scene.accept(fine.voxels()[0]), Err(crate::map::InsertError::Inexact));
    for v in m.voxels() {
        scene.accept(*v).unwrap();
    }
    assert_eq!(scene.accept(m.voxels()[0]), Err(crate::map::InsertError::Full));
    let n = m.len();
    let pm = pyramid(&model);
    let as_map = Pyramid::build_as(&m, 4, 1.0, Role::Scene, heap_pyramid(n, 3 * n, 400_000)).unwrap();
    let cap = PyramidCapacity::for_scene(&scene, 4, 1.0);
    assert_eq!((cap.voxels, cap.slots), (0, 0));
    let as_scene = Pyramid::build_scene(&scene, 4, 1.0, VecPyramidStorage::new(cap)).unwrap();
    for l in 0..4 {
        let (a, b) = (as_map.level(l).unwrap(), as_scene.level(l).unwrap());
        assert_eq!(a.len(), b.len(), "level {l}");
        assert!(a.iter().zip(b.iter()).all(|(x, y)| x == y), "level {l}");
    }
    let (fa, fb) = (as_map.footprint().unwrap(), as_scene.footprint().unwrap());
    assert_eq!(fa.cell(), fb.cell());
    let start = from_xyz_rpy(1.0, -0.5, 0.0, 0.0, 0.0, 0.25);
    let a = Matcher::default().align(&pm, &as_map, &start).unwrap();
    let b = Matcher::default().align(&pm, &as_scene, &start).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.status, MatchStatus::Converged);
    assert!((a.transform.translation.vector - t.translation.vector).norm() < 0.05, "{:?}", a.transform);
    let search = crate::matching::search::GlobalSearch::default();
    let ga = crate::matching::global::align_searched(&Matcher::default(), &pm, &as_map, &search, || {}).unwrap();
    let gb = crate::matching::global::align_searched(&Matcher::default(), &pm, &as_scene, &search, || {}).unwrap();
    assert_eq!(ga.0, gb.0);
    assert_eq!(Matcher::default().align(&as_scene, &pm, &start), Err(MatchError::SceneAsModel));
}

/// Coarse levels indexed by 16-bit slots (a storage of fewer than
/// `NARROW_LIMIT` entries, as a robot's) find the same cells as 32-bit ones
/// (a large host storage), and merge into the same levels, so the same
/// match to the bit.
#[test]
fn narrow_and_wide_coarse_indexes_agree() {
    let mut m = new_map();
    corner(&mut m, &Isometry3::identity());
    let n = m.len();
    let narrow = Pyramid::build(&m, 4, 1.0, heap_pyramid(n, 3 * n, 400_000)).unwrap();
    let wide = Pyramid::build(&m, 4, 1.0, heap_pyramid(n, super::pyramid::NARROW_LIMIT, 400_000)).unwrap();
    assert!(3 * n < super::pyramid::NARROW_LIMIT);
    for l in 1..4 {
        let (a, b) = (narrow.level(l).unwrap(), wide.level(l).unwrap());
        assert_eq!(a.len(), b.len());
        for e in a.iter() {
            let (x, y): (Vec<Entry>, Vec<Entry>) = (a.cell(e.key).collect(), b.cell(e.key).collect());
            assert!(!x.is_empty() && x == y, "level {l}: {:?}", e.key);
            assert!(x.contains(&e));
        }
        assert!(a.cell(crate::map::VoxelKey::new(i16::MAX, i16::MAX, i16::MAX)).next().is_none());
    }
    let start = from_xyz_rpy(0.4, -0.3, 0.0, 0.0, 0.0, 0.08);
    let (ra, rb) = (
        Matcher::default().align(&narrow, &narrow, &start).unwrap(),
        Matcher::default().align(&wide, &wide, &start).unwrap(),
    );
    assert_eq!(ra, rb);
}

/// From a fix, `track_in` corrects what a bare street constrains (across
/// it, the heading) and holds what it does not (along it) where the fix
/// put it: the answer is not Degenerate, its degeneracy says how weakly
/// the maps hold it. `align` from the same start finds it Degenerate.
#[test]
fn tracking_holds_what_a_street_leaves_free_at_the_fix() {
    // The scene's part of the street ends well inside the model's: no end
    // holds it along the street.
    let (gt, model, scene) = street_pair(false);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    // The fix: 0.4 m along the street, 0.1 m across it and 0.3 degrees off
    // (within a cell: these maps are of 0.2 m).
    let fix = from_xyz_rpy(0.4, 0.1, 0.0, 0.0, 0.0, 0.3f32.to_radians()) * gt;
    let m = Matcher::default();
    let none = &mut search::SearchScratch::new(&mut []);
    let held = m.track_in(&pm, &ps, &fix, none).unwrap();
    assert_eq!(held.status, MatchStatus::Converged, "{held:?}");
    assert!(held.degeneracy < m.settings.degeneracy_threshold, "{held:?}");
    let off = held.transform * gt.inverse();
    let (along, across) = (off.translation.vector.x, off.translation.vector.y);
    assert!((along - 0.4).abs() < 0.05, "along the street: {along} (the fix: 0.4)");
    assert!(across.abs() < 0.05 && off.rotation.angle().to_degrees() < 0.2, "{off:?}");
    assert_eq!(m.align(&pm, &ps, &fix).unwrap().status, MatchStatus::Degenerate);
    // Bit for bit repeatable.
    assert_eq!(m.track_in(&pm, &ps, &fix, none).unwrap(), held);
    // Its verdict reads the scene at twice a match's stride (a matcher
    // whose sample is a few hundred entries, well under the scene's).
    use super::associate::agreement;
    let small = Matcher::new(MatchSettings { max_agreement_entries: 300, ..MatchSettings::DEFAULT });
    let tracked = small.track_in(&pm, &ps, &fix, none).unwrap();
    let (m0, c0, cover) = (pm.level(0).unwrap(), ps.level(0).unwrap(), pm.level(3));
    assert!(c0.len() > 1000, "{}", c0.len());
    let read = |n: usize| agreement(&m0, cover.as_ref(), &c0, &tracked.transform, c0.len().div_ceil(n));
    assert_eq!((tracked.inliers, tracked.overlap), (read(150).inliers, read(150).overlap));
    assert_ne!((tracked.inliers, tracked.overlap), (read(300).inliers, read(300).overlap));
}

/// From a fix a round's drift off (a few centimetres, a tenth of a
/// degree, or most of a cell and 0.4 degrees), tracking's looser stop
/// ([`em::TRACKED_TOLERANCE_SCALE`]) lands within a centimetre and 0.02
/// degrees of EM run to a tenth of that tolerance, in no more iterations
/// (fewer over the three).
#[test]
fn tracking_stops_early_where_tighter_steps_would_not_move_it() {
    let (gt, model, scene) = street_pair(true);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    let m = Matcher::default();
    let s = m.settings;
    let tight = Matcher::new(MatchSettings {
        translation_tolerance: s.translation_tolerance / em::TRACKED_TOLERANCE_SCALE,
        rotation_tolerance: s.rotation_tolerance / em::TRACKED_TOLERANCE_SCALE,
        ..s
    });
    let none = &mut search::SearchScratch::new(&mut []);
    let mut iterations = (0, 0);
    for fix in [
        from_xyz_rpy(0.05, -0.03, 0.0, 0.0, 0.0, 0.1f32.to_radians()) * gt,
        from_xyz_rpy(-0.04, 0.06, 0.02, 0.0, 0.0, -0.15f32.to_radians()) * gt,
        from_xyz_rpy(0.12, 0.1, 0.0, 0.0, 0.0, 0.4f32.to_radians()) * gt,
    ] {
        let (quick, slow) = (m.track_in(&pm, &ps, &fix, none).unwrap(), tight.track_in(&pm, &ps, &fix, none).unwrap());
        assert_eq!((quick.status, slow.status), (MatchStatus::Converged, MatchStatus::Converged));
        let apart = quick.transform * slow.transform.inverse();
        assert!(apart.translation.vector.norm() < 0.01, "{apart:?}");
        assert!(apart.rotation.angle().to_degrees() < 0.02, "{apart:?}");
        assert!(quick.iterations <= slow.iterations, "{} against {}", quick.iterations, slow.iterations);
        iterations.0 += quick.iterations;
        iterations.1 += slow.iterations;
        // Both right: the street's poles hold it along.
        let off = quick.transform * gt.inverse();
        assert!(off.translation.vector.norm() < 0.05 && off.rotation.angle().to_degrees() < 0.1, "{off:?}");
    }
    assert!(iterations.0 < iterations.1, "{iterations:?}");
}

/// Pyramids prepared for tracking only (a model's levels up to its cover,
/// normals at level 0; a scene's level 0; no footprints) track as the
/// whole ones do, bit for bit, from a fix right or off; a search, or EM
/// down the levels, refuses them.
#[test]
fn pyramids_prepared_for_tracking_track_as_whole_ones_and_refuse_a_search() {
    let (gt, model, scene) = street_pair(true);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    let tm = Pyramid::build_vec_tracked(&model, Role::Model).unwrap();
    let ts = Pyramid::build_vec_tracked(&scene, Role::Scene).unwrap();
    assert!(tm.is_tracked() && ts.is_tracked() && !pm.is_tracked());
    // 0.2 m cells: 0.2 m and the cover, 1.6 m, as the whole pyramid's.
    assert_eq!((tm.levels(), ts.levels()), (2, 1));
    assert_eq!(tm.level(1).map(|l| l.resolution()), pm.level(3).map(|l| l.resolution()));
    assert!(tm.footprint().is_none() && ts.footprint().is_none());
    let m = Matcher::default();
    for fix in [
        gt,
        from_xyz_rpy(0.4, 0.1, 0.0, 0.0, 0.0, 0.3f32.to_radians()) * gt,
        from_xyz_rpy(3.0, 2.0, 0.0, 0.0, 0.0, 0.2) * gt,
    ] {
        let whole = m.track_in(&pm, &ps, &fix, &mut search::SearchScratch::new(&mut [])).unwrap();
        // With EM's memory of the blocks, for every entry and for a few.
        for n in [m.settings.max_scene_entries as usize, 50] {
            let mut reach = vec![Reach::EMPTY; n];
            let scratch = &mut search::SearchScratch::new(&mut []).with_reach(&mut reach);
            assert_eq!(m.track_in(&tm, &ts, &fix, scratch).unwrap(), whole);
            assert_eq!(m.track_in(&tm, &ps, &fix, scratch).unwrap(), whole);
        }
        // The model's normals left to EM: kept for every entry, for a few
        // (the rest fitted again each time) or for none; twice with one
        // room (emptied for each match).
        let lazy = Pyramid::build_vec_tracked_lazy(&model).unwrap();
        assert!(lazy.is_lazy() && lazy.is_tracked() && !tm.is_lazy());
        let unfit = lazy.level(0).unwrap().iter().filter(|e| e.normal == PackedNormal::UNFIT).count();
        assert_eq!(unfit, model.len());
        for n in [model.len(), 100, 0] {
            let mut normals = vec![PackedNormal::NONE; n];
            let mut reach = vec![Reach::EMPTY; m.settings.max_scene_entries as usize];
            let scratch = &mut search::SearchScratch::new(&mut []).with_reach(&mut reach).with_normals(&mut normals);
            assert_eq!(m.track_in(&lazy, &ts, &fix, scratch).unwrap(), whole);
            assert_eq!(m.track_in(&lazy, &ts, &fix, scratch).unwrap(), whole);
        }
    }
    assert_eq!(m.align(&tm, &ps, &gt), Err(MatchError::TrackingOnly));
    assert_eq!(m.align(&pm, &ts, &gt), Err(MatchError::TrackingOnly));
    let how = Alignment::default();
    let mut words = vec![0u32; search::SearchScratch::WINDOWED];
    let mut scratch = search::SearchScratch::new(&mut words);
    let searched = align_prepared(&tm, &ts, None, &how, &mut scratch, || {});
    assert_eq!(searched.map(|r| r.0), Err(MatchError::TrackingOnly));
}

#[test]
fn a_placement_that_agrees_with_nothing_is_not_refined_at_the_finest_level() {
    let gt = from_xyz_rpy(1.5, -0.7, 0.05, 0.0, 0.0, 0.2);
    let (model, scene) = corner_seen_from(&gt);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    // Handed down 30 m off, where nothing of the model stands: judged at
    // once, never Converged.
    // (No search of a window around it: EM from where it is put.)
    let em = Matcher::new(MatchSettings { search: None, ..MatchSettings::default() });
    let far = from_xyz_rpy(30.0, 0.0, 0.0, 0.0, 0.0, 0.0) * gt;
    let r = em.align(&pm, &ps, &far).unwrap();
    assert_eq!(r.iterations_per_level[0], 0, "{r:?}");
    assert_ne!(r.status, MatchStatus::Converged, "{r:?}");
    // Near the truth it agrees at once and is refined there.
    let near = from_xyz_rpy(0.3, -0.2, 0.0, 0.0, 0.0, 0.02) * gt;
    let r = em.align(&pm, &ps, &near).unwrap();
    assert!(r.iterations_per_level[0] > 0, "{r:?}");
    assert_eq!(r.status, MatchStatus::Converged, "{r:?}");
}

/// A work budget that pays for everything changes nothing; one that does
/// not is never spent past its limit and never yields `Converged` where it
/// cut: a windowed alignment cut in EM is `NotConverged`, a prior-free one
/// cut before its first placement is judged is `NotConverged` too, and
/// the meter says both were refused.
#[test]
fn a_work_budget_bounds_a_match_and_never_passes_a_cut_answer() {
    use super::search::SearchScratch;
    let gt = from_xyz_rpy(1.5, -0.7, 0.05, 0.0, 0.0, 0.2);
    let (model, scene) = corner_seen_from(&gt);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    let costs = WorkCosts {
        fine_iteration: 2_000,
        coarse_iteration: 1_000,
        placement: 10_000,
        global_node: 5,
        window_node: 20,
    };
    let start = from_xyz_rpy(2.0, 1.0, 0.0, 0.0, 0.0, 0.3) * gt;
    let search = crate::matching::search::GlobalSearch::default();
    let run = |limit: Option<u64>| {
        let mut words = vec![0u32; SearchScratch::WINDOWED];
        let mut work = limit.map_or(Work::UNBOUNDED, |l| Work::new(costs, l));
        let mut scratch = SearchScratch::new(&mut words).with_work(&mut work);
        let windowed = Matcher::default().align_in(&pm, &ps, &start, &mut scratch).unwrap();
        let after_windowed = *scratch.work();
        let global =
            crate::matching::global::align_searched_in(&Matcher::default(), &pm, &ps, &search, || {}, &mut scratch)
                .unwrap()
                .0;
        (windowed, global, after_windowed, *scratch.work())
    };
    let (w, g, _, free) = run(None);
    assert_eq!((w.status, g.status), (MatchStatus::Converged, MatchStatus::Converged));
    assert!(!free.refused());
    // Counted but never short: the same answers.
    let (wm, gm, spent_w, spent) = run(Some(u64::MAX));
    assert_eq!((wm, gm), (w, g));
    assert!(!spent.refused() && spent_w.spent() > u64::from(costs.placement + 3 * costs.fine_iteration));
    assert!(spent.spent() > spent_w.spent());
    // Nothing, less than a placement, half of what the windowed match
    // takes, all of it but one, and that and a placement more (the
    // prior-free match cut).
    let whole = spent_w.spent();
    for limit in [0, u64::from(costs.placement) - 1, whole / 2, whole - 1, whole + u64::from(costs.placement)] {
        let (wc, gc, after_w, after) = run(Some(limit));
        assert!(after.spent() <= limit, "limit {limit}: spent {}", after.spent());
        assert!(after.refused(), "limit {limit}");
        assert_ne!(gc.status, MatchStatus::Converged, "limit {limit}: the prior-free match was cut: {gc:?}");
        if limit < whole {
            assert!(after_w.refused());
            assert_ne!(wc.status, MatchStatus::Converged, "limit {limit}: {wc:?}");
        } else {
            assert_eq!(wc, w);
        }
    }
}
