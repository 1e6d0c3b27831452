"""Writes a ROS 2 recording (MCAP) with the Python `mcap` and
`mcap-ros2-support` writers, a client cosem did not write, from scans as
`cosem export scans --format pcd` leaves them (binary PCD: x, y, z float32,
label uint32; poses.txt: each LiDAR pose in KITTI's layout).

The recording: PointCloud2 scans in frame `velodyne` on /velodyne_points,
the mount base_link -> velodyne on /tf_static, and odom -> base_link on /tf
at each scan's stamp, under world -> odom on /tf_static (a chain of three).

With `odom`, odom -> base_link goes on /odom as nav_msgs/msg/Odometry
instead of /tf.

usage: write_recording.py SCANS_DIR OUT.mcap [zstd|lz4|none] [odom]
"""

import math
import struct
import sys
from pathlib import Path

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

POINTCLOUD2 = """std_msgs/Header header
uint32 height
uint32 width
PointField[] fields
bool is_bigendian
uint32 point_step
uint32 row_step
uint8[] data
bool is_dense
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: sensor_msgs/PointField
uint8 INT8=1
uint8 UINT8=2
uint8 INT16=3
uint8 UINT16=4
uint8 INT32=5
uint8 UINT32=6
uint8 FLOAT32=7
uint8 FLOAT64=8
string name
uint32 offset
uint8 datatype
uint32 count
"""

TFMESSAGE = """geometry_msgs/TransformStamped[] transforms
================================================================================
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
Transform transform
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/Transform
Vector3 translation
Quaternion rotation
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""

ODOMETRY = """std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/PoseWithCovariance
Pose pose
float64[36] covariance
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
================================================================================
MSG: geometry_msgs/TwistWithCovariance
Twist twist
float64[36] covariance
================================================================================
MSG: geometry_msgs/Twist
Vector3 linear
Vector3 angular
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def inverse(m):
    r = [[m[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(r[i][k] * m[k][3] for k in range(3)) for i in range(3)]
    return [r[0] + [t[0]], r[1] + [t[1]], r[2] + [t[2]], [0.0, 0.0, 0.0, 1.0]]


def quaternion(m):
    """(x, y, z, w) of a rotation matrix (Shepperd's method)."""
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s)
    if m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        return (0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    if m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        return ((m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
    return ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s)


def transform(parent, child, m, stamp):
    q = quaternion(m)
    return {
        "header": {"stamp": stamp, "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": {"x": m[0][3], "y": m[1][3], "z": m[2][3]},
            "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
        },
    }


def read_pcd(path):
    data = path.read_bytes()
    end = data.index(b"DATA binary\n") + len(b"DATA binary\n")
    header = data[:end].decode()
    assert "FIELDS x y z label" in header, header
    return data[end:]


def main():
    scans, out = Path(sys.argv[1]), sys.argv[2]
    compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[
        sys.argv[3] if len(sys.argv) > 3 else "zstd"
    ]
    use_odom = len(sys.argv) > 4 and sys.argv[4] == "odom"
    poses = []
    for line in (scans / "poses.txt").read_text().splitlines():
        v = [float(x) for x in line.split()]
        poses.append([v[0:4], v[4:8], v[8:12], [0.0, 0.0, 0.0, 1.0]])
    files = sorted(scans.glob("*.pcd"))
    # A world -> odom offset, a LiDAR mounted 1.7 m up and turned a little.
    world_odom = [[1.0, 0.0, 0.0, 100.0], [0.0, 1.0, 0.0, -50.0], [0.0, 0.0, 1.0, 2.0], [0.0, 0.0, 0.0, 1.0]]
    c, s = math.cos(0.1), math.sin(0.1)
    mount = [[c, -s, 0.0, 0.3], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 1.7], [0.0, 0.0, 0.0, 1.0]]
    with open(out, "wb") as f:
        writer = Writer(f, compression=compression)
        pc = writer.register_msgdef("sensor_msgs/msg/PointCloud2", POINTCLOUD2)
        tf = writer.register_msgdef("tf2_msgs/msg/TFMessage", TFMESSAGE)
        odom = writer.register_msgdef("nav_msgs/msg/Odometry", ODOMETRY)
        zero = {"sec": 0, "nanosec": 0}
        statics = [transform("world", "odom", world_odom, zero), transform("base_link", "velodyne", mount, zero)]
        writer.write_message("/tf_static", tf, {"transforms": statics}, log_time=0, publish_time=0)
        for k, (path, pose) in enumerate(zip(files, poses)):
            ns = 1_000_000_000 + k * 100_000_000
            stamp = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
            # odom -> base_link such that world -> velodyne is the scan's pose.
            odom_base = matmul(matmul(inverse(world_odom), pose), inverse(mount))
            t = transform("odom", "base_link", odom_base, stamp)
            if use_odom:
                zero3 = {"x": 0.0, "y": 0.0, "z": 0.0}
                msg = {
                    "header": t["header"],
                    "child_frame_id": "base_link",
                    "pose": {
                        "pose": {"position": t["transform"]["translation"], "orientation": t["transform"]["rotation"]},
                        "covariance": [0.0] * 36,
                    },
                    "twist": {"twist": {"linear": zero3, "angular": zero3}, "covariance": [0.0] * 36},
                }
                writer.write_message("/odom", odom, msg, log_time=ns, publish_time=ns)
            else:
                writer.write_message("/tf", tf, {"transforms": [t]}, log_time=ns, publish_time=ns)
            data = read_pcd(path)
            n = len(data) // 16
            fields = [
                {"name": name, "offset": off, "datatype": dt, "count": 1}
                for name, off, dt in (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("label", 12, 6))
            ]
            cloud = {
                "header": {"stamp": stamp, "frame_id": "velodyne"},
                "height": 1,
                "width": n,
                "fields": fields,
                "is_bigendian": False,
                "point_step": 16,
                "row_step": 16 * n,
                "data": data,
                "is_dense": True,
            }
            writer.write_message("/velodyne_points", pc, cloud, log_time=ns, publish_time=ns)
        writer.finish()
    print(f"{out}: {len(files)} scans")


if __name__ == "__main__":
    main()
