//! The compact voxel encoding shared by map files and the link.
//!
//! Voxels travel in Morton (Z) order of their keys, so neighbours in space
//! are neighbours in the stream and a key costs only the gap to the previous
//! one, coded with an adaptive Golomb-Rice code (the parameter follows the
//! running mean of the gaps, identically on both sides). Per voxel:
//!
//! | field | bits |
//! |---|---|
//! | gap to the previous Morton code, minus one | Golomb-Rice, adaptive |
//! | class: same as the previous voxel's? | 1 (the chunk's first voxel: none) |
//! | class index (31: none), when it changed | 5 |
//! | confidence of the class, one of [`CONFIDENCE_LEVELS`] | 3 |
//! | occupancy: 1 to 4 hits' worth of log-odds | 2 |
//! | mean position, 1/16 of the voxel per axis | 12 |
//!
//! The stream is cut into *chunks* of a bounded size, decoded in order: a
//! chunk starts with its voxel count and the gap from the previous chunk's
//! last code to its first (the first chunk: the absolute code), so a map
//! larger than any buffer streams chunk by chunk and a lost chunk is resent
//! alone. The decoder checks everything: codes strictly
//! increasing across chunks (no duplicates), classes in range, no trailing
//! bits; it never panics, never loops without consuming input, never
//! allocates.
//!
//! The encoding is lossy, but idempotent: a decoded map encodes to the same
//! bytes. So a map read from a file and the same map received over the link
//! are identical.

use super::bits::{rice_len, BitReader, BitWriter, Overflow, Truncated, MAX_RICE_K};
use super::crc::Crc32;
use crate::classes::{Class, NUM_CLASSES};
use crate::map::labels::{LabelDistribution, SCORE_MAX, SCORE_UNITS_PER_NAT};
use crate::map::voxel::LOGODDS_UNITS;
use crate::map::{InsertError, LocalMap, SemanticVoxel, VoxelKey, VoxelStorage};

/// Probabilities a voxel's class confidence is rounded to.
pub const CONFIDENCE_LEVELS: [f32; 8] = [0.15, 0.35, 0.55, 0.7, 0.82, 0.91, 0.97, 0.995];

/// Log-odds of one hit in the encoding's occupancy levels (OctoMap's 0.7).
const OCCUPANCY_STEP: f32 = 0.85;
/// Bytes a chunk header takes at most (two LEB128 varints).
pub const CHUNK_HEADER_MAX: usize = 5 + 7;
/// Smallest chunk buffer the encoder accepts: a header and one voxel.
pub const MIN_CHUNK: usize = CHUNK_HEADER_MAX + 8;
const NO_CLASS: u32 = 31;
const MORTON_LIMIT: u64 = 1 << 48;

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
        position: [u32::from(m[0] >> 12), u32::from(m[1] >> 12), u32::from(m[2] >> 12)],
    }
}

/// Feeds one voxel's canonical record (6 bytes of code, 4 of quantised
/// fields) into a digest: the same in the encoder and the decoder, whatever
/// the chunking.
fn digest_voxel(crc: &mut Crc32, code: u64, q: &Quantised) {
    let packed = q.class
        | (q.confidence << 5)
        | (q.occupancy << 8)
        | (q.position[0] << 10)
        | (q.position[1] << 14)
        | (q.position[2] << 18);
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
    let mean = q.position.map(|p| ((p as u16) << 12) | 0x800);
    Ok(SemanticVoxel::from_parts(key, mean, occupancy, hits, labels))
}

/// The adaptive Golomb-Rice parameter, the same on both sides: the smallest
/// `k` with `count * 2^k >= sum` of the recent gaps.
#[derive(Clone, Copy)]
struct Adapt {
    sum: u64,
    count: u64,
}

impl Adapt {
    fn new() -> Self {
        Adapt { sum: 8, count: 1 }
    }
    fn k(&self) -> u32 {
        let mut k = 0;
        while k < MAX_RICE_K && (self.count << k) < self.sum {
            k += 1;
        }
        k
    }
    fn update(&mut self, gap: u64) {
        self.sum = self.sum.saturating_add(gap);
        self.count += 1;
        if self.count >= 32 {
            self.sum /= 2;
            self.count /= 2;
        }
    }
}

fn voxel_bits(gap: Option<u64>, adapt: &Adapt, q: &Quantised, prev_class: Option<u32>) -> usize {
    let mut bits = 3 + 2 + 12;
    if let Some(g) = gap {
        bits += rice_len(g, adapt.k());
    }
    bits += match prev_class {
        Some(c) if c == q.class => 1,
        Some(_) => 6,
        None => 5,
    };
    bits
}

fn write_voxel(
    w: &mut BitWriter<'_>,
    gap: Option<u64>,
    adapt: &Adapt,
    q: &Quantised,
    prev_class: Option<u32>,
) -> Result<(), Overflow> {
    if let Some(g) = gap {
        w.write_rice(g, adapt.k())?;
    }
    match prev_class {
        Some(c) if c == q.class => w.write(1, 1)?,
        Some(_) => {
            w.write(0, 1)?;
            w.write(q.class, 5)?;
        }
        None => w.write(q.class, 5)?,
    }
    w.write(q.confidence, 3)?;
    w.write(q.occupancy, 2)?;
    for p in q.position {
        w.write(p, 4)?;
    }
    Ok(())
}

fn write_varint(out: &mut [u8], at: &mut usize, mut v: u64) -> Result<(), EncodeError> {
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

fn read_varint(input: &[u8], at: &mut usize, max_bytes: usize) -> Result<u64, DecodeError> {
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

/// Streams a map out as chunks.
pub struct MapEncoder<'a, S: VoxelStorage> {
    map: &'a LocalMap<S>,
    /// The caller's scratch; its first `map.len()` entries hold the order.
    scratch: &'a mut [u32],
    next: usize,
}

impl<'a, S: VoxelStorage> MapEncoder<'a, S> {
    /// Prepares the Morton order of `map` in `scratch` (at least one `u32`
    /// per voxel).
    pub fn new(map: &'a LocalMap<S>, scratch: &'a mut [u32]) -> Result<Self, EncodeError> {
        let order = scratch.get_mut(..map.len()).ok_or(EncodeError::Scratch)?;
        for (i, o) in order.iter_mut().enumerate() {
            *o = i as u32;
        }
        let voxels = map.voxels();
        order.sort_unstable_by_key(|&i| voxels.get(i as usize).map(|v| morton(v.key)).unwrap_or(u64::MAX));
        Ok(MapEncoder { map, scratch, next: 0 })
    }

    /// The voxel indices in stream (Morton) order.
    fn order(&self) -> &[u32] {
        self.scratch.get(..self.map.len()).unwrap_or(&[])
    }

    /// Gives the scratch back (its contents are the stream order), e.g. for
    /// the next stage of a robot that reuses it.
    pub fn into_scratch(self) -> &'a mut [u32] {
        self.scratch
    }

    /// Digest of the whole map's encoded content (all voxels, in stream
    /// order): what [`MapDecoder::digest`] gives after the last chunk.
    pub fn digest(&self) -> u32 {
        let mut crc = Crc32::new();
        for v in self.order().iter().filter_map(|&i| self.map.voxel(i as usize)) {
            digest_voxel(&mut crc, morton(v.key), &quantise(v));
        }
        crc.finish()
    }

    /// Index (in stream order) of the next voxel to encode.
    pub fn position(&self) -> usize {
        self.next
    }

    /// Moves to voxel `index` of the stream (e.g. to encode a chunk again,
    /// smaller). Beyond the end means done.
    pub fn seek(&mut self, index: usize) {
        self.next = index.min(self.map.len());
    }

    /// Voxels not yet encoded.
    pub fn remaining(&self) -> usize {
        self.map.len() - self.next
    }

    /// Whether every voxel went out.
    pub fn is_done(&self) -> bool {
        self.next >= self.map.len()
    }

    /// Writes the next chunk (as many voxels as fit in `out`) and returns its
    /// length; 0 when done.
    pub fn next_chunk(&mut self, out: &mut [u8]) -> Result<usize, EncodeError> {
        if self.is_done() {
            return Ok(0);
        }
        if out.len() < MIN_CHUNK {
            return Err(EncodeError::Buffer);
        }
        let voxel = |i: usize| self.order().get(i).and_then(|&v| self.map.voxel(v as usize));
        let first = voxel(self.next).ok_or(EncodeError::Buffer)?;
        // The first code as a gap from the previous chunk's last one.
        let lead = match self.next.checked_sub(1).and_then(voxel) {
            Some(prev) => morton(first.key) - morton(prev.key) - 1,
            None => morton(first.key),
        };
        // Dry run: how many voxels fit after the header (a voxel takes at
        // least 18 bits, which bounds the count's varint).
        let count_len = varint_len((out.len() * 8 / 18) as u64);
        let budget = out.len().saturating_sub(count_len + varint_len(lead)) * 8;
        let (mut bits, mut n) = (0usize, 0usize);
        let (mut adapt, mut prev_code, mut prev_class) = (Adapt::new(), 0u64, None);
        while let Some(v) = voxel(self.next + n) {
            let code = morton(v.key);
            let q = quantise(v);
            let gap = (n > 0).then(|| code - prev_code - 1);
            let b = voxel_bits(gap, &adapt, &q, prev_class);
            if bits + b > budget {
                break;
            }
            bits += b;
            if let Some(g) = gap {
                adapt.update(g);
            }
            prev_code = code;
            prev_class = Some(q.class);
            n += 1;
        }
        if n == 0 {
            return Err(EncodeError::Buffer);
        }
        let mut at = 0;
        write_varint(out, &mut at, n as u64)?;
        write_varint(out, &mut at, lead)?;
        let mut w = BitWriter::new(out.get_mut(at..).ok_or(EncodeError::Buffer)?);
        let (mut adapt, mut prev_code, mut prev_class) = (Adapt::new(), 0u64, None);
        for i in 0..n {
            let v = voxel(self.next + i).ok_or(EncodeError::Buffer)?;
            let code = morton(v.key);
            let q = quantise(v);
            let gap = (i > 0).then(|| code - prev_code - 1);
            write_voxel(&mut w, gap, &adapt, &q, prev_class).map_err(|_| EncodeError::Buffer)?;
            if let Some(g) = gap {
                adapt.update(g);
            }
            prev_code = code;
            prev_class = Some(q.class);
        }
        self.next += n;
        Ok(at + w.byte_len())
    }
}

fn truncated(_: Truncated) -> DecodeError {
    DecodeError::Truncated
}

/// Rebuilds a map from its chunks, in order.
#[derive(Clone, Copy, Debug)]
pub struct MapDecoder {
    expected: usize,
    decoded: usize,
    last: Option<u64>,
    digest: Crc32,
}

impl MapDecoder {
    /// A decoder for a map of `voxels` voxels.
    pub fn new(voxels: usize) -> Self {
        MapDecoder { expected: voxels, decoded: 0, last: None, digest: Crc32::new() }
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

    /// Decodes one chunk into `map`; returns the voxels it held.
    pub fn decode_chunk<S: VoxelStorage>(&mut self, chunk: &[u8], map: &mut LocalMap<S>) -> Result<usize, DecodeError> {
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
        if code >= MORTON_LIMIT {
            return Err(DecodeError::Range);
        }
        let mut r = BitReader::new(chunk.get(at..).unwrap_or(&[]));
        let mut adapt = Adapt::new();
        let mut prev_class = None;
        for i in 0..n {
            if i > 0 {
                let gap = r.read_rice(adapt.k()).map_err(|_| DecodeError::Truncated)?;
                code = code.checked_add(gap).and_then(|c| c.checked_add(1)).ok_or(DecodeError::Range)?;
                if code >= MORTON_LIMIT {
                    return Err(DecodeError::Range);
                }
                adapt.update(gap);
            }
            if self.last.is_some_and(|l| code <= l) {
                return Err(DecodeError::Order);
            }
            let class = match prev_class {
                Some(c) => {
                    if r.read(1).map_err(truncated)? == 1 {
                        c
                    } else {
                        r.read(5).map_err(truncated)?
                    }
                }
                None => r.read(5).map_err(truncated)?,
            };
            if class != NO_CLASS && class as usize >= NUM_CLASSES {
                return Err(DecodeError::Class);
            }
            let confidence = r.read(3).map_err(truncated)?;
            let occupancy = r.read(2).map_err(truncated)?;
            let position =
                [r.read(4).map_err(truncated)?, r.read(4).map_err(truncated)?, r.read(4).map_err(truncated)?];
            let q = Quantised { class, confidence, occupancy, position };
            let key = key_of(code).ok_or(DecodeError::Range)?;
            map.insert_voxel(rebuild(key, &q)?).map_err(|e| match e {
                InsertError::DuplicateKey => DecodeError::Order,
                _ => DecodeError::Full,
            })?;
            digest_voxel(&mut self.digest, code, &q);
            self.last = Some(code);
            self.decoded += 1;
            prev_class = Some(class);
        }
        // Only zero padding to the byte boundary may follow.
        if r.remaining() >= 8 || r.read(r.remaining() as u32).map_err(|_| DecodeError::Truncated)? != 0 {
            return Err(DecodeError::Trailing);
        }
        Ok(n)
    }
}
