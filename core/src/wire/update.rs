//! Map updates between robots that keep driving: what changed in a
//! sender's map since a version its peer holds (voxels new or changed, in
//! the codec's encoding, and the cells that left it), and the peer's
//! answer. Each is one message, carried whole by whatever transport (the
//! UART link, a ROS 2 topic, a test); damage is caught by its CRC-32.
//!
//! An update (fixed integers little-endian; varints LEB128, each at most
//! five bytes and within 32 bits):
//!
//! | bytes | field |
//! |---|---|
//! | 1 | kind, [`UPDATE_KIND`] |
//! | 2 | epoch: the sender's session (a restarted sender takes another) |
//! | 4 | digest: the map at `version`'s digest ([`digest_of`]) |
//! | varint | base: the version it applies to (0: to nothing, a snapshot) |
//! | varint | the version it makes less the base (wrapping; never 0) |
//! | varint | voxels: the map's voxels at `version` |
//! | varint | removals: cells removed by rank (besides the cut's) |
//! | varint | upserts: voxels new |
//! | varint | changed: voxels held with another record |
//! | ... | the cut: a varint, 0 (none) or its threshold + 1; then, with one, its centre, three zigzag varints ([`Cut`]) |
//! | ... | the cells removed by rank, as runs of their ranks in the base map's Morton order: per run two varints, its start less the end of the run before (0 at first), its length - 1 |
//! | ... | with changed voxels: a varint, their bytes, then the range-coded changed voxels, each by its rank in the base map's Morton order and its record against the one held ([`super::change`]) |
//! | ... | the upserts in codec chunks, each a u16 length and the chunk, without occupancy ([`super::codec::update_record`]) |
//! | 4 | CRC-32 of everything before |
//!
//! New voxels are the cells the base map does not hold; a cell it holds
//! whose record changed goes among the changed voxels, named by its rank
//! and coded against the record it replaces: about 12 bits where it took
//! 14 as a new voxel (town, true labels), and a third of an update's voxels
//! with a network's labels.
//!
//! The codec models are not reset for each update: an update is
//! coded with the model the update to its base left (at the sender, the
//! model after encoding it; at the receiver, after decoding it), a
//! snapshot with a fresh one. An update's few hundred voxels left the
//! adaptive probabilities little to learn from: each update relearnt them
//! (on the town, an update's bytes over its map 0.24 to 0.21 at the median
//! when they carried over). Both sides keep the model of the version the
//! update builds on, which the base and version already pair.
//!
//! The digest is a sum over the map's voxels, each voxel's hash of its
//! cell and record ([`voxel_hash`]), not a CRC over the map in Morton
//! order: the receiver keeps it as it applies an update (less the voxels
//! removed or replaced, plus those written) instead of ordering and
//! hashing its whole copy each round (about 0.6 ms of a 9 ms round on
//! the host). It still covers every voxel the copy holds: a voxel missing,
//! extra or with another record changes it (but for a 2^-32 chance).
//!
//! Removals go first by a cut, then by rank, not by Morton code. A full
//! map that keeps driving evicts the far side of the ball it keeps around
//! the robot, so most of what leaves it is every cell beyond some distance
//! from where the robot is: a [`Cut`] (a centre and a threshold, about
//! fifteen bytes) names them all, and the receiver, which holds the base map, finds
//! them itself. Cells removed inside the cut's threshold (the eviction's
//! ties, and a peer sent only the part of a map that fits it) go by their
//! rank in the base map's Morton order: a rank names a cell as well as its
//! code, and they come in runs, about 0.3 bytes a removal (codes took 1.1).
//! On the town, an update that evicted took 161 bytes of ranks for about
//! 980 cells; with the cut, 47 at the mean (town seed 1, true labels:
//! about 20 cells a cut left, tied at its distance or cut about another
//! of the round's places).
//!
//! An answer ([`UpdateAck`], [`ACK_KIND`]): the epoch it answers, the
//! version and digest the receiver now holds (0, 0: nothing: send a
//! snapshot), the voxels it can hold, a CRC-32.

use super::change::{decode_gap, decode_record, encode_change, ChangeModel};
use super::codec::{read_varint, write_varint, CodecModel, DecodeError, MapDecoder, MapEncoder};
use super::crc::crc32;
use super::range::{RangeDecoder, RangeEncoder};
use crate::map::{LocalMap, VoxelKey, VoxelSink, VoxelStorage};

/// The least budget (bytes) an update may be given: room for its header,
/// its removals and a few voxels.
pub const MIN_UPDATE_BUDGET: u32 = 64;

/// First byte of an update (0xD1 was the first format, its removals as
/// Morton codes; 0xD3 reset the codec model for each update; 0xD4's
/// digest was a CRC over the map in Morton order; 0xD5 had no cut, every
/// removal by rank; 0xD6 carried each voxel's occupancy and coded a
/// changed voxel as a new one; 0xD7's header was 31 bytes of fixed
/// fields, about 16 more than its varints take).
pub const UPDATE_KIND: u8 = 0xD8;
/// First byte of an answer.
pub const ACK_KIND: u8 = 0xD2;
/// Bytes of an update's fixed fields (kind, epoch, digest); its varints
/// follow.
pub const UPDATE_HEADER: usize = 7;
/// Bytes of an answer.
pub const ACK_BYTES: usize = 1 + 2 + 4 + 4 + 4 + 4;
/// Largest codec chunk an update holds (its length is a u16).
pub const MAX_UPDATE_CHUNK: usize = 4096;

/// An update's fixed fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateHeader {
    /// The sender's session.
    pub epoch: u16,
    /// The version it applies to (0: a snapshot, to an empty map).
    pub base: u32,
    /// The version it makes.
    pub version: u32,
    /// The sender's map's voxels at `version`.
    pub voxels: u32,
    /// The digest of the map at `version` ([`digest_of`]).
    pub digest: u32,
    /// Cells removed by rank (those of the [`Cut`] besides).
    pub removals: u32,
    /// Voxels new: cells the base map does not hold.
    pub upserts: u32,
    /// Voxels the base map holds with another record.
    pub changed: u32,
}

/// The codec models an update is coded with, its new voxels' and its
/// changed voxels', as the update to its base left them (fresh for a
/// snapshot): the sender and the receiver each keep the pair.
#[derive(Clone, Copy, Default)]
pub struct UpdateModel {
    /// The new voxels' model.
    pub voxels: CodecModel,
    /// The changed voxels' model.
    pub changes: ChangeModel,
}

impl UpdateModel {
    /// Models that have seen nothing.
    pub const fn new() -> Self {
        UpdateModel { voxels: CodecModel::new(), changes: ChangeModel::new() }
    }

    /// Forgets everything, in place.
    pub fn reset(&mut self) {
        self.voxels.reset();
        self.changes.reset();
    }
}

/// The cells an update removes: by a [`Cut`], and by their ranks in the
/// base map's Morton order (ascending), `count` of them.
pub struct Removed<I: Iterator<Item = u32>> {
    /// The cut, if any.
    pub cut: Option<Cut>,
    /// The ranks of the cells removed besides the cut's.
    pub ranks: I,
    /// How many ranks.
    pub count: usize,
}

/// Where an update's changed voxels go: the copy of its base map.
pub trait ChangeSink {
    /// The record held for the cell of this rank in the base map's Morton
    /// order ([`super::codec::update_record`]); `None`: no such rank.
    fn held(&mut self, rank: u32) -> Option<u32>;
    /// Gives that cell, which held `held`, the record `record`.
    fn change(&mut self, rank: u32, held: u32, record: u32) -> Result<(), DecodeError>;
}

/// The cells an update removes by distance: every cell of the base map
/// whose centre is at least `threshold` from `centre`, squared, in 32nds
/// of a cell (integers: the sender and the receiver find the same cells). A
/// full map evicts the far side of the ball it keeps ([`crate::map::FullPolicy`]),
/// so this names most of an update's removals in about fifteen bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cut {
    /// The centre, in 32nds of a cell (a cell `k`'s centre is at `32 k +
    /// 16`), each axis within [`Cut::MAX_CENTRE`]. (Half cells left a
    /// tenth more cells to name by rank.)
    pub centre: [i32; 3],
    /// Squared distance (32nds of a cell) from which cells are removed.
    pub threshold: u64,
}

impl Cut {
    /// Largest centre coordinate, in 32nds of a cell, either way: past the
    /// farthest cell a key reaches (2^20), so any cut can be said.
    pub const MAX_CENTRE: i32 = 1 << 22;

    /// The cut about `centre` (map coordinates, metres) for a map of
    /// `resolution`: its centre the nearest 32nd of a cell (clamped; a centre
    /// that is not finite is the origin), its threshold to be set.
    pub fn about(centre: [f32; 3], resolution: f32) -> Cut {
        let step = |v: f32| {
            let h = libm::roundf(CUT_STEPS as f32 * v / resolution);
            if h.is_finite() {
                (h as i32).clamp(-Cut::MAX_CENTRE, Cut::MAX_CENTRE)
            } else {
                0
            }
        };
        Cut { centre: centre.map(step), threshold: u64::MAX }
    }

    /// The centre in map coordinates (metres) for a map of `resolution`:
    /// where the sender was, to a 32nd of a cell.
    pub fn centre_m(&self, resolution: f32) -> [f32; 3] {
        self.centre.map(|c| c as f32 * resolution / CUT_STEPS as f32)
    }

    /// The squared distance of a cell's centre from the cut's, in 32nds of
    /// a cell.
    pub fn distance_sq(&self, key: VoxelKey) -> u64 {
        let axis = |k: i16, c: i32| {
            let d = (CUT_STEPS * i64::from(k) + CUT_STEPS / 2 - i64::from(c)).unsigned_abs();
            d * d
        };
        axis(key.x, self.centre[0]) + axis(key.y, self.centre[1]) + axis(key.z, self.centre[2])
    }

    /// Whether the cut removes the cell of `key`.
    pub fn removes(&self, key: VoxelKey) -> bool {
        self.distance_sq(key) >= self.threshold
    }
}

fn zigzag(v: i32) -> u64 {
    u64::from(((v << 1) ^ (v >> 31)) as u32)
}

fn unzigzag(v: u64) -> Option<i32> {
    let v = u32::try_from(v).ok()?;
    Some(((v >> 1) as i32) ^ -((v & 1) as i32))
}

/// Steps of a cut's centre in a cell.
const CUT_STEPS: i64 = 32;

/// Bytes the cut's threshold takes at most (a squared distance below 2^49).
const THRESHOLD_BYTES: usize = 8;

fn write_cut(out: &mut [u8], at: &mut usize, cut: Option<&Cut>) -> Result<(), UpdateError> {
    let buffer = |_| UpdateError::Buffer;
    match cut {
        None => write_varint(out, at, 0).map_err(buffer),
        Some(c) => {
            write_varint(out, at, c.threshold.saturating_add(1)).map_err(buffer)?;
            c.centre.iter().try_for_each(|&v| write_varint(out, at, zigzag(v)).map_err(buffer))
        }
    }
}

fn read_cut(body: &[u8], at: &mut usize) -> Result<Option<Cut>, UpdateError> {
    let t = read_varint(body, at, THRESHOLD_BYTES).map_err(|_| UpdateError::Counts)?;
    if t == 0 {
        return Ok(None);
    }
    let mut centre = [0i32; 3];
    for c in &mut centre {
        let v = read_varint(body, at, 5).map_err(|_| UpdateError::Counts)?;
        *c = unzigzag(v).filter(|v| v.abs() <= Cut::MAX_CENTRE).ok_or(UpdateError::Counts)?;
    }
    Ok(Some(Cut { centre, threshold: t - 1 }))
}

/// A receiver's answer: what it holds of the sender's map now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateAck {
    /// The sender's epoch it answers.
    pub epoch: u16,
    /// The version it holds (0: none).
    pub version: u32,
    /// The digest of what it holds.
    pub digest: u32,
    /// Voxels it can hold of the sender's map.
    pub capacity: u32,
}

/// Why an update or an answer was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateError {
    /// Shorter than its fixed fields, or than what they announce.
    Truncated,
    /// The CRC-32 does not match: damaged.
    Checksum,
    /// Not the kind of message expected.
    Kind,
    /// Counts that do not fit the message or each other.
    Counts,
    /// Removed ranks out of order or out of range.
    Removal,
    /// Changed voxels out of order, beyond the base map or not a record.
    Changed,
    /// The upserts' chunks did not decode.
    Decode(DecodeError),
    /// Bytes after the last chunk.
    Trailing,
    /// The output buffer is too small (sending).
    Buffer,
}

impl core::fmt::Display for UpdateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            UpdateError::Truncated => f.write_str("update truncated"),
            UpdateError::Checksum => f.write_str("update damaged (CRC-32 mismatch)"),
            UpdateError::Kind => f.write_str("not a map update"),
            UpdateError::Counts => f.write_str("update counts do not fit the message"),
            UpdateError::Removal => f.write_str("removed ranks out of order or range"),
            UpdateError::Changed => f.write_str("changed voxels out of order or range, or not a record"),
            UpdateError::Decode(e) => write!(f, "update voxels: {e}"),
            UpdateError::Trailing => f.write_str("bytes after the update's last chunk"),
            UpdateError::Buffer => f.write_str("update buffer too small"),
        }
    }
}

impl core::error::Error for UpdateError {}

/// One voxel's share of a map's digest: a hash of its cell's Morton code
/// and its record ([`super::codec::update_record`]), 32-bit arithmetic
/// only (murmur3's finaliser, three times), the same on every platform.
pub fn voxel_hash(code: u64, record: u32) -> u32 {
    fn mix(mut h: u32) -> u32 {
        h ^= h >> 16;
        h = h.wrapping_mul(0x85EB_CA6B);
        h ^= h >> 13;
        h = h.wrapping_mul(0xC2B2_AE35);
        h ^ (h >> 16)
    }
    mix(mix(mix(record ^ 0x2545_F491) ^ (code >> 32) as u32) ^ code as u32)
}

/// The digest of a map whose voxels have these cells' codes and records:
/// the wrapping sum of their [`voxel_hash`]es (0 for an empty map), in any
/// order.
pub fn digest_of(records: impl Iterator<Item = (u64, u32)>) -> u32 {
    records.fold(0u32, |d, (code, record)| d.wrapping_add(voxel_hash(code, record)))
}

fn put(out: &mut [u8], at: &mut usize, bytes: &[u8]) -> Result<(), UpdateError> {
    let dst = out.get_mut(*at..*at + bytes.len()).ok_or(UpdateError::Buffer)?;
    dst.copy_from_slice(bytes);
    *at += bytes.len();
    Ok(())
}

fn u32_at(bytes: &[u8], at: usize) -> Result<u32, UpdateError> {
    let b = bytes.get(at..at + 4).ok_or(UpdateError::Truncated)?;
    Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

fn u16_at(bytes: &[u8], at: usize) -> Result<u16, UpdateError> {
    let b = bytes.get(at..at + 2).ok_or(UpdateError::Truncated)?;
    Ok(u16::from_le_bytes([b[0], b[1]]))
}

/// Writes an update into `out`: `header` (its `upserts` taken from
/// `upserts`), the cells `removed` (no cut for a snapshot), the
/// `header.changed` voxels `changed` (each its rank in the base map's
/// Morton order, ascending, the record held and the record now), the
/// voxels `upserts` streams (a [`MapEncoder::subset_continuing`]
/// [`MapEncoder::without_occupancy`] of the new voxels, or none) coded
/// with `model`: the models encoding the update to the base left, fresh
/// for a snapshot. Returns its length.
pub fn write_update<'m, S: VoxelStorage + 'm>(
    header: &UpdateHeader,
    removed: Removed<impl Iterator<Item = u32>>,
    changed: impl Iterator<Item = (u32, u32, u32)>,
    upserts: Option<&mut MapEncoder<'_, S, &'m LocalMap<S>>>,
    model: &mut UpdateModel,
    out: &mut [u8],
) -> Result<usize, UpdateError> {
    let count = upserts.as_ref().map_or(0, |e| e.count());
    let mut at = 0;
    put(out, &mut at, &[UPDATE_KIND])?;
    put(out, &mut at, &header.epoch.to_le_bytes())?;
    put(out, &mut at, &header.digest.to_le_bytes())?;
    let step = header.version.wrapping_sub(header.base);
    let fields = [header.base, step, header.voxels, removed.count as u32, count as u32, header.changed];
    for v in fields {
        write_varint(out, &mut at, u64::from(v)).map_err(|_| UpdateError::Buffer)?;
    }
    write_cut(out, &mut at, removed.cut.as_ref())?;
    write_removals(out, &mut at, removed.ranks, removed.count)?;
    write_changes(out, &mut at, changed, header.changed, &mut model.changes)?;
    if let Some(encoder) = upserts {
        while !encoder.is_done() {
            let room = out.len().saturating_sub(at + 2 + 4).min(MAX_UPDATE_CHUNK);
            let end = at + 2 + room;
            let chunk = out.get_mut(at + 2..end).ok_or(UpdateError::Buffer)?;
            let n = encoder.next_chunk(&mut model.voxels, chunk).map_err(|_| UpdateError::Buffer)?;
            put(out, &mut at, &(n as u16).to_le_bytes())?;
            at += n;
        }
    }
    let crc = crc32(out.get(..at).ok_or(UpdateError::Buffer)?);
    put(out, &mut at, &crc.to_le_bytes())?;
    Ok(at)
}

/// An update read and checked (kind, CRC-32, counts against its length,
/// removed cells in order): its fields, its cut, its removed cells and its
/// voxels.
#[derive(Clone, Copy, Debug)]
pub struct UpdateView<'a> {
    /// The fixed fields.
    pub header: UpdateHeader,
    /// The cells it removes by distance, if any.
    pub cut: Option<Cut>,
    body: &'a [u8],
    runs_at: usize,
    changes_at: usize,
    chunks_at: usize,
}

impl<'a> UpdateView<'a> {
    /// Reads an update; nothing in it sizes anything before it is checked
    /// against the message's length.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, UpdateError> {
        if bytes.len() < UPDATE_HEADER + 4 {
            return Err(UpdateError::Truncated);
        }
        if bytes.first() != Some(&UPDATE_KIND) {
            return Err(UpdateError::Kind);
        }
        let body = bytes.get(..bytes.len() - 4).ok_or(UpdateError::Truncated)?;
        if crc32(body) != u32_at(bytes, bytes.len() - 4)? {
            return Err(UpdateError::Checksum);
        }
        let mut at = UPDATE_HEADER;
        let mut field = || {
            let v = read_varint(body, &mut at, 5).map_err(|_| UpdateError::Truncated)?;
            u32::try_from(v).map_err(|_| UpdateError::Counts)
        };
        let (base, step) = (field()?, field()?);
        let (voxels, removals, upserts, changed) = (field()?, field()?, field()?, field()?);
        let header = UpdateHeader {
            epoch: u16_at(body, 1)?,
            base,
            version: base.wrapping_add(step),
            voxels,
            digest: u32_at(body, 3)?,
            removals,
            upserts,
            changed,
        };
        let room = body.len().saturating_sub(at) as u64;
        let sent = u64::from(header.upserts) + u64::from(header.changed);
        // A run of removals takes two bytes at least, a voxel a bit at
        // least; a snapshot removes nothing; a map holds what it says.
        let counts_fit = (header.removals == 0 || room >= 2)
            && sent <= 8 * room
            && sent <= u64::from(header.voxels)
            && (header.base != 0 || (header.removals == 0 && header.changed == 0 && header.upserts == header.voxels))
            && header.version != header.base;
        if !counts_fit {
            return Err(UpdateError::Counts);
        }
        let cut = read_cut(body, &mut at)?;
        if cut.is_some() && header.base == 0 {
            // A snapshot applies to nothing: it has nothing to cut.
            return Err(UpdateError::Counts);
        }
        let runs_at = at;
        // Each run two bytes at least: as many runs as the message holds.
        let (mut end, mut total) = (0u64, 0u64);
        while total < u64::from(header.removals) {
            let (start, len) = next_run(body, &mut at, end)?;
            total += len;
            end = start + len;
        }
        if total != u64::from(header.removals) {
            return Err(UpdateError::Counts);
        }
        let mut changes_at = at;
        if header.changed > 0 {
            let len = read_varint(body, &mut at, 5).map_err(|_| UpdateError::Truncated)?;
            changes_at = at;
            at = usize::try_from(len).ok().and_then(|l| at.checked_add(l)).ok_or(UpdateError::Truncated)?;
            if at > body.len() {
                return Err(UpdateError::Truncated);
            }
        }
        Ok(UpdateView { header, cut, body, runs_at, changes_at, chunks_at: at })
    }

    /// The ranks in the base map's Morton order of the cells removed
    /// besides the cut's, ascending.
    pub fn removed(&self) -> impl Iterator<Item = u32> + '_ {
        let (mut at, mut end, mut run) = (self.runs_at, 0u64, 0..0u64);
        (0..self.header.removals).map_while(move |_| {
            if run.is_empty() {
                let (start, len) = next_run(self.body, &mut at, end).ok()?;
                end = start + len;
                run = start..end;
            }
            run.next().and_then(|r| u32::try_from(r).ok())
        })
    }

    /// Applies the changed voxels to `sink` (the copy of the base map), in
    /// rank order, with `model`: the model decoding the update to the base
    /// left (a snapshot resets it here); every byte of their section is
    /// used, or it is an error.
    pub fn decode_changes<K: ChangeSink + ?Sized>(
        &self,
        model: &mut ChangeModel,
        sink: &mut K,
    ) -> Result<(), UpdateError> {
        if self.header.base == 0 {
            model.reset();
        }
        if self.header.changed == 0 {
            return Ok(());
        }
        let bytes = self.body.get(self.changes_at..self.chunks_at).ok_or(UpdateError::Truncated)?;
        let mut d = RangeDecoder::new(bytes);
        let mut next = 0u64;
        for _ in 0..self.header.changed {
            let gap = decode_gap(&mut d, model).ok_or(UpdateError::Changed)?;
            let rank = next.checked_add(gap).and_then(|r| u32::try_from(r).ok()).ok_or(UpdateError::Changed)?;
            let held = sink.held(rank).ok_or(UpdateError::Changed)?;
            let record = decode_record(&mut d, model, held).ok_or(UpdateError::Changed)?;
            sink.change(rank, held, record).map_err(|_| UpdateError::Changed)?;
            next = u64::from(rank) + 1;
        }
        d.finish().map_err(|over| if over { UpdateError::Truncated } else { UpdateError::Trailing })
    }

    /// Decodes the upserts into `sink`, chunk by chunk, with `model`: the
    /// model decoding the update to the base left (a snapshot resets it
    /// here); every byte of the update is used, or it is an error.
    pub fn decode_upserts<K: VoxelSink + ?Sized>(
        &self,
        model: &mut CodecModel,
        sink: &mut K,
    ) -> Result<(), UpdateError> {
        if self.header.base == 0 {
            model.reset();
        }
        let mut decoder = MapDecoder::continuing(self.header.upserts as usize).without_occupancy();
        let mut at = self.chunks_at;
        while !decoder.is_complete() {
            let len = usize::from(u16_at(self.body, at)?);
            let chunk = self.body.get(at + 2..at + 2 + len).ok_or(UpdateError::Truncated)?;
            decoder.decode_chunk(model, chunk, sink).map_err(UpdateError::Decode)?;
            at += 2 + len;
        }
        if at != self.body.len() {
            return Err(UpdateError::Trailing);
        }
        Ok(())
    }

    /// The update's bytes on the wire (with its CRC).
    pub fn wire_len(&self) -> usize {
        self.body.len() + 4
    }
}

/// Writes the changed voxels (rank, record held, record now; ranks
/// ascending), `count` of them: a varint, their bytes, then the range-coded
/// voxels ([`super::change`]).
fn write_changes(
    out: &mut [u8],
    at: &mut usize,
    changed: impl Iterator<Item = (u32, u32, u32)>,
    count: u32,
    model: &mut ChangeModel,
) -> Result<(), UpdateError> {
    if count == 0 {
        return if changed.count() == 0 { Ok(()) } else { Err(UpdateError::Counts) };
    }
    // The voxels after room for the longest length, then moved up.
    const ROOM: usize = 5;
    let body = out.get_mut(*at + ROOM..).ok_or(UpdateError::Buffer)?;
    let mut e = RangeEncoder::new(body);
    let (mut written, mut next) = (0u32, 0u64);
    for (rank, held, now) in changed {
        let gap = u64::from(rank).checked_sub(next).ok_or(UpdateError::Changed)?;
        encode_change(&mut e, model, gap, held, now).map_err(|_| UpdateError::Buffer)?;
        next = u64::from(rank) + 1;
        written += 1;
    }
    if written != count {
        return Err(UpdateError::Counts);
    }
    let len = e.finish().map_err(|_| UpdateError::Buffer)?;
    let start = *at + ROOM;
    write_varint(out, at, len as u64).map_err(|_| UpdateError::Buffer)?;
    out.copy_within(start..start + len, *at);
    *at += len;
    Ok(())
}

/// Writes the removed ranks (ascending) as runs: per run, its start less
/// the end of the run before, and its length - 1, as varints.
fn write_removals(
    out: &mut [u8],
    at: &mut usize,
    removed: impl Iterator<Item = u32>,
    removals: usize,
) -> Result<(), UpdateError> {
    let mut emit = |start: u64, len: u64, end: u64, at: &mut usize| {
        write_varint(out, at, start - end).and_then(|_| write_varint(out, at, len - 1)).map_err(|_| UpdateError::Buffer)
    };
    let (mut written, mut end, mut run) = (0usize, 0u64, None::<(u64, u64)>);
    for rank in removed.map(u64::from) {
        written += 1;
        run = match run {
            None => Some((rank, 1)),
            Some((s, l)) if rank == s + l => Some((s, l + 1)),
            Some((s, l)) if rank > s + l => {
                emit(s, l, end, at)?;
                end = s + l;
                Some((rank, 1))
            }
            Some(_) => return Err(UpdateError::Removal),
        };
    }
    if let Some((s, l)) = run {
        emit(s, l, end, at)?;
    }
    if written != removals {
        return Err(UpdateError::Counts);
    }
    Ok(())
}

/// The next run of removed ranks after `end`: its start and length.
fn next_run(body: &[u8], at: &mut usize, end: u64) -> Result<(u64, u64), UpdateError> {
    let gap = read_varint(body, at, 5).map_err(|_| UpdateError::Truncated)?;
    let len = read_varint(body, at, 5).map_err(|_| UpdateError::Truncated)? + 1;
    let start = end + gap;
    if start + len > u64::from(u32::MAX) {
        return Err(UpdateError::Removal);
    }
    Ok((start, len))
}

impl UpdateAck {
    /// The answer's bytes.
    pub fn encode(&self) -> [u8; ACK_BYTES] {
        let mut out = [0u8; ACK_BYTES];
        out[0] = ACK_KIND;
        out[1..3].copy_from_slice(&self.epoch.to_le_bytes());
        out[3..7].copy_from_slice(&self.version.to_le_bytes());
        out[7..11].copy_from_slice(&self.digest.to_le_bytes());
        out[11..15].copy_from_slice(&self.capacity.to_le_bytes());
        let crc = crc32(&out[..15]);
        out[15..19].copy_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads an answer, its CRC-32 checked.
    pub fn decode(bytes: &[u8]) -> Result<UpdateAck, UpdateError> {
        if bytes.len() != ACK_BYTES {
            return Err(UpdateError::Truncated);
        }
        if bytes.first() != Some(&ACK_KIND) {
            return Err(UpdateError::Kind);
        }
        if crc32(bytes.get(..15).ok_or(UpdateError::Truncated)?) != u32_at(bytes, 15)? {
            return Err(UpdateError::Checksum);
        }
        Ok(UpdateAck {
            epoch: u16_at(bytes, 1)?,
            version: u32_at(bytes, 3)?,
            digest: u32_at(bytes, 7)?,
            capacity: u32_at(bytes, 11)?,
        })
    }
}
