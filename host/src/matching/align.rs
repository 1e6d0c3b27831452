//! Aligning two maps on the host: pyramids on the heap, sized for each
//! map, aligned by the one matching path the robots take too
//! ([`cosem_core::matching::align_prepared`]) with the host's
//! [`Alignment`] (its settings, the default search budget).

use crate::maps::mapping::HostMap;
use cosem_core::geometry::Isometry3;
use cosem_core::matching::global::Searched;
use cosem_core::matching::search::SearchScratch;
use cosem_core::matching::{align_prepared, Alignment, MatchError, MatchResult, Pyramid, Reach, Role, VecPyramid};
use cosem_core::pipeline::{Pipeline, Setting};

/// Default number of pyramid levels: 0.2 m maps get cells up to 3.2 m.
pub const DEFAULT_LEVELS: usize = Pipeline::HOST.levels;

/// Default footprint cell (m) for the coarse search.
pub const FOOTPRINT_CELL: f32 = Pipeline::HOST.footprint_cell;

/// A map prepared for matching on the host (it borrows the map).
pub type HostPyramid<'m> = VecPyramid<'m>;

/// Finest voxel size the matcher supports (m), that of a robot's map
/// ([`cosem_core::map::VOXEL_SIZES`]): its pyramid has at most
/// [`cosem_core::matching::MAX_LEVELS`] levels, and the coarsest must reach
/// the footprint's 1 m cells for the coarse search's answer to land in EM's
/// basin (0.02 m x 2^7 = 2.56 m).
pub const MIN_VOXEL: f32 = *cosem_core::map::VOXEL_SIZES.start();

/// Pyramid levels for maps of `resolution`: at least `levels`, and enough
/// that the coarsest cell reaches 3.2 m (0.2 m maps: 5 levels; 0.04 m: 8).
pub fn levels_for(resolution: f32, levels: usize) -> usize {
    let mut n = levels.max(1);
    while n < cosem_core::matching::MAX_LEVELS && resolution * ((1u32 << (n - 1)) as f32) < 3.2 {
        n += 1;
    }
    n
}

/// Prepares a map for matching, as model or scene, in storage sized for it,
/// with at least `levels` levels ([`levels_for`]). Maps finer than
/// [`MIN_VOXEL`] are refused with the reason.
pub fn prepare(map: &HostMap, levels: usize) -> Result<HostPyramid<'_>, crate::error::Error> {
    prepare_as(map, levels, Role::Model)
}

/// Prepares a map only ever matched as the scene ([`Role::Scene`]): no
/// normals fitted and no coarse level indexed (the matcher reads neither
/// of a scene), the same answers as [`prepare`]'s. A session's copy of a
/// peer's map is one (the robot's own map is the model).
pub fn prepare_scene(map: &HostMap, levels: usize) -> Result<HostPyramid<'_>, crate::error::Error> {
    prepare_as(map, levels, Role::Scene)
}

/// Prepares a map for tracking from a fix only
/// ([`cosem_core::matching::Pyramid::build_tracked`]): a model's levels up
/// to its cover, its level-0 normals left for EM to fit as it reads them
/// ([`cosem_core::matching::Pyramid::build_tracked_lazy`]), a scene's
/// level 0; what tracking reads, the same answers as from [`prepare`]'s
/// and [`prepare_scene`]'s.
pub fn prepare_tracked(map: &HostMap, role: Role) -> Result<HostPyramid<'_>, crate::error::Error> {
    voxel_checked(map)?;
    Ok(match role {
        Role::Model => Pyramid::build_vec_tracked_lazy(map)?,
        Role::Scene => Pyramid::build_vec_tracked(map, role)?,
    })
}

fn prepare_as(map: &HostMap, levels: usize, role: Role) -> Result<HostPyramid<'_>, crate::error::Error> {
    let r = voxel_checked(map)?;
    Ok(Pyramid::build_vec(map, levels_for(r, levels), FOOTPRINT_CELL, role)?)
}

/// The map's voxel size, where the matcher supports it.
fn voxel_checked(map: &HostMap) -> Result<f32, crate::error::Error> {
    let r = map.resolution();
    if Setting::Voxel.check(f64::from(r)).is_err() {
        return Err(crate::maps::mapping::BuildError::Voxel(r).into());
    }
    Ok(r)
}

/// Why two maps could not be aligned.
#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    /// The matcher refused its input.
    #[error("matching: {0}")]
    Match(MatchError),
}

impl crate::error::LayerError for AlignError {}

/// Aligns two prepared maps (`pyramids.0` the model): from `prior`
/// (`T_model_scene`) when given, else with none (the conventions) by the
/// core's prior-free alignment, through the one matching path
/// ([`align_prepared`]) as the robots do; then what its search found comes
/// back too. `how`: an [`Alignment`], or the matcher's settings alone
/// (with the host's search budget).
pub fn align(
    how: impl Into<Alignment>,
    prior: Option<&Isometry3<f32>>,
    pyramids: (&HostPyramid<'_>, &HostPyramid<'_>),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    let how: Alignment = how.into();
    let mut words = [0u32; SearchScratch::WINDOWED];
    // EM remembers the blocks its sampled entries reached (the same
    // answers, fewer lookups).
    let mut reach = vec![Reach::EMPTY; reach_room(&how)];
    let scratch = &mut SearchScratch::new(&mut words).with_reach(&mut reach);
    align_prepared(pyramids.0, pyramids.1, prior, &how, scratch, || {}).map_err(AlignError::Match)
}

/// EM's room to remember the blocks of its sampled scene entries
/// ([`SearchScratch::with_reach`]): one per entry the settings sample, at
/// most 65,536 (beyond, the rest are looked up each iteration).
pub fn reach_room(how: &Alignment) -> usize {
    (how.settings.max_scene_entries as usize).min(1 << 16)
}

/// Two maps prepared and matched, with the times it took: what `cosem
/// match` and `cosem link` report.
pub struct TimedMatch {
    /// The match (`T_model_scene`).
    pub result: MatchResult,
    /// What the prior-free search found (no prior only).
    pub global: Option<Searched>,
    /// Milliseconds preparing both maps.
    pub prepare_ms: f64,
    /// Milliseconds matching.
    pub match_ms: f64,
}

/// Prepares `model` and `scene` (an error names the map by `names`) and
/// aligns them as [`align`] does, timing both steps.
pub fn prepare_and_align(
    model: &HostMap,
    scene: &HostMap,
    names: [&str; 2],
    how: Alignment,
    prior: Option<&Isometry3<f32>>,
) -> Result<TimedMatch, crate::error::Error> {
    let named = |name: &str, e: crate::error::Error| crate::error::Error::Invalid(format!("{name}: {e}"));
    let t0 = std::time::Instant::now();
    let pm = prepare(model, DEFAULT_LEVELS).map_err(|e| named(names[0], e))?;
    let ps = prepare(scene, DEFAULT_LEVELS).map_err(|e| named(names[1], e))?;
    let prepare_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = std::time::Instant::now();
    let (result, global) = align(how, prior, (&pm, &ps))?;
    Ok(TimedMatch { result, global, prepare_ms, match_ms: t1.elapsed().as_secs_f64() * 1e3 })
}
