//! The one matching path: two prepared maps aligned from a prior (the
//! windowed search, then EM) or without one (the prior-free search's best
//! placements, refined in turn), every answer through the verdict. The
//! robots (on the boards and in the host's twin runs), the host's commands
//! and the Python bindings all align here; what differs between them
//! (EM iterations, the search's budget, the method) is an [`Alignment`],
//! not another path.

use super::global::{align_searched_in, Searched};
use super::search::{GlobalSearch, SearchScratch};
use super::{MatchError, MatchResult, MatchSettings, Matcher, Pyramid, PyramidStorage};
use crate::geometry::Isometry3;

/// How two prepared maps are aligned: the matcher's settings, and the
/// prior-free search's when there is no prior.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    /// The matcher (method, degrees of freedom, EM iterations, verdict).
    pub settings: MatchSettings,
    /// The prior-free search (its budget of nodes among others).
    pub search: GlobalSearch,
}

impl Alignment {
    /// The matcher's and the search's defaults (the host's).
    pub const DEFAULT: Alignment = Alignment { settings: MatchSettings::DEFAULT, search: GlobalSearch::DEFAULT };
}

/// The matcher's settings with the default search (the host's budget).
impl From<MatchSettings> for Alignment {
    fn from(settings: MatchSettings) -> Self {
        Alignment { settings, ..Alignment::DEFAULT }
    }
}

impl Default for Alignment {
    fn default() -> Self {
        Alignment::DEFAULT
    }
}

/// Aligns `scene` to `model` (`T_model_scene`) from `prior`, or without
/// one by the prior-free search (whose findings come back too), as `how`
/// says, the searches' caches in `scratch`. `searched` runs once the
/// coarse search is done (before EM from a prior).
pub fn align_prepared<P: PyramidStorage, Q: PyramidStorage>(
    model: &Pyramid<'_, P>,
    scene: &Pyramid<'_, Q>,
    prior: Option<&Isometry3<f32>>,
    how: &Alignment,
    scratch: &mut SearchScratch<'_>,
    mut searched: impl FnMut(),
) -> Result<(MatchResult, Option<Searched>), MatchError> {
    let matcher = Matcher::new(how.settings);
    match prior {
        Some(p) => {
            searched();
            Ok((matcher.align_in(model, scene, p, scratch)?, None))
        }
        None => align_searched_in(&matcher, model, scene, &how.search, searched, scratch),
    }
}
