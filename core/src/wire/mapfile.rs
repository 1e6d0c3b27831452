//! The `.cmap` map file, read and written without an allocator: the link's
//! compact voxel encoding ([`super::codec`]) in a versioned, checksummed
//! container, so a map read from a file and the same map received over the
//! link are identical.
//!
//! Layout (format 4):
//!
//! | bytes | content |
//! |---|---|
//! | 4 | magic `CMAP` |
//! | 2 | format version, u16 little endian |
//! | 4 | header length, u32 little endian |
//! | n | header ([`MapFileHeader`], postcard) |
//! | … | chunks, each a LEB128 length then the chunk |
//! | 4 | CRC-32 of everything before it, little endian |
//!
//! Files of another version are refused by name, never misread; every
//! truncation, flipped byte, bad chunk or impossible count is a typed error
//! with the byte offset where it was found.

use super::codec::{self, CodecModel, DecodeError, EncodeError, MapDecoder, MapEncoder};
use super::crc::{crc32, Crc32};
use crate::classes::CLASS_TABLE_VERSION;
use crate::map::{LocalMap, VoxelSink, VoxelStorage};
use serde::{Deserialize, Serialize};

/// File magic.
pub const MAGIC: [u8; 4] = *b"CMAP";
/// Format version this build reads and writes.
pub const MAP_FILE_VERSION: u16 = 4;
/// Magic, version and header length.
pub const PREAMBLE: usize = 10;
/// Chunk size in files (the link uses smaller ones).
pub const FILE_CHUNK: usize = 4096;
/// Most voxels a byte of encoding can hold: a voxel is 22 coded decisions
/// at least, each costing at least log2(2048/2017) bits (the most skewed
/// probability), so about half a bit. Bounds the voxel count a file can claim.
const MAX_VOXELS_PER_BYTE: usize = 16;

/// What a map file says about its map. `S` is the text of its source:
/// `&str` borrowed from the file's bytes here (no allocator), an owned
/// string on a host ([`MapFileHeader::map_source`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapFileHeader<S> {
    /// Class table the labels refer to ([`CLASS_TABLE_VERSION`]).
    pub class_table_version: u16,
    /// Voxel edge length (m).
    pub resolution: f32,
    /// Label sensor model's accuracy used to fuse the map.
    pub label_accuracy: f32,
    /// Number of voxel records.
    pub voxel_count: u32,
    /// Timestamp of the anchor scan (s), if known.
    pub anchor_time: Option<f64>,
    /// Where the map came from, e.g. `kitti00 0:5` (UTF-8, as written:
    /// print it escaped).
    pub source: Option<S>,
}

impl<S> MapFileHeader<S> {
    /// The same header with its source text converted (e.g. to an owned
    /// string).
    pub fn map_source<T>(self, f: impl FnOnce(S) -> T) -> MapFileHeader<T> {
        MapFileHeader {
            class_table_version: self.class_table_version,
            resolution: self.resolution,
            label_accuracy: self.label_accuracy,
            voxel_count: self.voxel_count,
            anchor_time: self.anchor_time,
            source: self.source.map(f),
        }
    }
}

/// Which part of a file an offset points into.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Part {
    /// Magic, version and header length.
    Preamble,
    /// The postcard header.
    Header,
    /// A chunk or its length.
    Chunk,
    /// The closing CRC-32.
    Checksum,
}

impl Part {
    fn as_str(&self) -> &'static str {
        match self {
            Part::Preamble => "preamble",
            Part::Header => "header",
            Part::Chunk => "chunk",
            Part::Checksum => "checksum",
        }
    }
}

/// Why a map file was rejected. Offsets count bytes from the file's start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MapFileError {
    /// Not a map file (no `CMAP` magic).
    Magic,
    /// Another format version.
    Version(u16),
    /// The file ends inside `part`, which started at `offset` and needs
    /// `needed` bytes in all (the file has `len`).
    Truncated {
        /// What was being read.
        part: Part,
        /// Where that part starts.
        offset: u32,
        /// Bytes the file would need to hold it.
        needed: u32,
        /// Bytes the file has.
        len: u32,
    },
    /// The structure is whole but the CRC does not match: corrupted bytes.
    Checksum {
        /// CRC stored in the file.
        stored: u32,
        /// CRC of the bytes before it.
        computed: u32,
    },
    /// The header does not decode.
    Header,
    /// Labels refer to another class table.
    ClassTable(u16),
    /// Resolution or label accuracy not usable (non-finite, out of range).
    Numbers,
    /// The header claims more voxels than the chunk bytes can hold.
    TooManyVoxels {
        /// Voxels claimed.
        claimed: u32,
        /// Bytes of chunks.
        chunk_bytes: u32,
    },
    /// The map to read into has another resolution than the file.
    Resolution,
    /// A chunk did not decode.
    Chunk {
        /// Offset of the chunk's length.
        offset: u32,
        /// Why.
        error: DecodeError,
    },
    /// Fewer voxels than announced.
    Incomplete {
        /// Voxels decoded.
        present: u32,
        /// Voxels announced.
        announced: u32,
    },
    /// Writing: the output refused bytes, or the map could not be encoded.
    Write,
}

impl core::fmt::Display for MapFileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MapFileError::Magic => f.write_str("not a cosem map file (bad magic)"),
            MapFileError::Version(v) => {
                write!(f, "map format version {v}, this build reads version {MAP_FILE_VERSION}")
            }
            MapFileError::Truncated { part, offset, needed, len } => write!(
                f,
                "truncated: the {} at byte offset {offset} needs the file to be {needed} bytes, it has {len}",
                part.as_str()
            ),
            MapFileError::Checksum { stored, computed } => write!(
                f,
                "checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupted"
            ),
            MapFileError::Header => write!(f, "byte offset {PREAMBLE}: the header does not decode"),
            MapFileError::ClassTable(v) => write!(
                f,
                "byte offset {PREAMBLE}: class table version {v} (this build: {CLASS_TABLE_VERSION})"
            ),
            MapFileError::Numbers => {
                write!(f, "byte offset {PREAMBLE}: resolution or label accuracy out of range")
            }
            MapFileError::TooManyVoxels { claimed, chunk_bytes } => write!(
                f,
                "byte offset {PREAMBLE}: header claims {claimed} voxels, more than {chunk_bytes} bytes of chunks can hold"
            ),
            MapFileError::Resolution => f.write_str("the map's resolution differs from the file's"),
            MapFileError::Chunk { offset, error } => write!(f, "byte offset {offset}: chunk: {error}"),
            MapFileError::Incomplete { present, announced } => {
                write!(f, "{present} of {announced} voxels present")
            }
            MapFileError::Write => f.write_str("the map could not be written"),
        }
    }
}

impl core::error::Error for MapFileError {}

/// A parsed (checked, not yet decoded) map file.
#[derive(Clone, Copy, Debug)]
pub struct MapFile<'a> {
    /// Its header.
    pub header: MapFileHeader<&'a str>,
    /// The chunk stream.
    chunks: &'a [u8],
    /// Offset of the chunk stream in the file.
    chunks_at: usize,
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at + 4)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Reads one LEB128 length at `at`; `None` if it runs off `bytes` or past
/// 28 bits.
fn leb128(bytes: &[u8], at: &mut usize) -> Option<usize> {
    let mut len = 0usize;
    for shift in [0, 7, 14, 21] {
        let b = *bytes.get(*at)?;
        *at += 1;
        len |= usize::from(b & 0x7F) << shift;
        if b & 0x80 == 0 {
            return Some(len);
        }
    }
    None
}

fn truncated(part: Part, offset: usize, needed: usize, len: usize) -> MapFileError {
    let c = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
    MapFileError::Truncated { part, offset: c(offset), needed: c(needed), len: c(len) }
}

/// Tells a truncated file from a corrupted one when the CRC fails: walks
/// the chunks from the header on, adding up the voxels each announces. A
/// whole file has a chunk boundary exactly 4 bytes before its end (where
/// the CRC starts) with all the header's voxels announced before it: then
/// bytes were changed. A file cut short runs out before that; the part cut
/// is named with its offset.
fn find_truncation(bytes: &[u8]) -> Option<MapFileError> {
    let len = bytes.len();
    let header_len = u32_at(bytes, 6)? as usize;
    let mut at = PREAMBLE.checked_add(header_len)?;
    if at.checked_add(4)? > len {
        return Some(truncated(Part::Header, PREAMBLE, at + 4, len));
    }
    let header: MapFileHeader<&str> = postcard::from_bytes(bytes.get(PREAMBLE..at)?).ok()?;
    let mut announced = 0u64;
    loop {
        if at + 4 == len && announced >= u64::from(header.voxel_count) {
            return None;
        }
        if at + 4 >= len {
            return Some(truncated(Part::Chunk, at, at + 5, len));
        }
        let start = at;
        let Some(n) = leb128(bytes, &mut at) else { return Some(truncated(Part::Chunk, start, at + 5, len)) };
        let end = at.checked_add(n)?;
        if end + 4 > len {
            return Some(truncated(Part::Chunk, start, end + 4, len));
        }
        announced += codec::chunk_voxel_count(bytes.get(at..end)?)?;
        at = end;
    }
}

/// Checks a map file's bytes (magic, version, checksum, header, counts)
/// without decoding its voxels.
pub fn parse(bytes: &[u8]) -> Result<MapFile<'_>, MapFileError> {
    let len = bytes.len();
    if bytes.get(..4).is_some_and(|m| m != MAGIC) || (len < 4 && bytes != &MAGIC[..len]) {
        return Err(MapFileError::Magic);
    }
    let pre = bytes.get(..PREAMBLE).ok_or(truncated(Part::Preamble, 0, PREAMBLE, len))?;
    let version = u16::from_le_bytes([pre[4], pre[5]]);
    if version != MAP_FILE_VERSION {
        return Err(MapFileError::Version(version));
    }
    let body_end =
        len.checked_sub(4).filter(|&e| e >= PREAMBLE).ok_or(truncated(Part::Checksum, PREAMBLE, PREAMBLE + 4, len))?;
    let stored = u32_at(bytes, body_end).ok_or(truncated(Part::Checksum, body_end, body_end + 4, len))?;
    let computed = crc32(bytes.get(..body_end).unwrap_or(&[]));
    if stored != computed {
        return Err(find_truncation(bytes).unwrap_or(MapFileError::Checksum { stored, computed }));
    }
    let header_len = u32_at(bytes, 6).unwrap_or(0) as usize;
    let header_end = PREAMBLE.checked_add(header_len).filter(|&e| e <= body_end).ok_or(truncated(
        Part::Header,
        PREAMBLE,
        PREAMBLE.saturating_add(header_len),
        body_end,
    ))?;
    let header: MapFileHeader<&str> =
        postcard::from_bytes(bytes.get(PREAMBLE..header_end).unwrap_or(&[])).map_err(|_| MapFileError::Header)?;
    if header.class_table_version != CLASS_TABLE_VERSION {
        return Err(MapFileError::ClassTable(header.class_table_version));
    }
    let usable = |v: f32, lo: f32, hi: f32| v.is_finite() && (lo..=hi).contains(&v);
    if !usable(header.resolution, 1e-3, 100.0) || !usable(header.label_accuracy, 0.0, 1.0) {
        return Err(MapFileError::Numbers);
    }
    let chunks = bytes.get(header_end..body_end).unwrap_or(&[]);
    if header.voxel_count as usize > chunks.len().saturating_mul(MAX_VOXELS_PER_BYTE) {
        return Err(MapFileError::TooManyVoxels { claimed: header.voxel_count, chunk_bytes: chunks.len() as u32 });
    }
    Ok(MapFile { header, chunks, chunks_at: header_end })
}

impl MapFile<'_> {
    /// Decodes the voxels into `map` (cleared first; its resolution must be
    /// the file's and its capacity at least the voxel count): a
    /// [`LocalMap`], or a [`crate::map::SceneMap`] to match it as a scene.
    pub fn decode_into<K: VoxelSink + ?Sized>(&self, map: &mut K) -> Result<(), MapFileError> {
        let r = self.header.resolution;
        if (map.resolution() - r).abs() > 1e-6 * r {
            return Err(MapFileError::Resolution);
        }
        map.clear();
        let announced = self.header.voxel_count;
        let mut model = CodecModel::new();
        let mut decoder = MapDecoder::new(announced as usize, &mut model);
        let (body, base) = (self.chunks, self.chunks_at);
        let mut at = 0;
        while at < body.len() {
            let start = at;
            let chunk_err = |error| MapFileError::Chunk { offset: (base + start) as u32, error };
            let n = leb128(body, &mut at).ok_or(chunk_err(DecodeError::Truncated))?;
            let end = at.checked_add(n).filter(|&e| e <= body.len()).ok_or(chunk_err(DecodeError::Truncated))?;
            decoder.decode_chunk(&mut model, body.get(at..end).unwrap_or(&[]), map).map_err(chunk_err)?;
            at = end;
        }
        if decoder.is_complete() {
            Ok(())
        } else {
            Err(MapFileError::Incomplete { present: decoder.decoded() as u32, announced })
        }
    }
}

/// Decodes a map file's bytes into `map` (cleared first; its resolution must
/// be the file's); returns the header.
pub fn read_into<'a, K: VoxelSink + ?Sized>(
    bytes: &'a [u8],
    map: &mut K,
) -> Result<MapFileHeader<&'a str>, MapFileError> {
    let file = parse(bytes)?;
    file.decode_into(map)?;
    Ok(file.header)
}

/// The header a map would be written with.
pub fn header_of<'a, S: VoxelStorage>(
    map: &LocalMap<S>,
    anchor_time: Option<f64>,
    source: Option<&'a str>,
) -> MapFileHeader<&'a str> {
    MapFileHeader {
        class_table_version: CLASS_TABLE_VERSION,
        resolution: map.resolution(),
        label_accuracy: map.config().sensor.accuracy,
        voxel_count: map.len() as u32,
        anchor_time,
        source,
    }
}

/// Writes `map` as a map file through `sink` (called with consecutive
/// pieces of the file), with `scratch` of one `u32` per voxel and `chunk` a
/// buffer of [`FILE_CHUNK`] bytes (at least `codec::MIN_CHUNK`). Returns the
/// file's length. `sink` returning `false` stops the write with
/// [`MapFileError::Write`].
pub fn write<S: VoxelStorage>(
    map: &LocalMap<S>,
    header: &MapFileHeader<impl Serialize>,
    scratch: &mut [u32],
    chunk: &mut [u8],
    sink: impl FnMut(&[u8]) -> bool,
) -> Result<usize, MapFileError> {
    /// The file as it goes out: its CRC and length follow every piece.
    struct Out<F> {
        crc: Crc32,
        written: usize,
        sink: F,
    }
    impl<F: FnMut(&[u8]) -> bool> Out<F> {
        fn put(&mut self, bytes: &[u8]) -> Result<(), MapFileError> {
            self.crc.update(bytes);
            self.written += bytes.len();
            if (self.sink)(bytes) {
                Ok(())
            } else {
                Err(MapFileError::Write)
            }
        }
    }
    let mut out = Out { crc: Crc32::new(), written: 0, sink };
    let mut head = [0u8; 512];
    let header_bytes = postcard::to_slice(header, &mut head).map_err(|_| MapFileError::Write)?;
    out.put(&MAGIC)?;
    out.put(&MAP_FILE_VERSION.to_le_bytes())?;
    out.put(&(header_bytes.len() as u32).to_le_bytes())?;
    out.put(header_bytes)?;
    let mut model = CodecModel::new();
    let mut encoder = MapEncoder::new(map, scratch, &mut model).map_err(|_: EncodeError| MapFileError::Write)?;
    loop {
        let n = encoder.next_chunk(&mut model, chunk).map_err(|_| MapFileError::Write)?;
        if n == 0 {
            break;
        }
        // The chunk's length, LEB128 (what `leb128` reads).
        let (mut len, mut k, mut v) = ([0u8; 4], 0, n);
        while let Some(slot) = len.get_mut(k) {
            let byte = (v & 0x7F) as u8;
            v >>= 7;
            *slot = if v == 0 { byte } else { byte | 0x80 };
            k += 1;
            if v == 0 {
                break;
            }
        }
        out.put(len.get(..k).ok_or(MapFileError::Write)?)?;
        out.put(chunk.get(..n).ok_or(MapFileError::Write)?)?;
    }
    let total = out.crc.finish();
    out.put(&total.to_le_bytes())?;
    Ok(out.written)
}

/// A small map file, frozen: the map of [`golden_map_points`] at 0.5 m
/// (three voxels: a pole, a road cell, a building cell), anchor time 1.5 s,
/// source `golden`, in one chunk ([`GOLDEN_CHUNK`]).
pub const GOLDEN_FILE: &[u8] = &[
    67, 77, 65, 80, 4, 0, 27, 0, 0, 0, 1, 0, 0, 0, 63, 205, 204, 76, 63, 3, 1, 0, 0, 0, 0, 0, 0, 248, 63, 1, 6, 103,
    111, 108, 100, 101, 110, 30, 3, 136, 182, 219, 237, 182, 219, 21, 68, 15, 181, 36, 146, 73, 36, 140, 54, 67, 139,
    109, 182, 219, 109, 185, 123, 24, 11, 97, 8, 0, 81, 123, 59, 65,
];

/// The golden map's voxels as one chunk of the compact encoding
/// ([`super::codec`]): count, lead gap, then the range-coded voxels (gaps,
/// classes, confidences, occupancies, sub-voxel positions).
pub const GOLDEN_CHUNK: &[u8] = &[
    3, 136, 182, 219, 237, 182, 219, 21, 68, 15, 181, 36, 146, 73, 36, 140, 54, 67, 139, 109, 182, 219, 109, 185, 123,
    24, 11, 97, 8, 0,
];

/// The points of the golden map (each inserted once into a 0.5 m map).
pub fn golden_map_points() -> [([f32; 3], crate::classes::Class); 3] {
    use crate::classes::Class;
    [([1.1, 2.2, 0.3], Class::Pole), ([-3.0, 0.4, -1.6], Class::Road), ([7.9, -5.2, 2.1], Class::Building)]
}

/// Builds the golden map in `map` (cleared and set to 0.5 m first), writes
/// it as a file and reads [`GOLDEN_FILE`] back into `back`: `Ok` when both
/// directions give exactly the frozen bytes and the same voxels. Runs on the
/// chip too (the self-test).
pub fn check_golden<S: VoxelStorage, T: VoxelStorage>(
    map: &mut LocalMap<S>,
    back: &mut LocalMap<T>,
) -> Result<(), MapFileError> {
    let config = crate::map::MapConfig::with_resolution(0.5);
    map.reset(config).map_err(|_| MapFileError::Numbers)?;
    back.reset(config).map_err(|_| MapFileError::Numbers)?;
    for (p, c) in golden_map_points() {
        map.insert_point(p, c).map_err(|_| MapFileError::Write)?;
    }
    let header = header_of(map, Some(1.5), Some("golden"));
    let (mut scratch, mut chunk) = ([0u32; 3], [0u8; 64]);
    let mut at = 0usize;
    let mut same = true;
    write(map, &header, &mut scratch, &mut chunk, |b| {
        same &= GOLDEN_FILE.get(at..at + b.len()) == Some(b);
        at += b.len();
        true
    })?;
    if !same || at != GOLDEN_FILE.len() {
        return Err(MapFileError::Write);
    }
    let read = read_into(GOLDEN_FILE, back)?;
    let voxels_equal = map.len() == back.len() && map.voxels().iter().all(|v| back.get(v.key).is_some());
    if read != header || !voxels_equal {
        return Err(MapFileError::Incomplete { present: back.len() as u32, announced: map.len() as u32 });
    }
    Ok(())
}
