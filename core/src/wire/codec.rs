//! The compact voxel encoding shared by map files and the link.
//!
//! Voxels travel in Morton (Z) order of their keys, so neighbours in space
//! are neighbours in the stream and a key costs only the gap to the previous
//! one. Every field is coded by an adaptive binary range coder
//! ([`super::range`]) whose probabilities follow the map as it goes, each in
//! a context that predicts it:
//!
//! | field | coded as | context |
//! |---|---|---|
//! | gap to the previous Morton code | bit length, then the two bits below the leading one, then the rest at even odds | the previous gap's length |
//! | class (or none) | 5-bit symbol | the previous voxel's class |
//! | confidence of the class, one of [`CONFIDENCE_LEVELS`] | 3-bit symbol | the class |
//! | occupancy: 1 to 4 hits' worth of log-odds | 2-bit symbol | the class |
//! | mean position in the voxel, [`POSITION_BITS`] bits per axis | symbol per axis | the axis, ground or not |
//!
//! The position keeps a quarter of a voxel per axis: what matching needs
//! (`cosem eval --through-encoding` moves rotation errors by about as much
//! as 1/16 did, 0.005-0.04 degrees) at two thirds of the bytes. Coarser
//! positions make a one-period slide along a street of regular structures
//! a little likelier (`cosem synth --seed 5` did slide at 1/4, and one way
//! at 1/16 too): the matcher's look-alike check ([`crate::matching::Matcher::align`])
//! refines the better-agreeing placement one period over.
//!
//! The stream is cut into *chunks* of a bounded size, decoded in order: a
//! chunk starts with its voxel count and the gap from the previous chunk's
//! last code to its first (the first chunk: the absolute code), then the
//! range-coded voxels. The probabilities ([`CodecModel`]) carry over from
//! chunk to chunk, so a map larger than any buffer streams chunk by chunk at
//! the rate of one long stream; chunks must be decoded in the order they
//! were encoded (the link's stream and map files keep that order). The
//! decoder checks everything: codes strictly increasing across chunks (no
//! duplicates), classes in range, every byte of the chunk used and no more;
//! it never panics, never loops without consuming input, never allocates.
//!
//! The encoding is lossy, but idempotent: a decoded map encodes to the same
//! bytes. So a map read from a file and the same map received over the link
//! are identical.

use super::crc::Crc32;
use super::range::{RangeDecoder, RangeEncoder, PROB_INIT};
use crate::classes::{Class, NUM_CLASSES};
use crate::map::key::sort_indices_by_code;
use crate::map::labels::{LabelDistribution, SCORE_MAX, SCORE_UNITS_PER_NAT};
use crate::map::voxel::LOGODDS_UNITS;
use crate::map::{InsertError, LocalMap, SemanticVoxel, VoxelKey, VoxelSink, VoxelStorage};
use core::borrow::Borrow;
use core::marker::PhantomData;

/// Probabilities a voxel's class confidence is rounded to.
pub const CONFIDENCE_LEVELS: [f32; 8] = [0.15, 0.35, 0.55, 0.7, 0.82, 0.91, 0.97, 0.995];

/// Log-odds of one hit in the encoding's occupancy levels (OctoMap's 0.7).
const OCCUPANCY_STEP: f32 = 0.85;
/// Bytes a chunk header takes at most (two LEB128 varints).
pub const CHUNK_HEADER_MAX: usize = 5 + 7;
/// Bytes one voxel can take at most in the range coder, with its flush.
const VOXEL_MAX: usize = 36;
/// Smallest chunk buffer the encoder accepts: a header and one voxel.
pub const MIN_CHUNK: usize = CHUNK_HEADER_MAX + VOXEL_MAX;
/// Bits of the mean position per axis: `2^POSITION_BITS` steps a voxel.
pub const POSITION_BITS: u32 = 2;
/// Class symbols: the classes, then "none".
const CLASS_SYMBOLS: usize = NUM_CLASSES + 1;
const NO_CLASS: u32 = 31;
pub(crate) const MORTON_LIMIT: u64 = 1 << 48;

/// Why a map could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The scratch buffer is shorter than the map.
    Scratch,
    /// The chunk buffer is smaller than [`MIN_CHUNK`].
    Buffer,
}

/// Why a chunk was rejected. The voxels decoded before the error stay in
/// the map: decode into a staging map and keep it only when all is well.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The chunk ends early.
    Truncated,
    /// A varint is longer than its type.
    Varint,
    /// A chunk announces no voxel.
    Empty,
    /// More voxels than the map header announced.
    TooMany,
    /// A Morton code is not above the previous one (duplicate or disorder).
    Order,
    /// A Morton code beyond 48 bits.
    Range,
    /// A class index beyond the table.
    Class,
    /// Bits left after the last voxel, or non-zero padding.
    Trailing,
    /// The map is full.
    Full,
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DecodeError::Truncated => "chunk truncated",
            DecodeError::Varint => "varint too long",
            DecodeError::Empty => "chunk with no voxel",
            DecodeError::TooMany => "more voxels than announced",
            DecodeError::Order => "voxel keys not strictly increasing",
            DecodeError::Range => "voxel key out of range",
            DecodeError::Class => "unknown class",
            DecodeError::Trailing => "data after the last voxel",
            DecodeError::Full => "receiving map is full",
        })
    }
}

impl core::error::Error for DecodeError {}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            EncodeError::Scratch => "scratch buffer shorter than the map",
            EncodeError::Buffer => "chunk buffer too small",
        })
    }
}

impl core::error::Error for EncodeError {}

/// The Morton code of a key: x, y, z interleaved (x lowest), each in offset
/// binary so that the order of codes follows the keys.
pub fn morton(key: VoxelKey) -> u64 {
    fn spread(v: i16) -> u64 {
        let mut x = u64::from((v as u16) ^ 0x8000);
        x = (x | (x << 32)) & 0x001F_0000_0000_FFFF;
        x = (x | (x << 16)) & 0x001F_0000_FF00_00FF;
        x = (x | (x << 8)) & 0x100F_00F0_0F00_F00F;
        x = (x | (x << 4)) & 0x10C3_0C30_C30C_30C3;
        x = (x | (x << 2)) & 0x1249_2492_4924_9249;
        x
    }
    spread(key.x) | (spread(key.y) << 1) | (spread(key.z) << 2)
}

/// The key of a Morton code (below 2^48).
pub fn key_of(code: u64) -> Option<VoxelKey> {
    if code >= MORTON_LIMIT {
        return None;
    }
    fn compact(mut x: u64) -> i16 {
        x &= 0x1249_2492_4924_9249;
        x = (x ^ (x >> 2)) & 0x10C3_0C30_C30C_30C3;
        x = (x ^ (x >> 4)) & 0x100F_00F0_0F00_F00F;
        x = (x ^ (x >> 8)) & 0x001F_0000_FF00_00FF;
        x = (x ^ (x >> 16)) & 0x001F_0000_0000_FFFF;
        x = (x ^ (x >> 32)) & 0x001F_FFFF;
        ((x as u16) ^ 0x8000) as i16
    }
    Some(VoxelKey::new(compact(code), compact(code >> 1), compact(code >> 2)))
}

/// What the encoding keeps of a voxel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Quantised {
    class: u32,
    confidence: u32,
    occupancy: u32,
    position: [u32; 3],
}

fn quantise(v: &SemanticVoxel) -> Quantised {
    let class = v.class();
    let p = class.map(|c| v.labels.probability(c)).unwrap_or(0.0);
    let mut confidence = 0;
    let mut best = f32::INFINITY;
    for (i, level) in CONFIDENCE_LEVELS.iter().enumerate() {
        let d = (p - level).abs();
        if d < best {
            best = d;
            confidence = i as u32;
        }
    }
    let hits = libm::roundf(v.occupancy_logodds() / OCCUPANCY_STEP);
    let occupancy = if hits.is_nan() || hits < 1.0 { 0 } else { (hits as u32 - 1).min(3) };
    let m = v.mean_raw();
    Quantised {
        class: class.map(|c| u32::from(c.index())).unwrap_or(NO_CLASS),
        confidence,
        occupancy,
        position: m.map(|v| u32::from(v >> (16 - POSITION_BITS))),
    }
}

/// Where each quantised field sits in a packed record, `(shift, bits)`:
/// class, confidence, occupancy, then the mean's three axes (4 bits each,
/// room for [`POSITION_BITS`]). The one layout the digests cover and an
/// update's deadband compares ([`within_step`]).
const CLASS_FIELD: (u32, u32) = (0, 5);
const STEPPED_FIELDS: [(u32, u32); 5] = [CONFIDENCE_FIELD, OCCUPANCY_FIELD, (10, 4), (14, 4), (18, 4)];
const CONFIDENCE_FIELD: (u32, u32) = (5, 3);
const OCCUPANCY_FIELD: (u32, u32) = (8, 2);

/// One voxel's quantised fields packed in 32 bits (the layout above).
fn pack(q: &Quantised) -> u32 {
    let values = [q.confidence, q.occupancy, q.position[0], q.position[1], q.position[2]];
    STEPPED_FIELDS.iter().zip(values).fold(q.class << CLASS_FIELD.0, |r, (&(shift, _), v)| r | (v << shift))
}

/// A packed record's field.
fn field(record: u32, (shift, bits): (u32, u32)) -> u32 {
    (record >> shift) & ((1 << bits) - 1)
}

/// The fields [`pack`] packed.
fn unpack(record: u32) -> Quantised {
    let [confidence, occupancy, x, y, z] = STEPPED_FIELDS.map(|f| field(record, f));
    Quantised { class: field(record, CLASS_FIELD), confidence, occupancy, position: [x, y, z] }
}

/// A record's class index ([`NO_CLASS`] for none).
pub(crate) fn record_class(record: u32) -> u32 {
    field(record, CLASS_FIELD)
}

/// A record's confidence level.
pub(crate) fn record_confidence(record: u32) -> u32 {
    field(record, CONFIDENCE_FIELD)
}

/// A record's mean on `axis` (0-2), in steps of the cell.
pub(crate) fn record_position(record: u32, axis: usize) -> u32 {
    STEPPED_FIELDS.get(2 + axis).map_or(0, |&f| field(record, f))
}

/// The record (no occupancy: [`update_record`]) of a class symbol
/// ([`class_symbol`]), a confidence level and a mean.
pub(crate) fn record_of(symbol: usize, confidence: u32, position: [u32; 3]) -> u32 {
    let class = if symbol >= NUM_CLASSES { NO_CLASS } else { symbol as u32 };
    pack(&Quantised { class, confidence, occupancy: 0, position })
}

/// The voxel of cell `key` a record decodes to (what a copy holds for it);
/// an error for a class beyond the table or a level beyond the scale.
pub(crate) fn voxel_of_record(key: VoxelKey, record: u32) -> Result<SemanticVoxel, DecodeError> {
    let q = unpack(record);
    if q.position.iter().any(|&p| p >= 1 << POSITION_BITS) {
        return Err(DecodeError::Range);
    }
    rebuild(key, &q)
}

/// Feeds one voxel's canonical record (6 bytes of code, 4 of packed
/// fields) into a digest: the same in the encoder and the decoder, whatever
/// the chunking.
fn digest_voxel(crc: &mut Crc32, code: u64, packed: u32) {
    let c = code.to_le_bytes();
    crc.update(&c[..6]);
    crc.update(&packed.to_le_bytes());
}

fn rebuild(key: VoxelKey, q: &Quantised) -> Result<SemanticVoxel, DecodeError> {
    let mut labels = LabelDistribution::EMPTY;
    if q.class != NO_CLASS {
        let class = Class::from_index(q.class as u8).ok_or(DecodeError::Class)?;
        let p = CONFIDENCE_LEVELS.get(q.confidence as usize).copied().ok_or(DecodeError::Class)?;
        // The score whose single-slot posterior gives p: p = e^s / (e^s + 18).
        let nats = libm::logf(p * (NUM_CLASSES as f32 - 1.0) / (1.0 - p));
        let score = libm::roundf(nats * SCORE_UNITS_PER_NAT).clamp(1.0, f32::from(SCORE_MAX)) as u16;
        labels.observe(class, score);
    }
    let hits = q.occupancy as u16 + 1;
    let occupancy = libm::roundf(f32::from(hits) * OCCUPANCY_STEP * LOGODDS_UNITS) as i16;
    let mean = q.position.map(|p| ((p as u16) << (16 - POSITION_BITS)) | (1 << (15 - POSITION_BITS)));
    Ok(SemanticVoxel::from_parts(key, mean, occupancy, hits, labels))
}

/// The probabilities of the range coder, per field and context: what the
/// encoder and the decoder of one map learn as it goes (about 3.6 KiB).
/// Kept by the caller, so a robot can keep it with its other buffers.
/// Plain integers, any value valid (a zeroed one is reset before use), so
/// it may be carved out of a robot's memory.
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct CodecModel {
    gap_len: [[u16; 64]; 8],
    gap_top: [[u16; 4]; 50],
    class: [[u16; 32]; CLASS_SYMBOLS],
    confidence: [[u16; 8]; CLASS_SYMBOLS],
    occupancy: [[u16; 4]; CLASS_SYMBOLS],
    position: [[[u16; 1 << POSITION_BITS]; POSITION_CONTEXTS]; 3],
    prev_class: u32,
    prev_len: u32,
}

/// Contexts of a position: ground or not (the previous voxel's position as
/// a context gained 2% and cost 3 KiB of a robot's RAM per model).
const POSITION_CONTEXTS: usize = 2;

fn is_ground(symbol: usize) -> bool {
    matches!(symbol, 8..=11 | 16)
}

fn position_context(symbol: usize) -> usize {
    usize::from(is_ground(symbol))
}

impl Default for CodecModel {
    fn default() -> Self {
        Self::new()
    }
}

impl CodecModel {
    /// A model that has seen nothing.
    pub const fn new() -> Self {
        CodecModel {
            gap_len: [[PROB_INIT; 64]; 8],
            gap_top: [[PROB_INIT; 4]; 50],
            class: [[PROB_INIT; 32]; CLASS_SYMBOLS],
            confidence: [[PROB_INIT; 8]; CLASS_SYMBOLS],
            occupancy: [[PROB_INIT; 4]; CLASS_SYMBOLS],
            position: [[[PROB_INIT; 1 << POSITION_BITS]; POSITION_CONTEXTS]; 3],
            prev_class: NUM_CLASSES as u32,
            prev_len: 0,
        }
    }

    /// Forgets everything (a new map), in place: no copy of the model on
    /// the stack, which a robot's is too small to waste.
    pub fn reset(&mut self) {
        fn fill<const N: usize>(rows: &mut [[u16; N]]) {
            for row in rows {
                row.fill(PROB_INIT);
            }
        }
        fill(&mut self.gap_len);
        fill(&mut self.gap_top);
        fill(&mut self.class);
        fill(&mut self.confidence);
        fill(&mut self.occupancy);
        for axis in &mut self.position {
            fill(axis);
        }
        self.prev_class = NUM_CLASSES as u32;
        self.prev_len = 0;
    }
}

/// The symbol of a class index (none: after the classes).
pub(crate) fn class_symbol(class: u32) -> usize {
    if class == NO_CLASS {
        NUM_CLASSES
    } else {
        class as usize
    }
}

/// A gap as its bit length `len` (of `gap + 1`), the two bits below the
/// leading one, and the rest.
fn gap_parts(gap: u64) -> (u32, u32, u32, u64, u32) {
    let v = gap.saturating_add(1);
    let len = 64 - v.leading_zeros();
    let below = len - 1;
    let top = below.min(2);
    let rest = below - top;
    (len, ((v >> rest) & ((1 << top) - 1)) as u32, top, v & ((1u64 << rest) - 1), rest)
}

/// Codes a gap (between Morton codes, or ranks): its bit length in the
/// context of the previous gap's (`prev_len`, updated), the two bits below
/// the leading one in the context of the length, the rest at even odds.
pub(crate) fn encode_gap(
    e: &mut RangeEncoder<'_>,
    gap_len: &mut [[u16; 64]; 8],
    gap_top: &mut [[u16; 4]],
    prev_len: &mut u32,
    gap: u64,
) -> Result<(), super::range::Full> {
    use super::range::Full;
    let (len, top_bits, top, rest_bits, rest) = gap_parts(gap);
    let ctx = (*prev_len).min(7) as usize;
    e.tree(gap_len.get_mut(ctx).ok_or(Full)?, len - 1, 6)?;
    e.tree(gap_top.get_mut(len as usize).ok_or(Full)?, top_bits, top)?;
    e.direct(rest_bits, rest)?;
    *prev_len = len;
    Ok(())
}

/// Decodes a gap coded by [`encode_gap`] with the same probabilities.
pub(crate) fn decode_gap(
    d: &mut RangeDecoder<'_>,
    gap_len: &mut [[u16; 64]; 8],
    gap_top: &mut [[u16; 4]],
    prev_len: &mut u32,
) -> Option<u64> {
    let ctx = (*prev_len).min(7) as usize;
    let len = d.tree(gap_len.get_mut(ctx)?, 6)? + 1;
    let below = len - 1;
    let top = below.min(2);
    let top_bits = d.tree(gap_top.get_mut(len as usize)?, top)?;
    let rest = below - top;
    let rest_bits = d.direct(rest);
    *prev_len = len;
    Some(((1u64 << below) | (u64::from(top_bits) << rest) | rest_bits) - 1)
}

/// Codes one voxel: its gap to the previous one (not coded when `coded`
/// is false: the chunk header holds it) and its fields (the occupancy only
/// when `occupancy`).
fn encode_voxel(
    e: &mut RangeEncoder<'_>,
    m: &mut CodecModel,
    gap: u64,
    coded: bool,
    q: &Quantised,
    occupancy: bool,
) -> Result<(), super::range::Full> {
    use super::range::Full;
    if coded {
        encode_gap(e, &mut m.gap_len, &mut m.gap_top, &mut m.prev_len, gap)?;
    }
    let cls = class_symbol(q.class);
    e.tree(m.class.get_mut(m.prev_class as usize).ok_or(Full)?, cls as u32, 5)?;
    m.prev_class = cls as u32;
    e.tree(m.confidence.get_mut(cls).ok_or(Full)?, q.confidence, 3)?;
    if occupancy {
        e.tree(m.occupancy.get_mut(cls).ok_or(Full)?, q.occupancy, 2)?;
    }
    for (axis, &p) in q.position.iter().enumerate() {
        let ctx = position_context(cls);
        e.tree(m.position.get_mut(axis).and_then(|a| a.get_mut(ctx)).ok_or(Full)?, p, POSITION_BITS)?;
    }
    Ok(())
}

/// Decodes one voxel's gap (when `coded`; else `gap` is it) and fields
/// (the occupancy only when `occupancy`; else the lowest level, one hit);
/// `None` for a class symbol beyond the table.
fn decode_voxel(
    d: &mut RangeDecoder<'_>,
    m: &mut CodecModel,
    mut gap: u64,
    coded: bool,
    with_occupancy: bool,
) -> Option<(u64, Quantised)> {
    if coded {
        gap = decode_gap(d, &mut m.gap_len, &mut m.gap_top, &mut m.prev_len)?;
    }
    let cls = d.tree(m.class.get_mut(m.prev_class as usize)?, 5)? as usize;
    if cls >= CLASS_SYMBOLS {
        return None;
    }
    m.prev_class = cls as u32;
    let confidence = d.tree(m.confidence.get_mut(cls)?, 3)?;
    let occupancy = if with_occupancy { d.tree(m.occupancy.get_mut(cls)?, 2)? } else { 0 };
    let mut position = [0u32; 3];
    for (axis, p) in position.iter_mut().enumerate() {
        let ctx = position_context(cls);
        *p = d.tree(m.position.get_mut(axis)?.get_mut(ctx)?, POSITION_BITS)?;
    }
    let class = if cls == NUM_CLASSES { NO_CLASS } else { cls as u32 };
    Some((gap, Quantised { class, confidence, occupancy, position }))
}

pub(crate) fn write_varint(out: &mut [u8], at: &mut usize, mut v: u64) -> Result<(), EncodeError> {
    loop {
        let byte = (v & 0x7F) as u8;
        v >>= 7;
        let slot = out.get_mut(*at).ok_or(EncodeError::Buffer)?;
        *slot = if v == 0 { byte } else { byte | 0x80 };
        *at += 1;
        if v == 0 {
            return Ok(());
        }
    }
}

fn varint_len(v: u64) -> usize {
    let bits = 64 - v.max(1).leading_zeros() as usize;
    bits.div_ceil(7)
}

/// The voxel count a chunk announces (its first varint), without decoding it.
pub fn chunk_voxel_count(chunk: &[u8]) -> Option<u64> {
    read_varint(chunk, &mut 0, 5).ok()
}

pub(crate) fn read_varint(input: &[u8], at: &mut usize, max_bytes: usize) -> Result<u64, DecodeError> {
    let mut v = 0u64;
    for i in 0..max_bytes {
        let byte = *input.get(*at).ok_or(DecodeError::Truncated)?;
        *at += 1;
        v |= u64::from(byte & 0x7F) << (7 * i);
        if byte & 0x80 == 0 {
            // Canonical form only: no redundant zero continuation bytes.
            if byte == 0 && i > 0 {
                return Err(DecodeError::Varint);
            }
            return Ok(v);
        }
    }
    Err(DecodeError::Varint)
}

/// Streams a map out as chunks, learning in a [`CodecModel`] the caller
/// keeps and passes to each chunk (the same one throughout). The map is
/// borrowed (`O = &LocalMap`) or owned for the stream's life and given back
/// ([`MapEncoder::into_parts`]).
pub struct MapEncoder<'a, S: VoxelStorage, O: Borrow<LocalMap<S>> = &'a LocalMap<S>> {
    map: O,
    /// The caller's scratch; its first `map.len()` entries hold the order.
    scratch: &'a mut [u32],
    /// Voxels streamed: the map's, or a subset's.
    count: usize,
    next: usize,
    /// Whether each voxel's occupancy goes out ([`MapEncoder::without_occupancy`]).
    occupancy: bool,
    _storage: PhantomData<S>,
}

impl<'a, S: VoxelStorage, O: Borrow<LocalMap<S>>> MapEncoder<'a, S, O> {
    /// Prepares the Morton order of `map` in `scratch` (at least one `u32`
    /// per voxel); resets `model`, which codes every chunk.
    pub fn new(map: O, scratch: &'a mut [u32], model: &mut CodecModel) -> Result<Self, EncodeError> {
        stream_order(map.borrow(), scratch)?;
        model.reset();
        let count = map.borrow().len();
        Ok(MapEncoder { map, scratch, count, next: 0, occupancy: true, _storage: PhantomData })
    }

    /// Streams only the voxels whose indices are the first `count` entries
    /// of `scratch` (each a voxel of `map`, none twice): the changed voxels
    /// of an update. They are put in stream order here; resets `model`.
    pub fn subset(map: O, scratch: &'a mut [u32], count: usize, model: &mut CodecModel) -> Result<Self, EncodeError> {
        let encoder = Self::subset_continuing(map, scratch, count)?;
        model.reset();
        Ok(encoder)
    }

    /// [`MapEncoder::subset`] without resetting the model: the stream
    /// continues one whose model its decoder kept (an update, coded with
    /// the model the update to its base left: [`crate::wire::update`]).
    pub fn subset_continuing(map: O, scratch: &'a mut [u32], count: usize) -> Result<Self, EncodeError> {
        let m = map.borrow();
        let order = scratch.get_mut(..count).ok_or(EncodeError::Scratch)?;
        if order.iter().any(|&i| i as usize >= m.len()) {
            return Err(EncodeError::Scratch);
        }
        sort_by_code(m.voxels(), scratch, count)?;
        let order = scratch.get(..count).ok_or(EncodeError::Scratch)?;
        if order.windows(2).any(|w| w[0] == w[1]) {
            return Err(EncodeError::Scratch);
        }
        Ok(MapEncoder { map, scratch, count, next: 0, occupancy: true, _storage: PhantomData })
    }

    /// Streams no occupancy: each voxel as an update carries it
    /// ([`update_record`]), decoded by a [`MapDecoder::without_occupancy`].
    pub fn without_occupancy(mut self) -> Self {
        self.occupancy = false;
        self
    }

    /// The map streamed (whole or in part).
    pub fn map(&self) -> &LocalMap<S> {
        self.map.borrow()
    }

    /// The indices of the voxels streamed, in stream (Morton) order.
    pub fn order(&self) -> &[u32] {
        self.scratch.get(..self.count).unwrap_or(&[])
    }

    /// Gives the scratch back (its contents are the stream order), e.g. for
    /// the next stage of a robot that reuses it.
    pub fn into_scratch(self) -> &'a mut [u32] {
        self.scratch
    }

    /// Gives back the map and the scratch.
    pub fn into_parts(self) -> (O, &'a mut [u32]) {
        (self.map, self.scratch)
    }

    /// Digest of the whole map's encoded content (all voxels, in stream
    /// order): what [`MapDecoder::digest`] gives after the last chunk.
    pub fn digest(&self) -> u32 {
        digest_in_order(self.map(), self.order())
    }

    /// Index (in stream order) of the next voxel to encode.
    pub fn position(&self) -> usize {
        self.next
    }

    /// Voxels not yet encoded.
    pub fn remaining(&self) -> usize {
        self.count - self.next
    }

    /// Voxels streamed in all (the map's, or the subset's).
    pub fn count(&self) -> usize {
        self.count
    }

    /// Whether every voxel went out.
    pub fn is_done(&self) -> bool {
        self.next >= self.count
    }

    /// Writes the next chunk (as many voxels as surely fit in `out`, at
    /// least [`MIN_CHUNK`] bytes), coded with `model` (the one given to
    /// [`MapEncoder::new`]), and returns its length; 0 when done.
    pub fn next_chunk(&mut self, model: &mut CodecModel, out: &mut [u8]) -> Result<usize, EncodeError> {
        if self.is_done() {
            return Ok(0);
        }
        if out.len() < MIN_CHUNK {
            return Err(EncodeError::Buffer);
        }
        let map: &LocalMap<S> = self.map.borrow();
        let (order, start) = (self.scratch.get(..self.count).unwrap_or(&[]), self.next);
        let voxel = |i: usize| order.get(i).and_then(|&v| map.voxel(v as usize));
        let first = voxel(start).ok_or(EncodeError::Buffer)?;
        // The first code as a gap from the previous chunk's last one.
        let lead = match start.checked_sub(1).and_then(voxel) {
            Some(prev) => morton(first.key) - morton(prev.key) - 1,
            None => morton(first.key),
        };
        // The body goes after room for the largest header, then moves up.
        let room = varint_len((self.count - start) as u64) + varint_len(lead);
        let body = out.get_mut(room..).ok_or(EncodeError::Buffer)?;
        let capacity = body.len();
        let mut e = RangeEncoder::new(body);
        let (mut n, mut prev_code) = (0usize, morton(first.key));
        while let Some(v) = voxel(start + n) {
            if n > 0 && e.len_if_finished() + VOXEL_MAX > capacity {
                break;
            }
            let code = morton(v.key);
            let gap = if n > 0 { code - prev_code - 1 } else { lead };
            encode_voxel(&mut e, model, gap, n > 0, &quantise(v), self.occupancy).map_err(|_| EncodeError::Buffer)?;
            prev_code = code;
            n += 1;
        }
        let body_len = e.finish().map_err(|_| EncodeError::Buffer)?;
        let mut head = [0u8; CHUNK_HEADER_MAX];
        let mut at = 0;
        write_varint(&mut head, &mut at, n as u64)?;
        write_varint(&mut head, &mut at, lead)?;
        if at > room {
            return Err(EncodeError::Buffer);
        }
        out.copy_within(room..room + body_len, at);
        out.get_mut(..at).ok_or(EncodeError::Buffer)?.copy_from_slice(head.get(..at).unwrap_or(&[]));
        self.next += n;
        Ok(at + body_len)
    }
}

fn digest_in_order<S: VoxelStorage>(map: &LocalMap<S>, order: &[u32]) -> u32 {
    records_digest(order.iter().filter_map(|&i| map.voxel(i as usize)).map(|v| (morton(v.key), voxel_record(v))))
}

/// The order of `map`'s voxels in the stream (Morton order), in `scratch`.
pub(crate) fn stream_order<'s, S: VoxelStorage>(
    map: &LocalMap<S>,
    scratch: &'s mut [u32],
) -> Result<&'s mut [u32], EncodeError> {
    let n = map.len();
    let order = scratch.get_mut(..n).ok_or(EncodeError::Scratch)?;
    for (i, o) in order.iter_mut().enumerate() {
        *o = i as u32;
    }
    sort_by_code(map.voxels(), scratch, n)?;
    scratch.get_mut(..n).ok_or(EncodeError::Scratch)
}

/// Sorts the first `count` words of `scratch` (indices of `voxels`) by
/// their voxels' Morton codes ([`sort_indices_by_code`]: each index beside
/// its code where the scratch has two words a voxel).
fn sort_by_code(voxels: &[SemanticVoxel], scratch: &mut [u32], count: usize) -> Result<(), EncodeError> {
    let code = |i: u32| voxels.get(i as usize).map_or(u64::MAX, |v| morton(v.key));
    sort_indices_by_code(scratch, count, voxels.len(), code).then_some(()).ok_or(EncodeError::Scratch)
}

/// A voxel's record as the wire carries it (its quantised class,
/// confidence, occupancy and mean, packed): equal for two voxels of one
/// cell exactly when the wire would carry them alike. What an update
/// compares to find the voxels that changed.
pub fn voxel_record(v: &SemanticVoxel) -> u32 {
    pack(&quantise(v))
}

/// A voxel's record as a map update carries it: its [`voxel_record`] at
/// the lowest occupancy level. An update sends no occupancy
/// ([`MapEncoder::without_occupancy`]): nothing that matches reads it (a
/// pyramid keeps a voxel's mean, class and confidence), and it was about a
/// tenth of an update's bytes. A peer's copy holds each voxel at one hit,
/// whose record is this.
pub fn update_record(v: &SemanticVoxel) -> u32 {
    pack(&Quantised { occupancy: 0, ..quantise(v) })
}

/// Steps of each axis of the mean a held record may be from the map's
/// ([`within_step`]): two quarter cells. Matching reads a mean through
/// Gaussians at least half a cell wide, and a mean that moved two steps
/// was over a third of an update's changed voxels (town, true labels):
/// withheld, an update's bytes fell by a tenth (p95 over the map 0.27 to
/// 0.25) with the same estimates' availability and accuracy.
pub const MEAN_DEADBAND: u32 = 2;

/// Whether a voxel's record `now` is within the deadband of the record
/// `held` a peer has: the same class, the confidence at most one step
/// apart and each axis of the mean at most [`MEAN_DEADBAND`] steps. An
/// update resends a voxel only when it moved further, so a peer's copy is
/// never further than that from the map in these fields. The occupancy is
/// not compared: nothing that matches reads it (a pyramid keeps a voxel's
/// mean, class and confidence), and a young voxel's climbs a level with
/// most scans that see it (resending those was about a tenth of an
/// update's bytes); it goes out, current, whenever the voxel does.
pub fn within_step(held: u32, now: u32) -> bool {
    let band = |f: (u32, u32)| if f == CONFIDENCE_FIELD { 1 } else { MEAN_DEADBAND };
    field(held, CLASS_FIELD) == field(now, CLASS_FIELD)
        && STEPPED_FIELDS
            .iter()
            .filter(|&&f| f != OCCUPANCY_FIELD)
            .all(|&f| field(held, f).abs_diff(field(now, f)) <= band(f))
}

/// The digest of a map whose voxels, in stream (Morton) order, have these
/// cells' codes and records ([`voxel_record`]): what [`MapEncoder::digest`]
/// and [`MapDecoder::digest`] give for such a map.
pub fn records_digest(records: impl Iterator<Item = (u64, u32)>) -> u32 {
    let mut crc = Crc32::new();
    for (code, record) in records {
        digest_voxel(&mut crc, code, record);
    }
    crc.finish()
}

/// The digest [`MapEncoder::digest`] gives, without a codec model
/// (`scratch`: one `u32` per voxel).
pub fn map_digest<S: VoxelStorage>(map: &LocalMap<S>, scratch: &mut [u32]) -> Result<u32, EncodeError> {
    let order = stream_order(map, scratch)?;
    Ok(digest_in_order(map, order))
}

/// Rebuilds a map from its chunks, in order, learning in a [`CodecModel`]
/// the caller keeps and passes to each chunk (the same one throughout).
pub struct MapDecoder {
    expected: usize,
    decoded: usize,
    last: Option<u64>,
    digest: Crc32,
    /// Whether each voxel's occupancy is in the stream.
    occupancy: bool,
}

impl MapDecoder {
    /// A decoder for a map of `voxels` voxels; resets `model`, which
    /// decodes every chunk.
    pub fn new(voxels: usize, model: &mut CodecModel) -> Self {
        model.reset();
        Self::continuing(voxels)
    }

    /// [`MapDecoder::new`] without resetting the model: for a stream coded
    /// with [`MapEncoder::subset_continuing`], decoded with the model the
    /// stream it continues left.
    pub fn continuing(voxels: usize) -> Self {
        MapDecoder { expected: voxels, decoded: 0, last: None, digest: Crc32::new(), occupancy: true }
    }

    /// Decodes a stream of a [`MapEncoder::without_occupancy`]: each voxel
    /// at the lowest occupancy level, one hit ([`update_record`]).
    pub fn without_occupancy(mut self) -> Self {
        self.occupancy = false;
        self
    }

    /// Voxels decoded so far.
    pub fn decoded(&self) -> usize {
        self.decoded
    }

    /// Digest of the voxels decoded so far (compare with the sender's
    /// [`MapEncoder::digest`] once complete).
    pub fn digest(&self) -> u32 {
        self.digest.finish()
    }

    /// Whether all announced voxels arrived.
    pub fn is_complete(&self) -> bool {
        self.decoded == self.expected
    }

    /// Decodes one chunk into `map` with `model` (the one given to
    /// [`MapDecoder::new`]); returns the voxels it held.
    pub fn decode_chunk<K: VoxelSink + ?Sized>(
        &mut self,
        model: &mut CodecModel,
        chunk: &[u8],
        map: &mut K,
    ) -> Result<usize, DecodeError> {
        let mut at = 0;
        let n = read_varint(chunk, &mut at, 5)?;
        if n == 0 {
            return Err(DecodeError::Empty);
        }
        let n = usize::try_from(n).map_err(|_| DecodeError::TooMany)?;
        if n > self.expected - self.decoded {
            return Err(DecodeError::TooMany);
        }
        let lead = read_varint(chunk, &mut at, 7)?;
        let mut code = match self.last {
            Some(l) => l.checked_add(lead).and_then(|c| c.checked_add(1)).ok_or(DecodeError::Range)?,
            None => lead,
        };
        let mut d = RangeDecoder::new(chunk.get(at..).unwrap_or(&[]));
        for i in 0..n {
            let (gap, q) = decode_voxel(&mut d, model, lead, i > 0, self.occupancy).ok_or(DecodeError::Class)?;
            if i > 0 {
                code = code.checked_add(gap).and_then(|c| c.checked_add(1)).ok_or(DecodeError::Range)?;
            }
            if code >= MORTON_LIMIT {
                return Err(DecodeError::Range);
            }
            if self.last.is_some_and(|l| code <= l) {
                return Err(DecodeError::Order);
            }
            let key = key_of(code).ok_or(DecodeError::Range)?;
            map.accept(rebuild(key, &q)?).map_err(|e| match e {
                InsertError::DuplicateKey => DecodeError::Order,
                _ => DecodeError::Full,
            })?;
            digest_voxel(&mut self.digest, code, pack(&q));
            self.last = Some(code);
            self.decoded += 1;
        }
        // Every byte of the chunk, and no more.
        d.finish().map_err(|over| if over { DecodeError::Truncated } else { DecodeError::Trailing }).map(|()| n)
    }
}

#[cfg(test)]
mod deadband_tests {
    use super::*;

    /// The deadband: a step in the confidence and two in each axis of the
    /// mean are within it, two in the confidence or three in an axis are
    /// not, another class never is; the occupancy is not compared at all.
    #[test]
    fn the_deadband_compares_class_confidence_and_mean_not_occupancy() {
        let q = Quantised { class: 3, confidence: 2, occupancy: 0, position: [0, 1, 3] };
        let held = pack(&q);
        assert!(within_step(held, pack(&Quantised { occupancy: 3, ..q })));
        assert!(within_step(held, pack(&Quantised { confidence: 3, position: [1, 0, 3], ..q })));
        assert!(within_step(held, pack(&Quantised { confidence: 1, position: [2, 3, 1], ..q })));
        assert!(!within_step(held, pack(&Quantised { confidence: 4, ..q })));
        assert!(!within_step(held, pack(&Quantised { position: [3, 1, 3], ..q })));
        assert!(!within_step(held, pack(&Quantised { position: [0, 1, 0], ..q })));
        assert!(!within_step(held, pack(&Quantised { class: 4, ..q })));
        assert!(!within_step(held, pack(&Quantised { class: NO_CLASS, ..q })));
    }
}

#[cfg(test)]
mod scene_point_tests {
    use super::*;
    use crate::map::ScenePoint;

    /// Every voxel the decoder can give fits a [`ScenePoint`] exactly: each
    /// class (and none) at each confidence level, each quarter-cell mean.
    #[test]
    fn every_decoded_voxel_is_a_scene_point_exactly() {
        let key = VoxelKey::new(-3, 7, 1);
        for class in (0..NUM_CLASSES as u32).chain([NO_CLASS]) {
            for confidence in 0..CONFIDENCE_LEVELS.len() as u32 {
                for position in 0..(1u32 << (3 * POSITION_BITS)) {
                    let m = (1 << POSITION_BITS) - 1;
                    let q = Quantised {
                        class,
                        confidence,
                        occupancy: position % 4,
                        position: [position & m, (position >> POSITION_BITS) & m, position >> (2 * POSITION_BITS)],
                    };
                    let v = rebuild(key, &q).unwrap();
                    let p = ScenePoint::of(&v);
                    assert!(p.is_some(), "class {class} level {confidence} position {position}");
                    let p = p.unwrap();
                    assert_eq!((p.class(), p.confidence()), crate::map::class_and_confidence(&v));
                    assert_eq!(p.position(0.5), v.position(0.5));
                    assert_eq!(p.key, key);
                }
            }
        }
        // A decoded voxel encodes as it was decoded: a peer's copy kept by
        // updates digests as the sender's map does.
        for class in (0..NUM_CLASSES as u32).chain([NO_CLASS]) {
            for confidence in 0..CONFIDENCE_LEVELS.len() as u32 {
                for occupancy in 0..4 {
                    let q = Quantised { class, confidence, occupancy, position: [1, 2, 3] };
                    let q = if class == NO_CLASS { Quantised { confidence: 0, ..q } } else { q };
                    assert_eq!(quantise(&rebuild(key, &q).unwrap()), q, "{class} {confidence} {occupancy}");
                }
            }
        }
        // A mean the wire cannot carry is refused, not rounded.
        let fine = crate::map::SemanticVoxel::from_parts(key, [1, 2, 3], 0, 1, Default::default());
        assert_eq!(ScenePoint::of(&fine), None);
        assert_eq!(core::mem::size_of::<ScenePoint>(), 8);
    }
}
