//! EM alignment: from far starts, with unknown classes, repeatable, the
//! verdict on a flat road and far-apart maps, bad input, and the finest
//! level skipped for a placement that agrees with nothing.

use super::*;

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
