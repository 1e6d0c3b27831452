//! A round's work budget ([`Work`]) on the corner's matches: never spent
//! past its limit, never passing a cut answer.

use super::*;

/// A work budget that pays for everything changes nothing; one that does
/// not is never spent past its limit and never yields `Converged` where it
/// cut: a windowed alignment cut in EM is `NotConverged`, a prior-free one
/// cut before its first placement is judged is `NotConverged` too, and
/// the meter says both were refused.
#[test]
fn a_work_budget_bounds_a_match_and_never_passes_a_cut_answer() {
    use crate::matching::search::SearchScratch;
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
