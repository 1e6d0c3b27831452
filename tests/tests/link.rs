//! Two `cosem link` processes exchange maps over 127.0.0.1; each must print
//! the transform `cosem match` gives on the same two map files.

use cosem_tests::{cosem_bin, cosem_ok, real_data, synth, workspace_root};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

fn transform(v: &Value) -> Vec<f64> {
    v["transform"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// Starts `cosem` in the background with its output piped.
fn spawn(args: &[&str]) -> std::process::Child {
    Command::new(cosem_bin())
        .args(args)
        .current_dir(workspace_root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The first line a background `cosem` writes to stderr.
fn first_line(child: &mut std::process::Child) -> String {
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    line
}

fn exchange(a: &Path, b: &Path) {
    let (sa, sb) = (a.display().to_string(), b.display().to_string());
    let mut listener = spawn(&["link", "--map", &sa, "--listen", "0", "--json"]);
    // The listener says where it listens.
    let line = first_line(&mut listener);
    let addr = line.trim().strip_prefix("listening on ").unwrap_or_else(|| panic!("listener said: {line}")).to_string();
    let client = cosem_tests::cosem(&["link", "--map", &sb, "--tcp", &addr, "--json"]);
    let client: Value = serde_json::from_slice(&client.stdout).unwrap();
    let out = listener.wait_with_output().unwrap();
    let server: Value = serde_json::from_str(&String::from_utf8_lossy(&out.stdout)).unwrap();
    // The exit code says the match's status (0: Converged, 5: NoOverlap, ...).
    let code = |v: &Value| match v["match"]["status"].as_str() {
        Some("Converged") => Some(0),
        Some("NotConverged") => Some(3),
        Some("Degenerate") => Some(4),
        Some("NoOverlap") => Some(5),
        _ => None,
    };
    assert_eq!(out.status.code(), code(&server), "listener: {server}");
    // Robot 0 holds A and matched B against it; robot 1 the other way.
    let json = |args: &[&str]| -> Value { serde_json::from_slice(&cosem_tests::cosem(args).stdout).unwrap() };
    let (ab, ba) = (json(&["match", &sa, &sb, "--json"]), json(&["match", &sb, &sa, "--json"]));
    assert_eq!(transform(&server["match"]), transform(&ab));
    assert_eq!(transform(&client["match"]), transform(&ba));
    assert_eq!(server["match"]["status"], ab["status"]);
    let info = |p: &str| -> Value { serde_json::from_str(&cosem_ok(&["info", p, "--json"])).unwrap() };
    assert_eq!(server["voxels_received"], info(&sb)["voxels"]);
    assert_eq!(client["voxels_received"], info(&sa)["voxels"]);
    for v in [&server, &client] {
        for k in ["bytes_sent", "bytes_received", "frames", "retransmissions", "wire_bytes_per_voxel"] {
            assert!(v[k].as_f64().is_some(), "{k} missing: {v}");
        }
        assert!(v["wire_bytes_per_voxel"].as_f64().unwrap() <= 4.0);
    }
}

#[test]
fn two_link_processes_agree_with_match_on_synthetic_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 8, 13);
    let (a, b) = (tmp.path().join("a.cmap"), tmp.path().join("b.cmap"));
    for (m, f) in [(&a, "0:4"), (&b, "4:8")] {
        cosem_ok(&["map", "--data", &seq.display().to_string(), "--frames", f, "-o", &m.display().to_string()]);
    }
    exchange(&a, &b);
}

#[test]
fn two_link_processes_exchange_the_kitti00_maps() {
    let Some(dir) = real_data("kitti00") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a.cmap"), tmp.path().join("b.cmap"));
    for (m, f) in [(&a, "0:5"), (&b, "5:10")] {
        cosem_ok(&["map", "--data", &dir.display().to_string(), "--frames", f, "-o", &m.display().to_string()]);
    }
    exchange(&a, &b);
}

#[test]
fn link_without_a_peer_is_a_clean_error() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 2, 13);
    let a = tmp.path().join("a.cmap");
    cosem_ok(&["map", "--data", &seq.display().to_string(), "--frames", "0:2", "-o", &a.display().to_string()]);
    // Nobody listens on this port: the connection is refused after retrying.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    drop(listener);
    let e = cosem_tests::cosem_err(&[
        "link",
        "--map",
        &a.display().to_string(),
        "--tcp",
        &format!("127.0.0.1:{port}"),
        "--connect-timeout",
        "0.5",
    ]);
    assert!(e.contains(&format!("127.0.0.1:{port}")), "{e}");
}

/// Two `cosem link` processes through `cosem relay`, which paces each
/// direction to 115200 baud and flips, drops or duplicates 1% of the bytes
/// (seeded), with robot-sized maps (0.5 m voxels): both maps arrive whole
/// (the count each received is what the other sent) and each match equals
/// `cosem match` on the same files. Checks delivery and results, never times.
#[test]
fn two_link_processes_through_a_lossy_relay() {
    through_relay(&["--error-rate", "0.01", "--seed", "5"]);
}

/// The same through `cosem relay --mix`: 2% of the bytes substituted by
/// another value, dropped or duplicated in equal shares (issue 32's mix).
#[test]
fn two_link_processes_through_a_relay_that_substitutes_drops_and_duplicates() {
    through_relay(&["--error-rate", "0.02", "--mix", "byte=1,drop=1,dup=1", "--seed", "6"]);
}

fn through_relay(damage: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 2, 17);
    let (a, b) = (tmp.path().join("a.cmap"), tmp.path().join("b.cmap"));
    for (m, f) in [(&a, "0:1"), (&b, "1:2")] {
        let (d, o) = (seq.display().to_string(), m.display().to_string());
        cosem_ok(&["map", "--data", &d, "--frames", f, "--voxel", "0.5", "--max-range", "25", "-o", &o]);
    }
    let mut relay = spawn(&[&["relay", "--baud", "115200"][..], damage].concat());
    let line = first_line(&mut relay);
    let addrs: Vec<String> = line.trim().strip_prefix("relay on ").unwrap().split(' ').map(str::to_string).collect();
    let (sa, sb) = (a.display().to_string(), b.display().to_string());
    let link = |map: &str, addr: &str, id: &str| {
        spawn(&[
            "link",
            "--map",
            map,
            "--tcp",
            addr,
            "--robot-id",
            id,
            "--baud",
            "115200",
            "--json",
            "--deadline",
            "300",
        ])
    };
    let (p0, p1) = (link(&sa, &addrs[0], "0"), link(&sb, &addrs[1], "1"));
    let (o0, o1) = (p0.wait_with_output().unwrap(), p1.wait_with_output().unwrap());
    let parse = |o: &std::process::Output| -> Value {
        serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&o.stderr)))
    };
    let (r0, r1) = (parse(&o0), parse(&o1));
    let _ = relay.wait();
    assert_eq!(r0["voxels_received"], r1["voxels_sent"], "{r0}");
    assert_eq!(r1["voxels_received"], r0["voxels_sent"], "{r1}");
    let json = |args: &[&str]| -> Value { serde_json::from_slice(&cosem_tests::cosem(args).stdout).unwrap() };
    assert_eq!(transform(&r0["match"]), transform(&json(&["match", &sa, &sb, "--json"])));
    assert_eq!(transform(&r1["match"]), transform(&json(&["match", &sb, &sa, "--json"])));
    assert!(
        r0["retransmissions"].as_u64().unwrap() + r1["retransmissions"].as_u64().unwrap() > 0,
        "no error hit the line"
    );
}

/// `--listen` gives up when no peer comes, naming the wait.
#[test]
fn listen_without_a_peer_gives_up() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 2, 13);
    let a = tmp.path().join("a.cmap");
    cosem_ok(&["map", "--data", &seq.display().to_string(), "--frames", "0:2", "-o", &a.display().to_string()]);
    let e = cosem_tests::cosem_err(&[
        "link",
        "--map",
        &a.display().to_string(),
        "--listen",
        "0",
        "--accept-timeout",
        "0.5",
    ]);
    assert!(e.contains("no peer connected"), "{e}");
}

/// The seeded line simulation on robot-sized maps (a synthetic street, 0.5 m
/// voxels, thousands of voxels each way), both maps at once at 115200 baud,
/// bytes substituted, dropped and duplicated alike: at 1%, 5% and 20% byte
/// errors every seed delivers both maps whole, and so does a half-duplex
/// line at 5%.
#[test]
fn robot_sized_maps_cross_a_five_percent_line_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 10, 23);
    let spec = cosem_host::evaluation::pair::PairSpec::new(&seq, "0:5".parse().unwrap(), "5:10".parse().unwrap(), 0.5);
    let pair = cosem_host::evaluation::pair::Pair::load(&spec).unwrap();
    assert!(pair.map_a.len() > 3000 && pair.map_b.len() > 3000, "{} {}", pair.map_a.len(), pair.map_b.len());
    for (rate, seeds) in [(0.01, 1..=1), (0.05, 1..=2), (0.2, 1..=1)] {
        for seed in seeds {
            let run =
                cosem_host::evaluation::bench::link(&pair, (rate, cosem_core::sim::Mix::THIRDS, false), 115_200, seed)
                    .unwrap();
            assert!(run.delivered, "rate {rate} seed {seed}: {run:?}");
            assert!(run.retransmissions[0] + run.retransmissions[1] > 0, "no error hit the line");
        }
    }
    // One medium for both directions: the maps in turns, bursts of frames.
    let run =
        cosem_host::evaluation::bench::link(&pair, (0.05, cosem_core::sim::Mix::THIRDS, true), 115_200, 1).unwrap();
    assert!(run.delivered, "half duplex: {run:?}");
}
