//! Every ROS 2 message type cosem reads or writes is what a ROS 2 Jazzy
//! node sends and expects: its CDR bytes equal, to the byte, those the
//! `mcap_ros2` Python package makes from ROS 2's own definitions
//! (`tests/python/ros_golden.py`, kept in `tests/golden/ros_messages.json`),
//! its `ros2msg` definition is the same text, and a message read back
//! is the message written.

use cosem_host::sources::ros_msgs::*;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::Value;

fn header(sec: i32, nanosec: u32, frame: &str) -> Header {
    Header { stamp: Time { sec, nanosec }, frame_id: frame.into() }
}

fn vec3(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x, y, z }
}

const QUAT: Quaternion = Quaternion { x: 0.125, y: -0.25, z: 0.5, w: 0.8 };

fn cov() -> [[f64; 6]; 6] {
    let mut c = [[0.0; 6]; 6];
    for (i, v) in c.iter_mut().flatten().enumerate() {
        *v = i as f64 * 0.5 - 3.0;
    }
    c
}

/// `m` in CDR, checked to read back as itself.
fn both<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(m: T) -> Vec<u8> {
    let bytes = to_cdr(&m).unwrap();
    assert_eq!(from_cdr::<T>(&bytes).unwrap(), m, "read back differs");
    bytes
}

fn pose(x: f64, y: f64, z: f64) -> PoseWithCovariance {
    PoseWithCovariance { pose: Pose { position: vec3(x, y, z), orientation: QUAT }, covariance: cov() }
}

/// The messages of `tests/python/ros_golden.py`, as cosem's types, in CDR.
fn messages() -> Vec<(&'static str, Vec<u8>)> {
    let mut all = inputs();
    all.extend(outputs());
    all
}

/// What a robot's stack gives cosem: scans, transforms, odometry.
fn inputs() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        (
            "sensor_msgs/msg/PointCloud2",
            both(PointCloud2 {
                header: header(1_700_000_000, 123_456_789, "velo_link"),
                height: 1,
                width: 2,
                fields: vec![
                    PointField { name: "x".into(), offset: 0, datatype: 7, count: 1 },
                    PointField { name: "label".into(), offset: 12, datatype: 6, count: 1 },
                ],
                is_bigendian: false,
                point_step: 16,
                row_step: 32,
                data: (0..32).collect(),
                is_dense: true,
            }),
        ),
        (
            "tf2_msgs/msg/TFMessage",
            both(TfMessage {
                transforms: vec![
                    TransformStamped {
                        header: header(-2, 5, "robot_a/odom"),
                        child_frame_id: "robot_b/odom".into(),
                        transform: Transform { translation: vec3(1.5, -2.25, 0.125), rotation: QUAT },
                    },
                    TransformStamped {
                        header: header(3, 0, "odom"),
                        child_frame_id: "base".into(),
                        transform: Transform { translation: vec3(0.0, 0.0, 0.0), rotation: QUAT },
                    },
                ],
            }),
        ),
        ("std_msgs/msg/String", both(StringMsg { data: "Converged".into() })),
        (
            "nav_msgs/msg/Odometry",
            both(Odometry {
                header: header(7, 8, "odom"),
                child_frame_id: "base_link".into(),
                pose: pose(1.0, 2.0, 3.0),
                twist: TwistWithCovariance {
                    twist: Twist { linear: vec3(0.5, 0.0, -0.5), angular: vec3(0.0, 0.1, 0.0) },
                    covariance: cov(),
                },
            }),
        ),
    ]
}

/// What cosem gives: poses, diagnostics, map updates.
fn outputs() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        (
            "geometry_msgs/msg/PoseWithCovarianceStamped",
            both(PoseWithCovarianceStamped { header: header(9, 10, "robot_a/odom"), pose: pose(-4.0, 5.5, 0.25) }),
        ),
        (
            "diagnostic_msgs/msg/DiagnosticArray",
            both(DiagnosticArray {
                header: header(11, 12, ""),
                status: vec![
                    DiagnosticStatus {
                        level: DiagnosticStatus::OK,
                        name: "cosem: robot_a / robot_b".into(),
                        message: "Converged".into(),
                        hardware_id: "robot_a".into(),
                        values: vec![
                            KeyValue { key: "agreement".into(), value: "0.61".into() },
                            KeyValue { key: "overlap".into(), value: "0.4".into() },
                        ],
                    },
                    DiagnosticStatus {
                        level: DiagnosticStatus::STALE,
                        name: "cosem: robot_a / robot_c".into(),
                        message: "NoOverlap".into(),
                        hardware_id: String::new(),
                        values: vec![],
                    },
                ],
            }),
        ),
        (
            "cosem_msgs/msg/MapUpdate",
            both(MapUpdate {
                header: header(13, 14, "robot_a/odom"),
                robot: "robot_a".into(),
                peer: String::new(),
                protocol: MAP_UPDATE_PROTOCOL,
                voxel_size: 0.5,
                heading_walk: 0.125,
                payload: vec![0xD8, 1, 0, 2, 3, 4, 5, 6, 7],
            }),
        ),
    ]
}

fn root() -> std::path::PathBuf {
    cosem_tests::workspace_root()
}

fn check_against(golden: &Value, source: &str) {
    let defs = definitions();
    let ours = messages();
    assert_eq!(golden.as_object().unwrap().len(), ours.len(), "{source}: another set of message types");
    for (name, bytes) in ours {
        let g = &golden[name];
        assert_eq!(g["cdr"].as_str(), Some(hex(&bytes).as_str()), "{source}: {name}'s CDR bytes differ");
        let def = defs.iter().find(|(n, _)| *n == name).map(|(_, d)| d.as_str());
        assert_eq!(g["definition"].as_str(), def, "{source}: {name}'s definition differs");
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The kept golden bytes.
fn kept() -> Value {
    serde_json::from_str(&std::fs::read_to_string(root().join("tests/golden/ros_messages.json")).unwrap()).unwrap()
}

#[test]
fn every_message_is_the_bytes_ros_2_makes() {
    check_against(&kept(), "the kept golden bytes");
}

#[test]
fn the_kept_golden_bytes_are_mcap_ros2s() {
    let script = root().join("tests/python/ros_golden.py").display().to_string();
    let run = "import runpy, sys\nrunpy.run_path(sys.argv[1], run_name='__main__')\n";
    let Some(out) = cosem_tests::python_or_skip(run, &[&script]) else { return };
    let made: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(made, kept(), "tests/golden/ros_messages.json is not what mcap_ros2 makes now: regenerate it");
    check_against(&made, "mcap_ros2");
}

#[test]
fn the_map_update_definition_is_the_msg_file() {
    let text = std::fs::read_to_string(root().join("host/ros/cosem_msgs/msg/MapUpdate.msg")).unwrap();
    let lines: String = text
        .lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(lines, MAP_UPDATE_DEF);
    assert!(MAP_UPDATE_DEF.starts_with(&format!("uint32 PROTOCOL={MAP_UPDATE_PROTOCOL}\n")));
}
