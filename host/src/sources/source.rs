//! Where scans come from, for every command that reads them: a
//! SemanticKITTI-layout folder (the synthetic street is one), a ROS 2
//! recording (`.mcap`), or a folder of PCD or PLY scans with their
//! `poses.txt`. One path names any of them ([`Source::open`] tells which);
//! a range of frames comes back as [`Frame`]s in the range's anchor frame
//! (the sensor frame of its first scan), with the same arithmetic for all
//! three, and the ground truth between two frames of one source is the
//! source's own poses.

use crate::error::Error;
use crate::sources::class_table::ClassTable;
use crate::sources::cloud::CloudFormat;
use crate::sources::kitti::{Frame, FrameRange, Sequence};
use crate::sources::recording::RecordingScans;
use nalgebra::{Isometry3, Matrix4};
use std::path::{Path, PathBuf};

/// How a recording or a user's scans are read (a SemanticKITTI folder
/// needs none of it but the class table).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SourceOptions {
    /// A recording's point cloud topic.
    pub points: String,
    /// The label field of a recording's or a user's scans.
    pub label_field: String,
    /// The frame a recording's poses are chained from.
    pub pose_frame: String,
    /// A recording's odometry topic joining its transforms.
    pub odom: Option<String>,
    /// A class table for a user's label ids (any source).
    pub classes: Option<PathBuf>,
    /// A recording cut short is an error (else read up to the cut, with a
    /// warning).
    pub strict: bool,
}

impl Default for SourceOptions {
    fn default() -> Self {
        SourceOptions {
            points: "/velodyne_points".into(),
            label_field: "label".into(),
            pose_frame: "world".into(),
            odom: None,
            classes: None,
            strict: false,
        }
    }
}

/// What the scans come from.
#[derive(Clone, Debug)]
pub enum SourceKind {
    /// A SemanticKITTI-layout folder (boxed: its calibration is large).
    Folder(Box<Sequence>),
    /// A ROS 2 recording.
    Recording(PathBuf),
    /// One file a scan (in this order) and each scan's sensor pose.
    Scans {
        /// PCD or PLY.
        format: CloudFormat,
        /// The scans.
        files: Vec<PathBuf>,
        /// `T_world_sensor` of each scan.
        poses: Vec<Matrix4<f64>>,
    },
}

/// A source of labelled scans.
#[derive(Clone, Debug)]
pub struct Source {
    /// The path it was opened from.
    pub path: PathBuf,
    /// What it is.
    pub kind: SourceKind,
    /// How it is read.
    pub options: SourceOptions,
    table: Option<ClassTable>,
}

impl Source {
    /// Opens `path`: a `.mcap` file is a recording; a folder with
    /// `velodyne/` a SemanticKITTI folder; a folder of `.pcd` or `.ply`
    /// files (in name order) with `poses.txt` a user's scans.
    pub fn open(path: &Path, options: &SourceOptions) -> Result<Source, Error> {
        let kind = if path.is_file() && path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap")) {
            SourceKind::Recording(path.to_owned())
        } else if path.join("velodyne").is_dir() || !path.is_dir() {
            // A folder without velodyne/ that is not a folder of scans either
            // gets the folder reader's error naming what is missing.
            let seq = Sequence::open(path)?;
            SourceKind::Folder(Box::new(if options.classes.is_some() { seq.with_user_ids() } else { seq }))
        } else {
            Self::scans_folder(path)?
        };
        Self::with_kind(path, kind, options)
    }

    /// A user's scans given one by one, with their poses file.
    pub fn scans(
        format: CloudFormat,
        files: &[PathBuf],
        poses: &Path,
        options: &SourceOptions,
    ) -> Result<Source, Error> {
        let files = &in_frame_order(files.to_vec())?;
        let read = crate::sources::cloud::read_poses(poses)?;
        if read.len() < files.len() {
            let what = format!("{} poses for {} scans", read.len(), files.len());
            return Err(crate::sources::cloud::CloudError::Poses { path: poses.to_owned(), what }.into());
        }
        let kind = SourceKind::Scans { format, files: files.to_vec(), poses: read };
        let first = files.first().map_or(poses, PathBuf::as_path);
        Self::with_kind(first, kind, options)
    }

    /// A ROS 2 recording.
    pub fn recording(path: &Path, options: &SourceOptions) -> Result<Source, Error> {
        Self::with_kind(path, SourceKind::Recording(path.to_owned()), options)
    }

    fn with_kind(path: &Path, kind: SourceKind, options: &SourceOptions) -> Result<Source, Error> {
        let table = match &options.classes {
            Some(t) => Some(ClassTable::read(t).map_err(|e| Error::Invalid(e.to_string()))?),
            None => None,
        };
        Ok(Source { path: path.to_owned(), kind, options: options.clone(), table })
    }

    /// A folder of PCD or PLY scans with `poses.txt`.
    fn scans_folder(dir: &Path) -> Result<SourceKind, Error> {
        let io = |source| Error::Io { path: dir.to_owned(), source };
        let mut pcd = Vec::new();
        let mut ply = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(io)? {
            let path = entry.map_err(io)?.path();
            match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
                Some("pcd") => pcd.push(path),
                Some("ply") => ply.push(path),
                _ => {}
            }
        }
        let (format, files) = match (pcd.is_empty(), ply.is_empty()) {
            (false, true) => (CloudFormat::Pcd, pcd),
            (true, false) => (CloudFormat::Ply, ply),
            (false, false) => {
                return Err(Error::Invalid(format!(
                    "{}: holds both .pcd and .ply files: one format a folder",
                    dir.display()
                )))
            }
            (true, true) => {
                return Err(Error::Invalid(format!(
                    "{}: not a source of scans: no velodyne/ (a SemanticKITTI folder), no .pcd or .ply files with poses.txt, not a .mcap recording",
                    dir.display()
                )))
            }
        };
        let files = in_frame_order(files)?;
        let poses = crate::sources::cloud::read_poses(&dir.join("poses.txt"))?;
        if poses.len() < files.len() {
            return Err(Error::Invalid(format!(
                "{}: {} poses for {} scans",
                dir.join("poses.txt").display(),
                poses.len(),
                files.len()
            )));
        }
        Ok(SourceKind::Scans { format, files, poses })
    }

    /// The source's name for captions: its folder's or file's name.
    pub fn name(&self) -> String {
        let p = match &self.kind {
            SourceKind::Scans { files, .. } if self.path.is_file() => {
                files.first().and_then(|f| f.parent()).unwrap_or(&self.path)
            }
            _ => &self.path,
        };
        p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    }

    /// The SemanticKITTI folder, when the source is one (`cosem label` and
    /// the camera's calibration need one).
    pub fn folder(&self) -> Option<&Sequence> {
        match &self.kind {
            SourceKind::Folder(seq) => Some(seq),
            _ => None,
        }
    }

    /// The frames of `range` (all of a recording's or a user's scans when
    /// `None`) in the range's anchor frame, their labels through the class
    /// table where one is given, and the anchor's pose `T_world_anchor`.
    /// Points skipped for a NaN coordinate are counted in the third value.
    pub fn load(&self, range: Option<FrameRange>) -> Result<(Vec<Frame>, Matrix4<f64>, usize), Error> {
        let (mut frames, anchor, skipped) = match &self.kind {
            SourceKind::Folder(seq) => {
                let range = range.ok_or_else(|| {
                    Error::Invalid(format!(
                        "{}: a SemanticKITTI folder needs its frames (START:END)",
                        self.path.display()
                    ))
                })?;
                let frames = seq.load_range(range)?;
                (frames, seq.velodyne_matrix(range.start)?, 0)
            }
            SourceKind::Recording(path) => {
                let what = RecordingScans {
                    points: &self.options.points,
                    label_field: &self.options.label_field,
                    pose_frame: &self.options.pose_frame,
                    frames: range,
                    odom: self.options.odom.as_deref(),
                    strict: self.options.strict,
                };
                let (frames, skipped, world) = crate::sources::recording::read_scans_in_world(path, &what)?;
                (frames, world.first().copied().unwrap_or_else(Matrix4::identity), skipped)
            }
            SourceKind::Scans { format, files, poses } => {
                let all = FrameRange { start: 0, end: files.len(), stride: 1 };
                let range = range.unwrap_or(all);
                let anchor = *poses.get(range.start).ok_or_else(|| self.beyond(range, files.len()))?;
                let anchor_inv = crate::sources::kitti::rigid_inverse(&anchor);
                let mut frames = Vec::new();
                let mut skipped = 0;
                for i in range.frames() {
                    let file = files.get(i).ok_or_else(|| self.beyond(range, files.len()))?;
                    let pose = poses.get(i).ok_or_else(|| self.beyond(range, poses.len()))?;
                    let cloud = crate::sources::cloud::read(*format, file, &self.options.label_field)?;
                    skipped += cloud.skipped;
                    frames.push(crate::sources::kitti::frame_of(i, None, &(anchor_inv * pose), cloud));
                }
                (frames, anchor, skipped)
            }
        };
        if let (Some(table), Some(path)) = (&self.table, &self.options.classes) {
            table.relabel(&mut frames).map_err(|(f, i, id)| {
                let scan = match &self.kind {
                    SourceKind::Scans { files, .. } => {
                        files.get(frames[f].index).map_or_else(String::new, |p| p.display().to_string())
                    }
                    SourceKind::Recording(_) => format!("{} message {}", self.options.points, frames[f].index),
                    SourceKind::Folder(_) => format!("frame {}", frames[f].index),
                };
                Error::Invalid(format!("{scan}: point {i}: label id {id} is not in the class table {}", path.display()))
            })?;
        }
        Ok((frames, anchor, skipped))
    }

    fn beyond(&self, range: FrameRange, n: usize) -> Error {
        Error::Invalid(format!("{}: frames {range} beyond its {n} scans", self.path.display()))
    }

    /// `T_a_b`: frame `b`'s sensor pose in frame `a`'s sensor frame, from
    /// the source's own poses.
    pub fn relative_pose(&self, a: usize, b: usize) -> Result<Isometry3<f64>, Error> {
        Ok(relative(&self.world_pose(a)?, &self.world_pose(b)?))
    }

    /// `T_world_sensor` of frame `i`.
    pub fn world_pose(&self, i: usize) -> Result<Matrix4<f64>, Error> {
        match &self.kind {
            SourceKind::Folder(seq) => Ok(seq.velodyne_matrix(i)?),
            SourceKind::Scans { poses, .. } => poses
                .get(i)
                .copied()
                .ok_or_else(|| self.beyond(FrameRange { start: i, end: i + 1, stride: 1 }, poses.len())),
            SourceKind::Recording(_) => Ok(self.load(Some(FrameRange { start: i, end: i + 1, stride: 1 }))?.1),
        }
    }

    /// Whether `other`'s poses are in this source's world: one trajectory
    /// ([`Source::same_trajectory`]), or folders of one world (a town's
    /// robots: [`crate::sources::kitti::Sequence::shares_world`]).
    pub fn shares_world(&self, other: &Source) -> bool {
        match (&self.kind, &other.kind) {
            (SourceKind::Folder(a), SourceKind::Folder(b)) => a.shares_world(b),
            _ => self.same_trajectory(other),
        }
    }

    /// Whether `other` shares this source's world frame (the same
    /// trajectory: a folder's poses, a recording, a user's poses), so the
    /// truth between their frames is known.
    pub fn same_trajectory(&self, other: &Source) -> bool {
        match (&self.kind, &other.kind) {
            (SourceKind::Folder(a), SourceKind::Folder(b)) => a.same_trajectory(b),
            (SourceKind::Recording(a), SourceKind::Recording(b)) => {
                crate::paths::same_file(a, b) && self.options == other.options
            }
            (SourceKind::Scans { poses: a, .. }, SourceKind::Scans { poses: b, .. }) => a == b,
            _ => false,
        }
    }
}

/// `T_a_b` from two sensor poses in one world, `inv(W_a) * W_b` (with the
/// files' own numbers, as the folder reader moves points).
pub fn relative(wa: &Matrix4<f64>, wb: &Matrix4<f64>) -> Isometry3<f64> {
    crate::sources::kitti::isometry(&(crate::sources::kitti::rigid_inverse(wa) * wb))
}

/// Scan files in frame order: numbered files (`5.pcd`, `000010.pcd`) by
/// their number, not their text (a shell's `*.pcd` puts 10 before 5);
/// files with no number keep the order given. Numbered and unnumbered
/// files mixed is an error: which pose is whose cannot be told.
pub fn in_frame_order(mut files: Vec<PathBuf>) -> Result<Vec<PathBuf>, Error> {
    let number = |p: &PathBuf| p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<u64>().ok());
    let numbered = files.iter().filter(|f| number(f).is_some()).count();
    if numbered == files.len() {
        files.sort_by_key(|f| (number(f), f.clone()));
    } else if numbered > 0 {
        let (n, other) = (files.iter().find(|f| number(f).is_some()), files.iter().find(|f| number(f).is_none()));
        let name = |f: Option<&PathBuf>| f.map(|f| f.display().to_string()).unwrap_or_default();
        return Err(Error::Invalid(format!(
            "scans mix numbered files ({}) with others ({}): name every scan by its frame number, or none",
            name(n),
            name(other)
        )));
    }
    Ok(files)
}
