//! `cosem ros play`: scans from any source (a SemanticKITTI folder, a ROS 2
//! recording, PCD/PLY scans) published live over DDS as a robot's drivers
//! would publish them, for the nodes to read without a robot: each scan as
//! a labelled `PointCloud2` on `/<robot>/points`, its odometry on `/tf`
//! (`<robot>/odom -> <robot>/base_link`), and `/tf_static`
//! (`<robot>/base_link -> <robot>/velodyne`, the identity: a source's poses
//! are its sensor's), at the scans' recorded rate, like `ros2 bag play`.
//!
//! Each robot's odometry starts at its first scan, moved by a random
//! transform (seeded): the truth between two robots is never the
//! identity, and [`PlayedRobot::world_odom`] says what it is.

use super::dds::{edge, published, stamp_now, DdsNode, TopicKind};
use crate::error::Error;
use crate::evaluation::team::RobotSpec;
use crate::knobs::Knob;
use crate::sources::kitti::Frame;
use crate::sources::recording::labelled_cloud;
use crate::sources::ros_msgs::*;
use crate::sources::source::{Source, SourceOptions};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3 as V3};
use std::time::{Duration, Instant};

/// The longest wait for readers (`PlaySpec::wait_readers`).
pub const WAIT_LIMIT: Duration = Duration::from_secs(20);

/// What to play.
#[derive(Clone, Debug)]
pub struct PlaySpec {
    /// The robots (named `robot_<i>` in this order).
    pub robots: Vec<RobotSpec>,
    /// The DDS domain.
    pub domain: u16,
    /// Scans a second, for sources without timestamps.
    pub rate: f64,
    /// Times the recorded rate.
    pub speed: f64,
    /// Points farther than this (m) from their sensor are left out.
    pub crop: Option<f32>,
    /// Seed of the odometry origins' offsets.
    pub seed: u64,
    /// Seconds between the publishers' creation (or, with `wait_readers`,
    /// their readers' match) and the first scan: time for the subscribers
    /// to be discovered (a sample sent before is lost to them).
    pub delay: f64,
    /// Before the first scan, wait (at most [`WAIT_LIMIT`]) until each topic
    /// has matched this many readers.
    pub wait_readers: usize,
}

/// A robot as played.
#[derive(Clone, Debug)]
pub struct PlayedRobot {
    /// `robot_<i>`.
    pub name: String,
    /// Its scans' topic.
    pub topic: String,
    /// Its scans.
    pub frames: usize,
    /// `T_world_odom`: where its odometry frame is in the source's world
    /// (the truth between two robots is `inv(T_world_odom_i) *
    /// T_world_odom_j`).
    pub world_odom: Isometry3<f64>,
    /// Scans published.
    pub published: usize,
    /// Bytes of the scans published (CDR).
    pub bytes: usize,
}

/// One robot's scans, ready to publish.
struct Track {
    played: PlayedRobot,
    /// Per scan: seconds from the robot's first, `T_odom_base`, the
    /// cloud in the sensor frame.
    scans: Vec<(f64, Isometry3<f64>, PointCloud2)>,
}

/// The random offset of robot `i`'s odometry origin: a heading anywhere
/// and up to 50 m aside.
fn odom_offset(seed: u64, i: usize) -> Isometry3<f64> {
    let mut rng = crate::rng::Rng::new(seed ^ (0x9E37_79B9_7F4A_7C15u64.wrapping_mul(i as u64 + 1)));
    let yaw = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
    let t = V3::new(rng.range(-50.0, 50.0), rng.range(-50.0, 50.0), rng.range(-1.0, 1.0));
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
}

/// The cloud of `frame` in its sensor's frame, cropped.
fn sensor_cloud(frame: &Frame, crop: Option<f32>, sensor: &str) -> PointCloud2 {
    let inv = frame.pose.inverse();
    let keep = |k: &usize| crop.is_none_or(|c| frame.ranges.get(*k).is_some_and(|r| *r <= c));
    let idx: Vec<usize> = (0..frame.points.len().min(frame.labels.len())).filter(keep).collect();
    let points = idx.iter().map(|&k| {
        let p = frame.points[k];
        let q = inv * nalgebra::Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        [q.x as f32, q.y as f32, q.z as f32]
    });
    let labels: Vec<u32> = idx.iter().map(|&k| frame.labels[k]).collect();
    labelled_cloud(Header { stamp: Time::default(), frame_id: sensor.into() }, points, &labels)
}

fn track(i: usize, r: &RobotSpec, spec: &PlaySpec) -> Result<Track, Error> {
    let source = Source::open(&r.data, &SourceOptions::default())?;
    let (frames, world_anchor, _) = source.load(Some(r.frames))?;
    if frames.is_empty() {
        return Err(Error::Invalid(format!("{}: frames {}: no scan", r.data.display(), r.frames)));
    }
    let name = format!("robot_{i}");
    let offset = odom_offset(spec.seed, i);
    let world_anchor = crate::sources::kitti::isometry(&world_anchor);
    let t0 = frames[0].time;
    let sensor = format!("{name}/velodyne");
    let mut scans = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        let t = match (f.time, t0) {
            (Some(t), Some(t0)) => t - t0,
            _ => k as f64 / spec.rate,
        };
        let at = t / spec.speed;
        if !(at.is_finite() && (0.0..=1e7).contains(&at)) {
            let what = format!("{}: frame {}: at {at} s from the first scan", r.data.display(), f.index);
            return Err(Error::Invalid(format!("{what} (timestamps out of order, or {} too slow)", Knob::Speed)));
        }
        scans.push((at, offset * f.pose, sensor_cloud(f, spec.crop, &sensor)));
    }
    let played = PlayedRobot {
        topic: format!("/{name}/points"),
        frames: frames.len(),
        world_odom: world_anchor * offset.inverse(),
        published: 0,
        bytes: 0,
        name,
    };
    Ok(Track { played, scans })
}

/// Plays `spec`: `ready` hears the robots once the publishers exist (before
/// the delay), then every scan goes out at its time. The robots as played.
pub fn play(spec: &PlaySpec, ready: impl FnOnce(&[PlayedRobot])) -> Result<Vec<PlayedRobot>, Error> {
    if !(spec.rate.is_finite() && spec.rate > 0.0 && spec.speed.is_finite() && spec.speed > 0.0) {
        return Err(Error::Invalid(format!("{} and {}: positive numbers", Knob::Rate, Knob::Speed)));
    }
    if !(spec.delay.is_finite() && (0.0..=3600.0).contains(&spec.delay)) {
        return Err(Error::Invalid("the delay: 0 to 3600 seconds".into()));
    }
    let mut tracks: Vec<Track> =
        spec.robots.iter().enumerate().map(|(i, r)| track(i, r, spec)).collect::<Result<_, _>>()?;
    let mut node = DdsNode::new(spec.domain, "cosem_play")?;
    let tf = node.publisher::<TfMessage>("/tf", ("tf2_msgs", "TFMessage"), TopicKind::Tf)?;
    let tf_static = node.publisher::<TfMessage>("/tf_static", ("tf2_msgs", "TFMessage"), TopicKind::Latched)?;
    let clouds = tracks
        .iter()
        .map(|t| node.publisher::<PointCloud2>(&t.played.topic, ("sensor_msgs", "PointCloud2"), TopicKind::Sensor))
        .collect::<Result<Vec<_>, _>>()?;
    let robots: Vec<PlayedRobot> = tracks.iter().map(|t| t.played.clone()).collect();
    ready(&robots);
    let stamp = stamp_now();
    let statics = tracks
        .iter()
        .map(|t| {
            let n = &t.played.name;
            edge(stamp, format!("{n}/base_link"), format!("{n}/velodyne"), &Isometry3::identity())
        })
        .collect();
    tf_static.publish(TfMessage { transforms: statics }).map_err(|e| published("/tf_static", e))?;
    let waited = Instant::now();
    let matched = |n: &DdsNode| {
        let least = clouds.iter().map(|c| n.readers(c)).chain([n.readers(&tf), n.readers(&tf_static)]).min();
        least.unwrap_or(0)
    };
    while matched(&node) < spec.wait_readers {
        if waited.elapsed() > WAIT_LIMIT {
            return Err(Error::Invalid(format!(
                "{} {}: a topic had {} readers after {} s",
                Knob::WaitReaders,
                spec.wait_readers,
                matched(&node),
                WAIT_LIMIT.as_secs()
            )));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_secs_f64(spec.delay));
    // Every robot's scans in time order, robots side by side.
    let mut order: Vec<(f64, usize, usize)> = tracks
        .iter()
        .enumerate()
        .flat_map(|(i, t)| t.scans.iter().enumerate().map(move |(k, s)| (s.0, i, k)))
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let start = Instant::now();
    for (t, i, k) in order {
        if let Some(wait) = Duration::from_secs_f64(t.max(0.0)).checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        let track = &mut tracks[i];
        let (_, pose, cloud) = &mut track.scans[k];
        let stamp = stamp_now();
        let n = &track.played.name;
        let odom = edge(stamp, format!("{n}/odom"), format!("{n}/base_link"), pose);
        tf.publish(TfMessage { transforms: vec![odom] }).map_err(|e| published("/tf", e))?;
        // Each scan is published once: taken out, not copied (megabytes).
        let mut cloud = std::mem::replace(cloud, labelled_cloud(Header::default(), std::iter::empty(), &[]));
        cloud.header.stamp = stamp;
        let bytes = cdr_size(&cloud) as usize;
        clouds[i].publish(cloud).map_err(|e| published(&track.played.topic, e))?;
        track.played.published += 1;
        track.played.bytes += bytes;
    }
    // Reliable samples still in flight get a moment to be delivered.
    std::thread::sleep(Duration::from_millis(500));
    Ok(tracks.into_iter().map(|t| t.played).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odometry_origins_are_offset_and_seeded() {
        let (a, b) = (odom_offset(1, 0), odom_offset(1, 1));
        assert_ne!(a, b);
        assert_eq!(a, odom_offset(1, 0));
        assert!(a.translation.vector.norm() > 0.0);
    }
}
