//! A pair robot's memory: two regions of words ([`crate::region`]) that
//! serve its stages in turn, handed from stage to stage by ownership, so a
//! board declares them once (two zeroed statics) and no stage can reach
//! another's buffers:
//!
//! - the **own** region holds the robot's map (index slots, then voxels)
//!   while it maps and sends; then its voxels become the model's level 0
//!   where they lie ([`CopiedBase::compact`](crate::matching::CopiedBase::compact): an 18-byte point in place of
//!   each 24-byte voxel; the index stays), and what the points leave free
//!   holds pyramid buffers;
//! - the **turn** region holds the link's Morton scratch (one word per
//!   voxel) and, after it, the link's words (its buffers at their start)
//!   while maps are exchanged; the endpoint gives both back whole
//!   ([`crate::link::Endpoint::finish`]) and they hold the rest of the
//!   model's and the scene's pyramids.
//!
//! Where each pyramid buffer goes is planned once, for a full map, by
//! [`Capacity::plan`] (the smallest link region that takes what the other
//! two places cannot); the sizes are `const`, so a board sizes its statics
//! with [`Capacity::own_words`] and [`Capacity::turn_words`].

use crate::link::LINK_WORDS;
use crate::map::{LocalMap, SemanticVoxel, WordStorage};
use crate::matching::{CoarseEntry, ModelPoint, PackedNormal, PyramidPartsMut};
use crate::region::{words_for, Region, RegionError};
use bytemuck::Pod;

/// A robot's map: 16-bit index slots and voxels carved out of its own
/// region, the region's spare words kept after the voxels.
pub type OwnMap<'a> = LocalMap<WordStorage<'a>>;

/// The capacities of a pair robot: its map's voxels and, for a robot that
/// matches, its pyramids' coarse entries and footprint words (a sender's
/// are zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Capacity {
    /// Voxels of the robot's map (and of the model's level 0).
    pub voxels: usize,
    /// Coarse entries of each pyramid (model and scene).
    pub coarse: usize,
    /// Footprint words of the model's pyramid.
    pub model_words: usize,
    /// Footprint words of the scene's pyramid.
    pub scene_words: usize,
    /// Pyramid levels (level 0 the map): fewer levels, fewer coarse
    /// entries.
    pub levels: usize,
    /// Words of the own region after the map, for pyramid buffers: a board
    /// whose memories are split (an STM32F405's SRAM and CCM) fills the one
    /// that holds the map with them.
    pub spare_words: usize,
    /// Words of the searches' caches
    /// ([`SearchScratch`](crate::matching::search::SearchScratch)), carved
    /// with the pyramids; 0: on the stack
    /// ([`SearchScratch::WINDOWED`](crate::matching::search::SearchScratch::WINDOWED)
    /// words).
    pub search_words: usize,
    /// EM iterations its refinement may take: its compute budget
    /// ([`super::EM_ITERATIONS`] on the 512 KiB board).
    pub em_iterations: u32,
}

impl Capacity {
    /// The matching robot of the 512 KiB board ([`super::VOXELS`] voxels).
    pub const BOARD: Capacity = Capacity {
        voxels: super::VOXELS,
        coarse: super::COARSE,
        model_words: super::MODEL_WORDS,
        scene_words: super::SCENE_WORDS,
        levels: super::LEVELS,
        spare_words: 0,
        search_words: 0,
        em_iterations: super::EM_ITERATIONS,
    };

    /// The matching robot of an STM32F405 (128 KiB of SRAM and 64 KiB of
    /// core-coupled memory, each a region of its own): 0.7 m voxels
    /// ([`SMALL_VOXEL_M`]), 3,008 of them (28 bytes each in the map, 8 in
    /// the received one), pyramids of 3 levels with 0.66 coarse entries
    /// per voxel (a network's labels on maps that share nothing took up to
    /// 0.632), footprints of about 2 m cells, the searches' caches planned
    /// with the pyramids and 40 EM iterations. The own region (the map's
    /// index, its voxels, then [`Self::spare_words`]) and the received map
    /// fill the SRAM; the turn region (link, then pyramid buffers), the
    /// receive rings and the stack share the CCM. See
    /// `firmware/boards/stm32f405/README.md`.
    pub const STM32F405: Capacity = Capacity {
        voxels: SMALL_MATCHING_VOXELS,
        coarse: 1986,
        model_words: 1872,
        scene_words: SMALL_SCENE_WORDS,
        levels: super::LEVELS,
        // The SRAM's 128 KiB less the map (28 B a voxel) and the received
        // map (8 B a voxel).
        spare_words: (128 * 1024 - 36 * SMALL_MATCHING_VOXELS) / 4,
        // A cache for every cell a scene's footprint can list: its grid
        // and the list (three words a cell, one listed per 2 x 2 cells) fit
        // its words, so at most about 330 (a windowed search never thins
        // them).
        search_words: crate::matching::search::SearchScratch::windowed(512),
        // Its maps' refinements took up to 36 (kitti00 0:5 / 5:10, a
        // straight street, with a network's labels: 30 stopped one of them
        // short of the tolerance at the right answer); the others 11-23.
        em_iterations: crate::pipeline::Pipeline::STM32F405.alignment.settings.max_iterations,
    };

    /// A team robot of an STM32F405 ([`super::team::TeamRobot`]): it keeps
    /// its map through every round (the model's level 0 is the map and 6
    /// bytes a voxel of extras, not a copy) and solves the pose graph on
    /// its stack (44 KiB deep), so it holds fewer voxels than the pair
    /// robot: 1,760 (at 1 m, what a few scans' 25 m give). Its map, both pyramid storages, the
    /// received map and the scratch (the searches' caches while it
    /// matches) fill the SRAM; the link's buffers, the receive rings and
    /// the stack the CCM.
    pub const STM32F405_TEAM: Capacity = Capacity {
        voxels: 1760,
        coarse: 1162,
        model_words: 1100,
        scene_words: 1320,
        levels: super::LEVELS,
        spare_words: 0,
        search_words: 0,
        em_iterations: crate::pipeline::Pipeline::STM32F405_TEAM.alignment.settings.max_iterations,
    };

    /// A robot that only sends its map ([`super::Robot::sender`]).
    pub const fn sender(voxels: usize) -> Capacity {
        Capacity {
            voxels,
            coarse: 0,
            model_words: 0,
            scene_words: 0,
            levels: 0,
            spare_words: 0,
            search_words: 0,
            em_iterations: 0,
        }
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
    /// model's and the scene's footprint, the model's normals and index,
    /// the searches' caches.
    const fn pyramid_words(&self) -> [usize; PYRAMID_BUFFERS] {
        let e = self.coarse;
        [
            words_for::<CoarseEntry>(e),
            words_for::<CoarseEntry>(e),
            self.model_words,
            self.scene_words,
            words_for::<PackedNormal>(e),
            words_for::<u32>(e),
            self.search_words,
        ]
    }

    /// Words a full map's level 0 leaves free in the own region: what the
    /// points leave of the voxels' words, and the spare words after them.
    const fn level0_leaves(&self) -> usize {
        self.map_words()[0] - words_for::<ModelPoint>(self.voxels) + self.spare_words
    }

    /// Where each buffer goes: 0 the words the level 0 leaves in the own
    /// region, 1 the link's scratch, 2 the link's words; with the link's
    /// words that plan needs (at least the link's buffers). Of every
    /// placement (3^7), the one with the fewest link words.
    pub const fn plan(&self) -> Plan {
        let need = self.pyramid_words();
        let room = [self.level0_leaves(), self.voxels];
        let mut best = Plan { place: [LINK_ROOM; PYRAMID_BUFFERS], link_words: usize::MAX };
        let mut code = 0;
        while code < ROOMS.pow(PYRAMID_BUFFERS as u32) {
            let (mut used, mut place, mut c, mut i) = ([0usize; ROOMS], [0u8; PYRAMID_BUFFERS], code, 0);
            while i < PYRAMID_BUFFERS {
                place[i] = (c % ROOMS) as u8;
                used[c % ROOMS] += need[i];
                c /= ROOMS;
                i += 1;
            }
            let link = if used[2] > LINK_WORDS { used[2] } else { LINK_WORDS };
            if used[0] <= room[0] && used[1] <= room[1] && link < best.link_words {
                best = Plan { place, link_words: link };
            }
            code += 1;
        }
        best
    }

    /// Words of the own region: the map (its index, then its voxels), then
    /// the spare words.
    pub const fn own_words(&self) -> usize {
        let [voxels, slots] = self.map_words();
        voxels + slots + self.spare_words
    }

    /// Words of the turn region: the Morton scratch (a word per voxel),
    /// then the link's words ([`Capacity::plan`]; a sender's: its buffers).
    pub const fn turn_words(&self) -> usize {
        self.voxels + if self.matches() { self.plan().link_words } else { LINK_WORDS }
    }
}

/// Voxels of [`Capacity::STM32F405`]'s maps.
pub const SMALL_MATCHING_VOXELS: usize = 3008;
/// Footprint words of [`Capacity::STM32F405`]'s scene.
const SMALL_SCENE_WORDS: usize = 2256;
/// The voxel size (m) a robot of [`Capacity::STM32F405`] maps at: its few
/// voxels cover the 25 m a sensor sees around it (at 0.5 m they would
/// cover half as far, and its maps match worse).
pub const SMALL_VOXEL_M: f32 = crate::pipeline::Pipeline::STM32F405.voxel;

/// Buffers a robot carves when it aligns: the model's entries, normals,
/// index and footprint, the scene's entries and footprint, the searches'
/// caches.
const PYRAMID_BUFFERS: usize = 7;
/// Places a pyramid buffer may go ([`Plan::place`]).
const ROOMS: usize = 3;
/// The place that grows to take what the others cannot: the link's words.
const LINK_ROOM: u8 = 2;

/// Where a robot's pyramid buffers go ([`Capacity::plan`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    /// Per buffer, in carving order: 0 the own region's words the level 0
    /// leaves, 1 the link's scratch, 2 the link's words.
    pub place: [u8; PYRAMID_BUFFERS],
    /// Words of the link region (after the scratch).
    pub link_words: usize,
}

/// What the robot keeps of its turn region while it maps and sends: the
/// Morton scratch and the link's words (its buffers at their start).
pub(super) struct Spare<'a> {
    pub(super) scratch: &'a mut [u32],
    pub(super) link: &'a mut [u32],
}

/// Carves the map and the spare buffers out of the two regions (checked
/// against `capacity`'s sizes).
pub(super) fn carve_map<'a>(
    own: &'a mut [u32],
    turn: &'a mut [u32],
    capacity: &Capacity,
) -> Result<(WordStorage<'a>, Spare<'a>), RegionError> {
    let (need_own, need_turn) = (capacity.own_words(), capacity.turn_words());
    if own.len() < need_own {
        return Err(RegionError::Short { need: need_own, have: own.len() });
    }
    if turn.len() < need_turn {
        return Err(RegionError::Short { need: need_turn, have: turn.len() });
    }
    // The slots first: the voxels, and the spare words after them, are
    // one run of words, which the level 0 leaves whole.
    let mut own = Region::new(own);
    let slots = own.take::<u16>(2 * capacity.voxels)?;
    let map = WordStorage::new(own.into_words(), capacity.voxels, slots).ok_or(RegionError::Layout)?;
    let mut turn = Region::new(turn);
    let scratch = turn.take_words(capacity.voxels)?;
    Ok((map, Spare { scratch, link: turn.into_words() }))
}

/// Takes `n` values of `T` from the region `plan` puts buffer `k` in.
fn take_planned<'a, T: Pod>(
    pool: &mut [Region<'a>; ROOMS],
    plan: &Plan,
    k: usize,
    n: usize,
) -> Result<&'a mut [T], RegionError> {
    let at = plan.place.get(k).map_or(usize::from(LINK_ROOM), |&p| usize::from(p));
    pool.get_mut(at).ok_or(RegionError::Layout)?.take(n)
}

/// What a robot aligns in: the model's pyramid storage (coarse levels,
/// normals, index, footprint), the scene's, and the searches' words.
pub(super) struct AlignParts<'a> {
    pub(super) model: PyramidPartsMut<'a>,
    pub(super) scene: PyramidPartsMut<'a>,
    pub(super) search: &'a mut [u32],
}

/// The pyramid storages and the searches' words, carved as
/// [`Capacity::plan`] says out of what the level 0 leaves in the own
/// region (with its spare words) and the turn region's words the link
/// gave back.
pub(super) fn carve_pyramids<'a>(
    leaves: &'a mut [u32],
    spare: Spare<'a>,
    capacity: &Capacity,
) -> Result<AlignParts<'a>, RegionError> {
    let plan = capacity.plan();
    let mut pool = [Region::new(leaves), Region::new(spare.scratch), Region::new(spare.link)];
    let e = capacity.coarse;
    // The order of `Capacity::pyramid_words`.
    let model_entries = take_planned::<CoarseEntry>(&mut pool, &plan, 0, e)?;
    let scene_entries = take_planned::<CoarseEntry>(&mut pool, &plan, 1, e)?;
    let model_words = take_planned::<u32>(&mut pool, &plan, 2, capacity.model_words)?;
    let scene_words = take_planned::<u32>(&mut pool, &plan, 3, capacity.scene_words)?;
    let normals = take_planned::<PackedNormal>(&mut pool, &plan, 4, e)?;
    let model_slots = take_planned::<u32>(&mut pool, &plan, 5, e)?;
    let search = take_planned::<u32>(&mut pool, &plan, 6, capacity.search_words)?;
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
    Ok(AlignParts { model, scene, search })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{LocalMap, VoxelStorage};
    use std::vec;

    /// The board's regions: the map's 224 KiB, and the turn region a little
    /// over today's 176 KiB; every stage's buffers are carved from them,
    /// and a word short of either region is an error, not a smaller robot.
    #[test]
    fn board_regions_carve_every_stage() {
        let c = Capacity::BOARD;
        assert_eq!(c.own_words() * 4, 229_376);
        let plan = c.plan();
        assert!(plan.link_words >= LINK_WORDS);
        assert!(c.turn_words() * 4 <= 184_320, "turn region {} B", c.turn_words() * 4);
        let (mut own, mut turn) = (vec![0u32; c.own_words()], vec![0u32; c.turn_words()]);
        let (storage, spare) = carve_map(&mut own, &mut turn, &c).unwrap();
        assert_eq!((storage.voxels().len(), storage.slots().len()), (c.voxels, 2 * c.voxels));
        assert!(spare.link.len() >= LINK_WORDS);
        let mut map = LocalMap::new(storage, super::super::map_config(0.5)).unwrap();
        map.insert_point([1.0, 2.0, 0.5], crate::classes::Class::Pole).unwrap();
        let (copied, level0, leaves) = crate::matching::CopiedBase::compact(map).unwrap();
        assert_eq!((level0.points.len(), level0.slots.len()), (c.voxels, 2 * c.voxels));
        let _ = copied;
        let AlignParts { model, scene, search } = carve_pyramids(leaves, spare, &c).unwrap();
        assert!(search.is_empty());
        assert_eq!((model.entries.len(), model.normals.len(), model.slots.len()), (c.coarse, c.coarse, c.coarse));
        assert_eq!((model.words.len(), scene.words.len()), (c.model_words, scene.words.len()));
        assert_eq!((scene.entries.len(), scene.words.len()), (c.coarse, c.scene_words));
        let (mut own, mut turn) = (vec![0u32; c.own_words() - 1], vec![0u32; c.turn_words()]);
        assert!(carve_map(&mut own, &mut turn, &c).is_err());
        let (mut own, mut turn) = (vec![0u32; c.own_words()], vec![0u32; c.turn_words() - 1]);
        assert!(carve_map(&mut own, &mut turn, &c).is_err());
    }

    /// The plan puts no more in a place than it holds, and no placement
    /// needs fewer link words.
    /// The STM32F405's regions fit its memories: the own region and the
    /// received map its SRAM, the turn region its CCM with 28 KiB left for
    /// the receive rings and the stack.
    #[test]
    fn the_stm32f405_regions_fit_its_memories() {
        let c = Capacity::STM32F405;
        let received = c.voxels * core::mem::size_of::<crate::map::ScenePoint>();
        assert!(c.own_words() * 4 + received <= 128 * 1024, "SRAM {} B", c.own_words() * 4 + received);
        // The CCM less the stack's 17 KiB and the rings' 3 KiB and more.
        assert!(c.turn_words() * 4 <= 64 * 1024 - 17 * 1024 - 3200, "turn region {} B", c.turn_words() * 4);
        assert!(c.plan().link_words >= LINK_WORDS);
    }

    #[test]
    fn the_plan_is_the_smallest_that_fits() {
        let small =
            Capacity { voxels: 3200, coarse: 1500, model_words: 3300, scene_words: 2600, levels: 2, ..Capacity::BOARD };
        for c in [Capacity::BOARD, small, Capacity { spare_words: 4000, ..small }, Capacity::STM32F405] {
            let plan = c.plan();
            let need = c.pyramid_words();
            let mut used = [0usize; ROOMS];
            for (k, &p) in plan.place.iter().enumerate() {
                used[usize::from(p)] += need[k];
            }
            assert!(used[0] <= c.level0_leaves() && used[1] <= c.voxels);
            assert_eq!(plan.link_words, used[2].max(LINK_WORDS));
            // Everything in the link's words is never better.
            assert!(plan.link_words <= need.iter().sum::<usize>().max(LINK_WORDS));
        }
        let s = Capacity::sender(1000);
        assert_eq!(s.own_words(), 7000);
        assert_eq!(s.turn_words(), 1000 + LINK_WORDS);
    }
}
