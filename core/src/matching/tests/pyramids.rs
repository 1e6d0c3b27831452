//! The pyramid: packed normals, storage sizes, a copied or scene-role
//! level, swept normals, a received scene map and the coarse indexes, each
//! matching as the map model does.

use super::*;

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
            assert_eq!(e.normal, crate::matching::pyramid::fit_normal_for_tests(&a, &e), "level {l} entry {i}");
            planar += usize::from(e.is_planar());
        }
    }
    assert!(planar > n / 2, "{planar} planar of {n}");
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
    let wide = Pyramid::build(&m, 4, 1.0, heap_pyramid(n, crate::matching::pyramid::NARROW_LIMIT, 400_000)).unwrap();
    assert!(3 * n < crate::matching::pyramid::NARROW_LIMIT);
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
