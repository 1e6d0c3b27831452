//! A pair robot's memory: two regions of words ([`crate::region`]) that
//! serve its stages in turn, handed from stage to stage by ownership, so a
//! board declares them once (two zeroed statics) and no stage can reach
//! another's buffers:
//!
//! - the **own** region holds the robot's map (voxels, then index slots)
//!   while it maps and sends; once the model's level 0 is copied out of the
//!   map, the map gives its storage back ([`LocalMap::into_storage`]) and
//!   its words hold the model's coarse levels, normals, index and
//!   footprint, and the scene's pyramid;
//! - the **turn** region holds the link's Morton scratch (one word per
//!   voxel) and the link's buffers while maps are exchanged; the endpoint
//!   gives both back whole ([`crate::link::Endpoint::finish`]) and they hold
//!   the model's copied level 0 (the scratch its index, the buffers' words
//!   its points).
//!
//! The sizes follow from a [`Capacity`]; [`Capacity::own_words`] and
//! [`Capacity::turn_words`] are `const`, so a board sizes its statics with
//! them.

use crate::link::LINK_WORDS;
use crate::map::{LocalMap, SemanticVoxel, SliceStorage};
use crate::matching::{CoarseEntry, ModelPoint, PackedNormal, PyramidPartsMut};
use crate::region::{words_for, words_of, Region, RegionError};
use bytemuck::Pod;

/// A robot's map: voxels and 16-bit index slots carved out of its own
/// region.
pub type OwnMap<'a> = LocalMap<SliceStorage<'a, u16>>;

/// The capacities of a pair robot: its map's voxels and, for a robot that
/// matches, its pyramids' coarse entries and footprint words (a sender's
/// are zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Capacity {
    /// Voxels of the robot's map (and of the model's copied level 0).
    pub voxels: usize,
    /// Coarse entries of each pyramid (model and scene).
    pub coarse: usize,
    /// Footprint words of the model's pyramid.
    pub model_words: usize,
    /// Footprint words of the scene's pyramid.
    pub scene_words: usize,
}

impl Capacity {
    /// The matching robot of the 512 KiB board ([`super::VOXELS`] voxels).
    pub const BOARD: Capacity = Capacity {
        voxels: super::VOXELS,
        coarse: super::COARSE,
        model_words: super::MODEL_WORDS,
        scene_words: super::SCENE_WORDS,
    };

    /// A robot that only sends its map ([`super::Robot::sender`]).
    pub const fn sender(voxels: usize) -> Capacity {
        Capacity { voxels, coarse: 0, model_words: 0, scene_words: 0 }
    }

    /// Whether the robot builds pyramids and matches.
    pub const fn matches(&self) -> bool {
        self.coarse > 0
    }

    /// Words of the map's voxels and of its index slots (two per voxel).
    const fn map_words(&self) -> [usize; 2] {
        [words_for::<SemanticVoxel>(self.voxels), words_for::<u16>(2 * self.voxels)]
    }

    /// Words of the pyramids' buffers, in the order they are carved
    /// ([`carve_pyramids`]): the model's entries, the scene's entries, the
    /// model's and the scene's footprint, the model's normals and index.
    const fn pyramid_words(&self) -> [usize; 6] {
        let e = self.coarse;
        [
            words_for::<CoarseEntry>(e),
            words_for::<CoarseEntry>(e),
            self.model_words,
            self.scene_words,
            words_for::<PackedNormal>(e),
            words_for::<u32>(e),
        ]
    }

    /// Words of the own region: the map, and beyond it whatever of the
    /// pyramids does not fit in the map's two buffers (first fit, in
    /// carving order).
    pub const fn own_words(&self) -> usize {
        let [voxels, slots] = self.map_words();
        let mut free = [voxels, slots];
        let mut beyond = 0;
        let need = self.pyramid_words();
        let mut i = 0;
        while i < need.len() {
            let n = need[i];
            if free[0] >= n {
                free[0] -= n;
            } else if free[1] >= n {
                free[1] -= n;
            } else {
                beyond += n;
            }
            i += 1;
        }
        voxels + slots + beyond
    }

    /// Words of the turn region: the Morton scratch (a word per voxel, then
    /// the copied level 0's index), and the larger of the link's buffers
    /// and the copied level 0's points.
    pub const fn turn_words(&self) -> usize {
        let points = if self.matches() { words_for::<ModelPoint>(self.voxels) } else { 0 };
        self.voxels + if points > LINK_WORDS { points } else { LINK_WORDS }
    }
}

/// What the robot keeps of its regions while it maps and sends: the
/// Morton scratch, the link's words (its buffers at their start) and the
/// own region beyond the map.
pub(super) struct Spare<'a> {
    pub(super) scratch: &'a mut [u32],
    pub(super) link: &'a mut [u32],
    pub(super) beyond: &'a mut [u32],
}

/// Carves the map and the spare buffers out of the two regions (checked
/// against `capacity`'s sizes).
pub(super) fn carve_map<'a>(
    own: &'a mut [u32],
    turn: &'a mut [u32],
    capacity: &Capacity,
) -> Result<(SliceStorage<'a, u16>, Spare<'a>), RegionError> {
    let (need_own, need_turn) = (capacity.own_words(), capacity.turn_words());
    if own.len() < need_own {
        return Err(RegionError::Short { need: need_own, have: own.len() });
    }
    if turn.len() < need_turn {
        return Err(RegionError::Short { need: need_turn, have: turn.len() });
    }
    let mut own = Region::new(own);
    let voxels = own.take::<SemanticVoxel>(capacity.voxels)?;
    let slots = own.take::<u16>(2 * capacity.voxels)?;
    let mut turn = Region::new(turn);
    let scratch = turn.take_words(capacity.voxels)?;
    Ok((SliceStorage { voxels, slots }, Spare { scratch, link: turn.into_words(), beyond: own.into_words() }))
}

/// Room for the model's copied level 0 in the turn region's buffers, given
/// back by the link: its points in the link's words, its index in the
/// scratch.
pub(super) fn carve_level0<'a>(
    scratch: &'a mut [u32],
    link: &'a mut [u32],
    capacity: &Capacity,
) -> Result<(&'a mut [ModelPoint], &'a mut [u16]), RegionError> {
    let points = Region::new(link).take::<ModelPoint>(capacity.voxels)?;
    let slots = Region::new(scratch).take::<u16>(2 * capacity.voxels)?;
    Ok((points, slots))
}

/// Takes `n` values of `T` from the first of `pool` with room (the order
/// [`Capacity::own_words`] plans with).
fn take_fit<'a, T: Pod>(pool: &mut [Region<'a>; 3], n: usize) -> Result<&'a mut [T], RegionError> {
    let words = words_for::<T>(n);
    let [a, b, c] = pool;
    let region = if a.len() >= words {
        a
    } else if b.len() >= words {
        b
    } else {
        c
    };
    region.take(n)
}

/// The model's (coarse levels, normals, index, footprint) and the scene's
/// pyramid storages, carved out of the map's storage once it is free and
/// the own region beyond it.
pub(super) fn carve_pyramids<'a>(
    map: SliceStorage<'a, u16>,
    beyond: &'a mut [u32],
    capacity: &Capacity,
) -> Result<(PyramidPartsMut<'a>, PyramidPartsMut<'a>), RegionError> {
    let SliceStorage { voxels, slots } = map;
    let mut pool = [Region::new(words_of(voxels)), Region::new(words_of(slots)), Region::new(beyond)];
    let e = capacity.coarse;
    // The order of `Capacity::pyramid_words`.
    let model_entries = take_fit::<CoarseEntry>(&mut pool, e)?;
    let scene_entries = take_fit::<CoarseEntry>(&mut pool, e)?;
    let model_words = take_fit::<u32>(&mut pool, capacity.model_words)?;
    let scene_words = take_fit::<u32>(&mut pool, capacity.scene_words)?;
    let normals = take_fit::<PackedNormal>(&mut pool, e)?;
    let model_slots = take_fit::<u32>(&mut pool, e)?;
    let model = PyramidPartsMut {
        extras: &mut [],
        entries: model_entries,
        normals,
        slots: model_slots,
        words: model_words,
        points: &mut [],
        point_slots: &mut [],
    };
    let scene = PyramidPartsMut {
        extras: &mut [],
        entries: scene_entries,
        normals: &mut [],
        slots: &mut [],
        words: scene_words,
        points: &mut [],
        point_slots: &mut [],
    };
    Ok((model, scene))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;

    /// The board's regions are today's statics (the own map's 224 KiB, the
    /// copied level 0's 176 KiB), and every buffer is carved from them with
    /// not a word to spare where the plan says so.
    #[test]
    fn board_regions_carve_every_stage() {
        let c = Capacity::BOARD;
        assert_eq!(c.own_words() * 4, 229_376);
        assert_eq!(c.turn_words() * 4, 180_224);
        let (mut own, mut turn) = (vec![0u32; c.own_words()], vec![0u32; c.turn_words()]);
        let (map, spare) = carve_map(&mut own, &mut turn, &c).unwrap();
        assert_eq!((map.voxels.len(), map.slots.len()), (c.voxels, 2 * c.voxels));
        assert!(spare.link.len() >= LINK_WORDS);
        let (points, slots) = carve_level0(spare.scratch, spare.link, &c).unwrap();
        assert_eq!((points.len(), slots.len()), (c.voxels, 2 * c.voxels));
        let (model, scene) = carve_pyramids(map, spare.beyond, &c).unwrap();
        assert_eq!((model.entries.len(), model.normals.len(), model.slots.len()), (c.coarse, c.coarse, c.coarse));
        assert_eq!((model.words.len(), scene.words.len()), (c.model_words, c.scene_words));
        // A word short of either region is an error, not a smaller robot.
        let (mut own, mut turn) = (vec![0u32; c.own_words() - 1], vec![0u32; c.turn_words()]);
        assert!(carve_map(&mut own, &mut turn, &c).is_err());
        let (mut own, mut turn) = (vec![0u32; c.own_words()], vec![0u32; c.turn_words() - 1]);
        assert!(carve_map(&mut own, &mut turn, &c).is_err());
    }

    /// Pyramids larger than the map's buffers spill beyond the map, as the
    /// plan sizes the region.
    #[test]
    fn pyramids_that_outgrow_the_map_spill_beyond_it() {
        let c = Capacity { voxels: 1000, coarse: 900, model_words: 3000, scene_words: 2000 };
        assert!(c.own_words() > 7 * c.voxels);
        let (mut own, mut turn) = (vec![0u32; c.own_words()], vec![0u32; c.turn_words()]);
        let (map, spare) = carve_map(&mut own, &mut turn, &c).unwrap();
        assert!(carve_pyramids(map, spare.beyond, &c).is_ok());
        let s = Capacity::sender(1000);
        assert_eq!(s.own_words(), 7000);
        assert_eq!(s.turn_words(), 1000 + LINK_WORDS);
    }
}
