//! A session as a ROS 2 recording to view in Foxglove: each robot's map
//! every round (`/robot_<i>/map`, PointCloud2 coloured by class, in frame
//! `robot_<i>/odom`), its odometry (`/tf`: `robot_<i>/odom ->
//! robot_<i>/base_link`) and the estimates that are `Converged` (`/tf`:
//! `robot_<i>/odom -> robot_<j>/odom`, robot i's estimate of robot j for
//! i < j only, so the frames stay a tree), at one second a round.
//!
//! As the live node will publish them: each `Converged` estimate of robot
//! i of robot j with its covariance (`/robot_<i>/peers/robot_<j>/pose`,
//! `geometry_msgs/PoseWithCovarianceStamped` in `robot_<i>/odom`,
//! [`crate::sources::ros_pose`]), and every estimate's status on
//! `/diagnostics` (`diagnostic_msgs/DiagnosticArray`, one status per
//! robot and peer: OK when `Converged` or `NoOverlap`, a warning
//! otherwise), which Foxglove shows without a custom package.

use crate::evaluation::session::RoundView;
use crate::reports::match_recording::map_cloud;
use crate::sources::recording::{transform_of, RecordingWriter};
use crate::sources::ros_msgs::*;
use crate::sources::ros_pose::pose_with_covariance;
use cosem_core::matching::MatchStatus;
use std::path::Path;

/// A session being recorded.
pub struct SessionRecorder<'p> {
    w: RecordingWriter<'p>,
    tf: u16,
    maps: Vec<u16>,
    /// `/robot_<i>/peers/robot_<j>/pose`, by `i * robots + j`.
    poses: Vec<u16>,
    diagnostics: u16,
    robots: usize,
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
        let pose = w.schema("geometry_msgs/msg/PoseWithCovarianceStamped", &pose_with_covariance_stamped_schema())?;
        let poses = (0..robots * robots)
            .map(|k| w.channel(pose, &format!("/robot_{}/peers/robot_{}/pose", k / robots, k % robots)))
            .collect::<Result<_, _>>()?;
        let diag = w.schema("diagnostic_msgs/msg/DiagnosticArray", &diagnostic_array_schema())?;
        let diagnostics = w.channel(diag, "/diagnostics")?;
        Ok(SessionRecorder { w, tf, maps, poses, diagnostics, robots, sequence: 0 })
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
        self.w.write(self.tf, self.sequence, time, &TfMessage { transforms })?;
        self.estimates(view, stamp, time)
    }

    /// Each Converged estimate as a pose with its covariance, and every
    /// estimate's status.
    fn estimates(&mut self, view: &RoundView<'_>, stamp: Time, time: u64) -> Result<(), crate::error::Error> {
        let mut status = Vec::new();
        for r in view.records {
            let Some(e) = r.estimate.as_ref() else { continue };
            let s = e.status();
            let t: nalgebra::Isometry3<f64> = nalgebra::convert(e.result.transform);
            let info: nalgebra::Matrix6<f64> = nalgebra::convert(e.result.information);
            let channel = self.poses.get(r.robot * self.robots + r.peer).copied();
            if let (MatchStatus::Converged, Some(pose), Some(channel)) = (s, pose_with_covariance(&t, &info), channel) {
                let header = Header { stamp, frame_id: format!("robot_{}/odom", r.robot) };
                self.sequence += 1;
                self.w.write(channel, self.sequence, time, &PoseWithCovarianceStamped { header, pose })?;
            }
            let value = |key: &str, value: String| KeyValue { key: key.into(), value };
            let well = matches!(s, MatchStatus::Converged | MatchStatus::NoOverlap);
            status.push(DiagnosticStatus {
                level: if well { DiagnosticStatus::OK } else { DiagnosticStatus::WARN },
                name: format!("cosem: robot_{} / robot_{}", r.robot, r.peer),
                message: s.as_str().into(),
                hardware_id: format!("robot_{}", r.robot),
                values: vec![
                    value("kind", e.kind.as_str().into()),
                    value("fix", e.fix.as_str().into()),
                    value("confirmed", e.confirmed.to_string()),
                    value("agreement", format!("{:.3}", e.result.agreement)),
                    value("overlap", format!("{:.3}", e.result.overlap)),
                ],
            });
        }
        self.sequence += 1;
        let header = Header { stamp, frame_id: String::new() };
        self.w.write(self.diagnostics, self.sequence, time, &DiagnosticArray { header, status })
    }

    /// Finishes the file and renames it into place.
    pub fn finish(self) -> Result<(), crate::error::Error> {
        self.w.finish()
    }
}
