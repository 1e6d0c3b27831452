//! Aligning two maps on the host: pyramids on the heap, sized for each
//! map, and one entry point with or without a prior (the robots' path,
//! [`cosem_core::robot::align`], with the host's capacities).

use crate::mapping::HostMap;
use cosem_core::geometry::Isometry3;
use cosem_core::matching::global::{align_searched, Searched};
use cosem_core::matching::search::GlobalSearch;
use cosem_core::matching::{MatchError, MatchResult, MatchSettings, Matcher, Pyramid, PyramidError, Role, VecPyramid};

/// Default number of pyramid levels: 0.2 m maps get cells up to 3.2 m.
pub const DEFAULT_LEVELS: usize = 5;

/// Default footprint cell (m) for the coarse search.
pub const FOOTPRINT_CELL: f32 = 1.0;

/// A map prepared for matching on the host (it borrows the map).
pub type HostPyramid<'m> = VecPyramid<'m>;

/// Prepares a map for matching, as model or scene, in storage sized for it.
pub fn prepare(map: &HostMap, levels: usize) -> Result<HostPyramid<'_>, PyramidError> {
    Pyramid::build_vec(map, levels, FOOTPRINT_CELL, Role::Model)
}

/// Why two maps could not be aligned.
#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    /// The matcher refused its input.
    #[error("matching: {0}")]
    Match(MatchError),
}

/// Aligns two prepared maps (`pyramids.0` the model): from `prior`
/// (`T_model_scene`) when given, else with none (the conventions) by the
/// core's prior-free alignment ([`align_searched`]) as the robots do; then
/// what its search found comes back too.
pub fn align(
    settings: MatchSettings,
    prior: Option<&Isometry3<f32>>,
    pyramids: (&HostPyramid<'_>, &HostPyramid<'_>),
) -> Result<(MatchResult, Option<Searched>), AlignError> {
    let matcher = Matcher::new(settings);
    match prior {
        Some(p) => Ok((matcher.align(pyramids.0, pyramids.1, p).map_err(AlignError::Match)?, None)),
        None => {
            align_searched(&matcher, pyramids.0, pyramids.1, &GlobalSearch::default(), || {}).map_err(AlignError::Match)
        }
    }
}
