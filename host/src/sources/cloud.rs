//! Users' own scans: labelled point clouds as PCD (ASCII and binary) or PLY
//! (ASCII and binary little endian) files, one file per scan in the
//! sensor's frame, with the sensor's poses in KITTI's layout (one line per
//! scan: the row-major 3x4 pose in the map frame). They become the same
//! [`Frame`]s a SemanticKITTI folder gives, put into the first scan's frame
//! with the same arithmetic, so the same scans give the same map
//! (`tests/tests/cli.rs` checks it to the voxel).
//!
//! A point's label is an integer field (`label` by default) holding the
//! SemanticKITTI id in its low 16 bits. Points with a NaN coordinate (the
//! holes of an organised cloud) are skipped; big-endian data and
//! compressed PCD are refused with an error naming the file. Every error
//! names the file and the line or byte offset at fault.

use crate::knobs::Knob;
use crate::sources::kitti::{frame_of, Cloud, Frame};
use nalgebra::Matrix4;
use std::path::{Path, PathBuf};

/// Why a cloud, or its poses, could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CloudError {
    /// Reading or writing the file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The header says something this reader cannot take, or is broken.
    #[error("{path}: header: {what}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The point data is broken.
    #[error("{path}: {what}")]
    Data {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where (point, line or byte offset).
        what: String,
    },
    /// The poses file is broken or too short.
    #[error("{path}: {what}")]
    Poses {
        /// The poses file.
        path: PathBuf,
        /// What is wrong, and on which line.
        what: String,
    },
}

impl crate::error::LayerError for CloudError {}

/// The file formats of users' scans.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloudFormat {
    /// Point Cloud Library's PCD (ASCII or binary).
    Pcd,
    /// Stanford PLY (ASCII or binary little endian).
    Ply,
}

impl CloudFormat {
    /// The names it is read from (the command line's, Python's).
    pub const NAMES: &'static [&'static str] = &["pcd", "ply"];
}

impl std::str::FromStr for CloudFormat {
    type Err = String;
    /// A scan file format: pcd or ply.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "pcd" => Ok(CloudFormat::Pcd),
            "ply" => Ok(CloudFormat::Ply),
            _ => Err(format!("`{s}`: expected pcd or ply")),
        }
    }
}

impl CloudFormat {
    /// The files' extension.
    pub fn extension(self) -> &'static str {
        match self {
            CloudFormat::Pcd => "pcd",
            CloudFormat::Ply => "ply",
        }
    }
}

/// A scalar type of a field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The value of little-endian `b` (exactly `size()` bytes).
    fn read(self, b: &[u8]) -> f64 {
        match self {
            Scalar::I8 => f64::from(b[0] as i8),
            Scalar::U8 => f64::from(b[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }

    /// A PLY property type.
    fn of_ply(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// A ROS `sensor_msgs/PointField` datatype.
    pub(crate) fn of_ros(datatype: u8) -> Option<Scalar> {
        Some(match datatype {
            1 => Scalar::I8,
            2 => Scalar::U8,
            3 => Scalar::I16,
            4 => Scalar::U16,
            5 => Scalar::I32,
            6 => Scalar::U32,
            7 => Scalar::F32,
            8 => Scalar::F64,
            _ => return None,
        })
    }

    /// A PCD field's TYPE and SIZE.
    fn of_pcd(kind: &str, size: usize) -> Option<Scalar> {
        Some(match (kind, size) {
            ("I", 1) => Scalar::I8,
            ("U", 1) => Scalar::U8,
            ("I", 2) => Scalar::I16,
            ("U", 2) => Scalar::U16,
            ("I", 4) => Scalar::I32,
            ("U", 4) => Scalar::U32,
            ("F", 4) => Scalar::F32,
            ("F", 8) => Scalar::F64,
            _ => return None,
        })
    }
}

/// The largest point record read (bytes): far beyond any real point type,
/// small enough that no size computed from it overflows.
const MAX_RECORD_BYTES: usize = 1 << 20;

/// A field of a point record: its scalar, its count, its byte offset.
#[derive(Clone, Debug)]
struct Field {
    name: String,
    scalar: Scalar,
    count: usize,
    offset: usize,
}

/// The fields of a point record.
pub(crate) struct Layout {
    fields: Vec<Field>,
    /// Bytes per record (binary).
    stride: usize,
}

impl Layout {
    /// Fields at explicit offsets (a ROS message's) in records of `stride`
    /// bytes; `None` when a field does not fit the record.
    pub(crate) fn with_offsets(fields: Vec<(String, Scalar, usize, usize)>, stride: usize) -> Option<Self> {
        let fields: Vec<Field> =
            fields.into_iter().map(|(name, scalar, count, offset)| Field { name, scalar, count, offset }).collect();
        let fits = fields.iter().all(|f| {
            f.scalar
                .size()
                .checked_mul(f.count.max(1))
                .and_then(|n| n.checked_add(f.offset))
                .is_some_and(|e| e <= stride)
        });
        fits.then_some(Layout { fields, stride })
    }

    /// Fields one after the other (a PCD's or PLY's); `Err` names the
    /// field whose size overflows a record (a count beyond any file).
    fn new(fields: Vec<(String, Scalar, usize)>) -> Result<Self, String> {
        let mut offset = 0usize;
        let mut out = Vec::with_capacity(fields.len());
        for (name, scalar, count) in fields {
            let end = scalar
                .size()
                .checked_mul(count)
                .and_then(|size| offset.checked_add(size))
                .filter(|&end| end <= MAX_RECORD_BYTES)
                .ok_or_else(|| {
                    format!("field `{name}`: COUNT {count} makes a point larger than {MAX_RECORD_BYTES} bytes")
                })?;
            out.push(Field { name, scalar, count, offset });
            offset = end;
        }
        Ok(Layout { fields: out, stride: offset })
    }

    /// The indices of x, y, z and the label field: all single scalars,
    /// the label an integer.
    pub(crate) fn pick(&self, label: &str, path: &Path) -> Result<[usize; 4], CloudError> {
        let find = |name: &str| {
            self.fields.iter().position(|f| f.name == name).ok_or_else(|| CloudError::Header {
                path: path.to_owned(),
                what: format!(
                    "no field `{name}` (fields: {})",
                    self.fields.iter().map(|f| f.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            })
        };
        let idx = [find("x")?, find("y")?, find("z")?, find(label)?];
        for &i in &idx {
            let f = &self.fields[i];
            if f.count != 1 {
                return Err(CloudError::Header {
                    path: path.to_owned(),
                    what: format!("field `{}` has {} values a point, not one", f.name, f.count),
                });
            }
        }
        if !self.fields[idx[3]].scalar.is_integer() {
            return Err(CloudError::Header {
                path: path.to_owned(),
                what: format!("label field `{label}` is not an integer"),
            });
        }
        Ok(idx)
    }
}

/// Adds one point (x, y, z, label as read) to `cloud`, checking the label.
fn push(cloud: &mut Cloud, v: [f64; 4], at: impl Fn() -> String, path: &Path) -> Result<(), CloudError> {
    let p = [v[0] as f32, v[1] as f32, v[2] as f32];
    if p.iter().any(|c| c.is_nan()) {
        cloud.skipped += 1;
        return Ok(());
    }
    if p.iter().any(|c| !c.is_finite()) {
        return Err(CloudError::Data { path: path.to_owned(), what: format!("{}: a coordinate is infinite", at()) });
    }
    let l = v[3];
    if !(l >= 0.0 && l <= f64::from(u32::MAX) && l.fract() == 0.0) {
        return Err(CloudError::Data {
            path: path.to_owned(),
            what: format!("{}: label {l} is not a label word", at()),
        });
    }
    cloud.points.push(p);
    cloud.labels.push(l as u32);
    Ok(())
}

/// Reads `n` binary little-endian records of `layout` from `body` into
/// `cloud`; `what` names a record in errors (e.g. "point", "vertex") and
/// `at` is the byte offset of `body` in the file.
pub(crate) fn read_records(
    body: &[u8],
    n: usize,
    layout: &Layout,
    idx: [usize; 4],
    path: &Path,
    (what, at): (&str, usize),
    cloud: &mut Cloud,
) -> Result<(), CloudError> {
    let need = n.checked_mul(layout.stride).filter(|&need| need <= body.len()).ok_or_else(|| CloudError::Data {
        path: path.to_owned(),
        what: format!(
            "{n} {what}s of {} bytes need {} bytes from byte offset {at}, there are {}",
            layout.stride,
            n.saturating_mul(layout.stride),
            body.len()
        ),
    })?;
    for (i, rec) in body[..need].chunks_exact(layout.stride.max(1)).enumerate() {
        let v = idx.map(|k| {
            let f = &layout.fields[k];
            f.scalar.read(&rec[f.offset..f.offset + f.scalar.size()])
        });
        push(cloud, v, || format!("{what} {i} (byte offset {})", at + i * layout.stride), path)?;
    }
    Ok(())
}

fn read_file(path: &Path) -> Result<Vec<u8>, CloudError> {
    std::fs::read(path).map_err(|source| CloudError::Io { path: path.to_owned(), source })
}

/// The header's lines (up to and including the line where `done` holds)
/// and the byte offset of the data after it.
fn header_lines(bytes: &[u8], path: &Path, done: impl Fn(&str) -> bool) -> Result<(Vec<String>, usize), CloudError> {
    let mut lines = Vec::new();
    let mut start = 0;
    while start < bytes.len() {
        let end = bytes[start..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |n| start + n);
        let line = std::str::from_utf8(&bytes[start..end]).map_err(|_| CloudError::Header {
            path: path.to_owned(),
            what: format!("line {} is not text", lines.len() + 1),
        })?;
        let line = line.trim_end_matches('\r').to_owned();
        let last = done(&line);
        lines.push(line);
        start = end + 1;
        if last {
            return Ok((lines, start.min(bytes.len())));
        }
        if lines.len() > 1000 {
            break;
        }
    }
    Err(CloudError::Header { path: path.to_owned(), what: "no end of the header".into() })
}

/// Reads a PCD file (ASCII or binary; `label` names the label field).
pub fn read_pcd(path: &Path, label: &str) -> Result<Cloud, CloudError> {
    parse_pcd(&read_file(path)?, path, label)
}

/// A PCD file's bytes (`path` names it in errors).
pub fn parse_pcd(bytes: &[u8], path: &Path, label: &str) -> Result<Cloud, CloudError> {
    let (lines, data_at) = header_lines(bytes, path, |l| l.starts_with("DATA"))?;
    let bad = |what: String| CloudError::Header { path: path.to_owned(), what };
    let mut keys: std::collections::HashMap<String, Vec<String>> = Default::default();
    for line in &lines {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or_default().to_owned();
        keys.insert(key, words.map(str::to_owned).collect());
    }
    let get = |k: &str| keys.get(k).ok_or_else(|| bad(format!("no {k} line")));
    let names = get("FIELDS")?.clone();
    let n = names.len();
    let sizes: Vec<usize> =
        get("SIZE")?.iter().map(|s| s.parse().map_err(|_| bad(format!("SIZE `{s}`")))).collect::<Result<_, _>>()?;
    let types = get("TYPE")?.clone();
    let counts: Vec<usize> = match keys.get("COUNT") {
        Some(c) => c.iter().map(|s| s.parse().map_err(|_| bad(format!("COUNT `{s}`")))).collect::<Result<_, _>>()?,
        None => vec![1; n],
    };
    if sizes.len() != n || types.len() != n || counts.len() != n {
        return Err(bad(format!("{n} FIELDS but {} SIZE, {} TYPE, {} COUNT", sizes.len(), types.len(), counts.len())));
    }
    let mut fields = Vec::with_capacity(n);
    for k in 0..n {
        let s = Scalar::of_pcd(&types[k], sizes[k]).ok_or_else(|| {
            bad(format!("field `{}`: TYPE {} SIZE {} is not a number type", names[k], types[k], sizes[k]))
        })?;
        fields.push((names[k].clone(), s, counts[k]));
    }
    let layout = Layout::new(fields).map_err(bad)?;
    let idx = layout.pick(label, path)?;
    let number = |k: &str| -> Result<usize, CloudError> {
        get(k)?.first().and_then(|s| s.parse().ok()).ok_or_else(|| bad(format!("{k} is not a count")))
    };
    // WIDTH x HEIGHT points (an organised cloud's rows), which POINTS
    // repeats: the two must agree.
    let size = match (keys.contains_key("WIDTH"), keys.contains_key("HEIGHT")) {
        (true, true) => {
            let (width, height) = (number("WIDTH")?, number("HEIGHT")?);
            let product = width
                .checked_mul(height)
                .ok_or_else(|| bad(format!("WIDTH {width} times HEIGHT {height} is beyond any file")))?;
            Some((width, height, product))
        }
        _ => None,
    };
    let points = match (keys.contains_key("POINTS"), size) {
        (true, _) => number("POINTS")?,
        (false, Some((_, _, product))) => product,
        (false, None) => return Err(bad("no POINTS line, nor WIDTH and HEIGHT".into())),
    };
    if let Some((width, height, product)) = size.filter(|s| s.2 != points) {
        return Err(bad(format!("POINTS {points} is not WIDTH {width} times HEIGHT {height} ({product})")));
    }
    let data = get("DATA")?.first().cloned().unwrap_or_default();
    let mut cloud = Cloud::default();
    match data.as_str() {
        "binary" => read_records(&bytes[data_at..], points, &layout, idx, path, ("point", data_at), &mut cloud)?,
        "ascii" => read_ascii(&bytes[data_at..], lines.len(), points, &layout, idx, path, &mut cloud)?,
        other => {
            return Err(bad(format!(
                "DATA {other}: only ascii and binary PCD are read (save binary_compressed clouds as binary)"
            )))
        }
    }
    Ok(cloud)
}

/// Reads `points` ASCII records (one per line, values in field order),
/// the first on line `first_line + 1` of the file.
fn read_ascii(
    body: &[u8],
    first_line: usize,
    points: usize,
    layout: &Layout,
    idx: [usize; 4],
    path: &Path,
    cloud: &mut Cloud,
) -> Result<(), CloudError> {
    let text = std::str::from_utf8(body)
        .map_err(|_| CloudError::Data { path: path.to_owned(), what: "ASCII data is not text".into() })?;
    // Each field's first value among a line's values.
    let mut at = Vec::with_capacity(layout.fields.len());
    let mut k = 0;
    for f in &layout.fields {
        at.push(k);
        k += f.count;
    }
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    for i in 0..points {
        let Some((n, line)) = lines.next() else {
            return Err(CloudError::Data {
                path: path.to_owned(),
                what: format!("{points} points announced, {i} found"),
            });
        };
        let line_no = first_line + n + 1;
        let values: Vec<&str> = line.split_whitespace().collect();
        if values.len() != k {
            return Err(CloudError::Data {
                path: path.to_owned(),
                what: format!("line {line_no}: {} values, the fields take {k}", values.len()),
            });
        }
        let mut v = [0.0f64; 4];
        for (slot, &fi) in v.iter_mut().zip(&idx) {
            let s = values[at[fi]];
            *slot = match s.parse::<f64>() {
                Ok(x) => x,
                Err(_) if s.eq_ignore_ascii_case("nan") => f64::NAN,
                Err(_) => {
                    return Err(CloudError::Data {
                        path: path.to_owned(),
                        what: format!("line {line_no}: `{s}` is not a number"),
                    })
                }
            };
        }
        push(cloud, v, || format!("line {line_no}"), path)?;
    }
    Ok(())
}

/// Reads a PLY file's `vertex` element (ASCII or binary little endian; the
/// vertices must come first; `label` names the label property).
pub fn read_ply(path: &Path, label: &str) -> Result<Cloud, CloudError> {
    parse_ply(&read_file(path)?, path, label)
}

/// A PLY file's bytes (`path` names it in errors).
pub fn parse_ply(bytes: &[u8], path: &Path, label: &str) -> Result<Cloud, CloudError> {
    let (lines, data_at) = header_lines(bytes, path, |l| l.trim() == "end_header")?;
    let bad = |what: String| CloudError::Header { path: path.to_owned(), what };
    if lines.first().map(|l| l.trim()) != Some("ply") {
        return Err(bad("not a PLY file (no `ply` line)".into()));
    }
    let mut format = None;
    let mut vertices: Option<usize> = None;
    let mut fields = Vec::new();
    let mut in_vertex = false;
    for (n, line) in lines.iter().enumerate().skip(1) {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, count] => {
                if vertices.is_some() {
                    in_vertex = false;
                    continue;
                }
                if *name != "vertex" {
                    return Err(bad(format!("line {}: element `{name}` before the vertices", n + 1)));
                }
                vertices = Some(count.parse().map_err(|_| bad(format!("line {}: `{count}` is not a count", n + 1)))?);
                in_vertex = true;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(bad(format!("line {}: a list property of a vertex", n + 1)));
            }
            ["property", kind, name] if in_vertex => {
                let s = Scalar::of_ply(kind).ok_or_else(|| bad(format!("line {}: type `{kind}`", n + 1)))?;
                fields.push((name.to_string(), s, 1));
            }
            _ => {}
        }
    }
    let vertices = vertices.ok_or_else(|| bad("no vertex element".into()))?;
    let layout = Layout::new(fields).map_err(bad)?;
    let idx = layout.pick(label, path)?;
    let mut cloud = Cloud::default();
    match format.as_deref() {
        Some("binary_little_endian") => {
            read_records(&bytes[data_at..], vertices, &layout, idx, path, ("vertex", data_at), &mut cloud)?
        }
        Some("ascii") => read_ascii(&bytes[data_at..], lines.len(), vertices, &layout, idx, path, &mut cloud)?,
        Some("binary_big_endian") => return Err(bad("big-endian PLY is not read: save it little endian".into())),
        other => return Err(bad(format!("format {other:?}"))),
    }
    Ok(cloud)
}

/// Reads a scan in `format`.
pub fn read(format: CloudFormat, path: &Path, label: &str) -> Result<Cloud, CloudError> {
    match format {
        CloudFormat::Pcd => read_pcd(path, label),
        CloudFormat::Ply => read_ply(path, label),
    }
}

/// Reads poses in KITTI's layout: one line per scan, 12 numbers, the
/// row-major 3x4 pose of the sensor in the map frame, each checked rigid
/// (its 3x3 part a rotation: a scaled pose would scale the map).
pub fn read_poses(path: &Path) -> Result<Vec<Matrix4<f64>>, CloudError> {
    let text = std::fs::read_to_string(path).map_err(|source| CloudError::Io { path: path.to_owned(), source })?;
    parse_poses(&text, path)
}

/// A poses file's text (`path` names it in errors).
pub fn parse_poses(text: &str, path: &Path) -> Result<Vec<Matrix4<f64>>, CloudError> {
    let mut poses = Vec::new();
    for (n, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        // The folder reader's parser of poses.txt lines.
        let m = crate::sources::kitti::parse_rigid(path, n + 1, line).map_err(|e| CloudError::Poses {
            path: path.to_owned(),
            what: match e {
                crate::sources::kitti::KittiError::Parse { line, what, .. } => format!("line {line}: {what}"),
                other => other.to_string(),
            },
        })?;
        poses.push(m);
    }
    Ok(poses)
}

/// Writes poses in KITTI's layout (exact: each number as Rust prints it
/// reads back to the same bits).
pub fn write_poses(path: &Path, poses: &[Matrix4<f64>]) -> Result<(), CloudError> {
    let mut out = String::new();
    for m in poses {
        let row: Vec<String> =
            (0..3).flat_map(|r| (0..4).map(move |c| (r, c))).map(|(r, c)| format!("{}", m[(r, c)])).collect();
        out.push_str(&row.join(" "));
        out.push('\n');
    }
    crate::paths::write_file(path, out).map_err(|source| CloudError::Io { path: path.to_owned(), source })
}

/// Points and labels as little-endian records of x, y, z (float32) and
/// label (uint32): 16 bytes a point, the body of the PCD, PLY and
/// PointCloud2 scans cosem writes.
pub(crate) fn records(points: impl Iterator<Item = [f32; 3]>, labels: &[u32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(16 * labels.len());
    for (p, l) in points.zip(labels) {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&l.to_le_bytes());
    }
    out
}

/// Writes a scan as a binary PCD file: fields x y z (float) and label
/// (uint32).
pub fn write_pcd(path: &Path, points: &[[f32; 3]], labels: &[u32]) -> Result<(), CloudError> {
    let n = points.len().min(labels.len());
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\n\
         COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .into_bytes();
    out.extend(records(points.iter().copied(), labels));
    crate::paths::write_file(path, out).map_err(|source| CloudError::Io { path: path.to_owned(), source })
}

/// Writes a scan as a binary little-endian PLY file: x y z (float) and
/// label (uint).
pub fn write_ply(path: &Path, points: &[[f32; 3]], labels: &[u32]) -> Result<(), CloudError> {
    let n = points.len().min(labels.len());
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment cosem scan export\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\nproperty uint label\nend_header\n"
    )
    .into_bytes();
    out.extend(records(points.iter().copied(), labels));
    crate::paths::write_file(path, out).map_err(|source| CloudError::Io { path: path.to_owned(), source })
}

/// `cosem export scans`: frames `frames` of the SemanticKITTI folder
/// `data` written as PCD or PLY scans (x, y, z, label) named by frame, and
/// their poses (`poses.txt`), into the folder `output`: the input `cosem
/// map --format` reads. The folder is written whole and swapped into
/// place: a new folder, an empty one, or (with `force`) an earlier export
/// (scans and poses.txt only: anything else in it is refused). Returns
/// the scans written.
pub fn export_scans(
    data: &Path,
    frames: crate::sources::kitti::FrameRange,
    format: CloudFormat,
    output: &Path,
    force: bool,
) -> Result<usize, crate::error::Error> {
    crate::paths::check_output(Knob::Output.name(), output, &[(Knob::Data.name(), data)])?;
    refuse_used_folder(output, force)?;
    let seq = crate::sources::kitti::Sequence::open(data)?;
    seq.check_range(frames)?;
    let io = |source| crate::error::Error::Io { path: output.to_path_buf(), source };
    let dir = crate::paths::OutputDir::create(output).map_err(io)?;
    let mut poses = Vec::new();
    for i in frames.frames() {
        let scan = seq.read_scan(i)?;
        poses.push(seq.velodyne_matrix(i)?);
        let points: Vec<[f32; 3]> = scan.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
        let path = dir.path().join(format!("{i:06}.{}", format.extension()));
        match format {
            CloudFormat::Pcd => write_pcd(&path, &points, &scan.labels)?,
            CloudFormat::Ply => write_ply(&path, &points, &scan.labels)?,
        }
    }
    write_poses(&dir.path().join("poses.txt"), &poses)?;
    dir.commit().map_err(io)?;
    Ok(poses.len())
}

/// Refuses a folder that holds anything but an earlier export's scans and
/// poses, and one that holds those without `force`.
fn refuse_used_folder(output: &Path, force: bool) -> Result<(), crate::error::Error> {
    let Ok(entries) = std::fs::read_dir(output) else { return Ok(()) };
    let ours = |n: &str| {
        n == "poses.txt"
            || n.strip_suffix(".pcd")
                .or_else(|| n.strip_suffix(".ply"))
                .is_some_and(|s| s.bytes().all(|b| b.is_ascii_digit()))
    };
    let mut held = None;
    for name in entries.flatten().map(|e| e.file_name().to_string_lossy().into_owned()) {
        if !ours(&name) {
            return Err(crate::error::Error::Invalid(format!(
                "{} {}: already holds {name}, which is not an earlier export's: the folder is replaced \
                 whole, not even with {}; choose a new or empty folder",
                Knob::Output,
                output.display(),
                Knob::Force
            )));
        }
        held = Some(name);
    }
    match held {
        Some(name) if !force => Err(crate::error::Error::Invalid(format!(
            "{} {}: already holds {name}: an earlier export is not replaced without {} (or choose a new folder)",
            Knob::Output,
            output.display(),
            Knob::Force
        ))),
        _ => Ok(()),
    }
}

/// Reads scans (one file each, in order) with their sensor poses and puts
/// them into the first scan's frame, as [`crate::sources::kitti::Sequence::load_range`]
/// does a SemanticKITTI folder's: frame `i` is the `i`-th file.
pub fn load_scans(
    format: CloudFormat,
    files: &[PathBuf],
    poses_path: &Path,
    label: &str,
) -> Result<(Vec<Frame>, usize), CloudError> {
    let poses = read_poses(poses_path)?;
    if poses.len() < files.len() {
        return Err(CloudError::Poses {
            path: poses_path.to_owned(),
            what: format!("{} poses for {} scans", poses.len(), files.len()),
        });
    }
    let Some(first) = poses.first() else { return Ok((Vec::new(), 0)) };
    let anchor_inv = crate::sources::kitti::rigid_inverse(first);
    let mut skipped = 0;
    let mut frames = Vec::with_capacity(files.len());
    for (i, (file, pose)) in files.iter().zip(&poses).enumerate() {
        let cloud = read(format, file, label)?;
        skipped += cloud.skipped;
        frames.push(frame_of(i, None, &(anchor_inv * pose), cloud));
    }
    Ok((frames, skipped))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        crate::paths::write_file(&p, bytes).unwrap();
        (dir, p)
    }

    #[test]
    fn binary_and_ascii_clouds_read_alike() {
        let points = [[1.0f32, 2.0, 3.0], [f32::NAN, 0.0, 0.0], [-4.5, 0.25, 7.0]];
        let labels = [40u32, 10, 0x0003_0050];
        let dir = tempfile::tempdir().unwrap();
        let (pcd, ply) = (dir.path().join("a.pcd"), dir.path().join("a.ply"));
        write_pcd(&pcd, &points, &labels).unwrap();
        write_ply(&ply, &points, &labels).unwrap();
        let want = Cloud { points: vec![points[0], points[2]], labels: vec![labels[0], labels[2]], skipped: 1 };
        assert_eq!(read_pcd(&pcd, "label").unwrap(), want);
        assert_eq!(read_ply(&ply, "label").unwrap(), want);
        // ASCII, extra fields, a 16-bit label, organised NaN holes.
        let text = "VERSION 0.7\nFIELDS x y z intensity class\nSIZE 4 4 4 4 2\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n\
                    WIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3 0.5 40\nnan nan nan 0 0\n-4.5 0.25 7 1 80\n";
        let (_d, p) = tmp("b.pcd", text.as_bytes());
        let c = read_pcd(&p, "class").unwrap();
        assert_eq!((c.points, c.labels, c.skipped), (want.points.clone(), vec![40, 80], 1));
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\n\
                    property double z\nproperty ushort label\nelement face 0\nproperty list uchar int vertex_indices\n\
                    end_header\n1 2 3 40\n-4.5 0.25 7 80\n";
        let (_d, p) = tmp("b.ply", text.as_bytes());
        let c = read_ply(&p, "label").unwrap();
        assert_eq!((c.points, c.labels), (want.points, vec![40, 80]));
    }

    #[test]
    fn sizes_that_would_wrap_are_refused_by_name() {
        let head = |count: &str, size: &str| {
            format!("VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT {count}\n{size}DATA binary\n")
        };
        let (_d, p) = tmp("a.pcd", head("1 1 1 18446744073709551608", "WIDTH 1\nHEIGHT 1\nPOINTS 1\n").as_bytes());
        let e = read_pcd(&p, "label").unwrap_err().to_string();
        assert!(e.contains("COUNT 18446744073709551608") && e.contains("a.pcd"), "{e}");
        let (_d, p) = tmp("b.pcd", head("1 1 1 1", "WIDTH 4294967296\nHEIGHT 4294967296\n").as_bytes());
        let e = read_pcd(&p, "label").unwrap_err().to_string();
        assert!(e.contains("WIDTH 4294967296 times HEIGHT 4294967296"), "{e}");
        let (_d, p) = tmp("c.pcd", head("1 1 1 1", "WIDTH 4294967296\nHEIGHT 4294967296\nPOINTS 0\n").as_bytes());
        let e = read_pcd(&p, "label").unwrap_err().to_string();
        assert!(e.contains("WIDTH") && e.contains("HEIGHT"), "{e}");
        let (_d, p) = tmp("d.pcd", head("1 1 1 1", "WIDTH 3\nHEIGHT 1\nPOINTS 2\n").as_bytes());
        let e = read_pcd(&p, "label").unwrap_err().to_string();
        assert!(e.contains("POINTS 2 is not WIDTH 3 times HEIGHT 1"), "{e}");
    }

    #[test]
    fn broken_clouds_are_typed_errors_naming_the_place() {
        let dir = tempfile::tempdir().unwrap();
        let pcd = dir.path().join("a.pcd");
        write_pcd(&pcd, &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], &[40, 40]).unwrap();
        let mut bytes = std::fs::read(&pcd).unwrap();
        bytes.truncate(bytes.len() - 3);
        let (_d, cut) = tmp("cut.pcd", &bytes);
        let e = read_pcd(&cut, "label").unwrap_err().to_string();
        assert!(e.contains("cut.pcd") && e.contains("byte offset"), "{e}");
        assert!(read_pcd(&pcd, "semantic").unwrap_err().to_string().contains("no field `semantic`"));
        let compressed =
            String::from_utf8_lossy(&std::fs::read(&pcd).unwrap()).replace("DATA binary", "DATA binary_compressed");
        let (_d, c) = tmp("c.pcd", compressed.as_bytes());
        assert!(read_pcd(&c, "label").unwrap_err().to_string().contains("binary_compressed"));
        let (_d, big) = tmp(
            "big.ply",
            b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty uint label\nend_header\n0000000000000000",
        );
        assert!(read_ply(&big, "label").unwrap_err().to_string().contains("big-endian"));
        let (_d, f) =
            tmp("f.pcd", b"FIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 1\nHEIGHT 1\nDATA ascii\n1 2 3 4\n");
        assert!(read_pcd(&f, "label").unwrap_err().to_string().contains("not an integer"));
        let (_d, a) = tmp(
            "a2.pcd",
            b"FIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nWIDTH 2\nHEIGHT 1\nDATA ascii\n1 2 3 4\n1 x 3 4\n",
        );
        let e = read_pcd(&a, "label").unwrap_err().to_string();
        assert!(e.contains("line 8") && e.contains("`x`"), "{e}");
        let (_d, poses) = tmp("poses.txt", b"1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0\n");
        let e = read_poses(&poses).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("3 numbers"), "{e}");
    }
}
