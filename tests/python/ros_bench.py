"""`cosem ros node` measured live on the synthetic town at 10 Hz (docs/ros.md):
two nodes, their robots' drivers on Cyclone DDS (ros_robots.py), and

- latency: from the publication that brings the pair's true overlap to 30%
  (the larger of the two directions, as `cosem session` computes it on the
  same maps: voxels, capacity, crop and scans a round the node's defaults)
  to the first /tf edge between them the client receives, both on the
  client's clock; for each meeting;
- CPU (share of one core over the node's life) and peak memory of a node;
- bytes per robot per second: map payload (the MapUpdate payloads on the
  wire) and RTPS (every UDP byte the node sent, counted by strace: map
  updates, fixes, /tf, poses, /diagnostics, discovery, acknowledgements);
- every /tf edge against the truth.

Run in a network namespace of its own (never on the machine's interfaces):

    unshare -n sh -c "$NETNS && python3 tests/python/ros_bench.py --cosem target/release/cosem"

with NETNS as in tests/tests/ros.rs. Prints a table, then one JSON line.
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def session_overlaps(cosem, town, frames):
    """Per round, the pair's true overlap (the larger direction)."""
    out = subprocess.run(
        [cosem, "session", "--robot", f"{town}/robot_0:0:{frames}", "--robot", f"{town}/robot_1:0:{frames}", "--json"],
        check=True, capture_output=True, text=True).stdout
    rounds = {}
    for line in out.splitlines():
        d = json.loads(line)
        if "round" in d and d.get("overlap_true") is not None:
            rounds[d["round"]] = max(rounds.get(d["round"], 0.0), d["overlap_true"])
    return [rounds.get(r, 0.0) for r in range(max(rounds) + 1)] if rounds else []


def iso(t, q):
    x, y, z, w = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def sent_bytes(path):
    """UDP bytes a process sent, from its strace log."""
    total = 0
    for line in open(path):
        if "sendto(" in line or "sendmsg(" in line:
            m = re.search(r"= (\d+)\s*$", line)
            if m:
                total += int(m.group(1))
    return total


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cosem", required=True)
    ap.add_argument("--town", help="a town (cosem synth --town) to use; else one is made")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--frames", type=int, default=None, help="scans a robot (default: all)")
    ap.add_argument("--domain", type=int, default=42)
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="cosem-ros-bench-")
    town = a.town
    if town is None:
        town = os.path.join(tmp, "town")
        subprocess.run([a.cosem, "synth", "--town", "--out", town, "--seg", "none", "--seed", str(a.seed)],
                       check=True, capture_output=True)
    frames = a.frames or sum(1 for line in open(os.path.join(town, "robot_0", "poses.txt")) if line.strip())
    overlaps = session_overlaps(a.cosem, town, frames)
    nodes = []
    for i in range(2):
        trace = os.path.join(tmp, f"strace.{i}")
        cmd = ["strace", "-f", "-qq", "-e", "trace=sendto,sendmsg", "-o", trace,
               a.cosem, "ros", "node", "--name", f"robot_{i}", "--domain", str(a.domain)]
        nodes.append({"cmd": cmd, "at": 0.0})
    robots = [{"name": f"robot_{i}", "data": os.path.join(town, f"robot_{i}"), "frames": list(range(frames)), "at": 0.0}
              for i in range(2)]
    spec = {"domain": a.domain, "rate": 10, "until": frames / 10 + 8, "robots": robots, "nodes": nodes}
    spec_path = os.path.join(tmp, "spec.json")
    json.dump(spec, open(spec_path, "w"))
    got = json.loads(subprocess.run([sys.executable, os.path.join(HERE, "ros_robots.py"), spec_path],
                                    check=True, capture_output=True, text=True).stdout)
    published = {(p[1], p[2]): p[0] for p in got["published"]}
    edges = [e for e in got["edges"] if e[1] == "robot_0/odom" and e[2] == "robot_1/odom"]
    # Meetings: the rounds where the true overlap rises through 30%.
    latencies = []
    for r in range(len(overlaps)):
        if overlaps[r] >= 0.3 and (r == 0 or overlaps[r - 1] < 0.3):
            k = min(2 * r + 1, frames - 1)
            t = max(published.get((f"robot_{i}", k), float("inf")) for i in range(2))
            after = [e[0] for e in edges if e[0] >= t]
            flowing = any(t - 1.0 <= e[0] < t for e in edges)
            latencies.append({"round": r, "at_s": t, "latency_s": (after[0] - t) if after else None,
                              "edge_already_flowing": flowing})
    w = {name: np.vstack([np.array(rows), [0, 0, 0, 1]]) for name, rows in got["truth"].items()}
    truth = np.linalg.inv(w["robot_0"]) @ w["robot_1"]
    errors = []
    for e in edges:
        d = np.linalg.inv(truth) @ iso(e[3], e[4])
        ang = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        errors.append((float(np.linalg.norm(d[:3, 3])), float(ang)))
    drive_s = frames / 10
    payload = {f"robot_{i}": sum(p[3] for p in got["map_payload"] if p[1] == f"robot_{i}") for i in range(2)}
    report = {
        "frames": frames,
        "meetings": latencies,
        "edges": len(edges),
        "edges_wrong": sum(1 for et, er in errors if et >= 0.5 or er >= 1.0),
        "edge_error_median": [float(np.median([e[0] for e in errors])), float(np.median([e[1] for e in errors]))]
        if errors else None,
        "nodes": [],
    }
    for i, u in enumerate(got["usage"]):
        rtps = sent_bytes(os.path.join(tmp, f"strace.{i}"))
        report["nodes"].append({
            "robot": f"robot_{i}",
            "cpu_share": u and u["cpu_s"] / u["wall_s"],
            "peak_mb": u and u["vmhwm_kb"] / 1024,
            "payload_bytes_per_s": payload[f"robot_{i}"] / drive_s,
            "rtps_bytes_per_s": rtps / u["wall_s"] if u else None,
            "updates": sum(1 for p in got["map_payload"] if p[1] == f"robot_{i}"),
        })
    print(f"town: {town}, {frames} scans a robot at 10 Hz; {len(edges)} /tf edges, "
          f"{report['edges_wrong']} beyond 0.5 m / 1 deg, median error {report['edge_error_median']}")
    for m in latencies:
        print(f"meeting at round {m['round']} ({m['at_s']:.1f} s): first /tf edge after {m['latency_s']} s"
              f"{' (edges already flowing)' if m['edge_already_flowing'] else ''}")
    for n in report["nodes"]:
        print(f"{n['robot']}: CPU {n['cpu_share']:.2f} of a core, peak {n['peak_mb']:.0f} MB, "
              f"map payload {n['payload_bytes_per_s']:.0f} B/s in {n['updates']} messages, "
              f"RTPS sent {n['rtps_bytes_per_s']:.0f} B/s")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
