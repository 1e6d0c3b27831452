//! A session as a ROS 2 recording to view in Foxglove: each robot's map
//! every round (`/robot_<i>/map`, PointCloud2 coloured by class, in frame
//! `robot_<i>/odom`), its odometry (`/tf`: `robot_<i>/odom ->
//! robot_<i>/base_link`) and the estimates that are `Converged` (`/tf`:
//! `robot_<i>/odom -> robot_<j>/odom`, robot i's estimate of robot j for
//! i < j only, so the frames stay a tree), at one second a round.

use crate::evaluation::session::RoundView;
use crate::reports::match_recording::map_cloud;
use crate::sources::recording::{transform_of, RecordingWriter};
use crate::sources::ros_msgs::*;
use cosem_core::matching::MatchStatus;
use std::path::Path;

/// A session being recorded.
pub struct SessionRecorder<'p> {
    w: RecordingWriter<'p>,
    tf: u16,
    maps: Vec<u16>,
    sequence: u32,
}

impl<'p> SessionRecorder<'p> {
    /// A new recording of `robots` robots at `path` (it appears when
    /// [`SessionRecorder::finish`] succeeds).
    pub fn create(path: &'p Path, robots: usize) -> Result<Self, crate::error::Error> {
        let mut w = RecordingWriter::create(path)?;
        let pc = w.schema("sensor_msgs/msg/PointCloud2", POINTCLOUD2_SCHEMA)?;
        let tf_schema = w.schema("tf2_msgs/msg/TFMessage", TFMESSAGE_SCHEMA)?;
        let tf = w.channel(tf_schema, "/tf")?;
        let maps = (0..robots).map(|i| w.channel(pc, &format!("/robot_{i}/map"))).collect::<Result<_, _>>()?;
        Ok(SessionRecorder { w, tf, maps, sequence: 0 })
    }

    /// Records one round.
    pub fn round(&mut self, view: &RoundView<'_>) -> Result<(), crate::error::Error> {
        let stamp = Time { sec: i32::try_from(view.round).unwrap_or(i32::MAX), nanosec: 0 };
        let time = view.round as u64 * 1_000_000_000;
        let edge = |parent: String, child: String, t: &nalgebra::Isometry3<f64>| TransformStamped {
            header: Header { stamp, frame_id: parent },
            child_frame_id: child,
            transform: transform_of(&t.to_homogeneous()),
        };
        let mut transforms = Vec::new();
        for (i, pose) in view.poses.iter().enumerate() {
            if let Some(p) = pose {
                transforms.push(edge(format!("robot_{i}/odom"), format!("robot_{i}/base_link"), p));
            }
        }
        for r in view.records.iter().filter(|r| r.robot < r.peer) {
            if let Some(e) = r.estimate.as_ref().filter(|e| e.status() == MatchStatus::Converged) {
                let t: nalgebra::Isometry3<f64> = nalgebra::convert(e.result.transform);
                transforms.push(edge(format!("robot_{}/odom", r.robot), format!("robot_{}/odom", r.peer), &t));
            }
        }
        for (i, (map, &channel)) in view.maps.iter().zip(&self.maps).enumerate() {
            let mut cloud = map_cloud(map, &format!("robot_{i}/odom"));
            cloud.header.stamp = stamp;
            self.sequence += 1;
            self.w.write(channel, self.sequence, time, &cloud)?;
        }
        self.sequence += 1;
        self.w.write(self.tf, self.sequence, time, &TfMessage { transforms })
    }

    /// Finishes the file and renames it into place.
    pub fn finish(self) -> Result<(), crate::error::Error> {
        self.w.finish()
    }
}
