//! `cosem ros` against a ROS 2 client on another DDS stack (Cyclone DDS's
//! Python binding, `tests/python/ros_client.py`), with ROS 2's DDS topic and
//! type names and plain CDR, in a network namespace the test makes itself
//! (`unshare -n`, a veth pair with multicast), never on the machine's
//! interfaces, with a domain id of its own. Where a namespace cannot be
//! made, or Python lacks `cyclonedds`, the test says so and skips.

use cosem_core::session::WALK_LIMIT_DEG;
use cosem_host::sources::source::{Source, SourceOptions};
use cosem_tests::{cosem_bin, real_data, synth, workspace_root};
use nalgebra::{Isometry3, Matrix4, Quaternion, Translation3, UnitQuaternion};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// The namespace's network: both ends of a veth pair up, with addresses
/// and multicast (RustDDS announces no loopback address).
const NETNS: &str = "ip link add v0 type veth peer name v1 && ip addr add 10.9.0.1/24 dev v0 && \
    ip addr add 10.9.0.2/24 dev v1 && ip link set v0 up && ip link set v1 up && ip link set lo up && \
    ip link set v0 multicast on && ip link set v1 multicast on && ip route add 224.0.0.0/4 dev v0";

/// Why the DDS tests cannot run here, if they cannot.
fn unavailable() -> Option<String> {
    let ns = Command::new("unshare").args(["-n", "sh", "-c", NETNS]).output();
    if !ns.is_ok_and(|o| o.status.success()) {
        return Some("no network namespace with a veth pair (unshare -n as root, iproute2)".into());
    }
    let py = Command::new("python3").args(["-c", "import cyclonedds.domain, numpy"]).output();
    if !py.is_ok_and(|o| o.status.success()) {
        return Some("Python's cyclonedds or numpy is not installed (pip install cyclonedds numpy)".into());
    }
    None
}

/// A domain id of this run's own (the namespace is its own too).
fn domain() -> u16 {
    (std::process::id() % 200 + 10) as u16
}

/// Runs the client, which starts `cosem ros play ARGS`, in a namespace of
/// its own; what the client received.
fn play_to_client(robots: usize, args: &[String]) -> Value {
    let d = domain();
    let mut command = vec![
        "python3".to_string(),
        workspace_root().join("tests/python/ros_client.py").display().to_string(),
        d.to_string(),
        robots.to_string(),
        "1".into(),
        "--".into(),
        cosem_bin().display().to_string(),
        "ros".into(),
        "play".into(),
        "--domain".into(),
        d.to_string(),
    ];
    command.extend(args.iter().cloned());
    let quoted: Vec<String> = command.iter().map(|a| format!("'{}'", a.replace('\'', "'\\''"))).collect();
    let script = format!("{NETNS} && timeout 120 {}", quoted.join(" "));
    let out = Command::new("unshare").args(["-n", "sh", "-c", &script]).output().expect("unshare");
    assert!(out.status.success(), "the client failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("the client's JSON")
}

fn iso(t: &[f64], q: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
    )
}

/// A pose matrix as an isometry (its rotation the nearest one).
fn iso_of(m: &Matrix4<f64>) -> Isometry3<f64> {
    let r = nalgebra::Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Isometry3::from_parts(Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]), UnitQuaternion::from_rotation_matrix(&r))
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// Plays `data` as two robots (frames `a` and `b`) and checks everything
/// the client received against the source.
fn check_play(data: &Path, a: (usize, usize), b: (usize, usize)) {
    let spec = |r: (usize, usize)| format!("{}:{}:{}", data.display(), r.0, r.1);
    let args = vec![
        "--robot".into(),
        spec(a),
        "--robot".into(),
        spec(b),
        "--wait-readers".into(),
        "1".into(),
        "--delay".into(),
        "0.5".into(),
    ];
    let got = play_to_client(2, &args);
    let publisher = &got["publisher"];
    assert_eq!(publisher["code"], 0, "cosem ros play failed: {}", publisher["stderr"]);
    let lines: Vec<Value> =
        publisher["stdout"].as_str().unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let source = Source::open(data, &SourceOptions::default()).unwrap();
    let mut origins = Vec::new();
    for (i, range) in [a, b].into_iter().enumerate() {
        let name = format!("robot_{i}");
        let frames = range.1 - range.0;
        let clouds = got["clouds"][&name].as_array().unwrap();
        // Best effort, but on a quiet veth pair with the readers matched
        // before the first scan: every scan arrives.
        assert_eq!(clouds.len(), frames, "{name}: scans received");
        for c in clouds {
            assert_eq!(c["frame_id"], format!("{name}/velodyne"));
            let fields: Vec<Value> =
                serde_json::from_str(r#"[["x",0,7,1],["y",4,7,1],["z",8,7,1],["label",12,6,1]]"#).unwrap();
            assert_eq!(c["fields"].as_array().unwrap(), &fields);
            let width = c["width"].as_u64().unwrap();
            assert!(width > 1000, "{name}: a scan of {width} points");
            assert_eq!(c["row_step"].as_u64(), Some(16 * width));
            assert_eq!(c["bytes"].as_u64(), Some(16 * width));
            assert!(!c["labels"].as_array().unwrap().is_empty());
        }
        let odom: Vec<&Value> =
            got["tf"].as_array().unwrap().iter().filter(|t| t[0] == format!("{name}/odom")).collect();
        assert_eq!(odom.len(), frames, "{name}: odometry transforms received");
        assert!(odom.iter().all(|t| t[1] == format!("{name}/base_link")));
        let statics = got["tf_static"].as_array().unwrap();
        assert!(
            statics.iter().any(|t| t[0] == format!("{name}/base_link") && t[1] == format!("{name}/velodyne")),
            "{name}: no static transform for a late joiner: {statics:?}"
        );
        // The printed origin is where the odometry frame is in the world:
        // with each odometry pose received, the source's own world pose.
        let line = lines.iter().find(|l| l["robot"] == name).expect("the robot's line");
        let m = f64s(&line["T_world_odom"]);
        let mut world_odom = Matrix4::identity();
        for r in 0..3 {
            for c in 0..4 {
                world_odom[(r, c)] = m[4 * r + c];
            }
        }
        let world_odom = iso_of(&world_odom);
        for (k, t) in odom.iter().enumerate() {
            let got_world = world_odom * iso(&f64s(&t[2]), &f64s(&t[3]));
            let truth = iso_of(&source.world_pose(range.0 + k).unwrap());
            let (e_t, e_r) = cosem_core::geometry::pose_errors(&got_world, &truth);
            assert!(e_t < 1e-3 && e_r < 1e-3, "{name} scan {k}: the world pose is off by {e_t} m, {e_r} deg");
        }
        origins.push(world_odom);
    }
    // Each robot's odometry starts somewhere of its own: the truth between
    // them is not the identity.
    let between = origins[0].inverse() * origins[1];
    assert!(between.translation.vector.norm() > 1.0 || between.rotation.angle() > 0.1);
}

#[test]
fn ros_play_reaches_a_cyclone_dds_client_synthetic() {
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 6, 3);
    check_play(&seq, (0, 3), (3, 6));
}

#[test]
fn ros_play_reaches_a_cyclone_dds_client_kitti() {
    let Some(data) = real_data("kitti00") else { return };
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    check_play(&data, (0, 3), (5, 8));
}

/// Runs `tests/python/ros_robots.py` on `spec` (its domain set here) in a
/// namespace of its own: the robots' drivers on Cyclone DDS, the nodes
/// it starts; what it saw.
fn robots_and_nodes(mut spec: Value, d: u16) -> Value {
    spec["domain"] = d.into();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("spec.json");
    std::fs::write(&path, spec.to_string()).unwrap();
    let script = workspace_root().join("tests/python/ros_robots.py");
    let command = format!("{NETNS} && timeout 180 python3 '{}' '{}'", script.display(), path.display());
    let out = Command::new("unshare").args(["-n", "sh", "-c", &command]).output().expect("unshare");
    assert!(out.status.success(), "the robots' side failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("the robots' side's JSON")
}

/// `cosem ros node` as robot `name` of domain `d`, started at `at` s.
fn node(name: &str, d: u16, at: f64) -> Value {
    let cmd = [cosem_bin().display().to_string(), "ros".into(), "node".into(), "--name".into(), name.into()];
    let cmd: Vec<String> = cmd.into_iter().chain(["--domain".into(), d.to_string()]).collect();
    serde_json::json!({ "cmd": cmd, "at": at })
}

/// A robot driving `frames` of `data` from `at` s.
fn robot(name: &str, data: &Path, frames: &[usize], at: f64) -> Value {
    serde_json::json!({ "name": name, "data": data.display().to_string(), "frames": frames, "at": at })
}

/// The truth `T_a_b` between two robots' odometry frames, from the
/// drivers' origins.
fn truth(got: &Value, a: &str, b: &str) -> Isometry3<f64> {
    let world_odom = |name: &str| {
        let rows = &got["truth"][name];
        let mut m = Matrix4::identity();
        for r in 0..3 {
            let row = f64s(&rows[r]);
            for c in 0..4 {
                m[(r, c)] = row[c];
            }
        }
        iso_of(&m)
    };
    world_odom(a).inverse() * world_odom(b)
}

/// The `/tf` edges between odometry frames received, as (parent, child,
/// `T_parent_child`).
fn edges(got: &Value) -> Vec<(String, String, Isometry3<f64>)> {
    let e = got["edges"].as_array().unwrap();
    e.iter()
        .map(|e| (e[1].as_str().unwrap().into(), e[2].as_str().unwrap().into(), iso(&f64s(&e[3]), &f64s(&e[4]))))
        .collect()
}

/// Every edge into `child`'s odometry frame is within 0.2 m and 0.5 degrees
/// of the truth, its parent a robot named lower; how many there were.
fn check_edges_into(got: &Value, child: &str) -> usize {
    let into: Vec<_> = edges(got).into_iter().filter(|e| e.1 == format!("{child}/odom")).collect();
    for (parent, _, t) in &into {
        let p = parent.trim_end_matches("/odom");
        assert!(p < child, "{child}: a parent named higher: {parent}");
        let (e_t, e_r) = cosem_core::geometry::pose_errors(t, &truth(got, p, child));
        assert!(e_t < 0.2 && e_r < 0.5, "{parent} -> {child}: {e_t:.3} m, {e_r:.3} deg from the truth");
    }
    into.len()
}

/// The last status each robot's `/diagnostics` gave each peer.
fn last_status(got: &Value) -> std::collections::BTreeMap<String, String> {
    let mut last = std::collections::BTreeMap::new();
    for d in got["diagnostics"].as_array().unwrap() {
        last.insert(d[1].as_str().unwrap().to_string(), d[3].as_str().unwrap().to_string());
    }
    last
}

/// The nodes ran until stopped (SIGTERM), none failed on its own, and
/// each stopped cleanly: exit 0, its summary the last line.
fn nodes_ran(got: &Value) -> Vec<String> {
    let nodes = got["nodes"].as_array().unwrap();
    for n in nodes {
        assert_eq!(n["running"], true, "a node ended on its own: {}", n["stderr"]);
        assert_eq!(n["code"], 0, "a node stopped by SIGTERM did not exit cleanly: {}", n["stderr"]);
        assert!(!n["stderr"].as_str().unwrap().contains("panicked"), "{}", n["stderr"]);
        let last = n["stdout"].as_str().unwrap().lines().last().unwrap_or("");
        assert!(last.starts_with("{\"summary\""), "a stopped node's last line is not its summary: {last}");
        // Its counts of estimates are those of the lines it printed.
        let lines: Vec<Value> =
            n["stdout"].as_str().unwrap().lines().filter_map(|l| serde_json::from_str(l).ok()).collect();
        let estimates: Vec<&Value> = lines.iter().filter(|l| l.get("round").is_some()).collect();
        let count = |f: &dyn Fn(&Value) -> bool| estimates.iter().filter(|e| f(e)).count();
        let summary = &lines.last().unwrap()["summary"];
        assert_eq!(summary["schema_version"], 4, "{last}");
        assert_eq!(summary["estimates"], count(&|e| e["confirmation"] == false), "{last}");
        // A confirmation tells a waiting estimate again, `Converged`.
        assert_eq!(summary["converged"], count(&|e| e["status"] == "Converged"), "{last}");
        assert!(estimates.iter().all(|e| e["confirmation"] == false || e["status"] == "Converged"), "{last}");
        assert_eq!(summary["adopted"], count(&|e| e["adopted"] == true), "{last}");
        assert_eq!(summary["contested"], count(&|e| e["contested"] == true), "{last}");
        assert_eq!(summary["walked"], count(&|e| e["walked"] == true), "{last}");
        // A walked estimate is never `Converged`.
        assert!(estimates.iter().all(|e| e["walked"] == false || e["status"] != "Converged"), "{last}");
    }
    nodes.iter().map(|n| n["stderr"].as_str().unwrap().to_string()).collect()
}

/// A class table (`cosem map --classes`) for SemanticKITTI's ids moved
/// by `offset`: each class's own id to it, every other id to unlabeled.
fn offset_class_table(offset: u32) -> String {
    use cosem_core::classes::Class;
    let mut t = String::from("[ids]\n");
    for id in 0..260u16 {
        let class = (0..19u8).filter_map(Class::from_index).find(|c| c.semantic_kitti_id() == id);
        t += &format!("\"{}\" = \"{}\"\n", u32::from(id) + offset, class.map_or("unlabeled", Class::name));
    }
    t
}

/// Two nodes, robot A on kitti00 0:5 and robot B on 5:10, their drivers
/// on Cyclone DDS: they trade maps, find each other, and the `/tf` edge
/// between their odometry frames is within 0.2 m and 0.5 degrees of the
/// truth; each publishes its peer's pose with a covariance. With
/// `odometry`, robot B's motion comes on a `nav_msgs/Odometry` topic, not
/// `/tf`, and its labels are its own ids, read through a class table.
fn two_nodes(data: &Path, a: &[usize], b: &[usize], odometry: bool) -> Value {
    let d = domain() + u16::from(odometry) * 4;
    let mut robot_b = robot("robot_1", data, b, 0.0);
    let mut node_b = node("robot_1", d, 0.0);
    let table = tempfile::NamedTempFile::new().unwrap();
    if odometry {
        robot_b["odometry"] = true.into();
        node_b["cmd"].as_array_mut().unwrap().extend(["--odometry".into(), "/robot_1/odom".into()]);
        // And labels of its own: SemanticKITTI's ids plus 1000, read
        // through a class table.
        robot_b["label_offset"] = 1000.into();
        std::fs::write(table.path(), offset_class_table(1000)).unwrap();
        let classes = ["--classes".into(), table.path().display().to_string()];
        node_b["cmd"].as_array_mut().unwrap().extend(classes.map(Value::from));
    }
    let spec = serde_json::json!({
        "rate": 10, "until": 12,
        "robots": [robot("robot_0", data, a, 0.0), robot_b],
        "nodes": [node("robot_0", d, 0.0), node_b],
    });
    let got = robots_and_nodes(spec, d);
    nodes_ran(&got);
    assert_eq!(got["published"].as_array().unwrap().len(), a.len() + b.len());
    let n = check_edges_into(&got, "robot_1");
    assert!(n > 0, "no /tf edge robot_0/odom -> robot_1/odom: {:?}", last_status(&got));
    let status = last_status(&got);
    for who in ["cosem: robot_0 / robot_1", "cosem: robot_1 / robot_0"] {
        assert_eq!(status.get(who).map(String::as_str), Some("Converged"), "{who}: {status:?}");
    }
    let poses = got["poses"].as_array().unwrap();
    for (a, b) in [("robot_0", "robot_1"), ("robot_1", "robot_0")] {
        let p = poses.iter().rfind(|p| p[1] == a && p[2] == b).unwrap_or_else(|| panic!("no pose of {b} from {a}"));
        assert_eq!(p[3], format!("{a}/odom"));
        let position = f64s(&p[4]);
        let t = truth(&got, a, b).translation.vector;
        assert!((nalgebra::Vector3::new(position[0], position[1], position[2]) - t).norm() < 0.2, "{a}'s pose of {b}");
        let cov = f64s(&p[5]);
        assert!((0..6).all(|i| cov[7 * i].is_finite() && cov[7 * i] > 0.0), "{a}'s covariance of {b}: {cov:?}");
    }
    got
}

#[test]
fn two_nodes_find_each_other_kitti() {
    let Some(data) = real_data("kitti00") else { return };
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    two_nodes(&data, &[0, 1, 2, 3, 4], &[5, 6, 7, 8, 9], false);
}

/// The same on scans the project makes itself, robot B's motion from a
/// `nav_msgs/Odometry` topic and its labels through a class table.
#[test]
fn two_nodes_find_each_other_synthetic_odometry() {
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 16, 3);
    // Robot B's motion from an Odometry topic; ten scans each, so that
    // each node has a figure of its heading walk (8 scans) to send.
    let (a, b): (Vec<usize>, Vec<usize>) = ((0..10).collect(), (6..16).collect());
    let got = two_nodes(&seq, &a, &b, true);
    // Each node's figure reaches its peer with its updates: the last
    // estimates carry both, small (no drift here), and none is walked.
    for n in got["nodes"].as_array().unwrap() {
        let out = n["stdout"].as_str().unwrap();
        let lines: Vec<Value> = out.lines().filter_map(|l| serde_json::from_str(l).ok()).collect();
        let last = lines.iter().rfind(|l| l.get("round").is_some()).unwrap_or_else(|| panic!("no estimate: {out}"));
        for key in ["walk", "walk_peer"] {
            let w = last[key].as_f64().unwrap_or_else(|| panic!("no {key} in the last estimate: {last}"));
            assert!((0.0..f64::from(WALK_LIMIT_DEG)).contains(&w), "{key} {w}: {last}");
        }
        assert_eq!(last["walked"], false, "{last}");
        println!("walk {} walk_peer {}", last["walk"], last["walk_peer"]);
    }
}

/// kitti00-loop's scans 88 and 850, 308 m apart: each node says
/// `NoOverlap`, and `/tf` carries no edge between them. A third robot of
/// another voxel size is refused by name, never matched.
#[test]
fn nodes_far_apart_say_no_overlap_and_tf_stays_silent() {
    let Some(data) = real_data("kitti00-loop") else { return };
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    let d = domain() + 1;
    // And a third robot mapping with 0.7 m voxels: its maps are not
    // matched by the others (the wire names cells, not metres).
    // It follows one peer at most: the other is not followed at all (each
    // peer holds a copy of a map; a node's peers are bounded).
    let mut coarse = node("robot_2", d, 0.0);
    let extra = ["--voxel", "0.7", "--max-peers", "1"];
    coarse["cmd"].as_array_mut().unwrap().extend(extra.map(Value::from));
    let spec = serde_json::json!({
        "rate": 10, "until": 9,
        "robots": [
            robot("robot_0", &data, &[88], 0.0),
            robot("robot_1", &data, &[850], 0.0),
            robot("robot_2", &data, &[52], 0.0),
        ],
        "nodes": [node("robot_0", d, 0.0), node("robot_1", d, 0.0), coarse],
    });
    let got = robots_and_nodes(spec, d);
    let logs = nodes_ran(&got);
    for (i, log) in logs.iter().enumerate().take(2) {
        let why = "robot_2: its map's voxels are 0.7 m, this robot's 0.5 m: not matched";
        assert!(log.contains(why), "node {i} did not refuse the coarse peer: {log}");
    }
    let refused = |who: &str| logs[2].contains(&format!("{who}: its map's voxels are 0.5 m, this robot's 0.7 m"));
    let capped = |who: &str| logs[2].contains(&format!("{who}: not followed: this node follows 1 peer at most"));
    let (zero, one) = (refused("robot_0") && capped("robot_1"), refused("robot_1") && capped("robot_0"));
    assert!(zero ^ one, "robot_2 should follow one peer (refused by its voxels) and drop the other: {}", logs[2]);
    let status = last_status(&got);
    for who in ["cosem: robot_0 / robot_1", "cosem: robot_1 / robot_0"] {
        assert_eq!(status.get(who).map(String::as_str), Some("NoOverlap"), "{who}: {status:?}");
    }
    assert!(edges(&got).is_empty(), "a /tf edge between robots 308 m apart: {:?}", got["edges"]);
    assert!(got["poses"].as_array().unwrap().is_empty());
}

/// A third node, started after the first two have traded maps, catches up
/// from the snapshots and the updates after them and is placed: its `/tf`
/// edge within the same tolerance (its scans read reliably, from a
/// reliable driver). Meanwhile a foreign peer publishes
/// garbage, a truncated update and one of another protocol version, and
/// robot A's driver two scans that lie (more points than data; a field
/// past the point): every node logs each and drops it, none stops.
#[test]
fn a_late_third_node_is_placed_and_bad_input_is_dropped() {
    let Some(data) = real_data("kitti00") else { return };
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    let d = domain() + 2;
    // The third robot's driver publishes reliably, and its node reads so.
    let mut third = robot("robot_2", &data, &[2, 3, 4, 5, 6, 7], 7.0);
    third["reliable"] = true.into();
    let mut third_node = node("robot_2", d, 6.0);
    third_node["cmd"].as_array_mut().unwrap().extend(["--points-qos".into(), "reliable".into()]);
    let spec = serde_json::json!({
        "rate": 10, "until": 16,
        "robots": [
            robot("robot_0", &data, &[0, 1, 2, 3, 4], 0.0),
            robot("robot_1", &data, &[5, 6, 7, 8, 9], 0.0),
            third,
        ],
        "nodes": [node("robot_0", d, 0.0), node("robot_1", d, 0.0), third_node],
        "inject": [
            { "at": 3.0, "kind": "update_garbage" },
            { "at": 3.2, "kind": "update_truncated" },
            { "at": 3.4, "kind": "update_protocol" },
            { "at": 3.6, "kind": "cloud_lies", "robot": 0 },
        ],
    });
    let got = robots_and_nodes(spec, d);
    let logs = nodes_ran(&got);
    assert!(check_edges_into(&got, "robot_1") > 0, "robots 0 and 1 did not find each other");
    assert!(check_edges_into(&got, "robot_2") > 0, "the late node was not placed: {:?}", last_status(&got));
    // The late node's edge came after it started, from maps it caught up on.
    let late = got["edges"].as_array().unwrap().iter().find(|e| e[2] == "robot_2/odom").unwrap();
    assert!(late[0].as_f64().unwrap() > 7.0);
    for (i, log) in logs.iter().enumerate().take(2) {
        let protocol = format!("of protocol 99, not {}", cosem_host::sources::ros_msgs::MAP_UPDATE_PROTOCOL);
        for why in ["a malformed map update (1024 bytes)", "a malformed map update (3 bytes)", protocol.as_str()] {
            assert!(log.contains(why), "node {i} did not log `{why}`: {log}");
        }
    }
    assert!(logs[0].contains("/robot_0/points: data holds"), "{}", logs[0]);
    assert!(logs[0].contains("beyond the point_step"), "{}", logs[0]);
}

/// QoS that cannot match is reported: a best-effort writer of `/tf` (the
/// nodes read it reliably), a volatile writer of `/tf_static` (read
/// transient local) and a transient-local reader of `/diagnostics`
/// (written volatile), each named on every node's log. And a peer that
/// vanishes and comes back (a restart: a new epoch, its scans driven
/// again) is followed: its copy replaced, and placed again.
#[test]
fn qos_mismatches_are_reported_and_a_restarted_peer_is_placed_again() {
    let Some(data) = real_data("kitti00") else { return };
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    let d = domain() + 3;
    let mut again = robot("robot_1", &data, &[5, 6, 7, 8, 9], 11.0);
    again["seed"] = 1.into();
    let mut first = robot("robot_1", &data, &[5, 6, 7, 8, 9], 0.0);
    first["seed"] = 1.into();
    let mut vanishing = node("robot_1", d, 0.0);
    vanishing["stop"] = 6.0.into();
    let spec = serde_json::json!({
        "rate": 10, "until": 19,
        "robots": [robot("robot_0", &data, &[0, 1, 2, 3, 4], 0.0), first, again],
        "nodes": [node("robot_0", d, 0.0), vanishing, node("robot_1", d, 9.0)],
        "inject": [{ "at": 2.0, "kind": "qos" }],
    });
    let got = robots_and_nodes(spec, d);
    let logs = nodes_ran(&got);
    for why in [
        "QoS: /tf: a writer offers best effort where this node's reader asks reliable",
        "QoS: /tf_static: a writer offers volatile where this node's reader asks transient local",
        "QoS: /diagnostics: a reader asks transient local where this node's writer offers volatile",
    ] {
        assert!(logs.iter().all(|l| l.contains(why)), "a node did not report `{why}`: {logs:?}");
    }
    assert!(logs[0].contains("robot_1: restarted"), "robot_0 did not notice robot_1's restart: {}", logs[0]);
    assert!(check_edges_into(&got, "robot_1") > 0);
    let after: Vec<f64> = got["edges"].as_array().unwrap().iter().map(|e| e[0].as_f64().unwrap()).collect();
    assert!(after.iter().any(|&t| t < 6.0), "no edge before robot_1 vanished: {after:?}");
    assert!(after.iter().any(|&t| t > 11.0), "robot_1 was not placed again after its restart: {after:?}");
}

/// A node stopped as a launcher stops it (SIGINT, then in a second run
/// SIGTERM) ends its loop, prints its summary as its last line and exits
/// with success, instead of dying without a word.
#[test]
fn a_node_asked_to_stop_prints_its_summary() {
    if let Some(why) = unavailable() {
        println!("skipped: {why}");
        return;
    }
    for (k, signal) in ["INT", "TERM"].into_iter().enumerate() {
        let d = domain() + 6 + k as u16;
        let command = format!("{NETNS} && exec '{}' ros node --name robot_0 --domain {d}", cosem_bin().display());
        let child = Command::new("unshare")
            .args(["-n", "sh", "-c", &command])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("unshare");
        std::thread::sleep(std::time::Duration::from_secs(3));
        let killed = Command::new("kill").args([&format!("-{signal}"), &child.id().to_string()]).status();
        assert!(killed.is_ok_and(|s| s.success()), "kill -{signal}");
        let started = std::time::Instant::now();
        let out = child.wait_with_output().expect("the node's output");
        assert!(started.elapsed().as_secs() < 10, "SIG{signal}: the node took {:?} to stop", started.elapsed());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "SIG{signal}: the node exited with {:?}: {stderr}", out.status);
        let stdout = String::from_utf8_lossy(&out.stdout);
        let last: Value = serde_json::from_str(stdout.lines().last().unwrap_or("")).expect("a JSON last line");
        assert_eq!(last["summary"]["scans"], 0, "SIG{signal}: {stdout}");
        assert_eq!(last["summary"]["rounds"], 0, "SIG{signal}: {stdout}");
    }
}
