"""A ROS 2 client on another DDS stack (Cyclone DDS, PyPI `cyclonedds`),
for tests/tests/ros.rs: subscribes to what `cosem ros play` publishes, with
ROS 2's DDS topic and type names and plain CDR (XCDR1, final types), and
prints what it received as JSON.

python3 ros_client.py DOMAIN ROBOTS SECONDS -- COMMAND...
runs COMMAND (the publisher) once its readers exist, reads until the
command has ended and SECONDS have passed, and checks nothing itself.
"""

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint8, uint32
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header
    height: uint32
    width: uint32
    fields: sequence[PointField]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


# A scan is a large sample (up to 2 MB, hundreds of UDP fragments): a
# receive buffer as large as the kernel allows keeps a busy reader from
# losing fragments, as ROS 2's own guidance for large messages says.
os.environ.setdefault(
    "CYCLONEDDS_URI",
    "<CycloneDDS><Domain><Internal><SocketReceiveBufferSize min='default' max='4MB'/></Internal></Domain></CycloneDDS>",
)


def main():
    domain, robots, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    command = sys.argv[sys.argv.index("--") + 1 :]
    dp = DomainParticipant(domain)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))
    reliable = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(100))
    latched = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
    clouds = {
        f"robot_{i}": DataReader(dp, Topic(dp, f"rt/robot_{i}/points", PointCloud2), qos=sensor) for i in range(robots)
    }
    tf = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=reliable)
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # /tf_static is transient local: read after the publisher has sent it,
    # as a late joiner.
    time.sleep(0.5)
    tf_static = DataReader(dp, Topic(dp, "rt/tf_static", TFMessage), qos=latched)
    got = {"clouds": {name: [] for name in clouds}, "tf": [], "tf_static": []}
    deadline = None
    while True:
        for name, reader in clouds.items():
            for c in reader.take(N=16):
                if not isinstance(c, PointCloud2):
                    continue  # a writer gone: not a sample
                labels = set()
                for k in range(c.width):
                    at = k * c.point_step + 12
                    labels.add(int.from_bytes(bytes(c.data[at : at + 4]), "little") & 0xFFFF)
                got["clouds"][name].append(
                    {
                        "frame_id": c.header.frame_id,
                        "stamp": [c.header.stamp.sec, c.header.stamp.nanosec],
                        "width": c.width,
                        "fields": [[f.name, f.offset, f.datatype, f.count] for f in c.fields],
                        "point_step": c.point_step,
                        "row_step": c.row_step,
                        "bytes": len(c.data),
                        "labels": sorted(labels),
                    }
                )
        for reader, key in ((tf, "tf"), (tf_static, "tf_static")):
            for m in reader.take(N=64):
                if not isinstance(m, TFMessage):
                    continue
                for t in m.transforms:
                    v, q = t.transform.translation, t.transform.rotation
                    got[key].append([t.header.frame_id, t.child_frame_id, [v.x, v.y, v.z], [q.x, q.y, q.z, q.w]])
        if proc.poll() is not None and deadline is None:
            deadline = time.time() + seconds
        if deadline is not None and time.time() > deadline:
            break
        time.sleep(0.02)
    out, err = proc.communicate()
    got["publisher"] = {"code": proc.returncode, "stdout": out, "stderr": err[-2000:]}
    json.dump(got, sys.stdout)


if __name__ == "__main__":
    main()
