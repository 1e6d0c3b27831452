//! SemanticKITTI reader: scans, labels, poses, calibration, timestamps.
//!
//! Every malformed input is an error naming the file (and frame, line or
//! byte offset) and what is wrong with it.

use cosem_core::geometry::{rigid_from_matrix, Isometry3};
use cosem_core::map::{LabelDistribution, LABEL_SLOTS};
use nalgebra::Matrix4;
use std::path::{Path, PathBuf};

/// Anything wrong with a SemanticKITTI-layout folder.
#[derive(Debug, thiserror::Error)]
pub enum KittiError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A scan file whose size is not a whole number of 16-byte points.
    #[error("{path}: size {len} bytes is not a multiple of 16 (x, y, z, intensity as f32)")]
    ScanSize {
        /// The scan file.
        path: PathBuf,
        /// Its size.
        len: u64,
    },
    /// A label file whose size is not a whole number of u32.
    #[error("{path}: size {len} bytes is not a multiple of 4 (one u32 per point)")]
    LabelSize {
        /// The label file.
        path: PathBuf,
        /// Its size.
        len: u64,
    },
    /// A label file whose count differs from its scan's.
    #[error("{path}: {labels} labels for {points} points in the scan")]
    LabelCount {
        /// The label file.
        path: PathBuf,
        /// Labels in it.
        labels: usize,
        /// Points in the scan.
        points: usize,
    },
    /// A non-finite coordinate in a scan.
    #[error("{path}: non-finite coordinate at byte offset {offset}")]
    NonFinite {
        /// The scan file.
        path: PathBuf,
        /// Byte offset of the value.
        offset: usize,
    },
    /// The poses file has no line for a frame.
    #[error("{path}: no pose for frame {frame} (the file has {lines} pose lines)")]
    MissingPose {
        /// poses.txt.
        path: PathBuf,
        /// The frame asked for.
        frame: usize,
        /// Lines in the file.
        lines: usize,
    },
    /// The calibration has no `Tr:` line.
    #[error("{path}: no `Tr:` line (velodyne to camera transform)")]
    MissingTr {
        /// calib.txt.
        path: PathBuf,
    },
    /// The calibration has no `P<camera>:` line.
    #[error("{path}: no `P{camera}:` line (projection matrix of camera {camera})")]
    MissingProjection {
        /// calib.txt.
        path: PathBuf,
        /// The camera asked for.
        camera: u8,
    },
    /// A frame's scan file does not exist.
    #[error("{path}: frame {frame} is missing")]
    MissingFrame {
        /// The expected scan file.
        path: PathBuf,
        /// The frame.
        frame: usize,
    },
    /// A text line that does not parse.
    #[error("{path}:{line}: {what}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// A binary file whose content is wrong.
    #[error("{path}: {what}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where.
        what: String,
    },
    /// A frame range that does not parse or is empty.
    #[error("frame range `{0}`: expected START:END[:STRIDE] with END > START and STRIDE >= 1")]
    Range(String),
    /// A frame range that asks for frames the source does not have.
    #[error("frames {0}")]
    FramesMissing(String),
}

impl crate::error::LayerError for KittiError {}

/// Frames `start..end` (end exclusive) every `stride`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    /// First frame.
    pub start: usize,
    /// One past the last frame.
    pub end: usize,
    /// Step.
    pub stride: usize,
}

impl FrameRange {
    /// The frames of the range.
    pub fn frames(&self) -> impl Iterator<Item = usize> + Clone {
        (self.start..self.end).step_by(self.stride)
    }

    /// How many frames the range has (counted, not listed).
    pub fn len(&self) -> usize {
        (self.end - self.start).div_ceil(self.stride.max(1))
    }

    /// Whether the range has no frame (never, as parsed).
    pub fn is_empty(&self) -> bool {
        self.end <= self.start
    }

    /// Whether `frame` is one of the range's.
    pub fn contains(&self, frame: usize) -> bool {
        frame >= self.start && frame < self.end && (frame - self.start).is_multiple_of(self.stride.max(1))
    }

    /// The range's frames among `available` (a source's frame numbers,
    /// sorted): listed from what exists, never from the range, so a huge
    /// range costs nothing; a frame of the range that is not there is an
    /// error naming the range, the frame and what `source` has.
    pub fn select(&self, available: &[usize], source: &std::path::Path) -> Result<Vec<usize>, KittiError> {
        let chosen: Vec<usize> = available.iter().copied().filter(|&f| self.contains(f)).collect();
        if chosen.len() == self.len() {
            return Ok(chosen);
        }
        let missing = self.frames().find(|f| available.binary_search(f).is_err()).unwrap_or(self.start);
        let has = match (available.first(), available.last()) {
            (Some(a), Some(b)) => format!("{} frames, {a} to {b}", available.len()),
            _ => "no frames".into(),
        };
        Err(KittiError::FramesMissing(format!("{self}: frame {missing} is not in {} ({has})", source.display())))
    }
}

impl std::str::FromStr for FrameRange {
    type Err = KittiError;
    fn from_str(s: &str) -> Result<Self, KittiError> {
        let bad = || KittiError::Range(s.to_string());
        let parts: Vec<&str> = s.split(':').collect();
        if parts.len() < 2 || parts.len() > 3 {
            return Err(bad());
        }
        let n = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
        let start = n(parts[0])?;
        let end = n(parts[1])?;
        let stride = if parts.len() == 3 { n(parts[2])? } else { 1 };
        if end <= start || stride == 0 {
            return Err(bad());
        }
        Ok(FrameRange { start, end, stride })
    }
}

impl std::fmt::Display for FrameRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.stride == 1 {
            write!(f, "{}:{}", self.start, self.end)
        } else {
            write!(f, "{}:{}:{}", self.start, self.end, self.stride)
        }
    }
}

/// One raw scan: points in the LiDAR frame and raw label words.
#[derive(Clone, Debug)]
pub struct Scan {
    /// Frame number.
    pub frame: usize,
    /// x, y, z (metres, LiDAR frame) and intensity.
    pub points: Vec<[f32; 4]>,
    /// Raw SemanticKITTI label words (semantic id in the low 16 bits).
    pub labels: Vec<u32>,
}

/// A scan put into a robot's anchor frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Frame number.
    pub index: usize,
    /// Timestamp (s), when `times.txt` is present.
    pub time: Option<f64>,
    /// Pose of this scan's LiDAR in the anchor frame.
    pub pose: Isometry3<f64>,
    /// Points in the anchor frame.
    pub points: Vec<[f32; 3]>,
    /// Range of each point from its own sensor (m).
    pub ranges: Vec<f32>,
    /// Raw label words.
    pub labels: Vec<u32>,
    /// Per-point label evidence from a camera network's probabilities
    /// (`evidence/NNNNNN.bin`, written by `cosem label --probabilities`),
    /// fused instead of the hard label where present.
    pub evidence: Option<Vec<Option<cosem_core::map::LabelDistribution>>>,
}

/// A SemanticKITTI sequence folder.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// The folder.
    pub dir: PathBuf,
    /// Velodyne-to-camera transform `Tr` as calib.txt gives it (checked to
    /// be rigid to [`cosem_core::geometry::RIGID_TOLERANCE`]); points are
    /// moved with the file's exact numbers, transforms handed out as
    /// isometries ([`Sequence::tr`]).
    tr: Matrix4<f64>,
    /// The cameras' 3x4 projections `P0`..`P3` (as 4x4, last row 0 0 0 1),
    /// where given: projections, not rigid transforms.
    pub projections: [Option<Matrix4<f64>>; 4],
    /// Camera-frame poses, one per line of poses.txt (checked rigid).
    camera_poses: Vec<Matrix4<f64>>,
    /// Timestamps, when times.txt is present.
    pub times: Option<Vec<f64>>,
    /// Labels are checked to be SemanticKITTI ids (off when a user's class
    /// table reads them: [`Sequence::with_user_ids`]).
    check_ids: bool,
    /// The world its poses are in, when `world.txt` names one (the robots
    /// of a synthetic town): folders naming the same world share it.
    pub world: Option<String>,
}

fn read(path: &Path) -> Result<Vec<u8>, KittiError> {
    std::fs::read(path).map_err(|source| KittiError::Io { path: path.to_path_buf(), source })
}

/// The most bytes of a `world.txt`: one line naming a world.
const MAX_WORLD_BYTES: u64 = 4096;

/// The world a folder's `world.txt` names (its first line), if it has one.
fn read_world(path: &Path) -> Result<Option<String>, KittiError> {
    let Ok(meta) = std::fs::metadata(path) else { return Ok(None) };
    if meta.len() > MAX_WORLD_BYTES {
        return Err(KittiError::Parse {
            path: path.to_path_buf(),
            line: 0,
            what: format!("{} bytes: a world's name is one line of at most {MAX_WORLD_BYTES}", meta.len()),
        });
    }
    let text = read_text(path)?;
    let name = text.lines().next().unwrap_or("").trim();
    if name.is_empty() {
        return Err(KittiError::Parse { path: path.to_path_buf(), line: 1, what: "no world named".into() });
    }
    Ok(Some(name.to_string()))
}

fn read_text(path: &Path) -> Result<String, KittiError> {
    let bytes = read(path)?;
    String::from_utf8(bytes).map_err(|e| KittiError::Parse {
        path: path.to_path_buf(),
        line: 0,
        what: format!("not UTF-8 text ({e})"),
    })
}

/// Parses 12 numbers of a 3x4 row-major matrix into a 4x4 one.
pub(crate) fn parse_3x4(path: &Path, line: usize, text: &str) -> Result<Matrix4<f64>, KittiError> {
    let err = |what: String| KittiError::Parse { path: path.to_path_buf(), line, what };
    let vals: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse::<f64>().map_err(|_| err(format!("`{t}` is not a number"))))
        .collect::<Result<_, _>>()?;
    if vals.len() != 12 {
        return Err(err(format!("{} numbers, a 3x4 matrix takes 12", vals.len())));
    }
    if vals.iter().any(|v| !v.is_finite()) {
        return Err(err("non-finite number".into()));
    }
    let mut m = Matrix4::identity();
    for r in 0..3 {
        for c in 0..4 {
            m[(r, c)] = vals[r * 4 + c];
        }
    }
    Ok(m)
}

/// Parses a 3x4 matrix that must be a rigid transform (a pose, `Tr`).
pub(crate) fn parse_rigid(path: &Path, line: usize, text: &str) -> Result<Matrix4<f64>, KittiError> {
    let m = parse_3x4(path, line, text)?;
    match rigid_from_matrix(&m) {
        Some(_) => Ok(m),
        None => Err(KittiError::Parse {
            path: path.to_path_buf(),
            line,
            what: "not a rigid transform (its 3x3 part must be a rotation)".into(),
        }),
    }
}

/// Inverse of a rigid 4x4 matrix (transpose of the rotation).
pub(crate) fn rigid_inverse(m: &Matrix4<f64>) -> Matrix4<f64> {
    let r = m.fixed_view::<3, 3>(0, 0).transpose();
    let t = -(r * m.fixed_view::<3, 1>(0, 3));
    let mut out = Matrix4::identity();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    out.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    out
}

/// The isometry of a matrix already checked rigid.
pub(crate) fn isometry(m: &Matrix4<f64>) -> Isometry3<f64> {
    rigid_from_matrix(m).unwrap_or_else(Isometry3::identity)
}

impl Sequence {
    /// Opens a folder: reads calib.txt (`Tr`), poses.txt and, if present, times.txt.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, KittiError> {
        let dir = dir.as_ref().to_path_buf();
        let calib_path = dir.join("calib.txt");
        let calib = read_text(&calib_path)?;
        let mut tr = None;
        let mut projections = [None; 4];
        // A key given twice is refused: which one is meant cannot be told.
        let mut first_line: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
        for (i, line) in calib.lines().enumerate() {
            let line = line.trim_start();
            if let Some((key, _)) = line.split_once(':') {
                if let Some(before) = first_line.insert(key.trim(), i + 1) {
                    return Err(KittiError::Parse {
                        path: calib_path.clone(),
                        line: i + 1,
                        what: format!("`{}:` again (first on line {before}): one line a key", key.trim()),
                    });
                }
            }
            if let Some(rest) = line.strip_prefix("Tr:") {
                tr = Some(parse_rigid(&calib_path, i + 1, rest)?);
            }
            for (k, p) in projections.iter_mut().enumerate() {
                if let Some(rest) = line.strip_prefix(&format!("P{k}:")) {
                    *p = Some(parse_3x4(&calib_path, i + 1, rest)?);
                }
            }
        }
        let tr = tr.ok_or(KittiError::MissingTr { path: calib_path })?;
        let poses_path = dir.join("poses.txt");
        let mut camera_poses = Vec::new();
        let text = read_text(&poses_path)?;
        // Line i is frame i: a blank line would shift every later pose by
        // one frame. Only trailing blank lines are allowed.
        let lines: Vec<&str> = text.lines().collect();
        let used = lines.iter().rposition(|l| !l.trim().is_empty()).map_or(0, |i| i + 1);
        for (i, line) in lines[..used].iter().enumerate() {
            if line.trim().is_empty() {
                return Err(KittiError::Parse {
                    path: poses_path,
                    line: i + 1,
                    what: "blank line before the last pose (line N is frame N-1)".into(),
                });
            }
            camera_poses.push(parse_rigid(&poses_path, i + 1, line)?);
        }
        let times_path = dir.join("times.txt");
        let times = if times_path.exists() {
            let mut t = Vec::new();
            for (i, line) in read_text(&times_path)?.lines().enumerate() {
                let s = line.trim();
                if s.is_empty() {
                    continue;
                }
                let v: f64 = s.parse().map_err(|_| KittiError::Parse {
                    path: times_path.clone(),
                    line: i + 1,
                    what: format!("`{s}` is not a timestamp"),
                })?;
                t.push(v);
            }
            Some(t)
        } else {
            None
        };
        let world = read_world(&dir.join("world.txt"))?;
        Ok(Sequence { dir, tr, projections, camera_poses, times, check_ids: true, world })
    }

    /// Path of a frame's scan.
    pub fn scan_path(&self, frame: usize) -> PathBuf {
        self.dir.join("velodyne").join(format!("{frame:06}.bin"))
    }

    /// Path of a frame's labels.
    pub fn label_path(&self, frame: usize) -> PathBuf {
        self.dir.join("labels").join(format!("{frame:06}.label"))
    }

    /// `Tr`, velodyne to camera.
    pub fn tr(&self) -> Isometry3<f64> {
        isometry(&self.tr)
    }

    /// `Tr` as calib.txt writes it (a 4x4 matrix).
    pub fn tr_matrix(&self) -> &Matrix4<f64> {
        &self.tr
    }

    /// Whether `other` holds the same trajectory (the same `Tr` and poses):
    /// folders of one sequence, whose scans share one world frame.
    pub fn same_trajectory(&self, other: &Sequence) -> bool {
        self.tr == other.tr && self.camera_poses == other.camera_poses
    }

    /// Whether `other`'s poses are in this folder's world: the same
    /// trajectory, or folders whose `world.txt` names the same world (with
    /// the same `Tr`).
    pub fn shares_world(&self, other: &Sequence) -> bool {
        self.same_trajectory(other) || (self.world.is_some() && self.world == other.world && self.tr == other.tr)
    }

    /// Number of poses in poses.txt.
    pub fn pose_count(&self) -> usize {
        self.camera_poses.len()
    }

    /// Checks that `range` lies within the sequence (a pose for each of
    /// its frames), naming the range and the frames there are.
    pub fn check_range(&self, range: FrameRange) -> Result<(), KittiError> {
        let n = self.camera_poses.len();
        if range.end > n {
            return Err(KittiError::FramesMissing(format!(
                "{range}: {} has a pose for {n} frames (0 to {}): no pose for frame {n}",
                self.dir.join("poses.txt").display(),
                n.saturating_sub(1)
            )));
        }
        Ok(())
    }

    /// The LiDAR pose of a scan in the world as the matrix
    /// `inv(Tr) * P_i * Tr`, with the file's numbers (what
    /// [`Sequence::load_range`] moves points with).
    pub fn velodyne_matrix(&self, frame: usize) -> Result<Matrix4<f64>, KittiError> {
        let p = self.camera_poses.get(frame).ok_or_else(|| KittiError::MissingPose {
            path: self.dir.join("poses.txt"),
            frame,
            lines: self.camera_poses.len(),
        })?;
        Ok(rigid_inverse(&self.tr) * p * self.tr)
    }

    /// The same folder with labels that are a user's ids, read through a
    /// class table ([`crate::sources::class_table`]) instead of SemanticKITTI's.
    pub fn with_user_ids(mut self) -> Self {
        self.check_ids = false;
        self
    }

    /// LiDAR pose of a scan in the world: `inv(Tr) * P_i * Tr`.
    pub fn velodyne_pose(&self, frame: usize) -> Result<Isometry3<f64>, KittiError> {
        Ok(isometry(&self.velodyne_matrix(frame)?))
    }

    /// `T_a_b = inv(V_a) * V_b`: frame b's LiDAR pose in frame a's LiDAR frame.
    pub fn relative_pose(&self, a: usize, b: usize) -> Result<Isometry3<f64>, KittiError> {
        Ok(isometry(&(rigid_inverse(&self.velodyne_matrix(a)?) * self.velodyne_matrix(b)?)))
    }

    /// Camera `camera`'s projection matrix (`P<camera>` of calib.txt).
    pub fn projection(&self, camera: u8) -> Result<Matrix4<f64>, KittiError> {
        self.projections
            .get(usize::from(camera))
            .copied()
            .flatten()
            .ok_or(KittiError::MissingProjection { path: self.dir.join("calib.txt"), camera })
    }

    /// Frames with a scan file in `velodyne/`, in order.
    pub fn scan_frames(&self) -> Result<Vec<usize>, KittiError> {
        let dir = self.dir.join("velodyne");
        let entries = std::fs::read_dir(&dir).map_err(|source| KittiError::Io { path: dir.clone(), source })?;
        let mut frames = Vec::new();
        for e in entries {
            let e = e.map_err(|source| KittiError::Io { path: dir.clone(), source })?;
            let name = e.file_name();
            let name = name.to_string_lossy();
            if let Some(Ok(n)) = name.strip_suffix(".bin").map(str::parse::<usize>) {
                frames.push(n);
            }
        }
        frames.sort_unstable();
        Ok(frames)
    }

    /// Reads one scan's points (x, y, z, intensity), checking size and values.
    pub fn read_points(&self, frame: usize) -> Result<Vec<[f32; 4]>, KittiError> {
        let scan_path = self.scan_path(frame);
        if !scan_path.exists() {
            return Err(KittiError::MissingFrame { path: scan_path, frame });
        }
        let bytes = read(&scan_path)?;
        if bytes.len() % 16 != 0 {
            return Err(KittiError::ScanSize { path: scan_path, len: bytes.len() as u64 });
        }
        let mut points = Vec::with_capacity(bytes.len() / 16);
        for (i, chunk) in bytes.chunks_exact(16).enumerate() {
            let f = |k: usize| f32::from_le_bytes([chunk[4 * k], chunk[4 * k + 1], chunk[4 * k + 2], chunk[4 * k + 3]]);
            let p = [f(0), f(1), f(2), f(3)];
            if let Some(k) = p[..3].iter().position(|v| !v.is_finite()) {
                return Err(KittiError::NonFinite { path: scan_path, offset: i * 16 + 4 * k });
            }
            points.push(p);
        }
        Ok(points)
    }

    /// Reads one scan and its labels, checking sizes, counts and values.
    pub fn read_scan(&self, frame: usize) -> Result<Scan, KittiError> {
        let points = self.read_points(frame)?;
        let label_path = self.label_path(frame);
        if !label_path.exists() {
            return Err(KittiError::MissingFrame { path: label_path, frame });
        }
        let lbytes = read(&label_path)?;
        if lbytes.len() % 4 != 0 {
            return Err(KittiError::LabelSize { path: label_path, len: lbytes.len() as u64 });
        }
        let labels: Vec<u32> = lbytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let not_kitti = |l: &u32| !cosem_core::classes::Class::is_semantic_kitti_id(*l);
        if let Some(i) = labels.iter().position(not_kitti).filter(|_| self.check_ids) {
            return Err(KittiError::Malformed {
                path: label_path,
                what: format!(
                    "point {i} (byte offset {}): label id {} is not a SemanticKITTI id",
                    4 * i,
                    labels[i] & 0xFFFF
                ),
            });
        }
        if labels.len() != points.len() {
            return Err(KittiError::LabelCount { path: label_path, labels: labels.len(), points: points.len() });
        }
        Ok(Scan { frame, points, labels })
    }

    /// Reads the frames of a range and puts them into the anchor frame (the
    /// LiDAR frame of the range's first scan).
    pub fn load_range(&self, range: FrameRange) -> Result<Vec<Frame>, KittiError> {
        self.check_range(range)?;
        // Points move with the file's own numbers (as KITTI's tools do).
        let anchor_inv = rigid_inverse(&self.velodyne_matrix(range.start)?);
        range
            .frames()
            .map(|i| {
                let m = anchor_inv * self.velodyne_matrix(i)?;
                let scan = self.read_scan(i)?;
                let points = scan.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
                let cloud = Cloud { points, labels: scan.labels, skipped: 0 };
                let time = self.times.as_ref().and_then(|t| t.get(i).copied());
                let mut frame = frame_of(i, time, &m, cloud);
                frame.evidence = read_evidence(&self.dir, i, frame.points.len())?;
                Ok(frame)
            })
            .collect()
    }
}
/// Reads a frame's label evidence (`evidence/NNNNNN.bin`, which `cosem
/// label --probabilities` writes beside the labels), if the folder has
/// one: one label distribution per point (`None` for empty slots).
pub fn read_evidence(
    dir: &Path,
    frame: usize,
    points: usize,
) -> Result<Option<Vec<Option<LabelDistribution>>>, KittiError> {
    let path = dir.join("evidence").join(format!("{frame:06}.bin"));
    if !path.exists() {
        return Ok(None);
    }
    let bytes = std::fs::read(&path).map_err(|source| KittiError::Io { path: path.clone(), source })?;
    let per = 2 * LABEL_SLOTS;
    if bytes.len() != points * per {
        return Err(KittiError::Malformed {
            path,
            what: format!("{} bytes of evidence for {points} points ({per} bytes each)", bytes.len()),
        });
    }
    let mut out = Vec::with_capacity(points);
    for (i, c) in bytes.chunks_exact(per).enumerate() {
        let mut slots = [0u16; LABEL_SLOTS];
        for (k, s) in slots.iter_mut().enumerate() {
            *s = u16::from_le_bytes([c[2 * k], c[2 * k + 1]]);
        }
        let d = LabelDistribution::from_raw(slots).map_err(|e| KittiError::Malformed {
            path: path.clone(),
            what: format!("point {i} (byte offset {}): {e}", i * per),
        })?;
        out.push((!d.is_empty()).then_some(d));
    }
    Ok(Some(out))
}

/// One scan read from a file: points in the sensor's frame and their raw
/// label words.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cloud {
    /// x, y, z (m, sensor frame).
    pub points: Vec<[f32; 3]>,
    /// Label words (SemanticKITTI id in the low 16 bits).
    pub labels: Vec<u32>,
    /// Points skipped for a NaN coordinate.
    pub skipped: usize,
}

/// A scan as a [`Frame`]: its points moved by `m` (the scan's sensor pose
/// in the anchor frame) with the folder reader's arithmetic.
pub fn frame_of(index: usize, time: Option<f64>, m: &Matrix4<f64>, cloud: Cloud) -> Frame {
    let mut points = Vec::with_capacity(cloud.points.len());
    let mut ranges = Vec::with_capacity(cloud.points.len());
    for p in &cloud.points {
        let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        ranges.push((x * x + y * y + z * z).sqrt() as f32);
        points.push([
            (m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)]) as f32,
            (m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)]) as f32,
            (m[(2, 0)] * x + m[(2, 1)] * y + m[(2, 2)] * z + m[(2, 3)]) as f32,
        ]);
    }
    let pose: Isometry3<f64> = isometry(m);
    Frame { index, time, pose, points, ranges, labels: cloud.labels, evidence: None }
}
