//! `cosem ros` against a ROS 2 client on another DDS stack (Cyclone DDS's
//! Python binding, `tests/python/ros_client.py`), with ROS 2's DDS topic and
//! type names and plain CDR, in a network namespace the test makes itself
//! (`unshare -n`, a veth pair with multicast), never on the machine's
//! interfaces, with a domain id of its own. Where a namespace cannot be
//! made, or Python lacks `cyclonedds`, the test says so and skips.

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
    let py = Command::new("python3").args(["-c", "import cyclonedds.domain"]).output();
    if !py.is_ok_and(|o| o.status.success()) {
        return Some("Python's cyclonedds is not installed (pip install cyclonedds)".into());
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
