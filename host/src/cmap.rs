//! The `.cmap` map file: versioned, checksummed, in the link's compact
//! voxel encoding ([`cosem_core::wire::codec`]), so a map read from a file
//! and the same map received over the link are identical.
//!
//! Layout (format 2):
//!
//! | bytes | content |
//! |---|---|
//! | 4 | magic `CMAP` |
//! | 2 | format version, u16 little endian |
//! | 4 | header length, u32 little endian |
//! | n | header ([`CmapHeader`], postcard) |
//! | … | chunks, each a LEB128 length then the chunk |
//! | 4 | CRC-32 of everything before it, little endian |
//!
//! Files of another version are refused by name, never misread.

use crate::mapping::{new_map, HostMap};
use cosem_core::classes::CLASS_TABLE_VERSION;
use cosem_core::map::{MapConfig, SensorModel};
use cosem_core::wire::mapfile::{decode_chunks, MapFileError};
use cosem_core::wire::{crc32, MapEncoder};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// File magic.
pub const MAGIC: [u8; 4] = *b"CMAP";
/// Current format version.
pub const FORMAT_VERSION: u16 = 2;
const PREAMBLE: usize = 10;
/// Chunk size in files (the link uses smaller ones).
pub const FILE_CHUNK: usize = 4096;
/// Fewest bits a voxel takes in the encoding (flag, confidence, occupancy,
/// position, a one-bit gap): bounds the voxel count a file can claim.
const MIN_VOXEL_BITS: usize = 19;

/// What a map file says about its map.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CmapHeader {
    /// Class table the labels refer to.
    pub class_table_version: u16,
    /// Voxel edge length (m).
    pub resolution: f32,
    /// Label sensor model's accuracy used to fuse the map.
    pub label_accuracy: f32,
    /// Number of voxel records.
    pub voxel_count: u32,
    /// Timestamp of the anchor scan (s), if known.
    pub anchor_time: Option<f64>,
    /// Where the map came from, e.g. `kitti00 0:5`.
    pub source: Option<String>,
}

/// Why a map file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum CmapError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a map file.
    #[error("{path}: not a cosem map file (bad magic)")]
    BadMagic {
        /// The file.
        path: PathBuf,
    },
    /// A format this build does not read.
    #[error("{path}: map format version {found}, this build reads version {FORMAT_VERSION}")]
    Version {
        /// The file.
        path: PathBuf,
        /// Version in the file.
        found: u16,
    },
    /// The file ends early.
    #[error("{path}: truncated at byte offset {offset} ({what})")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Where it ended.
        offset: usize,
        /// What was being read.
        what: &'static str,
    },
    /// The checksum does not match.
    #[error("{path}: checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupted")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Stored CRC.
        stored: u32,
        /// Computed CRC.
        computed: u32,
    },
    /// A header or record that does not decode or is invalid.
    #[error("{path}: byte offset {offset}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Where.
        offset: usize,
        /// What is wrong.
        what: String,
    },
}

/// The map's voxels in the compact encoding, as chunks of at most `chunk` bytes.
pub fn encode_chunks(map: &HostMap, chunk: usize) -> Vec<Vec<u8>> {
    let mut scratch = vec![0u32; map.len()];
    let mut out = Vec::new();
    // The scratch holds one entry per voxel and the buffer exceeds the
    // minimum chunk, so the encoder cannot fail.
    if let Ok(mut enc) = MapEncoder::new(map, &mut scratch) {
        let mut buf = vec![0u8; chunk.max(cosem_core::wire::codec::MIN_CHUNK)];
        while let Ok(n) = enc.next_chunk(&mut buf) {
            if n == 0 {
                break;
            }
            out.push(buf[..n].to_vec());
        }
    }
    out
}

/// Encodes a map into the file format.
pub fn encode(map: &HostMap, anchor_time: Option<f64>, source: Option<String>) -> Vec<u8> {
    let header = CmapHeader {
        class_table_version: CLASS_TABLE_VERSION,
        resolution: map.resolution(),
        label_accuracy: map.config().sensor.accuracy,
        voxel_count: map.len() as u32,
        anchor_time,
        source,
    };
    let header_bytes = postcard::to_stdvec(&header).unwrap_or_default();
    let chunks = encode_chunks(map, FILE_CHUNK);
    let mut out = Vec::with_capacity(PREAMBLE + header_bytes.len() + map.len() * 4 + 4);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(header_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(&header_bytes);
    for c in &chunks {
        let mut n = c.len();
        loop {
            let byte = (n & 0x7F) as u8;
            n >>= 7;
            out.push(if n == 0 { byte } else { byte | 0x80 });
            if n == 0 {
                break;
            }
        }
        out.extend_from_slice(c);
    }
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Bytes of voxel encoding per voxel (what the link carries, chunk headers
/// included, file framing excluded).
pub fn wire_bytes_per_voxel(map: &HostMap, chunk: usize) -> f64 {
    let bytes: usize = encode_chunks(map, chunk).iter().map(Vec::len).sum();
    bytes as f64 / map.len().max(1) as f64
}

/// Decodes a map file's bytes; `path` names the file in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<(CmapHeader, HostMap), CmapError> {
    let p = || path.to_path_buf();
    if bytes.len() < 4 || bytes[..4] != MAGIC {
        return Err(CmapError::BadMagic { path: p() });
    }
    if bytes.len() < PREAMBLE + 4 {
        return Err(CmapError::Truncated { path: p(), offset: bytes.len(), what: "preamble" });
    }
    let version = u16::from_le_bytes([bytes[4], bytes[5]]);
    if version != FORMAT_VERSION {
        return Err(CmapError::Version { path: p(), found: version });
    }
    let body_end = bytes.len() - 4;
    let stored = u32::from_le_bytes([bytes[body_end], bytes[body_end + 1], bytes[body_end + 2], bytes[body_end + 3]]);
    let computed = crc32(&bytes[..body_end]);
    if stored != computed {
        return Err(CmapError::Checksum { path: p(), stored, computed });
    }
    let header_len = u32::from_le_bytes([bytes[6], bytes[7], bytes[8], bytes[9]]) as usize;
    let header_end = PREAMBLE.checked_add(header_len).filter(|&e| e <= body_end).ok_or(CmapError::Truncated {
        path: p(),
        offset: body_end,
        what: "header",
    })?;
    let header: CmapHeader = postcard::from_bytes(&bytes[PREAMBLE..header_end]).map_err(|e| CmapError::Invalid {
        path: p(),
        offset: PREAMBLE,
        what: format!("header: {e}"),
    })?;
    let invalid = |offset: usize, what: String| CmapError::Invalid { path: p(), offset, what };
    if header.class_table_version != CLASS_TABLE_VERSION {
        return Err(invalid(
            PREAMBLE,
            format!("class table version {} (this build: {CLASS_TABLE_VERSION})", header.class_table_version),
        ));
    }
    let count = header.voxel_count as usize;
    if count.saturating_mul(MIN_VOXEL_BITS) > (body_end - header_end) * 8 {
        return Err(invalid(
            PREAMBLE,
            format!("header claims {count} voxels, more than the {} bytes of chunks can hold", body_end - header_end),
        ));
    }
    let config = MapConfig {
        resolution: header.resolution,
        sensor: SensorModel { accuracy: header.label_accuracy },
        ..MapConfig::default()
    };
    let mut map = new_map(count, config).map_err(|e| invalid(PREAMBLE, format!("header: {e}")))?;
    decode_chunks(&bytes[header_end..body_end], header.voxel_count, &mut map).map_err(|e| match e {
        MapFileError::Truncated(o) => CmapError::Truncated { path: p(), offset: header_end + o, what: "chunk" },
        MapFileError::Chunk(o, e) => invalid(header_end + o, format!("chunk: {e}")),
        MapFileError::Incomplete => invalid(body_end, format!("{} of {count} voxels present", map.len())),
        e => invalid(header_end, format!("{e:?}")),
    })?;
    Ok((header, map))
}

/// Writes a map file.
pub fn write(path: &Path, map: &HostMap, anchor_time: Option<f64>, source: Option<String>) -> Result<usize, CmapError> {
    let bytes = encode(map, anchor_time, source);
    std::fs::write(path, &bytes).map_err(|source| CmapError::Io { path: path.to_path_buf(), source })?;
    Ok(bytes.len())
}

/// Reads a map file.
pub fn read(path: &Path) -> Result<(CmapHeader, HostMap), CmapError> {
    let bytes = std::fs::read(path).map_err(|source| CmapError::Io { path: path.to_path_buf(), source })?;
    decode(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cosem_core::classes::Class;

    fn sample() -> HostMap {
        let mut m = new_map(100, MapConfig::default()).unwrap();
        for i in 0..50 {
            let x = i as f32 * 0.37 - 9.0;
            m.insert_point([x, -x * 0.5, 1.0], if i % 3 == 0 { Class::Pole } else { Class::Road }).unwrap();
            m.insert_point([x + 0.01, -x * 0.5, 1.0], Class::Road).unwrap();
        }
        m
    }

    #[test]
    fn round_trip_keeps_the_map_and_is_idempotent() {
        let m = sample();
        let bytes = encode(&m, Some(1.5), Some("test".into()));
        let (h, back) = decode(&bytes, Path::new("x.cmap")).unwrap();
        assert_eq!(h.voxel_count as usize, m.len());
        assert_eq!(h.anchor_time, Some(1.5));
        assert_eq!(back.len(), m.len());
        assert_eq!(back.resolution(), m.resolution());
        for v in m.iter() {
            assert_eq!(back.get(v.key).and_then(|w| w.class()), v.class());
        }
        // What was read writes back byte for byte.
        assert_eq!(encode(&back, Some(1.5), Some("test".into())), bytes);
    }

    #[test]
    fn every_corruption_is_an_error_naming_the_file() {
        let bytes = encode(&sample(), None, None);
        let path = Path::new("robot.cmap");
        // Every truncation and every single-byte flip is caught.
        for cut in 0..bytes.len() {
            let e = decode(&bytes[..cut], path).err().expect("truncated file accepted");
            assert!(e.to_string().contains("robot.cmap"), "{e}");
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x5A;
            let e = decode(&b, path).err().expect("corrupted file accepted");
            assert!(e.to_string().contains("robot.cmap"), "{e}");
        }
    }

    #[test]
    fn a_valid_checksum_over_bad_records_is_still_rejected() {
        let mut bytes = encode(&sample(), None, None);
        bytes.truncate(bytes.len() - 4);
        bytes.extend_from_slice(&[0x05, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
        let crc = crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        assert!(matches!(decode(&bytes, Path::new("a")), Err(CmapError::Invalid { .. })));
    }
}
