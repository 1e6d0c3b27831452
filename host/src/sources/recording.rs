//! ROS 2 recordings (MCAP, rosbag2's default storage): labelled
//! `sensor_msgs/msg/PointCloud2` scans on one topic and the sensor's pose
//! at each scan's stamp from `/tf` and `/tf_static`
//! (`tf2_msgs/msg/TFMessage`). Messages are CDR (ROS 2's serialisation,
//! read and written by the `cdr` crate); chunks may be compressed with
//! zstd or lz4 (the `mcap` crate).
//!
//! A scan's pose is the chain of transforms from the pose frame (default
//! `world`) to the cloud's `frame_id`: a transform stamped exactly at the
//! scan is used as it is, otherwise the two around the stamp are
//! interpolated (linear translation, spherical rotation); static
//! transforms hold at every stamp. A stamp outside an edge's transforms,
//! or no chain, is an error naming the scan.

use crate::knobs::Knob;
use crate::sources::cloud::{read_records, Layout, Scalar};
use crate::sources::kitti::Frame;
use crate::sources::kitti::{frame_of, Cloud};
use crate::sources::ros_msgs::*;
use nalgebra::{Isometry3, Matrix4, Quaternion as NQuaternion, Translation3, UnitQuaternion};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Why a recording could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// Reading or writing the file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The MCAP container is broken or holds what this reader cannot take.
    #[error("{path}: {what}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A message could not be read, or a scan has no pose.
    #[error("{path}: {what}")]
    Message {
        /// The file.
        path: PathBuf,
        /// Which message (topic, index, stamp) and what is wrong.
        what: String,
    },
    /// A scan's points.
    #[error(transparent)]
    Cloud(#[from] crate::sources::cloud::CloudError),
}

impl crate::error::LayerError for RecordingError {}

/// A ROS transform as an isometry: `None` when a number is not finite or
/// the quaternion is zero (normalised otherwise).
pub fn iso_of(t: &Transform) -> Option<Isometry3<f64>> {
    let r = t.rotation;
    let q = NQuaternion::new(r.w, r.x, r.y, r.z);
    let n = q.norm();
    let finite = [r.x, r.y, r.z, r.w, t.translation.x, t.translation.y, t.translation.z].iter().all(|v| v.is_finite());
    (finite && n > 1e-9).then(|| {
        Isometry3::from_parts(
            Translation3::new(t.translation.x, t.translation.y, t.translation.z),
            UnitQuaternion::from_quaternion(q),
        )
    })
}

/// A rigid 4x4 matrix as a ROS 2 transform (translation, unit quaternion).
pub fn transform_of(m: &Matrix4<f64>) -> Transform {
    let iso = crate::sources::kitti::isometry(m);
    let q = iso.rotation.quaternion();
    let v = iso.translation.vector;
    Transform {
        translation: Vector3 { x: v.x, y: v.y, z: v.z },
        rotation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
    }
}

/// A (parent, child) frame pair.
pub type Edge = (String, String);
/// Stamped transforms of one edge (ns, `T_parent_child`).
type Samples = Vec<(i64, Isometry3<f64>)>;

/// The transforms of a recording or of a live `/tf`: per (parent, child)
/// edge, its stamped samples in time order, or one static transform.
#[derive(Default)]
pub struct TfTree {
    dynamic: BTreeMap<Edge, Samples>,
    fixed: BTreeMap<Edge, Isometry3<f64>>,
}

impl TfTree {
    /// Adds a transform: a static one replaces the edge's, a dynamic one
    /// joins its samples in stamp order.
    pub fn add(&mut self, fixed: bool, edge: Edge, t: i64, iso: Isometry3<f64>) {
        if fixed {
            self.fixed.insert(edge, iso);
        } else {
            let samples = self.dynamic.entry(edge).or_default();
            let i = samples.partition_point(|s| s.0 <= t);
            samples.insert(i, (t, iso));
        }
    }

    /// Forgets the dynamic samples older than `t` (ns), but the last one
    /// before it (what a lookup at `t` interpolates from): a live buffer's
    /// bound.
    pub fn trim(&mut self, t: i64) {
        for samples in self.dynamic.values_mut() {
            let keep_from = samples.partition_point(|s| s.0 < t).saturating_sub(1);
            samples.drain(..keep_from);
        }
    }

    /// The newest stamp (ns) of the dynamic edge into `child`, if any.
    pub fn newest(&self, child: &str) -> Option<i64> {
        self.dynamic.iter().filter(|((_, c), _)| c == child).filter_map(|(_, s)| s.last().map(|s| s.0)).max()
    }

    /// The parent edge of `child`, if any.
    fn parent_of(&self, child: &str) -> Option<(String, bool)> {
        if let Some((p, _)) = self.fixed.keys().find(|(_, c)| c == child) {
            return Some((p.clone(), true));
        }
        self.dynamic.keys().find(|(_, c)| c == child).map(|(p, _)| (p.clone(), false))
    }

    /// `T_parent_child` at `t` on a dynamic edge.
    fn at(&self, parent: &str, child: &str, t: i64) -> Result<Isometry3<f64>, String> {
        let samples = self.dynamic.get(&(parent.to_owned(), child.to_owned())).map(Vec::as_slice).unwrap_or(&[]);
        let i = samples.partition_point(|(s, _)| *s < t);
        if let Some((s, iso)) = samples.get(i) {
            if *s == t {
                return Ok(*iso);
            }
        }
        match (i.checked_sub(1).and_then(|k| samples.get(k)), samples.get(i)) {
            (Some((t0, a)), Some((t1, b))) => {
                let f = (t - t0) as f64 / (t1 - t0) as f64;
                let tr = a.translation.vector.lerp(&b.translation.vector, f);
                let rot = a.rotation.slerp(&b.rotation, f);
                Ok(Isometry3::from_parts(Translation3::from(tr), rot))
            }
            _ => Err(format!(
                "no /tf transform {parent} -> {child} around the stamp {}.{:09} s ({} transforms from {} to {})",
                t.div_euclid(1_000_000_000),
                t.rem_euclid(1_000_000_000),
                samples.len(),
                samples.first().map_or("-".into(), |s| format!("{:.3} s", s.0 as f64 * 1e-9)),
                samples.last().map_or("-".into(), |s| format!("{:.3} s", s.0 as f64 * 1e-9)),
            )),
        }
    }

    /// `T_root_frame` at `t`: the chain of edges from `frame` up to `root`.
    pub fn pose(&self, root: &str, frame: &str, t: i64) -> Result<Isometry3<f64>, String> {
        let mut pose = Isometry3::identity();
        let mut at = frame.to_owned();
        let mut steps = 0;
        while at != root {
            let Some((parent, fixed)) = self.parent_of(&at) else {
                return Err(format!("no chain of /tf transforms from `{root}` to `{frame}` (it ends at `{at}`)"));
            };
            let edge = if fixed { self.fixed[&(parent.clone(), at.clone())] } else { self.at(&parent, &at, t)? };
            pose = edge * pose;
            at = parent;
            steps += 1;
            if steps > 64 {
                return Err(format!("the /tf frames above `{frame}` form a loop"));
            }
        }
        Ok(pose)
    }
}

/// What [`read_scans`] reads.
#[derive(Clone, Debug)]
pub struct RecordingScans<'a> {
    /// The point cloud topic.
    pub points: &'a str,
    /// The label field's name.
    pub label_field: &'a str,
    /// The frame poses are expressed in (the root of the chain).
    pub pose_frame: &'a str,
    /// Which of the topic's messages (0-based, END exclusive; `None`: all).
    pub frames: Option<crate::sources::kitti::FrameRange>,
    /// An odometry topic (`nav_msgs/msg/Odometry`) whose poses join the
    /// transforms as `header.frame_id -> child_frame_id` (chained through
    /// `/tf_static` to the clouds' frame).
    pub odom: Option<&'a str>,
    /// A recording cut short (no footer) is an error; otherwise it is read
    /// up to its last whole record, with a warning naming the byte offset
    /// and what was read.
    pub strict: bool,
}

/// Reads scans from a recording and puts them into the first one's frame
/// (as a SemanticKITTI folder's); returns the frames and the points
/// skipped for a NaN coordinate.
///
/// The recording is read as a stream (see [`crate::sources::mcap_read`]): with
/// `frames` given, reading stops once those scans are in and every one's
/// pose can be resolved, so the first scans of an hour-long recording cost
/// what a recording of just those scans does.
pub fn read_scans(path: &Path, what: &RecordingScans<'_>) -> Result<(Vec<Frame>, usize), RecordingError> {
    read_scans_in_world(path, what).map(|(frames, skipped, _)| (frames, skipped))
}

/// A recording cut short at byte offset `at` after `seen` point cloud
/// messages: an error with `strict`, else a warning saying what was read.
fn cut_short(
    path: &Path,
    what: &RecordingScans<'_>,
    at: u64,
    missing: &str,
    seen: usize,
) -> Result<(), RecordingError> {
    let cut = format!("cut short at byte offset {at} ({missing})");
    if what.strict {
        let what = format!("{cut}; without {} the scans before the cut are read", Knob::Strict);
        return Err(RecordingError::Mcap { path: path.to_owned(), what });
    }
    let asked = what.frames.map_or(String::new(), |r| format!(" (frames {r} asked)"));
    crate::diagnostics::warn(&format!(
        "{}: {cut}: read the {seen} messages on {} before the cut{asked}",
        path.display(),
        what.points
    ));
    Ok(())
}

/// Scans in the first one's frame, the points skipped for a NaN
/// coordinate, and each scan's `T_world_sensor`.
pub type ScansInWorld = (Vec<Frame>, usize, Vec<Matrix4<f64>>);

/// [`read_scans`], and each scan's sensor pose in the pose frame
/// (`T_world_sensor`, before the scans are put into the first one's frame).
pub fn read_scans_in_world(path: &Path, what: &RecordingScans<'_>) -> Result<ScansInWorld, RecordingError> {
    let msg_err = |what: String| RecordingError::Message { path: path.to_owned(), what };
    let mut tree = TfTree::default();
    let mut clouds: Vec<(usize, Vec<u8>)> = Vec::new();
    // The stamp and frame of each cloud kept, to know when the poses are in.
    let mut stamps: Vec<(i64, String)> = Vec::new();
    let mut seen = 0usize;
    let wanted =
        |i: usize| what.frames.is_none_or(|r| i >= r.start && i < r.end && (i - r.start).is_multiple_of(r.stride));
    let all_in = |seen: usize| what.frames.is_some_and(|r| seen >= r.end);
    let ending = crate::sources::mcap_read::read_messages(path, |m| {
        let topic = m.channel.topic.as_str();
        let at = |e: String| format!("{topic} message at byte offset {} (log time {}): {e}", m.offset, m.log_time);
        let is_cdr = m.channel.message_encoding == "cdr";
        let mut new_pose = false;
        if topic == what.points {
            if wanted(seen) {
                if !is_cdr {
                    return Err(format!("{topic}: encoding `{}`, not cdr", m.channel.message_encoding));
                }
                let header =
                    crate::sources::cdr_read::Cdr::new(m.data).and_then(|mut c| c.point_cloud()).map_err(at)?.header;
                stamps.push((header.stamp.nanos(), header.frame_id));
                clouds.push((seen, m.data.to_vec()));
            }
            seen += 1;
        } else if Some(topic) == what.odom && is_cdr {
            let o = crate::sources::cdr_read::Cdr::new(m.data).and_then(|mut c| c.odometry_pose()).map_err(at)?;
            let iso = iso_of(&o.transform).ok_or_else(|| at("the pose is not a rigid transform".into()))?;
            tree.add(false, (o.header.frame_id, o.child_frame_id), o.header.stamp.nanos(), iso);
            new_pose = true;
        } else if (topic == "/tf" || topic == "/tf_static") && is_cdr {
            let transforms = crate::sources::cdr_read::Cdr::new(m.data).and_then(|mut c| c.tf_message()).map_err(at)?;
            for t in transforms {
                let iso = iso_of(&t.transform).ok_or_else(|| {
                    at(format!("transform {} -> {} is not a rigid transform", t.header.frame_id, t.child_frame_id))
                })?;
                let edge = (t.header.frame_id, t.child_frame_id);
                tree.add(topic == "/tf_static", edge, t.header.stamp.nanos(), iso);
            }
            new_pose = true;
        }
        // With the scans asked for all in, stop once each has its pose.
        if all_in(seen)
            && (new_pose || topic == what.points)
            && stamps.iter().all(|(t, frame)| tree.pose(what.pose_frame, frame, *t).is_ok())
        {
            return Ok(std::ops::ControlFlow::Break(()));
        }
        Ok(std::ops::ControlFlow::Continue(()))
    })
    .map_err(|e| RecordingError::Mcap { path: path.to_owned(), what: e.what })?;
    if let crate::sources::mcap_read::Ending::Cut { at, what: missing } = ending {
        cut_short(path, what, at, &missing, seen)?;
    }
    let asked = what.frames.map_or(1, |r| r.len());
    if clouds.len() < asked {
        let frames = what.frames.map_or("all".into(), |r| r.to_string());
        return Err(msg_err(format!("{}: {seen} messages, frames {frames} ask for {asked}", what.points)));
    }
    clouds_in_world(path, what, &tree, clouds)
}

/// The kept clouds (`(index, message)`) read, each with its pose in
/// `what.pose_frame` from `tree` at its stamp, re-anchored at the first.
fn clouds_in_world(
    path: &Path,
    what: &RecordingScans<'_>,
    tree: &TfTree,
    clouds: Vec<(usize, Vec<u8>)>,
) -> Result<ScansInWorld, RecordingError> {
    let msg_err = |what: String| RecordingError::Message { path: path.to_owned(), what };
    let mut frames = Vec::with_capacity(clouds.len());
    let mut world = Vec::with_capacity(clouds.len());
    let mut skipped = 0;
    let mut anchor_inv: Option<Matrix4<f64>> = None;
    for (index, data) in clouds {
        let at = |what_: String| msg_err(format!("{} message {index}: {what_}", what.points));
        let pc = crate::sources::cdr_read::Cdr::new(&data).and_then(|mut c| c.point_cloud()).map_err(at)?;
        let cloud = cloud_points(&pc, what.label_field, path).map_err(|e| match e {
            CloudRead::Message(m) => at(m),
            CloudRead::Cloud(c) => RecordingError::Cloud(c),
        })?;
        skipped += cloud.skipped;
        let t = pc.header.stamp.nanos();
        let pose = tree.pose(what.pose_frame, &pc.header.frame_id, t).map_err(at)?.to_homogeneous();
        let anchor = *anchor_inv.get_or_insert_with(|| crate::sources::kitti::rigid_inverse(&pose));
        let time = Some(t as f64 * 1e-9);
        frames.push(frame_of(index, time, &(anchor * pose), cloud));
        world.push(pose);
    }
    Ok((frames, skipped, world))
}

/// Why a PointCloud2's points could not be read.
enum CloudRead {
    /// The message's own fields disagree (named).
    Message(String),
    /// A point.
    Cloud(crate::sources::cloud::CloudError),
}

/// The points of a PointCloud2: its sizes checked against its data
/// before any row is read.
fn cloud_points(
    pc: &crate::sources::cdr_read::CloudMsg<'_>,
    label_field: &str,
    path: &Path,
) -> Result<Cloud, CloudRead> {
    let bad = CloudRead::Message;
    if pc.is_bigendian {
        return Err(bad("big-endian point data is not read".into()));
    }
    let mut fields = Vec::with_capacity(pc.fields.len());
    for (name, offset, datatype, count) in &pc.fields {
        let s = Scalar::of_ros(*datatype).ok_or_else(|| bad(format!("field `{name}`: datatype {datatype}")))?;
        fields.push((name.clone(), s, (*count).max(1) as usize, *offset as usize));
    }
    let layout = Layout::with_offsets(fields, pc.point_step as usize)
        .ok_or_else(|| bad(format!("a field lies beyond the point_step of {} bytes", pc.point_step)))?;
    let idx = layout.pick(label_field, path).map_err(CloudRead::Cloud)?;
    let mut cloud = Cloud::default();
    let (width, height, step, row) =
        (u64::from(pc.width), u64::from(pc.height), u64::from(pc.point_step), u64::from(pc.row_step));
    if width == 0 || height == 0 {
        return Ok(cloud);
    }
    if row < width * step {
        return Err(bad(format!(
            "row_step {row} is less than width {width} times point_step {step} ({}): rows would overlap",
            width * step
        )));
    }
    let need = (height - 1) * row + width * step;
    if need > pc.data.len() as u64 {
        return Err(bad(format!(
            "data holds {} bytes; height {height} rows of row_step {row} (width {width}, point_step {step}) need {need}",
            pc.data.len()
        )));
    }
    // Rows may be padded: each row read on its own.
    for r in 0..height as usize {
        let start = r * row as usize;
        let body = pc.data.get(start..).unwrap_or(&[]);
        read_records(body, width as usize, &layout, idx, path, ("point", start), &mut cloud)
            .map_err(CloudRead::Cloud)?;
    }
    Ok(cloud)
}

/// The points of a PointCloud2 heard live on `topic` (not read from a
/// file): its fields, sizes and row steps checked against its data before
/// any point is read, as a recording's are; an error names the topic and
/// what lies.
pub fn live_cloud(pc: &PointCloud2, label_field: &str, topic: &str) -> Result<Cloud, crate::error::Error> {
    let msg = crate::sources::cdr_read::CloudMsg {
        header: pc.header.clone(),
        height: pc.height,
        width: pc.width,
        fields: pc.fields.iter().map(|f| (f.name.clone(), f.offset, f.datatype, f.count)).collect(),
        is_bigendian: pc.is_bigendian,
        point_step: pc.point_step,
        row_step: pc.row_step,
        data: &pc.data,
    };
    cloud_points(&msg, label_field, Path::new(topic)).map_err(|e| match e {
        CloudRead::Message(what) => crate::error::Error::Invalid(format!("{topic}: {what}")),
        CloudRead::Cloud(e) => e.into(),
    })
}

/// How a recording's chunks are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChunkCompression {
    /// Uncompressed chunks.
    None,
    /// zstd (rosbag2's default).
    Zstd,
    /// LZ4 frames.
    Lz4,
}

impl ChunkCompression {
    /// The names it is read from (the command line's, Python's).
    pub const NAMES: &'static [&'static str] = &["none", "zstd", "lz4"];
}

impl std::str::FromStr for ChunkCompression {
    type Err = String;
    /// A chunk compression: none, zstd or lz4.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(ChunkCompression::None),
            "zstd" => Ok(ChunkCompression::Zstd),
            "lz4" => Ok(ChunkCompression::Lz4),
            _ => Err(format!("`{s}`: expected none, zstd or lz4")),
        }
    }
}

/// One scan to write: points and label words in the sensor's frame, the
/// sensor's pose in the world (4x4, rigid) and its stamp (s).
pub struct ScanRecord<'a> {
    /// x, y, z (m).
    pub points: &'a [[f32; 3]],
    /// Label words.
    pub labels: &'a [u32],
    /// `T_world_sensor`.
    pub pose: Matrix4<f64>,
    /// Stamp (s).
    pub seconds: f64,
}

/// Writes a SemanticKITTI folder's scans as a ROS 2 recording (see
/// [`write_scans`]; stamps from `times.txt`, else 0.1 s a frame). Returns
/// the scans written.
pub fn export(
    seq: &crate::sources::kitti::Sequence,
    frames: crate::sources::kitti::FrameRange,
    topic: &str,
    compression: ChunkCompression,
    out: &Path,
) -> Result<usize, crate::error::Error> {
    seq.check_range(frames)?;
    let mut scans = Vec::new();
    for i in frames.frames() {
        let scan = seq.read_scan(i)?;
        let seconds = seq.times.as_ref().and_then(|t| t.get(i).copied()).unwrap_or(0.1 * i as f64);
        let points: Vec<[f32; 3]> = scan.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
        scans.push((points, scan.labels, seq.velodyne_matrix(i)?, seconds));
    }
    let records = scans.iter().map(|(points, labels, pose, seconds)| ScanRecord {
        points,
        labels,
        pose: *pose,
        seconds: *seconds,
    });
    write_scans(out, topic, compression, true, records)
}

/// Writes scans as a ROS 2 recording: on `topic` each scan as a
/// PointCloud2 in frame `velodyne` (x, y, z float32, label uint32), on
/// `/tf` its pose `world -> velodyne` at the same stamp; chunks compressed
/// as asked, with their CRCs when `chunk_crcs`. Returns the scans written;
/// the file appears only when whole.
pub fn write_scans<'a>(
    out: &Path,
    topic: &str,
    compression: ChunkCompression,
    chunk_crcs: bool,
    scans: impl Iterator<Item = ScanRecord<'a>>,
) -> Result<usize, crate::error::Error> {
    let compression = match compression {
        ChunkCompression::None => None,
        ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
        ChunkCompression::Lz4 => Some(mcap::Compression::Lz4),
    };
    let mut w = RecordingWriter::create_with(
        out,
        mcap::WriteOptions::new().compression(compression).calculate_chunk_crcs(chunk_crcs),
    )?;
    let pc_schema = w.schema("sensor_msgs/msg/PointCloud2", POINTCLOUD2_SCHEMA)?;
    let tf_schema = w.schema("tf2_msgs/msg/TFMessage", TFMESSAGE_SCHEMA)?;
    let pc_channel = w.channel(pc_schema, topic)?;
    let tf_channel = w.channel(tf_schema, "/tf")?;
    let mut n = 0;
    for (k, scan) in scans.enumerate() {
        let stamp = Time::of_seconds(scan.seconds);
        let log_time = stamp.nanos().max(0) as u64;
        let header = |frame: &str| Header { stamp, frame_id: frame.to_owned() };
        let tf = TfMessage {
            transforms: vec![TransformStamped {
                header: header("world"),
                child_frame_id: "velodyne".into(),
                transform: transform_of(&scan.pose),
            }],
        };
        let pc = labelled_cloud(header("velodyne"), scan.points.iter().copied(), scan.labels);
        w.write(tf_channel, k as u32, log_time, &tf)?;
        w.write(pc_channel, k as u32, log_time, &pc)?;
        n += 1;
    }
    w.finish()?;
    Ok(n)
}

/// A labelled scan as cosem writes and publishes it: an unorganised
/// PointCloud2 of x, y, z (float32) and label (uint32), 16 bytes a point,
/// as many points as both `points` and `labels` hold.
pub fn labelled_cloud(header: Header, points: impl Iterator<Item = [f32; 3]>, labels: &[u32]) -> PointCloud2 {
    let data = crate::sources::cloud::records(points, labels);
    let count = (data.len() / 16) as u32;
    let field = |name: &str, offset, datatype| PointField { name: name.into(), offset, datatype, count: 1 };
    PointCloud2 {
        header,
        height: 1,
        width: count,
        fields: vec![field("x", 0, 7), field("y", 4, 7), field("z", 8, 7), field("label", 12, 6)],
        is_bigendian: false,
        point_step: 16,
        row_step: 16 * count,
        data,
        is_dense: true,
    }
}

/// A ROS 2 recording being written (zstd chunks, `ros2msg` schemas, CDR
/// messages), its errors naming the file; the file appears only when
/// [`RecordingWriter::finish`] succeeds.
pub struct RecordingWriter<'p> {
    w: mcap::Writer<crate::paths::Output>,
    path: &'p Path,
}

impl<'p> RecordingWriter<'p> {
    /// A new recording at `path` (zstd chunks).
    pub fn create(path: &'p Path) -> Result<Self, crate::error::Error> {
        Self::create_with(path, mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)))
    }

    /// A new recording at `path` written with `options`.
    pub fn create_with(path: &'p Path, options: mcap::WriteOptions) -> Result<Self, crate::error::Error> {
        let file = crate::paths::Output::create(path)
            .map_err(|source| crate::error::Error::Io { path: path.to_owned(), source })?;
        let w = options.profile("ros2").create(file);
        w.map(|w| RecordingWriter { w, path })
            .map_err(|e| crate::error::Error::Invalid(format!("{}: {e}", path.display())))
    }

    fn err(&self, e: impl std::fmt::Display) -> crate::error::Error {
        crate::error::Error::Invalid(format!("{}: {e}", self.path.display()))
    }

    /// Adds a `ros2msg` schema; its id.
    pub fn schema(&mut self, name: &str, definition: &str) -> Result<u16, crate::error::Error> {
        self.w.add_schema(name, "ros2msg", definition.as_bytes()).map_err(|e| self.err(e))
    }

    /// Adds a CDR channel on `topic`; its id.
    pub fn channel(&mut self, schema: u16, topic: &str) -> Result<u16, crate::error::Error> {
        self.w.add_channel(schema, topic, "cdr", &BTreeMap::new()).map_err(|e| self.err(e))
    }

    /// One message, CDR little endian with its encapsulation header.
    pub fn write<T: Serialize>(
        &mut self,
        channel_id: u16,
        sequence: u32,
        time: u64,
        msg: &T,
    ) -> Result<(), crate::error::Error> {
        let data = cdr::serialize::<_, _, cdr::CdrLe>(msg, cdr::Infinite).map_err(|e| self.err(format!("CDR: {e}")))?;
        let header = mcap::records::MessageHeader { channel_id, sequence, log_time: time, publish_time: time };
        self.w.write_to_known_channel(&header, &data).map_err(|e| self.err(e))
    }

    /// Finishes the file and renames it into place (an error before this
    /// leaves no file).
    pub fn finish(mut self) -> Result<(), crate::error::Error> {
        self.w.finish().map_err(|e| self.err(e))?;
        let out = self.w.into_inner();
        out.commit().map_err(|source| crate::error::Error::Io { path: self.path.to_owned(), source })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_interpolate_and_chain() {
        let mut tree = TfTree::default();
        let a = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity());
        let b =
            Isometry3::from_parts(Translation3::new(2.0, 0.0, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5));
        tree.dynamic.insert(("world".into(), "base".into()), vec![(0, a), (1_000, b)]);
        let mount = Isometry3::from_parts(Translation3::new(0.0, 0.0, 1.5), UnitQuaternion::identity());
        tree.fixed.insert(("base".into(), "lidar".into()), mount);
        let mid = tree.pose("world", "lidar", 500).unwrap();
        assert!((mid.translation.vector - nalgebra::Vector3::new(1.0, 0.0, 1.5)).norm() < 1e-12);
        assert!((mid.rotation.angle() - 0.25).abs() < 1e-12);
        assert_eq!(tree.pose("world", "lidar", 1_000).unwrap(), b * mount);
        assert!(tree.pose("world", "lidar", 2_000).unwrap_err().contains("around the stamp"));
        assert!(tree.pose("map", "lidar", 0).unwrap_err().contains("no chain"));
    }

    /// A recording of one PointCloud2 (as given) and its pose.
    fn one_cloud(path: &Path, pc: &PointCloud2) {
        let mut w = RecordingWriter::create(path).unwrap();
        let pcs = w.schema("sensor_msgs/msg/PointCloud2", POINTCLOUD2_SCHEMA).unwrap();
        let tfs = w.schema("tf2_msgs/msg/TFMessage", TFMESSAGE_SCHEMA).unwrap();
        let (pc_ch, tf_ch) = (w.channel(pcs, "/points").unwrap(), w.channel(tfs, "/tf").unwrap());
        let tf = TfMessage {
            transforms: vec![TransformStamped {
                header: Header { stamp: pc.header.stamp, frame_id: "world".into() },
                child_frame_id: pc.header.frame_id.clone(),
                transform: transform_of(&Matrix4::identity()),
            }],
        };
        w.write(tf_ch, 0, 0, &tf).unwrap();
        w.write(pc_ch, 0, 0, pc).unwrap();
        w.finish().unwrap();
    }

    fn read_one(path: &Path) -> Result<(Vec<Frame>, usize), RecordingError> {
        let what = RecordingScans {
            points: "/points",
            label_field: "label",
            pose_frame: "world",
            frames: None,
            odom: None,
            strict: false,
        };
        read_scans(path, &what)
    }

    fn two_points() -> PointCloud2 {
        let field = |name: &str, offset, datatype| PointField { name: name.into(), offset, datatype, count: 1 };
        PointCloud2 {
            header: Header { stamp: Time { sec: 1, nanosec: 0 }, frame_id: "lidar".into() },
            height: 1,
            width: 2,
            fields: vec![field("x", 0, 7), field("y", 4, 7), field("z", 8, 7), field("label", 12, 6)],
            is_bigendian: false,
            point_step: 16,
            row_step: 32,
            data: crate::sources::cloud::records([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]].into_iter(), &[40, 50]),
            is_dense: true,
        }
    }

    #[test]
    fn a_cloud_whose_sizes_disagree_with_its_data_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.mcap");
        one_cloud(&p, &two_points());
        let (frames, _) = read_one(&p).unwrap();
        assert_eq!(frames[0].labels, vec![40, 50]);
        // Rows that would overlap (row 1 read from row 0's bytes).
        let pc = PointCloud2 { height: 2, width: 1, row_step: 8, ..two_points() };
        one_cloud(&p, &pc);
        let e = read_one(&p).unwrap_err().to_string();
        assert!(e.contains("row_step 8") && e.contains("point_step 16"), "{e}");
        // More rows than the data holds.
        let pc = PointCloud2 { height: 3, width: 1, row_step: 16, ..two_points() };
        one_cloud(&p, &pc);
        let e = read_one(&p).unwrap_err().to_string();
        assert!(e.contains("data holds 32 bytes") && e.contains("need 48"), "{e}");
        // 4,294,967,295 empty rows: no points, read at once (no loop).
        let pc = PointCloud2 { height: u32::MAX, width: 0, row_step: 0, data: Vec::new(), ..two_points() };
        one_cloud(&p, &pc);
        let (frames, _) = read_one(&p).unwrap();
        assert!(frames[0].points.is_empty());
    }

    /// A live cloud is checked as a recorded one is: what lies is named
    /// with the topic, nothing is read past the data.
    #[test]
    fn a_live_cloud_that_lies_is_refused_by_name() {
        let t = "/robot_0/points";
        let ok = live_cloud(&two_points(), "label", t).unwrap();
        assert_eq!((ok.points.len(), ok.labels.clone()), (2, vec![40, 50]));
        let refused = |pc: PointCloud2, field: &str| live_cloud(&pc, field, t).unwrap_err().to_string();
        let e = refused(PointCloud2 { height: 2, width: 1, row_step: 8, ..two_points() }, "label");
        assert!(e.contains(t) && e.contains("row_step 8"), "{e}");
        let e = refused(PointCloud2 { width: 3, row_step: 48, ..two_points() }, "label");
        assert!(e.contains(t) && e.contains("data holds 32 bytes"), "{e}");
        let mut beyond = two_points();
        beyond.fields[3].offset = 14;
        let e = refused(beyond, "label");
        assert!(e.contains(t) && e.contains("point_step"), "{e}");
        let e = refused(PointCloud2 { is_bigendian: true, ..two_points() }, "label");
        assert!(e.contains("big-endian"), "{e}");
        let e = refused(two_points(), "semantic");
        assert!(e.contains("semantic"), "{e}");
    }

    #[test]
    fn a_flipped_byte_in_a_chunk_is_a_checksum_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.mcap");
        let big = PointCloud2 {
            width: 4000,
            row_step: 16 * 4000,
            data: crate::sources::cloud::records((0..4000).map(|i| [i as f32, 0.5, 1.0]), &[40; 4000]),
            ..two_points()
        };
        one_cloud(&p, &big);
        let mut bytes = std::fs::read(&p).unwrap();
        // Inside the compressed records of the chunk holding the cloud.
        let at = bytes.len() / 3;
        bytes[at] ^= 0x10;
        std::fs::write(&p, &bytes).unwrap();
        let e = read_one(&p).unwrap_err().to_string();
        assert!(e.contains("byte offset") && (e.contains("CRC") || e.contains("decompress")), "{e}");
    }

    #[test]
    fn messages_round_trip_through_cdr() {
        let pc = PointCloud2 {
            header: Header { stamp: Time { sec: 3, nanosec: 5 }, frame_id: "velodyne".into() },
            height: 1,
            width: 1,
            fields: vec![PointField { name: "x".into(), offset: 0, datatype: 7, count: 1 }],
            is_bigendian: false,
            point_step: 4,
            row_step: 4,
            data: vec![0, 0, 128, 63],
            is_dense: true,
        };
        let bytes = cdr::serialize::<_, _, cdr::CdrLe>(&pc, cdr::Infinite).unwrap();
        // The encapsulation header of little-endian CDR, then sec = 3.
        assert_eq!(&bytes[..8], &[0, 1, 0, 0, 3, 0, 0, 0]);
        assert_eq!(cdr::deserialize::<PointCloud2>(&bytes).unwrap(), pc);
    }
}
