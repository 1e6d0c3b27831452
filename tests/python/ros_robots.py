"""The robot side of a team, on another DDS stack (Cyclone DDS, PyPI
`cyclonedds`), for tests/tests/ros.rs: it starts `cosem ros node`s, plays
each robot's drivers as a ROS 2 robot would (a SemanticKITTI folder's
scans as labelled PointCloud2 on /<robot>/points, its odometry on /tf,
/tf_static), with ROS 2's DDS topic and type names and plain CDR (XCDR1,
final types), and reads what the nodes publish (/tf, /diagnostics, each
peer's pose). It prints what it saw as JSON and checks nothing itself.

python3 ros_robots.py SPEC.json

SPEC: {"domain": D, "rate": scans a second, "until": seconds,
       "robots": [{"name", "data", "frames": [numbers], "at": seconds,
                   "wait_readers": true|false}],
       "nodes": [{"cmd": [...], "at": seconds}],
       "inject": [{"at": seconds, "kind": ..., ...}]}

Each robot's odometry starts at its first scan, moved by a random
transform (seeded by its index): the truth between robots is printed as
each robot's T_world_odom.
"""

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

sys.path.insert(0, os.path.dirname(__file__))
from ros_client import (  # noqa: E402  (the shared ROS types)
    Header,
    PointCloud2,
    PointField,
    Quaternion,
    TFMessage,
    Time,
    Transform,
    TransformStamped,
    Vector3,
)


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header
    pose: PoseWithCovariance


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


@dataclass
class MapUpdate(IdlStruct, typename="cosem_msgs::msg::dds_::MapUpdate_"):
    header: Header
    robot: str
    peer: str
    protocol: uint32
    voxel_size: float32
    heading_walk: float32
    payload: sequence[uint8]


def matrix_rows(path):
    return [np.vstack([np.array([float(x) for x in line.split()]).reshape(3, 4), [0, 0, 0, 1]])
            for line in open(path) if line.strip()]


def calib_tr(path):
    for line in open(path):
        if line.startswith("Tr:"):
            return np.vstack([np.array([float(x) for x in line.split()[1:]]).reshape(3, 4), [0, 0, 0, 1]])
    raise ValueError(f"{path}: no Tr")


def offset(i):
    """Robot i's odometry origin offset: a heading anywhere, up to 50 m aside."""
    rng = np.random.default_rng(1000 + i)
    yaw = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = [rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-1, 1)]
    return m


def quaternion(r):
    """A rotation matrix as (x, y, z, w)."""
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    n = np.sqrt(w * w + x * x + y * y + z * z)
    return x / n, y / n, z / n, w / n


def transform(m):
    x, y, z, w = quaternion(m[:3, :3])
    return Transform(Vector3(*map(float, m[:3, 3])), Quaternion(float(x), float(y), float(z), float(w)))


def stamp_now():
    t = time.time()
    return Time(int(t), int((t - int(t)) * 1e9))


def cloud(data, frame, frame_id, crop=50.0, label_offset=0):
    """A scan, its points within `crop` m, as a labelled PointCloud2 (its
    label ids moved by `label_offset`: a robot with labels of its own)."""
    pts = np.fromfile(os.path.join(data, "velodyne", f"{frame:06d}.bin"), dtype=np.float32).reshape(-1, 4)
    labels = np.fromfile(os.path.join(data, "labels", f"{frame:06d}.label"), dtype=np.uint32)
    keep = np.linalg.norm(pts[:, :3], axis=1) <= crop
    rec = np.zeros(int(keep.sum()), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u4")])
    rec["x"], rec["y"], rec["z"] = pts[keep, 0], pts[keep, 1], pts[keep, 2]
    rec["label"] = (labels[keep] & 0xFFFF) + label_offset
    fields = [PointField("x", 0, 7, 1), PointField("y", 4, 7, 1), PointField("z", 8, 7, 1),
              PointField("label", 12, 6, 1)]
    n = len(rec)
    return PointCloud2(Header(stamp_now(), frame_id), 1, n, fields, False, 16, 16 * n, rec.tobytes(), True)


class Robot:
    def __init__(self, dp, i, spec, qos):
        self.name, self.data, self.frames = spec["name"], spec["data"], spec["frames"]
        self.at, self.wait = spec.get("at", 0.0), spec.get("wait_readers", True)
        tr = calib_tr(os.path.join(self.data, "calib.txt"))
        poses = matrix_rows(os.path.join(self.data, "poses.txt"))
        self.world = [np.linalg.inv(tr) @ poses[f] @ tr for f in self.frames]
        self.world_odom = self.world[0] @ np.linalg.inv(offset(spec.get("seed", i)))
        if spec.get("reliable"):
            qos = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(5))
        self.points = DataWriter(dp, Topic(dp, f"rt/{self.name}/points", PointCloud2), qos=qos)
        # Its motion on a nav_msgs/Odometry topic (/<name>/odom), not /tf.
        self.odometry = None
        if spec.get("odometry"):
            reliable = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.Volatile,
                           Policy.History.KeepLast(100))
            self.odometry = DataWriter(dp, Topic(dp, f"rt/{self.name}/odom", Odometry), qos=reliable)
        self.next = 0
        self.label_offset = spec.get("label_offset", 0)

    def odom_pose(self, k):
        return np.linalg.inv(self.world_odom) @ self.world[k]


def main():
    spec = json.load(open(sys.argv[1]))
    dp = DomainParticipant(spec["domain"])
    sensor = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))
    reliable = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(100))
    latched = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
    robots = [Robot(dp, i, r, sensor) for i, r in enumerate(spec["robots"])]
    tf = DataWriter(dp, Topic(dp, "rt/tf", TFMessage), qos=reliable)
    tf_static = DataWriter(dp, Topic(dp, "rt/tf_static", TFMessage), qos=latched)
    tf_in = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=reliable)
    diagnostics = DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=reliable)
    names = [r.name for r in robots]
    poses = {(a, b): DataReader(dp, Topic(dp, f"rt/{a}/peers/{b}/pose", PoseWithCovarianceStamped), qos=reliable)
             for a in names for b in names if a != b}
    updates = DataWriter(dp, Topic(dp, "rt/cosem/map_updates", MapUpdate),
                         qos=Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.TransientLocal,
                                 Policy.History.KeepLast(32)))
    map_readers = [DataReader(dp, Topic(dp, f"rt/cosem/{t}", MapUpdate), qos=Qos(
        Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.TransientLocal, Policy.History.KeepLast(d)))
        for t, d in (("map_updates", 32), ("map_snapshots", 1))]
    identity = np.eye(4)
    tf_static.write(TFMessage([TransformStamped(Header(stamp_now(), f"{r.name}/base_link"), f"{r.name}/velodyne",
                                                transform(identity)) for r in robots]))
    got = {"truth": {r.name: [list(map(float, row)) for row in r.world_odom[:3]] for r in robots},
           "started": [], "stopped": [], "map_payload": [],
           "published": [], "edges": [], "diagnostics": [], "poses": [], "nodes": [], "injected": []}
    nodes, pending = [], sorted(spec["nodes"], key=lambda n: n["at"])
    stopped = set()  # the nodes this run stopped before its end (pids)
    injects = sorted(spec.get("inject", []), key=lambda n: n["at"])
    rate, t0 = spec.get("rate", 10.0), time.time()
    while time.time() - t0 < spec["until"]:
        now = time.time() - t0
        while pending and pending[0]["at"] <= now:
            n = pending.pop(0)
            p = subprocess.Popen(n["cmd"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            nodes.append((p, n.get("stop")))
            got["started"].append([now, n["cmd"]])
        for p, stop in nodes:
            # Once: a second SIGTERM ends a node as by default (its handler
            # is reset by the first), and the node may take longer than
            # this loop's turn to exit.
            if stop is not None and now >= stop and p.poll() is None and p.pid not in stopped:
                p.send_signal(signal.SIGTERM)  # a peer that vanishes
                got["stopped"].append([now, p.args])
                stopped.add(p.pid)
        while injects and injects[0]["at"] <= now:
            got["injected"].append(inject(injects.pop(0), updates, robots, now))
        for r in robots:
            if r.next >= len(r.frames) or now < r.at + r.next / rate:
                continue
            if r.next == 0 and r.wait and len(r.points.get_matched_subscriptions()) == 0:
                if now < r.at + 20:
                    continue  # its node's reader is not matched yet: a scan now would be lost
            k = r.next
            c = cloud(r.data, r.frames[k], f"{r.name}/velodyne", label_offset=r.label_offset)
            odom = TransformStamped(Header(c.header.stamp, f"{r.name}/odom"), f"{r.name}/base_link", transform(r.odom_pose(k)))
            if r.odometry is None:
                tf.write(TFMessage([odom]))
            else:
                t = odom.transform
                pose = Pose(Point(t.translation.x, t.translation.y, t.translation.z), t.rotation)
                zero = Vector3(0.0, 0.0, 0.0)
                r.odometry.write(Odometry(odom.header, odom.child_frame_id, PoseWithCovariance(pose, [0.0] * 36),
                                          TwistWithCovariance(Twist(zero, zero), [0.0] * 36)))
            r.points.write(c)
            got["published"].append([time.time() - t0, r.name, k, c.width])
            r.next += 1
        read(got, t0, tf_in, diagnostics, poses)
        for kind, reader in zip(("update", "snapshot"), map_readers):
            for m in reader.take(N=64):
                if isinstance(m, MapUpdate) and m.robot != "intruder":
                    got["map_payload"].append([time.time() - t0, m.robot, kind, len(m.payload)])
        time.sleep(0.01)
    got["usage"] = [usage(p.pid, t0) for p, _ in nodes]
    # Which nodes were still running when the run ended (the rest ended on
    # their own: a crash, or an error).
    running = [p.poll() is None or p.pid in stopped for p, _ in nodes]
    for (p, _), u in zip(nodes, got["usage"]):
        if p.poll() is None:
            # The node itself (under strace, strace's child: strace ends
            # with it, and the node never outlives the run).
            try:
                os.kill(u["pid"] if u else p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    for (p, _), alive in zip(nodes, running):
        try:
            out, err = p.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            out, err = p.communicate()
        got["nodes"].append({"code": p.returncode, "running": alive, "stdout": out, "stderr": err[-4000:]})
    json.dump(got, sys.stdout)


def usage(pid, t0):
    """A process's CPU seconds (user + system, its threads' and reaped
    children's), peak and current resident memory (kB), from /proc; the
    process's first child instead where it runs one (a node under strace)."""
    try:
        kids = open(f"/proc/{pid}/task/{pid}/children").read().split()
        if kids and open(f"/proc/{pid}/comm").read().strip() == "strace":
            pid = int(kids[0])
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        tick = os.sysconf("SC_CLK_TCK")
        cpu = (int(fields[11]) + int(fields[12])) / tick
        status = dict(line.split(":", 1) for line in open(f"/proc/{pid}/status") if ":" in line)
        kb = lambda k: int(status[k].split()[0]) if k in status else None
        return {"pid": pid, "cpu_s": cpu, "wall_s": time.time() - t0, "vmhwm_kb": kb("VmHWM"), "vmrss_kb": kb("VmRSS")}
    except (OSError, ValueError, IndexError):
        return None


KEEP = []  # endpoints an injection made, kept alive to the end


def inject(what, updates, robots, now):
    """Bad input, as a faulty or foreign peer or driver would send it."""
    kind = what["kind"]
    if kind == "qos":
        dp = updates.participant
        best_effort = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))
        volatile = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(1))
        latched = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.Durability.TransientLocal,
                      Policy.History.KeepLast(1))
        # A best-effort writer of /tf (the nodes read it reliably), a
        # volatile writer of /tf_static (read transient local), a
        # transient-local reader of /diagnostics (written volatile).
        KEEP.append(DataWriter(dp, Topic(dp, "rt/tf", TFMessage), qos=best_effort))
        KEEP.append(DataWriter(dp, Topic(dp, "rt/tf_static", TFMessage), qos=volatile))
        KEEP.append(DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=latched))
        return [now, kind]
    header = Header(stamp_now(), "intruder/odom")
    if kind == "update_garbage":
        updates.write(MapUpdate(header, "intruder", "", 3, 0.5, -1.0, bytes(range(256)) * 4))
    elif kind == "update_truncated":
        updates.write(MapUpdate(header, "intruder", "", 3, 0.5, -1.0, b"\x05\x00\x01"))
    elif kind == "update_protocol":
        updates.write(MapUpdate(header, "intruder", "", 99, 0.5, -1.0, bytes(64)))
    elif kind == "cloud_lies":
        r = robots[what.get("robot", 0)]
        c = cloud(r.data, r.frames[0], f"{r.name}/velodyne")
        c.width, c.row_step = c.width * 2, c.row_step * 2  # more points than the data holds
        r.points.write(c)
        c = cloud(r.data, r.frames[0], f"{r.name}/velodyne")
        c.fields = [PointField("x", 0, 7, 1), PointField("y", 4, 7, 1), PointField("z", 40, 7, 1),
                    PointField("label", 12, 6, 1)]  # a field past the point
        r.points.write(c)
    return [now, kind]


def read(got, t0, tf_in, diagnostics, poses):
    now = time.time() - t0
    for m in tf_in.take(N=64):
        if not isinstance(m, TFMessage):
            continue
        for t in m.transforms:
            if t.header.frame_id.endswith("/odom") and t.child_frame_id.endswith("/odom"):
                v, q = t.transform.translation, t.transform.rotation
                got["edges"].append([now, t.header.frame_id, t.child_frame_id, [v.x, v.y, v.z], [q.x, q.y, q.z, q.w]])
    for m in diagnostics.take(N=64):
        if isinstance(m, DiagnosticArray):
            for s in m.status:
                got["diagnostics"].append([now, s.name, int(s.level), s.message, {kv.key: kv.value for kv in s.values}])
    for (a, b), reader in poses.items():
        for m in reader.take(N=16):
            if isinstance(m, PoseWithCovarianceStamped):
                p = m.pose.pose
                got["poses"].append([now, a, b, m.header.frame_id, [p.position.x, p.position.y, p.position.z],
                                     list(m.pose.covariance)])


if __name__ == "__main__":
    main()
