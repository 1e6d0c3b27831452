//! `.cmap` map files on the host: the core's format
//! ([`cosem_core::wire::mapfile`]) read into and written from heap maps,
//! every error naming its file.

use crate::maps::mapping::{new_map, BuildError, HostMap};
use cosem_core::map::MapConfig;
use cosem_core::map::SensorModel;
use cosem_core::wire::mapfile::{self, MapFileError, MapFileHeader, FILE_CHUNK};
use cosem_core::wire::{CodecModel, MapEncoder};
use std::path::{Path, PathBuf};

/// A map file's header with its source text owned.
pub type CmapHeader = MapFileHeader<String>;

/// Largest map file read (bytes): a map of 32 M voxels. A bound, so that
/// a device or a wrong path cannot make a read run without end.
pub const MAX_FILE_BYTES: u64 = 128 << 20;

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
    /// The bytes are not a valid map file.
    #[error("{path}: {error}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where.
        error: MapFileError,
    },
    /// The file is larger than any map file.
    #[error("{path}: {len} bytes, larger than any map file ({MAX_FILE_BYTES} bytes): not a map file")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size.
        len: u64,
    },
    /// A map with no voxel: nothing to match, never written or read.
    #[error("{path}: the map has no voxels: nothing to match (an empty map is never written or read)")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The map the header describes cannot be allocated.
    #[error("{path}: {source}")]
    Map {
        /// The file.
        path: PathBuf,
        /// Why.
        source: BuildError,
    },
}

impl crate::error::LayerError for CmapError {}

/// The map's voxels in the compact encoding, as chunks of at most `chunk` bytes.
pub fn encode_chunks(map: &HostMap, chunk: usize) -> Vec<Vec<u8>> {
    let mut scratch = vec![0u32; map.len()];
    let mut out = Vec::new();
    // The scratch holds one entry per voxel and the buffer exceeds the
    // minimum chunk, so the encoder cannot fail.
    let mut model = Box::new(CodecModel::new());
    if let Ok(mut enc) = MapEncoder::new(map, &mut scratch, &mut model) {
        let mut buf = vec![0u8; chunk.max(cosem_core::wire::codec::MIN_CHUNK)];
        while let Ok(n) = enc.next_chunk(&mut model, &mut buf) {
            if n == 0 {
                break;
            }
            out.push(buf[..n].to_vec());
        }
    }
    out
}

/// Bytes of voxel encoding per voxel (what the link carries, chunk headers
/// included, file framing excluded).
pub fn wire_bytes_per_voxel(map: &HostMap, chunk: usize) -> f64 {
    let bytes: usize = encode_chunks(map, chunk).iter().map(Vec::len).sum();
    bytes as f64 / map.len().max(1) as f64
}

/// Encodes a map into the file format.
pub fn encode(map: &HostMap, anchor_time: Option<f64>, source: Option<&str>) -> Vec<u8> {
    let header = mapfile::header_of(map, anchor_time, source);
    let mut out = Vec::with_capacity(64 + map.len() * 4);
    let (mut scratch, mut chunk) = (vec![0u32; map.len()], vec![0u8; FILE_CHUNK]);
    // Every buffer is sized for the map and the sink takes everything: the
    // core's writer cannot fail here.
    let _ = mapfile::write(map, &header, &mut scratch, &mut chunk, |b| {
        out.extend_from_slice(b);
        true
    });
    out
}

/// Decodes a map file's bytes; `path` names the file in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<(CmapHeader, HostMap), CmapError> {
    let format = |error| CmapError::Format { path: path.to_path_buf(), error };
    let file = mapfile::parse(bytes).map_err(format)?;
    let h = file.header;
    if h.voxel_count == 0 {
        return Err(CmapError::Empty { path: path.to_path_buf() });
    }
    let config = MapConfig {
        resolution: h.resolution,
        sensor: SensorModel { accuracy: h.label_accuracy },
        ..MapConfig::default()
    };
    let mut map = new_map(h.voxel_count as usize, config)
        .map_err(|source| CmapError::Map { path: path.to_path_buf(), source })?;
    file.decode_into(&mut map).map_err(format)?;
    Ok((h.map_source(String::from), map))
}

/// A map's file bytes and the map read back from them, checked to encode
/// to the same bytes again (the encoding is lossy but idempotent): what a
/// peer receives.
pub fn round_trip(map: &HostMap, source: &str) -> Result<(Vec<u8>, HostMap), CmapError> {
    let path = Path::new("(in memory)");
    let bytes = encode(map, None, Some(source));
    let (_, received) = decode(&bytes, path)?;
    if received.len() != map.len() || encode(&received, None, Some(source)) != bytes {
        let error = MapFileError::Incomplete { present: received.len() as u32, announced: map.len() as u32 };
        return Err(CmapError::Format { path: path.to_path_buf(), error });
    }
    Ok((bytes, received))
}

/// Writes a map file; returns its length.
pub fn write(path: &Path, map: &HostMap, anchor_time: Option<f64>, source: Option<&str>) -> Result<usize, CmapError> {
    if map.is_empty() {
        return Err(CmapError::Empty { path: path.to_path_buf() });
    }
    let bytes = encode(map, anchor_time, source);
    crate::paths::write_file(path, &bytes).map_err(|source| CmapError::Io { path: path.to_path_buf(), source })?;
    Ok(bytes.len())
}

/// Reads a map file (at most [`MAX_FILE_BYTES`]).
pub fn read(path: &Path) -> Result<(CmapHeader, HostMap), CmapError> {
    use std::io::Read;
    let io = |source| CmapError::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    // The magic first: a device or another kind of file is refused at once.
    let mut bytes = Vec::new();
    (&mut file).take(4).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() == 4 && bytes != mapfile::MAGIC {
        return Err(CmapError::Format { path: path.to_path_buf(), error: MapFileError::Magic });
    }
    file.take(MAX_FILE_BYTES + 1 - 4).read_to_end(&mut bytes).map_err(io)?;
    let len = bytes.len() as u64;
    if len > MAX_FILE_BYTES {
        return Err(CmapError::TooLarge { path: path.to_path_buf(), len });
    }
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
        let bytes = encode(&m, Some(1.5), Some("test"));
        let (h, back) = decode(&bytes, Path::new("x.cmap")).unwrap();
        assert_eq!(h.voxel_count as usize, m.len());
        assert_eq!((h.anchor_time, h.source.as_deref()), (Some(1.5), Some("test")));
        assert_eq!(back.len(), m.len());
        assert_eq!(back.resolution(), m.resolution());
        for v in m.iter() {
            assert_eq!(back.get(v.key).and_then(|w| w.class()), v.class());
        }
        // What was read writes back byte for byte.
        assert_eq!(encode(&back, Some(1.5), Some("test")), bytes);
    }

    #[test]
    fn every_corruption_is_an_error_naming_the_file() {
        let bytes = encode(&sample(), None, None);
        let path = Path::new("robot.cmap");
        for cut in 0..bytes.len() {
            let e = decode(&bytes[..cut], path).err().expect("truncated file accepted");
            assert!(e.to_string().contains("robot.cmap"), "{e}");
            if cut > 0 {
                assert!(e.to_string().contains("truncated"), "cut at {cut}: {e}");
            }
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x5A;
            let e = decode(&b, path).err().expect("corrupted file accepted");
            assert!(e.to_string().contains("robot.cmap"), "{e}");
        }
    }
}
