//! A received map kept only as what matching it as a scene reads.
//!
//! A robot matches the map it receives as the scene: the matcher walks the
//! scene's entries in order and never looks a scene cell up, reads no
//! occupancy, hit count or full label distribution, and fits no scene
//! normal. So a received map need not be a [`LocalMap`] (24 bytes per voxel
//! and two index slots): a [`SceneMap`] keeps 8 bytes per voxel (cell,
//! and what the link's encoding carries of the mean, class and confidence),
//! filled straight from the wire decoder through
//! [`VoxelSink`], in the order the voxels arrive. The pyramid built on it
//! ([`crate::matching::Pyramid::build_scene`]) gives the matcher exactly
//! the entries a [`LocalMap`] holding the same voxels would.

use super::local_map::{ConfigError, InsertError, MapConfig};
use super::voxel::mean_position;
use super::{LocalMap, SemanticVoxel, VoxelKey, VoxelStorage};
use crate::classes::NUM_CLASSES;

/// Where decoded voxels go: a [`LocalMap`], or a [`SceneMap`] for a map
/// that will only be matched as a scene.
pub trait VoxelSink {
    /// Voxels held.
    fn len(&self) -> usize;
    /// Whether no voxel is held.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Most voxels it can hold.
    fn capacity(&self) -> usize;
    /// Voxel size (m).
    fn resolution(&self) -> f32;
    /// Forgets every voxel (keeps the configuration).
    fn clear(&mut self);
    /// Forgets every voxel and takes `config` (a [`SceneMap`] keeps only
    /// its resolution).
    fn configure(&mut self, config: MapConfig) -> Result<(), ConfigError>;
    /// Takes one voxel; [`InsertError::DuplicateKey`] when its cell is held
    /// already (a sink that cannot tell, [`SceneMap`], takes voxels in
    /// strictly increasing order from a decoder that checks the order),
    /// [`InsertError::Full`] when there is no room.
    fn accept(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError>;
}

impl<S: VoxelStorage> VoxelSink for LocalMap<S> {
    fn len(&self) -> usize {
        LocalMap::len(self)
    }
    fn capacity(&self) -> usize {
        LocalMap::capacity(self)
    }
    fn resolution(&self) -> f32 {
        LocalMap::resolution(self)
    }
    fn clear(&mut self) {
        LocalMap::clear(self)
    }
    fn configure(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        self.reset(config)
    }
    fn accept(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        self.insert_voxel(voxel)
    }
}

/// A sink may be borrowed.
impl<T: VoxelSink + ?Sized> VoxelSink for &mut T {
    fn len(&self) -> usize {
        (**self).len()
    }
    fn capacity(&self) -> usize {
        (**self).capacity()
    }
    fn resolution(&self) -> f32 {
        (**self).resolution()
    }
    fn clear(&mut self) {
        (**self).clear()
    }
    fn configure(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        (**self).configure(config)
    }
    fn accept(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        (**self).accept(voxel)
    }
}

/// One voxel of a [`SceneMap`]: 8 bytes, exactly what the link's encoding
/// carries of it ([`crate::wire::codec`]): the cell, the mean to a quarter
/// of the cell per axis, the class and one of
/// [`CONFIDENCE_LEVELS`](crate::wire::codec::CONFIDENCE_LEVELS). Nothing a
/// received voxel holds is lost (a [`SceneMap`] refuses a voxel that holds
/// more, [`InsertError::Inexact`]), so a scene of them matches to the bit
/// as the decoded map would.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScenePoint {
    /// The cell.
    pub key: VoxelKey,
    /// Bits 0-5: the mean, [`MEAN_BITS`] per axis (x lowest); 6-10: the
    /// class ([`NO_CLASS`] without one); 11-13: the confidence level.
    packed: u16,
}

/// Bits of a scene point's mean per axis (the wire's position bits).
const MEAN_BITS: u32 = 2;
/// The class field of a point without a class.
const NO_CLASS: u16 = 31;
/// The class's probability in 1/255 at each of the encoding's confidence
/// levels, as a voxel decoded at that level gives it (its one label slot's
/// score rounded to 1/8 nat; tested against the decoder for every class).
const LEVEL_CONFIDENCE: [u8; 8] = [37, 88, 142, 179, 208, 233, 247, 254];
/// The confidence of a point without a class: a uniform distribution's.
const NO_CLASS_CONFIDENCE: u8 = (255.0 / NUM_CLASSES as f32 + 0.5) as u8;

/// A voxel's most probable class (`u8::MAX` without one) and that class's
/// probability in 1/255 (a uniform one's without a class): what a
/// pyramid's level 0 and a scene keep of its labels.
pub fn class_and_confidence(v: &SemanticVoxel) -> (u8, u8) {
    let class = v.class();
    let p = class.map(|c| v.labels.probability(c)).unwrap_or(1.0 / NUM_CLASSES as f32);
    (class.map(|c| c.index()).unwrap_or(u8::MAX), (p * 255.0 + 0.5) as u8)
}

/// [`class_and_confidence`] remembered for the last label distributions
/// seen (direct-mapped by their bits): a map's voxels repeat a few
/// distributions (a surface seen as one class so many times), and
/// preparing a map asks it of every voxel, each a few `expf`.
pub struct ClassMemo {
    /// A distribution's bits, its class and confidence.
    slots: [([u16; 4], u8, u8); CLASS_MEMO_SLOTS],
    /// A bit a slot: filled.
    filled: u64,
}

/// Slots of a [`ClassMemo`] (at most 64: `filled` is a bit each).
const CLASS_MEMO_SLOTS: usize = 64;

impl Default for ClassMemo {
    fn default() -> Self {
        ClassMemo { slots: [([0; 4], 0, 0); CLASS_MEMO_SLOTS], filled: 0 }
    }
}

impl ClassMemo {
    /// [`class_and_confidence`] of `v`.
    #[inline]
    pub fn of(&mut self, v: &SemanticVoxel) -> (u8, u8) {
        let bits: [u16; 4] = bytemuck::cast(v.labels);
        let word = bits.iter().fold(0u64, |acc, &b| (acc << 16) | u64::from(b));
        let k = (word.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize % CLASS_MEMO_SLOTS;
        match self.slots.get_mut(k) {
            Some(slot) if self.filled & (1 << k) != 0 && slot.0 == bits => (slot.1, slot.2),
            Some(slot) => {
                let (class, confidence) = class_and_confidence(v);
                *slot = (bits, class, confidence);
                self.filled |= 1 << k;
                (class, confidence)
            }
            None => class_and_confidence(v),
        }
    }
}

impl ScenePoint {
    /// All zero (a `static` of them lands in `.bss`).
    pub const EMPTY: ScenePoint = ScenePoint { key: VoxelKey::new(0, 0, 0), packed: 0 };

    /// What a scene keeps of `v`: its cell, mean, class and confidence
    /// ([`class_and_confidence`]); `None` when `v` holds more than a
    /// received voxel does (a mean off the quarter-cell grid, a confidence
    /// off the encoding's levels).
    pub fn of(v: &SemanticVoxel) -> Option<Self> {
        let (class, confidence) = class_and_confidence(v);
        let mut packed = 0u16;
        for (axis, m) in v.mean_raw().into_iter().enumerate() {
            let q = m >> (16 - MEAN_BITS);
            if m != mean_of(q) {
                return None;
            }
            packed |= q << (MEAN_BITS * axis as u32);
        }
        let (class_field, level) = if class == u8::MAX {
            (NO_CLASS, 0)
        } else {
            (u16::from(class), LEVEL_CONFIDENCE.iter().position(|&c| c == confidence)? as u16)
        };
        let point = ScenePoint { key: v.key, packed: packed | (class_field << 6) | (level << 11) };
        (point.confidence() == confidence).then_some(point)
    }

    /// The mean in 1/65536 of the cell per axis (a decoded voxel's).
    #[inline]
    fn mean(&self) -> [u16; 3] {
        let m = (1u16 << MEAN_BITS) - 1;
        [0, 1, 2].map(|axis| mean_of((self.packed >> (MEAN_BITS * axis)) & m))
    }

    /// Mean position (m, map frame), as [`SemanticVoxel::position`].
    #[inline]
    pub fn position(&self, resolution: f32) -> [f32; 3] {
        mean_position(self.key, self.mean(), resolution)
    }

    /// Class index (0..19; `u8::MAX` without one).
    #[inline]
    pub fn class(&self) -> u8 {
        match (self.packed >> 6) & 31 {
            NO_CLASS => u8::MAX,
            c => c as u8,
        }
    }

    /// Probability of the class, in 1/255.
    #[inline]
    pub fn confidence(&self) -> u8 {
        if self.class() == u8::MAX {
            NO_CLASS_CONFIDENCE
        } else {
            LEVEL_CONFIDENCE[usize::from((self.packed >> 11) & 7)]
        }
    }
}

/// The stored mean of a quarter-cell step: its centre, as the decoder
/// writes it.
#[inline]
fn mean_of(q: u16) -> u16 {
    (q << (16 - MEAN_BITS)) | (1 << (15 - MEAN_BITS))
}

/// A received map as a scene: [`ScenePoint`]s in arrival order, in a
/// buffer the caller provides (an array, a slice, a vector): its length is
/// the capacity.
pub struct SceneMap<S> {
    points: S,
    len: usize,
    resolution: f32,
}

impl<S: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> SceneMap<S> {
    /// An empty scene of voxels of `resolution` metres (a positive finite
    /// number in [1 mm, 1 km], as a map's).
    pub fn new(points: S, resolution: f32) -> Result<Self, ConfigError> {
        let mut scene = SceneMap { points, len: 0, resolution: 1.0 };
        scene.reset(resolution)?;
        Ok(scene)
    }

    /// Empties the scene and sets its voxel size.
    pub fn reset(&mut self, resolution: f32) -> Result<(), ConfigError> {
        super::local_map::check_resolution(resolution)?;
        self.len = 0;
        self.resolution = resolution;
        Ok(())
    }

    /// Voxel size (m).
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// The points held, in arrival order.
    pub fn points(&self) -> &[ScenePoint] {
        self.points.as_ref().get(..self.len).unwrap_or(&[])
    }

    /// The axis-aligned bounds of the held cells (m), as
    /// [`LocalMap::bounds`].
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        VoxelKey::bounds(self.points().iter().map(|p| p.key), self.resolution)
    }
}

impl<S: AsRef<[ScenePoint]> + AsMut<[ScenePoint]>> VoxelSink for SceneMap<S> {
    fn len(&self) -> usize {
        self.len
    }
    fn capacity(&self) -> usize {
        self.points.as_ref().len()
    }
    fn resolution(&self) -> f32 {
        self.resolution
    }
    fn clear(&mut self) {
        self.len = 0;
    }
    fn configure(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        self.reset(config.resolution)
    }
    fn accept(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        let slot = self.points.as_mut().get_mut(self.len).ok_or(InsertError::Full)?;
        *slot = ScenePoint::of(&voxel).ok_or(InsertError::Inexact)?;
        self.len += 1;
        Ok(())
    }
}
