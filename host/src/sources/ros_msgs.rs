//! The ROS 2 messages cosem reads and writes (`sensor_msgs/PointCloud2`,
//! `tf2_msgs/TFMessage`, `nav_msgs/Odometry`, `std_msgs/String`,
//! `geometry_msgs/PoseWithCovarianceStamped`,
//! `diagnostic_msgs/DiagnosticArray` and cosem's own
//! `cosem_msgs/MapUpdate`), as serde types in CDR field order, and their
//! `ros2msg` definitions ([`definitions`]). Plain CDR (XCDR1, final
//! types, little-endian): what a ROS 2 Jazzy node sends and expects,
//! checked byte for byte against the `mcap_ros2` Python package
//! (`tests/tests/ros_messages.rs`).

use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch.
    pub fn nanos(self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    /// The stamp of `t` seconds (rounded to the nanosecond).
    pub fn of_seconds(t: f64) -> Self {
        let ns = (t * 1e9).round() as i64;
        Time { sec: ns.div_euclid(1_000_000_000) as i32, nanosec: ns.rem_euclid(1_000_000_000) as u32 }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// In which frame.
    pub frame_id: String,
}

/// `sensor_msgs/msg/PointField`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointField {
    /// Field name.
    pub name: String,
    /// Byte offset in a point.
    pub offset: u32,
    /// 1 int8 ... 6 uint32, 7 float32, 8 float64.
    pub datatype: u8,
    /// Values.
    pub count: u32,
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointCloud2 {
    /// Stamp and sensor frame.
    pub header: Header,
    /// Rows (1 for an unorganised cloud).
    pub height: u32,
    /// Points a row.
    pub width: u32,
    /// The point layout.
    pub fields: Vec<PointField>,
    /// Big-endian data (refused).
    pub is_bigendian: bool,
    /// Bytes a point.
    pub point_step: u32,
    /// Bytes a row.
    pub row_step: u32,
    /// The points.
    pub data: Vec<u8>,
    /// No invalid points.
    pub is_dense: bool,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/msg/Transform`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`: the child frame's pose in the
/// parent (`header.frame_id`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// `T_parent_child`.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `geometry_msgs/msg/Pose`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: Pose,
    /// Row-major 6x6 covariance.
    pub covariance: [[f64; 6]; 6],
}

/// `geometry_msgs/msg/Twist`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity.
    pub linear: Vector3,
    /// Angular velocity.
    pub angular: Vector3,
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// The twist.
    pub twist: Twist,
    /// Row-major 6x6 covariance.
    pub covariance: [[f64; 6]; 6],
}

/// `nav_msgs/msg/Odometry`: the pose of `child_frame_id` in
/// `header.frame_id`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    /// Stamp and the odometry frame.
    pub header: Header,
    /// The moving frame.
    pub child_frame_id: String,
    /// Its pose.
    pub pose: PoseWithCovariance,
    /// Its velocity.
    pub twist: TwistWithCovariance,
}

/// The message definitions a recording's schemas carry (`ros2msg`).
/// The `ros2msg` definition of `sensor_msgs/msg/PointCloud2`.
pub const POINTCLOUD2_SCHEMA: &str = "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n================================================================================\nMSG: sensor_msgs/PointField\nuint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n";
/// The `ros2msg` definition of `tf2_msgs/msg/TFMessage`.
pub const TFMESSAGE_SCHEMA: &str = "geometry_msgs/TransformStamped[] transforms\n================================================================================\nMSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\nTransform transform\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n================================================================================\nMSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n================================================================================\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n================================================================================\nMSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";

/// `std_msgs/msg/String`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}

/// The `ros2msg` definition of `std_msgs/msg/String`.
pub const STRING_SCHEMA: &str = "string data\n";

/// `geometry_msgs/msg/PoseWithCovarianceStamped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovarianceStamped {
    /// Stamp and the frame the pose is in.
    pub header: Header,
    /// The pose and its covariance (ROS's convention: on the pose in
    /// `header.frame_id`, order x, y, z, rotation about x, y, z).
    pub pose: PoseWithCovariance,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    /// The name.
    pub key: String,
    /// Its value, as text.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// [`DiagnosticStatus::OK`], `WARN`, `ERROR` or `STALE`.
    pub level: u8,
    /// What is reported on.
    pub name: String,
    /// Its state, in words.
    pub message: String,
    /// The hardware it runs on.
    pub hardware_id: String,
    /// The figures.
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    /// Level: all is well.
    pub const OK: u8 = 0;
    /// Level: a warning.
    pub const WARN: u8 = 1;
    /// Level: an error.
    pub const ERROR: u8 = 2;
    /// Level: nothing heard for too long.
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// One status per thing reported on.
    pub status: Vec<DiagnosticStatus>,
}

/// `cosem_msgs/msg/MapUpdate`: one message of cosem's map-update protocol
/// between robots (an update, a snapshot or an answer, in the compact
/// wire format of `cosem_core::wire::update`, its CRC-32 included),
/// carried whole. Its definition is `host/ros/cosem_msgs/msg/MapUpdate.msg`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapUpdate {
    /// When it was sent, and the sender's odometry frame.
    pub header: Header,
    /// The sender's name.
    pub robot: String,
    /// The robot an answer is for (empty: an update, for every peer).
    pub peer: String,
    /// The protocol's version ([`MAP_UPDATE_PROTOCOL`]): a message of
    /// another is dropped before its payload is read.
    pub protocol: u32,
    /// The sender's voxel size (m): the payload's cells are of this size
    /// (the wire format names cells, not metres), and a robot of another
    /// size does not match them.
    pub voxel_size: f32,
    /// The sender's figure of its odometry's heading walk (degrees,
    /// `cosem_core::session::OdometryWalk::excess`), negative while it has
    /// none: a peer withholds its estimates while the two robots' walk
    /// together passes `cosem_core::session::WALK_LIMIT_DEG`.
    pub heading_walk: f32,
    /// The wire message.
    pub payload: Vec<u8>,
}

/// The version of the map-update protocol a [`MapUpdate`] carries: raised
/// whenever the message's or the payload's format changes (2: the
/// sender's voxel size joined the message; 3: its heading walk).
pub const MAP_UPDATE_PROTOCOL: u32 = 3;

const SEPARATOR: &str = "================================================================================\n";
const TIME_DEF: &str = "int32 sec\nuint32 nanosec\n";
const HEADER_DEF: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const POINT_DEF: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION_DEF: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const POSE_DEF: &str = "Point position\nQuaternion orientation\n";
const POSE_COV_DEF: &str = "Pose pose\nfloat64[36] covariance\n";
const KEY_VALUE_DEF: &str = "string key\nstring value\n";
const STATUS_DEF: &str = "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n";

/// A `ros2msg` definition: the message's own text, then each dependency
/// under its `MSG:` line.
fn definition(own: &str, deps: &[(&str, &str)]) -> String {
    let mut text = own.to_string();
    for (name, def) in deps {
        text.push_str(SEPARATOR);
        text.push_str("MSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(def);
    }
    text
}

/// A header and a pose with covariance: the dependencies
/// `PoseWithCovarianceStamped` and `Odometry` share, in their order.
const STAMPED_POSE_DEPS: [(&str, &str); 6] = [
    ("std_msgs/Header", HEADER_DEF),
    ("builtin_interfaces/Time", TIME_DEF),
    ("geometry_msgs/PoseWithCovariance", POSE_COV_DEF),
    ("geometry_msgs/Pose", POSE_DEF),
    ("geometry_msgs/Point", POINT_DEF),
    ("geometry_msgs/Quaternion", QUATERNION_DEF),
];

/// The `ros2msg` definition of `geometry_msgs/msg/PoseWithCovarianceStamped`.
pub fn pose_with_covariance_stamped_schema() -> String {
    definition("std_msgs/Header header\nPoseWithCovariance pose\n", &STAMPED_POSE_DEPS)
}

/// The `ros2msg` definition of `diagnostic_msgs/msg/DiagnosticArray`.
pub fn diagnostic_array_schema() -> String {
    definition(
        "std_msgs/Header header\nDiagnosticStatus[] status\n",
        &[
            ("std_msgs/Header", HEADER_DEF),
            ("builtin_interfaces/Time", TIME_DEF),
            ("diagnostic_msgs/DiagnosticStatus", STATUS_DEF),
            ("diagnostic_msgs/KeyValue", KEY_VALUE_DEF),
        ],
    )
}

/// The `ros2msg` definition of `nav_msgs/msg/Odometry`.
pub fn odometry_schema() -> String {
    let twist = [
        ("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"),
        ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
        ("geometry_msgs/Vector3", POINT_DEF),
    ];
    let deps: Vec<(&str, &str)> = STAMPED_POSE_DEPS.iter().chain(&twist).copied().collect();
    definition(
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
        &deps,
    )
}

/// The text of `host/ros/cosem_msgs/msg/MapUpdate.msg` (its comments left out).
pub const MAP_UPDATE_DEF: &str =
    "uint32 PROTOCOL=3\nstd_msgs/Header header\nstring robot\nstring peer\nuint32 protocol\nfloat32 voxel_size\nfloat32 heading_walk\nuint8[] payload\n";

/// The `ros2msg` definition of `cosem_msgs/msg/MapUpdate`.
pub fn map_update_schema() -> String {
    definition(MAP_UPDATE_DEF, &[("std_msgs/Header", HEADER_DEF), ("builtin_interfaces/Time", TIME_DEF)])
}

/// Every message type cosem reads or writes, by its full name, with its
/// `ros2msg` definition.
pub fn definitions() -> Vec<(&'static str, String)> {
    vec![
        ("sensor_msgs/msg/PointCloud2", POINTCLOUD2_SCHEMA.to_string()),
        ("tf2_msgs/msg/TFMessage", TFMESSAGE_SCHEMA.to_string()),
        ("std_msgs/msg/String", STRING_SCHEMA.to_string()),
        ("nav_msgs/msg/Odometry", odometry_schema()),
        ("geometry_msgs/msg/PoseWithCovarianceStamped", pose_with_covariance_stamped_schema()),
        ("diagnostic_msgs/msg/DiagnosticArray", diagnostic_array_schema()),
        ("cosem_msgs/msg/MapUpdate", map_update_schema()),
    ]
}

/// `msg` in plain CDR, little-endian, with its 4-byte encapsulation
/// header: a ROS 2 message's bytes on the wire and in a recording.
pub fn to_cdr<T: Serialize>(msg: &T) -> Result<Vec<u8>, String> {
    cdr::serialize::<_, _, cdr::CdrLe>(msg, cdr::Infinite).map_err(|e| format!("CDR: {e}"))
}

/// The bytes [`to_cdr`] would make of `msg`, counted without making them.
pub fn cdr_size<T: Serialize>(msg: &T) -> u64 {
    cdr::calc_serialized_size(msg)
}

/// A message of type `T` from its CDR bytes ([`to_cdr`]'s).
pub fn from_cdr<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, String> {
    cdr::deserialize::<T>(bytes).map_err(|e| format!("CDR: {e}"))
}
