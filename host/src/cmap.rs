//! The `.cmap` map file: versioned, checksummed, postcard-encoded.
//!
//! Layout (format 1):
//!
//! | bytes | content |
//! |---|---|
//! | 4 | magic `CMAP` |
//! | 2 | format version, u16 little endian |
//! | 4 | header length, u32 little endian |
//! | n | header ([`CmapHeader`], postcard) |
//! | … | `voxel_count` voxel records (postcard varints) |
//! | 4 | CRC-32 of everything before it, little endian |
//!
//! The link issue replaces the voxel records by the compact wire encoding;
//! the version number makes old files fail loudly rather than decode wrongly.

use crate::mapping::{new_map, HostMap};
use cosem_core::classes::CLASS_TABLE_VERSION;
use cosem_core::map::{InsertError, LabelDistribution, MapConfig, SemanticVoxel, SensorModel, VoxelKey};
use cosem_core::wire::crc32;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// File magic.
pub const MAGIC: [u8; 4] = *b"CMAP";
/// Current format version.
pub const FORMAT_VERSION: u16 = 1;
const PREAMBLE: usize = 10;
const MIN_RECORD_BYTES: usize = 12;

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

#[derive(Serialize, Deserialize)]
struct VoxelRecord {
    key: [i16; 3],
    mean: [u16; 3],
    occupancy: i16,
    hits: u16,
    labels: [u16; 4],
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
    let mut out = Vec::with_capacity(PREAMBLE + header_bytes.len() + map.len() * 20 + 4);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(header_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(&header_bytes);
    for v in map.iter() {
        let rec = VoxelRecord {
            key: [v.key.x, v.key.y, v.key.z],
            mean: v.mean_raw(),
            occupancy: v.occupancy_raw(),
            hits: v.hits(),
            labels: v.labels.raw(),
        };
        // Serialising plain integers into a Vec cannot fail.
        out.extend_from_slice(&postcard::to_stdvec(&rec).unwrap_or_default());
    }
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
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
    if count.saturating_mul(MIN_RECORD_BYTES) > body_end - header_end {
        return Err(invalid(
            PREAMBLE,
            format!("header claims {count} voxels, more than the {} bytes of records can hold", body_end - header_end),
        ));
    }
    let config = MapConfig {
        resolution: header.resolution,
        sensor: SensorModel { accuracy: header.label_accuracy },
        ..MapConfig::default()
    };
    let mut map = new_map(count, config).map_err(|e| invalid(PREAMBLE, format!("header: {e}")))?;
    let mut rest = &bytes[header_end..body_end];
    for i in 0..count {
        let offset = body_end - rest.len();
        let (rec, tail): (VoxelRecord, &[u8]) = postcard::take_from_bytes(rest).map_err(|e| match e {
            postcard::Error::DeserializeUnexpectedEnd => {
                CmapError::Truncated { path: p(), offset: body_end, what: "voxel records" }
            }
            e => invalid(offset, format!("voxel {i}: {e}")),
        })?;
        rest = tail;
        let labels = LabelDistribution::from_raw(rec.labels)
            .map_err(|e| invalid(offset, format!("voxel {i}: labels {:?}: {e:?}", rec.labels)))?;
        if rec.hits == 0 {
            return Err(invalid(offset, format!("voxel {i}: zero hits")));
        }
        let key = VoxelKey::new(rec.key[0], rec.key[1], rec.key[2]);
        let voxel = SemanticVoxel::from_parts(key, rec.mean, rec.occupancy, rec.hits, labels);
        map.insert_voxel(voxel).map_err(|e| match e {
            InsertError::DuplicateKey => invalid(offset, format!("voxel {i}: duplicate key {:?}", rec.key)),
            e => invalid(offset, format!("voxel {i}: {e}")),
        })?;
    }
    if !rest.is_empty() {
        return Err(invalid(body_end - rest.len(), format!("{} bytes after the last voxel", rest.len())));
    }
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
    fn round_trip_is_identical() {
        let m = sample();
        let bytes = encode(&m, Some(1.5), Some("test".into()));
        let (h, back) = decode(&bytes, Path::new("x.cmap")).unwrap();
        assert_eq!(h.voxel_count as usize, m.len());
        assert_eq!(h.anchor_time, Some(1.5));
        assert_eq!(back.voxels(), m.voxels());
        assert_eq!(back.resolution(), m.resolution());
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
        bytes.extend_from_slice(&[0xFF; 7]);
        let crc = crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        assert!(matches!(decode(&bytes, Path::new("a")), Err(CmapError::Invalid { .. })));
    }
}
