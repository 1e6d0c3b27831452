//! The ROS 2 messages cosem reads and writes (`sensor_msgs/PointCloud2`,
//! `tf2_msgs/TFMessage`, `nav_msgs/Odometry`, `std_msgs/String`), as
//! serde types in CDR field order, and their `ros2msg` definitions.

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
