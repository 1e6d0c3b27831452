//! A map prepared for matching as far as a round needs it: for tracking
//! from a fix only what [`cosem_core::matching::Matcher::track_in`] reads
//! ([`prepare_tracked`]), whole only when a search is needed. Most rounds
//! of a session track, so most rounds skip the coarse levels' normals, the
//! levels above the model's cover and the footprints.

use crate::error::Error;
use crate::maps::mapping::HostMap;
use crate::matching::align::{prepare, prepare_scene, prepare_tracked, HostPyramid, DEFAULT_LEVELS};
use cosem_core::matching::Role;
use std::time::Instant;

/// One map, prepared as model or scene, tracked and whole each at most
/// once, with the seconds each took.
pub struct Prepared<'m> {
    map: &'m HostMap,
    role: Role,
    tracked: Option<(HostPyramid<'m>, f64)>,
    whole: Option<(HostPyramid<'m>, f64)>,
}

impl<'m> Prepared<'m> {
    /// Nothing prepared yet.
    pub fn new(map: &'m HostMap, role: Role) -> Self {
        Prepared { map, role, tracked: None, whole: None }
    }

    /// Prepared for tracking (the whole pyramid, when it is there: the same
    /// answers), and the seconds that took.
    pub fn tracked(&mut self) -> Result<(&HostPyramid<'m>, f64), Error> {
        if let Some((p, s)) = &self.whole {
            return Ok((p, *s));
        }
        if self.tracked.is_none() {
            let t = Instant::now();
            let p = prepare_tracked(self.map, self.role)?;
            self.tracked = Some((p, t.elapsed().as_secs_f64()));
        }
        let (p, s) = self.tracked.as_ref().ok_or_else(|| Error::Invalid("no pyramid".into()))?;
        Ok((p, *s))
    }

    /// Seconds spent preparing it so far (tracked and whole).
    pub fn spent(&self) -> f64 {
        self.tracked.as_ref().map_or(0.0, |t| t.1) + self.whole.as_ref().map_or(0.0, |w| w.1)
    }

    /// Whether it has been prepared whole.
    pub fn is_whole(&self) -> bool {
        self.whole.is_some()
    }

    /// Prepared whole, and the seconds that took.
    pub fn whole(&mut self) -> Result<(&HostPyramid<'m>, f64), Error> {
        if self.whole.is_none() {
            let t = Instant::now();
            let p = match self.role {
                Role::Model => prepare(self.map, DEFAULT_LEVELS)?,
                Role::Scene => prepare_scene(self.map, DEFAULT_LEVELS)?,
            };
            self.whole = Some((p, t.elapsed().as_secs_f64()));
        }
        let (p, s) = self.whole.as_ref().ok_or_else(|| Error::Invalid("no pyramid".into()))?;
        Ok((p, *s))
    }
}
