//! The voxels an update changes, coded against what the peer holds of
//! them: each by its rank among the cells the peer holds (in Morton
//! order), and its fields in the context of the record it replaces.
//!
//! A voxel the peer holds is resent when its record moved beyond the
//! deadband ([`super::codec::within_step`]): mostly its confidence, two
//! levels up, its class and mean as they were. Coded as a new voxel (a
//! Morton gap from the update's previous voxel, its fields from scratch)
//! it took about 14 bits; here its cell is a rank gap among the few
//! thousand cells held (about 7 bits for one changed voxel in fifty) and
//! its fields a few bits: whether the class stayed, the confidence given
//! the one held, each axis of the mean given the one held.
//!
//! | field | coded as | context |
//! |---|---|---|
//! | rank gap from the previous changed voxel (its rank + 1; 0 first) | bit length, then the two bits below the leading one, then the rest at even odds | the previous gap's length |
//! | the class stayed | a bit | the held class |
//! | the class, when it did not | 5-bit symbol (never the held one) | none |
//! | confidence | 3-bit symbol | the held confidence, and whether the class stayed |
//! | mean, per axis | 2-bit symbol | the axis and its held value |
//!
//! Records carry no occupancy ([`super::codec::update_record`]). The
//! probabilities carry over from update to update, as the voxels' do
//! ([`super::update`]).

use super::codec::{
    class_symbol, decode_gap as decode_code_gap, encode_gap, record_class, record_confidence, record_of,
    record_position, POSITION_BITS,
};
use super::range::{Full, RangeDecoder, RangeEncoder, PROB_INIT};
use crate::classes::NUM_CLASSES;

/// Class symbols: the classes, then "none".
const CLASS_SYMBOLS: usize = NUM_CLASSES + 1;

/// The range coder's probabilities for changed voxels (about 1.8 KiB),
/// kept by the caller beside the voxels' [`super::CodecModel`]. Plain
/// integers, any value valid.
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct ChangeModel {
    gap_len: [[u16; 64]; 8],
    gap_top: [[u16; 4]; 34],
    same_class: [[u16; 2]; CLASS_SYMBOLS],
    class: [u16; 32],
    confidence: [[u16; 8]; 16],
    position: [[[u16; 1 << POSITION_BITS]; 1 << POSITION_BITS]; 3],
    prev_len: u32,
}

impl Default for ChangeModel {
    fn default() -> Self {
        Self::new()
    }
}

impl ChangeModel {
    /// A model that has seen nothing.
    pub const fn new() -> Self {
        ChangeModel {
            gap_len: [[PROB_INIT; 64]; 8],
            gap_top: [[PROB_INIT; 4]; 34],
            same_class: [[PROB_INIT; 2]; CLASS_SYMBOLS],
            class: [PROB_INIT; 32],
            confidence: [[PROB_INIT; 8]; 16],
            position: [[[PROB_INIT; 1 << POSITION_BITS]; 1 << POSITION_BITS]; 3],
            prev_len: 0,
        }
    }

    /// Forgets everything, in place.
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

/// Codes one changed voxel: the gap from the previous one's rank (its
/// rank + 1; the first: its rank), and its record `now` against the
/// record `held` the peer has.
pub(crate) fn encode_change(
    e: &mut RangeEncoder<'_>,
    m: &mut ChangeModel,
    gap: u64,
    held: u32,
    now: u32,
) -> Result<(), Full> {
    encode_gap(e, &mut m.gap_len, &mut m.gap_top, &mut m.prev_len, gap)?;
    let (was, is) = (class_symbol(record_class(held)), class_symbol(record_class(now)));
    let same = was == is;
    e.tree(m.same_class.get_mut(was).ok_or(Full)?, u32::from(same), 1)?;
    if !same {
        e.tree(&mut m.class, is as u32, 5)?;
    }
    let ctx = record_confidence(held) as usize + if same { 0 } else { 8 };
    e.tree(m.confidence.get_mut(ctx).ok_or(Full)?, record_confidence(now), 3)?;
    for axis in 0..3 {
        let probs = m.position.get_mut(axis).and_then(|a| a.get_mut(record_position(held, axis) as usize));
        e.tree(probs.ok_or(Full)?, record_position(now, axis), POSITION_BITS)?;
    }
    Ok(())
}

/// Decodes the next changed voxel's rank gap ([`encode_change`]).
pub(crate) fn decode_gap(d: &mut RangeDecoder<'_>, m: &mut ChangeModel) -> Option<u64> {
    decode_code_gap(d, &mut m.gap_len, &mut m.gap_top, &mut m.prev_len)
}

/// Decodes a changed voxel's record against the record `held` it
/// replaces; `None` for a class that is no class, or the held one.
pub(crate) fn decode_record(d: &mut RangeDecoder<'_>, m: &mut ChangeModel, held: u32) -> Option<u32> {
    let was = class_symbol(record_class(held));
    let same = d.tree(m.same_class.get_mut(was)?, 1)? == 1;
    let class = if same {
        was
    } else {
        let s = d.tree(&mut m.class, 5)? as usize;
        if s >= CLASS_SYMBOLS || s == was {
            return None;
        }
        s
    };
    let ctx = record_confidence(held) as usize + if same { 0 } else { 8 };
    let confidence = d.tree(m.confidence.get_mut(ctx)?, 3)?;
    let mut position = [0u32; 3];
    for (axis, p) in position.iter_mut().enumerate() {
        *p = d.tree(m.position.get_mut(axis)?.get_mut(record_position(held, axis) as usize)?, POSITION_BITS)?;
    }
    Some(record_of(class, confidence, position))
}
