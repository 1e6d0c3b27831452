//! Prior-free alignment: no prior, the maps alone. The coarse search over
//! every heading and offset ([`search_global`](super::search::search_global), branch and bound over the
//! footprints' class groups) proposes a few distinct placements, best
//! first; the matcher refines them in turn until one passes its verdict
//! (`Converged`: the maps agree where both saw standing structure, see
//! `MatchSettings::min_agreement`). None passing is an honest `NoOverlap`,
//! never a guess.

use super::search::{search_global_in, Candidate, GlobalSearch, GlobalSearchOutcome, SearchScratch};
use super::{MatchError, MatchResult, MatchSettings, MatchStatus, Matcher, Method, Pyramid, PyramidStorage};
use nalgebra::Isometry3;

/// What the prior-free alignment tried.
#[derive(Clone, Debug, PartialEq)]
pub struct Searched {
    /// The coarse search's candidates and effort.
    pub search: GlobalSearchOutcome,
    /// The candidate whose refinement is the answer (the first that passed
    /// the verdict, else the best).
    pub chosen: usize,
    /// Candidates refined.
    pub refined: usize,
}

impl From<&Searched> for crate::wire::feed::GlobalReport {
    fn from(s: &Searched) -> Self {
        let (score, runner_up) = s.search.scores();
        crate::wire::feed::GlobalReport {
            score,
            runner_up,
            refined: s.refined.min(255) as u8,
            chosen: s.chosen.min(255) as u8,
            evaluations: s.search.evaluations,
        }
    }
}

/// Aligns two prepared maps with no prior: the coarse search over every
/// heading and offset ([`search_global`](super::search::search_global)) gives a few distinct candidates,
/// best first; each is refined by the matcher (a narrow search window
/// around it, then EM) until one passes the matcher's verdict
/// (`Converged`). None passing: the best candidate's result, whatever its
/// status. Both searches together score at most
/// [`GlobalSearch::max_evaluations`] nodes. `None` with `NoOverlap` when a map has no footprint or the scene
/// no occupied cell. `searched` runs after the first search (e.g. to read
/// an instruction counter).
pub fn align_searched<A: PyramidStorage, B: PyramidStorage>(
    matcher: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    settings: &GlobalSearch,
    searched: impl FnMut(),
) -> Result<(MatchResult, Option<Searched>), MatchError> {
    let mut words = [0u32; SearchScratch::WINDOWED];
    align_searched_in(matcher, model, scene, settings, searched, &mut SearchScratch::new(&mut words))
}

/// [`align_searched`] with the searches' caches in `scratch` (at least
/// [`SearchScratch::global`] words for `settings`: fewer, no search and
/// `NoOverlap`; see [`Matcher::align_in`] for the windowed searches').
pub fn align_searched_in<A: PyramidStorage, B: PyramidStorage>(
    matcher: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    settings: &GlobalSearch,
    mut searched: impl FnMut(),
    scratch: &mut SearchScratch<'_>,
) -> Result<(MatchResult, Option<Searched>), MatchError> {
    super::em::whole(model, scene)?;
    let semantic = matcher.settings.method != Method::Geometric;
    let (Some(fm), Some(fs)) = (model.footprint(), scene.footprint()) else {
        return Ok((MatchResult::no_overlap(), None));
    };
    let local = Matcher::new(MatchSettings { search: Some(settings.refinement_window()), ..matcher.settings });
    // No search where a work budget could not pay for one: not judged.
    let unpaid = |scratch: &SearchScratch<'_>| {
        let r = if scratch.work().refused() {
            MatchResult::not_judged(Isometry3::identity())
        } else {
            MatchResult::no_overlap()
        };
        Ok((r, None))
    };
    // One search for the few best, each refined in turn (not the best
    // alone first: `GlobalSearch::best_alone_first`).
    if !settings.best_alone_first {
        let Some(search) = search_global_in(fm, fs, settings, semantic, scratch) else {
            return unpaid(scratch);
        };
        searched();
        return refine_in_turn(&local, model, scene, search, None, settings.exclusion, scratch);
    }
    // The best placement alone first (the cheap search); only when its
    // refinement fails, the few best distinct ones, with what is left of
    // the node budget. The second search explores the first one's tree
    // again before anything beyond it (its floor is lower), so it runs
    // only with more nodes left than the first took: not when the first
    // search took more than half the budget, as maps that share nothing
    // do (they prune little; their best placements are no better than
    // their runner-ups).
    let one = GlobalSearch { candidates: 1, ..*settings };
    let Some(search) = search_global_in(fm, fs, &one, semantic, scratch) else {
        return unpaid(scratch);
    };
    searched();
    // No placement at all (nothing in common, or the budget spent before
    // the first): what the search did comes back, nothing refined.
    let Some(best) = search.candidates.first().copied() else {
        return Ok((MatchResult::no_overlap(), Some(Searched { search, chosen: 0, refined: 0 })));
    };
    let first = local.align_in(model, scene, &best.transform, scratch)?;
    let left = settings.max_evaluations.saturating_sub(search.evaluations);
    if first.status == MatchStatus::Converged || settings.candidates <= 1 || left <= search.evaluations {
        return Ok((first, Some(Searched { search, chosen: 0, refined: 1 })));
    }
    let spent = search.evaluations;
    let more = search_global_in(fm, fs, &GlobalSearch { max_evaluations: left, ..*settings }, semantic, scratch);
    let Some(mut more) = more else {
        return Ok((first, Some(Searched { search, chosen: 0, refined: 1 })));
    };
    more.evaluations = more.evaluations.saturating_add(spent);
    refine_in_turn(&local, model, scene, more, Some((best, first)), settings.exclusion, scratch)
}

/// Refines `search`'s candidates in turn, best first, until one passes the
/// verdict; `done`, a placement refined already and its result, is not
/// refined again (a cut second search may not have found it first, or at
/// all), and is the answer when none passes; otherwise the best
/// candidate's result is.
fn refine_in_turn<A: PyramidStorage, B: PyramidStorage>(
    local: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    search: GlobalSearchOutcome,
    done: Option<(Candidate, MatchResult)>,
    exclusion: (f32, f32),
    scratch: &mut SearchScratch<'_>,
) -> Result<(MatchResult, Option<Searched>), MatchError> {
    let same = |c: &Candidate, d: &Candidate| {
        let d = c.transform.inverse() * d.transform;
        d.translation.vector.xy().norm() < exclusion.0 && d.rotation.angle() < exclusion.1
    };
    let mut refined = usize::from(done.is_some());
    let mut answer = done.as_ref().map(|(_, r)| *r);
    for (k, c) in search.candidates.iter().enumerate() {
        if done.as_ref().is_some_and(|(d, _)| same(c, d)) {
            continue;
        }
        refined += 1;
        let r = local.align_in(model, scene, &c.transform, scratch)?;
        if r.status == MatchStatus::Converged {
            return Ok((r, Some(Searched { search, chosen: k, refined })));
        }
        answer.get_or_insert(r);
    }
    let answer = answer.unwrap_or_else(MatchResult::no_overlap);
    Ok((answer, Some(Searched { search, chosen: 0, refined })))
}

#[cfg(test)]
mod tests {
    use super::super::search::search_global;
    use super::*;
    use crate::classes::Class;
    use crate::geometry::from_xyz_rpy;
    use crate::matching::Role;
    use crate::test_util::heap_map;

    /// A street corner: a floor, two walls, a fence, poles and a tree, as a
    /// LiDAR at the origin would see it.
    fn corner(t: &crate::geometry::Isometry3<f32>) -> crate::map::VecMap {
        let mut m = heap_map(60_000, crate::map::MapConfig::with_resolution(0.5));
        let mut put = |p: [f32; 3], c: Class| {
            let q = crate::geometry::transform_point(t, p);
            let _ = m.insert_point(q, c);
        };
        for i in -60..60 {
            for j in -40i32..40 {
                put([i as f32 * 0.25, j as f32 * 0.25, -1.7], if j.abs() < 24 { Class::Road } else { Class::Sidewalk });
            }
            for k in 0..24 {
                put([i as f32 * 0.25, 11.0, -1.7 + k as f32 * 0.25], Class::Building);
            }
        }
        for j in -40..40 {
            for k in 0..12 {
                put([14.0, j as f32 * 0.25, -1.7 + k as f32 * 0.25], Class::Fence);
            }
        }
        for (x, y) in [(-8.0, -7.0), (3.0, -7.5), (9.0, 8.0), (-12.0, 7.0)] {
            for k in 0..20 {
                put([x, y, -1.7 + k as f32 * 0.25], Class::Pole);
            }
        }
        for a in 0..60 {
            let th = a as f32 * 0.1;
            put(
                [-4.0 + 1.5 * libm::cosf(th), 8.0 + 1.5 * libm::sinf(th), 2.0 + (a % 5) as f32 * 0.3],
                Class::Vegetation,
            );
        }
        m
    }

    /// The corner seen from the origin (the model) and from a frame turned
    /// by 150 degrees, 6 m away (the scene), and `T_model_scene`.
    fn turned_corner() -> (crate::map::VecMap, crate::map::VecMap, crate::geometry::Isometry3<f32>) {
        let t = from_xyz_rpy(6.0, -3.0, 0.0, 0.0, 0.0, 150f32.to_radians());
        (corner(&crate::geometry::Isometry3::identity()), corner(&t.inverse()), t)
    }

    /// A map of only a floor and a wall of `class` somewhere else.
    fn floor_and_wall(class: Class, y: impl Fn(i32) -> f32) -> crate::map::VecMap {
        let mut other = heap_map(20_000, crate::map::MapConfig::with_resolution(0.5));
        for i in -40..40 {
            for k in 0..16 {
                let _ = other.insert_point([i as f32 * 0.25, y(i), k as f32 * 0.25], class);
                let _ = other.insert_point([i as f32 * 0.25, k as f32 * 0.5, -1.7], Class::Terrain);
            }
        }
        other
    }

    fn build(m: &crate::map::VecMap, role: Role) -> crate::matching::VecPyramid<'_> {
        crate::matching::Pyramid::build_vec(m, 3, 1.0, role).unwrap()
    }

    #[test]
    fn finds_a_turned_and_shifted_scene_and_refuses_another_place() {
        let (model, scene, t) = turned_corner();
        let (pm, ps) = (build(&model, Role::Model), build(&scene, Role::Scene));
        let matcher = Matcher::new(MatchSettings::default());
        let (r, found) = align_searched(&matcher, &pm, &ps, &GlobalSearch::default(), || {}).unwrap();
        assert_eq!(r.status, MatchStatus::Converged, "{r:?}");
        let d = r.transform * t.inverse();
        assert!(d.translation.vector.norm() < 0.1 && d.rotation.angle() < 0.01, "{d:?}");
        assert!(found.is_some_and(|f| f.search.evaluations > 0));
        // A map of only a floor and a wall elsewhere: refused, not guessed.
        let other = floor_and_wall(Class::Vegetation, |i| -6.0 + (i % 7) as f32);
        let po = build(&other, Role::Scene);
        let (r, _) = align_searched(&matcher, &pm, &po, &GlobalSearch::default(), || {}).unwrap();
        assert_ne!(r.status, MatchStatus::Converged, "{r:?}");
    }

    /// One search for the few best, refined in turn: the search is the
    /// one that keeps them all (no first search for the best alone), the
    /// right placement is found as with the best alone first, and when
    /// none passes every candidate was refined and the best's result is
    /// the answer.
    #[test]
    fn one_search_for_the_few_best_refines_them_in_turn() {
        let (model, scene, _) = turned_corner();
        let (pm, ps) = (build(&model, Role::Model), build(&scene, Role::Scene));
        let matcher = Matcher::new(MatchSettings::default());
        let settings = GlobalSearch { best_alone_first: false, max_evaluations: 200_000, ..GlobalSearch::default() };
        let (r, found) = align_searched(&matcher, &pm, &ps, &settings, || {}).unwrap();
        let (r0, _) = align_searched(&matcher, &pm, &ps, &GlobalSearch::default(), || {}).unwrap();
        assert_eq!(r.status, MatchStatus::Converged, "{r:?}");
        assert_eq!(r.transform, r0.transform);
        let found = found.unwrap();
        let alone = search_global(pm.footprint().unwrap(), ps.footprint().unwrap(), &settings, true).unwrap();
        assert_eq!(found.search, alone);
        assert!(alone.candidates.len() > 1, "{alone:?}");
        assert_eq!(found.refined, found.chosen + 1);
        // Nothing in common: every candidate refined, none passes.
        let other = floor_and_wall(Class::Fence, |i| 3.0 + (i % 5) as f32);
        let po = build(&other, Role::Scene);
        let (r, found) = align_searched(&matcher, &pm, &po, &settings, || {}).unwrap();
        let found = found.unwrap();
        assert_ne!(r.status, MatchStatus::Converged, "{r:?}");
        assert_eq!(found.refined, found.search.candidates.len());
        assert!(found.refined > 1, "{found:?}");
    }

    /// The node budget: a search that has it all finds what an unbounded
    /// one does; one cut short says so and keeps what it found; a cut first
    /// search leaves no second one, so the alignment refines once.
    #[test]
    fn the_node_budget_cuts_a_search_and_the_second_chance() {
        let (model, scene, _) = turned_corner();
        let (pm, ps) = (build(&model, Role::Model), build(&scene, Role::Scene));
        let (fm, fs) = (pm.footprint().unwrap(), ps.footprint().unwrap());
        let one = GlobalSearch { candidates: 1, ..GlobalSearch::default() };
        let budgeted = search_global(fm, fs, &one, true).unwrap();
        let unbounded = search_global(fm, fs, &GlobalSearch { max_evaluations: u32::MAX, ..one }, true).unwrap();
        assert!(!budgeted.exhausted && budgeted.evaluations < one.max_evaluations);
        assert_eq!(budgeted, GlobalSearchOutcome { exhausted: false, ..unbounded.clone() });
        let budget = unbounded.evaluations / 2;
        let cut = search_global(fm, fs, &GlobalSearch { max_evaluations: budget, ..one }, true).unwrap();
        assert!(cut.exhausted && cut.evaluations >= budget && cut.evaluations < budget + 8, "{cut:?}");
        assert!(!cut.candidates.is_empty());
        // Too few nodes for a second search: one refinement, whatever it says.
        let matcher = Matcher::new(MatchSettings::default());
        let tight = GlobalSearch { max_evaluations: budget, ..GlobalSearch::default() };
        let (_, found) = align_searched(&matcher, &pm, &ps, &tight, || {}).unwrap();
        let found = found.unwrap();
        assert_eq!(found.refined, 1);
        assert!(found.search.evaluations <= budget + 8);
    }
}
