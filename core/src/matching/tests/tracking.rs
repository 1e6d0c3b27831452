//! EM from a fix (`Matcher::track_in`): what a street leaves free held,
//! early stops, and pyramids prepared for tracking.

use super::*;

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
    let held = m.track_in(&pm, &ps, &fix, TrackStop::Coarse, none).unwrap();
    assert_eq!(held.status, MatchStatus::Converged, "{held:?}");
    assert!(held.degeneracy < m.settings.degeneracy_threshold, "{held:?}");
    let off = held.transform * gt.inverse();
    let (along, across) = (off.translation.vector.x, off.translation.vector.y);
    assert!((along - 0.4).abs() < 0.05, "along the street: {along} (the fix: 0.4)");
    assert!(across.abs() < 0.05 && off.rotation.angle().to_degrees() < 0.2, "{off:?}");
    assert_eq!(m.align(&pm, &ps, &fix).unwrap().status, MatchStatus::Degenerate);
    // Bit for bit repeatable.
    assert_eq!(m.track_in(&pm, &ps, &fix, TrackStop::Coarse, none).unwrap(), held);
    // Its verdict reads the scene at twice a match's stride (a matcher
    // whose sample is a few hundred entries, well under the scene's).
    use crate::matching::associate::agreement;
    let small = Matcher::new(MatchSettings { max_agreement_entries: 300, ..MatchSettings::DEFAULT });
    let tracked = small.track_in(&pm, &ps, &fix, TrackStop::Coarse, none).unwrap();
    let (m0, c0, cover) = (pm.level(0).unwrap(), ps.level(0).unwrap(), pm.level(3));
    assert!(c0.len() > 1000, "{}", c0.len());
    let read = |n: usize| agreement(&m0, cover.as_ref(), &c0, &tracked.transform, c0.len().div_ceil(n));
    assert_eq!((tracked.inliers, tracked.overlap), (read(150).inliers, read(150).overlap));
    assert_ne!((tracked.inliers, tracked.overlap), (read(300).inliers, read(300).overlap));
}

/// From a fix a round's drift off (a few centimetres, a tenth of a
/// degree, or most of a cell and 0.4 degrees), tracking's looser stop
/// ([`TrackStop::Coarse`]) lands within a centimetre and 0.02 degrees of EM
/// run to the match's own tolerances ([`TrackStop::Fine`]), in no more
/// iterations (fewer over the three).
#[test]
fn tracking_stops_early_where_tighter_steps_would_not_move_it() {
    let (gt, model, scene) = street_pair(true);
    let (pm, ps) = (pyramid(&model), pyramid(&scene));
    let m = Matcher::default();
    let none = &mut search::SearchScratch::new(&mut []);
    let mut iterations = (0, 0);
    for fix in [
        from_xyz_rpy(0.05, -0.03, 0.0, 0.0, 0.0, 0.1f32.to_radians()) * gt,
        from_xyz_rpy(-0.04, 0.06, 0.02, 0.0, 0.0, -0.15f32.to_radians()) * gt,
        from_xyz_rpy(0.12, 0.1, 0.0, 0.0, 0.0, 0.4f32.to_radians()) * gt,
    ] {
        let (quick, slow) = (
            m.track_in(&pm, &ps, &fix, TrackStop::Coarse, none).unwrap(),
            m.track_in(&pm, &ps, &fix, TrackStop::Fine, none).unwrap(),
        );
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
        let whole = m.track_in(&pm, &ps, &fix, TrackStop::Coarse, &mut search::SearchScratch::new(&mut [])).unwrap();
        // With EM's memory of the blocks, for every entry and for a few.
        for n in [m.settings.max_scene_entries as usize, 50] {
            let mut reach = vec![Reach::EMPTY; n];
            let scratch = &mut search::SearchScratch::new(&mut []).with_reach(&mut reach);
            assert_eq!(m.track_in(&tm, &ts, &fix, TrackStop::Coarse, scratch).unwrap(), whole);
            assert_eq!(m.track_in(&tm, &ps, &fix, TrackStop::Coarse, scratch).unwrap(), whole);
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
            assert_eq!(m.track_in(&lazy, &ts, &fix, TrackStop::Coarse, scratch).unwrap(), whole);
            assert_eq!(m.track_in(&lazy, &ts, &fix, TrackStop::Coarse, scratch).unwrap(), whole);
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
