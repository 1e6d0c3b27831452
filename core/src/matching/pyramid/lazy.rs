//! A tracked model whose level-0 normals are fitted as EM reads them. EM
//! from a fix reads the normals of the model entries the scene's sampled
//! entries match, about a sixth of a robot's map where two robots meet;
//! fitting every normal each round was a quarter of a tracking round.

use super::*;

/// How far a pyramid is prepared ([`Pyramid::build_base`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Prep {
    /// Every level the caller asks for, normals at each (a model's).
    Whole,
    /// For tracking ([`Pyramid::build_tracked`]).
    Tracked,
    /// For tracking, level 0's normals left to fit
    /// ([`Pyramid::build_tracked_lazy`]).
    Lazy,
}

impl PackedNormal {
    /// Not fitted yet ([`Pyramid::build_tracked_lazy`]): never a packed
    /// direction (a coordinate of -32768), nor [`PackedNormal::NONE`].
    pub const UNFIT: PackedNormal = PackedNormal([i16::MIN, 0]);
}

/// The normal of `e`, the entry `index` of `level` (level 0 of a model):
/// one left [`PackedNormal::UNFIT`] is fitted here ([`fit_normal`]: the
/// same normal the pyramid would have fitted, to the bit) and kept in
/// `memo` (by index, [`PackedNormal::UNFIT`] where not fitted yet) when it
/// has room for it.
#[inline]
pub(crate) fn normal_of(level: &Level<'_>, e: &Entry, index: u32, memo: &mut [PackedNormal]) -> Option<[f32; 3]> {
    if e.normal != PackedNormal::UNFIT {
        return e.normal.unpack();
    }
    match memo.get_mut(index as usize) {
        Some(m) => {
            if *m == PackedNormal::UNFIT {
                *m = fit_normal(level, e);
            }
            m.unpack()
        }
        None => fit_normal(level, e).unpack(),
    }
}

impl<'m, S: PyramidStorage> Pyramid<'m, S> {
    /// [`Pyramid::build_tracked`] as a model with level 0's normals not
    /// fitted ([`PackedNormal::UNFIT`]): EM fits each as it first reads it
    /// (kept for the round in room the caller gives,
    /// [`crate::matching::search::SearchScratch::with_normals`]). Tracking
    /// from it gives what it gives from [`Pyramid::build_tracked`], bit for
    /// bit; a host robot prepares its map this way each round it tracks.
    pub fn build_tracked_lazy<V: VoxelStorage>(map: &'m LocalMap<V>, storage: S) -> Result<Self, PyramidError> {
        let base = Base::Map { voxels: map.voxels(), index: map.index_slots() };
        let levels = Self::tracked_levels(map.resolution(), Role::Model);
        Self::build_base(base, map.resolution(), (levels, f32::NAN), Role::Model, Prep::Lazy, storage)
    }

    /// Whether level 0's normals are fitted as they are read
    /// ([`Pyramid::build_tracked_lazy`]).
    pub fn is_lazy(&self) -> bool {
        self.lazy
    }
}
