//! Reading a `.cmap` map file without an allocator (the host writes them;
//! the format is described in `cosem-host`'s `cmap` module): magic `CMAP`,
//! format version 2, a postcard header, length-prefixed chunks of the
//! compact encoding, CRC-32.

use super::codec::{DecodeError, MapDecoder};
use super::crc::crc32;
use crate::map::{LocalMap, VoxelStorage};
use serde::Deserialize;

/// Format version this reader understands.
pub const MAP_FILE_VERSION: u16 = 2;

/// What the file's header says (its leading fields).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
pub struct MapFileInfo {
    /// Class table version.
    pub class_table_version: u16,
    /// Voxel size (m).
    pub resolution: f32,
    /// Label accuracy of the sensor model.
    pub label_accuracy: f32,
    /// Voxels in the file.
    pub voxel_count: u32,
}

/// Why a map file was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MapFileError {
    /// Not a map file.
    Magic,
    /// Another format version.
    Version(u16),
    /// The CRC does not match.
    Checksum,
    /// Ends early (byte offset).
    Truncated(usize),
    /// The header does not decode, or its numbers are not usable.
    Header,
    /// The map's resolution differs from the file's.
    Resolution,
    /// A chunk did not decode (byte offset of its length).
    Chunk(usize, DecodeError),
    /// Fewer voxels than announced.
    Incomplete,
}

/// Decodes a map file's bytes into `map` (cleared first; its resolution must
/// be the file's).
pub fn read_into<S: VoxelStorage>(bytes: &[u8], map: &mut LocalMap<S>) -> Result<MapFileInfo, MapFileError> {
    if bytes.get(..4) != Some(b"CMAP") {
        return Err(MapFileError::Magic);
    }
    let pre = bytes.get(..10).ok_or(MapFileError::Truncated(bytes.len()))?;
    let version = u16::from_le_bytes([pre[4], pre[5]]);
    if version != MAP_FILE_VERSION {
        return Err(MapFileError::Version(version));
    }
    let body_end = bytes.len().checked_sub(4).filter(|&e| e >= 10).ok_or(MapFileError::Truncated(bytes.len()))?;
    let stored = bytes.get(body_end..).ok_or(MapFileError::Truncated(body_end))?;
    if crc32(bytes.get(..body_end).unwrap_or(&[])).to_le_bytes() != [stored[0], stored[1], stored[2], stored[3]] {
        return Err(MapFileError::Checksum);
    }
    let header_len = u32::from_le_bytes([pre[6], pre[7], pre[8], pre[9]]) as usize;
    let header_end =
        10usize.checked_add(header_len).filter(|&e| e <= body_end).ok_or(MapFileError::Truncated(body_end))?;
    let header = bytes.get(10..header_end).ok_or(MapFileError::Header)?;
    let (info, _rest): (MapFileInfo, _) = postcard::take_from_bytes(header).map_err(|_| MapFileError::Header)?;
    if !(info.resolution.is_finite() && (map.resolution() - info.resolution).abs() <= 1e-6 * info.resolution) {
        return Err(MapFileError::Resolution);
    }
    decode_chunks(bytes.get(header_end..body_end).unwrap_or(&[]), info.voxel_count, map)
        .map_err(|e| e.shifted(header_end))?;
    Ok(info)
}

impl MapFileError {
    /// The same error with its byte offset moved by `by`.
    fn shifted(self, by: usize) -> Self {
        match self {
            MapFileError::Truncated(o) => MapFileError::Truncated(o + by),
            MapFileError::Chunk(o, e) => MapFileError::Chunk(o + by, e),
            e => e,
        }
    }
}

/// Decodes a file's chunk stream (each chunk a LEB128 length, then the
/// chunk) holding `voxel_count` voxels into `map` (cleared first). Offsets in
/// errors count from the start of `body`.
pub fn decode_chunks<S: VoxelStorage>(
    body: &[u8],
    voxel_count: u32,
    map: &mut LocalMap<S>,
) -> Result<(), MapFileError> {
    map.clear();
    let mut decoder = MapDecoder::new(voxel_count as usize);
    let mut at = 0;
    while at < body.len() {
        let start = at;
        let mut len = 0usize;
        let mut shift = 0;
        loop {
            let b = *body.get(at).ok_or(MapFileError::Truncated(at))?;
            at += 1;
            len |= usize::from(b & 0x7F) << shift;
            shift += 7;
            if b & 0x80 == 0 {
                break;
            }
            if shift > 21 {
                return Err(MapFileError::Truncated(start));
            }
        }
        let end = at.checked_add(len).filter(|&e| e <= body.len()).ok_or(MapFileError::Truncated(body.len()))?;
        let chunk = body.get(at..end).ok_or(MapFileError::Truncated(at))?;
        decoder.decode_chunk(chunk, map).map_err(|e| MapFileError::Chunk(start, e))?;
        at = end;
    }
    if decoder.is_complete() {
        Ok(())
    } else {
        Err(MapFileError::Incomplete)
    }
}
