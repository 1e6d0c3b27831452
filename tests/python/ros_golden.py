"""Golden CDR bytes of every ROS 2 message type cosem reads or writes, made
by the mcap_ros2 Python package from ROS 2 Jazzy's definitions (written out
here, independently of the Rust ones), for tests/tests/ros_messages.rs.

python3 tests/python/ros_golden.py > tests/golden/ros_messages.json
"""

import json
import sys

from mcap_ros2._dynamic import serialize_dynamic

SEP = "=" * 80 + "\n"
TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
POINT = "float64 x\nfloat64 y\nfloat64 z\n"
QUATERNION = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
POSE = "Point position\nQuaternion orientation\n"
POSE_COV = "Pose pose\nfloat64[36] covariance\n"
POINT_FIELD = (
    "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\n"
    "uint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\n"
    "string name\nuint32 offset\nuint8 datatype\nuint32 count\n"
)


def definition(own, deps):
    return own + "".join(SEP + "MSG: " + name + "\n" + text for name, text in deps)


HDR = [("std_msgs/Header", HEADER), ("builtin_interfaces/Time", TIME)]
# A header and a pose with covariance, as PoseWithCovarianceStamped and
# Odometry list them.
STAMPED_POSE = HDR + [
    ("geometry_msgs/PoseWithCovariance", POSE_COV),
    ("geometry_msgs/Pose", POSE),
    ("geometry_msgs/Point", POINT),
    ("geometry_msgs/Quaternion", QUATERNION),
]
DEFINITIONS = {
    "sensor_msgs/msg/PointCloud2": definition(
        "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\n"
        "bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
        HDR + [("sensor_msgs/PointField", POINT_FIELD)],
    ),
    "tf2_msgs/msg/TFMessage": definition(
        "geometry_msgs/TransformStamped[] transforms\n",
        [("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform\n")]
        + HDR
        + [
            ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"),
            ("geometry_msgs/Vector3", POINT),
            ("geometry_msgs/Quaternion", QUATERNION),
        ],
    ),
    "std_msgs/msg/String": "string data\n",
    "nav_msgs/msg/Odometry": definition(
        "std_msgs/Header header\nstring child_frame_id\n"
        "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
        STAMPED_POSE
        + [
            ("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"),
            ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
            ("geometry_msgs/Vector3", POINT),
        ],
    ),
    "geometry_msgs/msg/PoseWithCovarianceStamped": definition(
        "std_msgs/Header header\nPoseWithCovariance pose\n",
        STAMPED_POSE,
    ),
    "diagnostic_msgs/msg/DiagnosticArray": definition(
        "std_msgs/Header header\nDiagnosticStatus[] status\n",
        HDR
        + [
            (
                "diagnostic_msgs/DiagnosticStatus",
                "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n"
                "string message\nstring hardware_id\nKeyValue[] values\n",
            ),
            ("diagnostic_msgs/KeyValue", "string key\nstring value\n"),
        ],
    ),
    "cosem_msgs/msg/MapUpdate": definition(
        "uint32 PROTOCOL=3\nstd_msgs/Header header\nstring robot\nstring peer\nuint32 protocol\nfloat32 voxel_size\nfloat32 heading_walk\nuint8[] payload\n",
        HDR,
    ),
}


def header(sec, nanosec, frame):
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame}


def vec(x, y, z):
    return {"x": x, "y": y, "z": z}


QUAT = {"x": 0.125, "y": -0.25, "z": 0.5, "w": 0.8}
COV = [float(i) * 0.5 - 3.0 for i in range(36)]
# The same messages as tests/tests/ros_messages.rs builds.
MESSAGES = {
    "sensor_msgs/msg/PointCloud2": {
        "header": header(1700000000, 123456789, "velo_link"),
        "height": 1,
        "width": 2,
        "fields": [
            {"name": "x", "offset": 0, "datatype": 7, "count": 1},
            {"name": "label", "offset": 12, "datatype": 6, "count": 1},
        ],
        "is_bigendian": False,
        "point_step": 16,
        "row_step": 32,
        "data": bytes(range(32)),
        "is_dense": True,
    },
    "tf2_msgs/msg/TFMessage": {
        "transforms": [
            {
                "header": header(-2, 5, "robot_a/odom"),
                "child_frame_id": "robot_b/odom",
                "transform": {"translation": vec(1.5, -2.25, 0.125), "rotation": QUAT},
            },
            {
                "header": header(3, 0, "odom"),
                "child_frame_id": "base",
                "transform": {"translation": vec(0.0, 0.0, 0.0), "rotation": QUAT},
            },
        ]
    },
    "std_msgs/msg/String": {"data": "Converged"},
    "nav_msgs/msg/Odometry": {
        "header": header(7, 8, "odom"),
        "child_frame_id": "base_link",
        "pose": {"pose": {"position": vec(1.0, 2.0, 3.0), "orientation": QUAT}, "covariance": COV},
        "twist": {"twist": {"linear": vec(0.5, 0.0, -0.5), "angular": vec(0.0, 0.1, 0.0)}, "covariance": COV},
    },
    "geometry_msgs/msg/PoseWithCovarianceStamped": {
        "header": header(9, 10, "robot_a/odom"),
        "pose": {"pose": {"position": vec(-4.0, 5.5, 0.25), "orientation": QUAT}, "covariance": COV},
    },
    "diagnostic_msgs/msg/DiagnosticArray": {
        "header": header(11, 12, ""),
        "status": [
            {
                "level": 0,
                "name": "cosem: robot_a / robot_b",
                "message": "Converged",
                "hardware_id": "robot_a",
                "values": [{"key": "agreement", "value": "0.61"}, {"key": "overlap", "value": "0.4"}],
            },
            {"level": 3, "name": "cosem: robot_a / robot_c", "message": "NoOverlap", "hardware_id": "", "values": []},
        ],
    },
    "cosem_msgs/msg/MapUpdate": {
        "header": header(13, 14, "robot_a/odom"),
        "robot": "robot_a",
        "peer": "",
        "protocol": 3,
        "voxel_size": 0.5,
        "heading_walk": 0.125,
        "payload": bytes([0xD8, 1, 0, 2, 3, 4, 5, 6, 7]),
    },
}


def main():
    out = {}
    for name, text in DEFINITIONS.items():
        encoders = serialize_dynamic(name, text)
        out[name] = {"definition": text, "cdr": encoders[name](MESSAGES[name]).hex()}
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
