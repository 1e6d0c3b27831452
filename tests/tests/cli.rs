//! The CLI end to end on synthetic data: synth -> map -> info -> export.

use cosem_tests::{cosem_ok, synth};
use serde_json::Value;

#[test]
fn synth_map_info_export() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 6, 3);
    for f in ["calib.txt", "poses.txt", "times.txt", "velodyne/000005.bin", "labels/000005.label"] {
        assert!(seq.join(f).exists(), "synth did not write {f}");
    }
    let map = tmp.path().join("a.cmap");
    let s = |p: &std::path::Path| p.display().to_string();
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "0:6:2", "--voxel", "0.25", "-o", &s(&map)]);
    let info: Value = serde_json::from_str(&cosem_ok(&["info", &s(&map), "--json"])).unwrap();
    let voxels = info["voxels"].as_u64().unwrap();
    let bytes = info["bytes"].as_u64().unwrap();
    assert!(voxels > 5_000, "{info}");
    assert_eq!(info["resolution"].as_f64().unwrap(), 0.25);
    assert_eq!(bytes, std::fs::metadata(&map).unwrap().len());
    assert!((info["bytes_per_voxel"].as_f64().unwrap() - bytes as f64 / voxels as f64).abs() < 1e-9);
    assert!(info["memory_bytes_per_voxel"].as_u64().unwrap() <= 32);
    let classes = info["classes"].as_object().unwrap();
    let total: u64 = classes.values().map(|v| v.as_u64().unwrap()).sum();
    assert_eq!(total, voxels);
    for c in ["road", "sidewalk", "building", "vegetation", "trunk", "pole", "car", "terrain"] {
        assert!(classes.get(c).and_then(Value::as_u64).unwrap_or(0) > 0, "no {c} voxel in {info}");
    }
    let ply = tmp.path().join("a.ply");
    cosem_ok(&["export", "ply", &s(&map), "-o", &s(&ply)]);
    let data = std::fs::read(&ply).unwrap();
    let end = data.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8_lossy(&data[..end]);
    assert!(header.contains(&format!("element vertex {voxels}\n")), "{header}");
    assert_eq!(data.len() - end, voxels as usize * 18, "binary body size");
}

#[test]
fn synth_is_deterministic() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    synth(&a, 2, 7);
    synth(&b, 2, 7);
    synth(&c, 2, 8);
    for f in ["velodyne/000001.bin", "labels/000001.label", "poses.txt"] {
        assert_eq!(std::fs::read(a.join(f)).unwrap(), std::fs::read(b.join(f)).unwrap(), "{f} differs for one seed");
    }
    assert_ne!(
        std::fs::read(a.join("velodyne/000001.bin")).unwrap(),
        std::fs::read(c.join("velodyne/000001.bin")).unwrap()
    );
}

#[test]
fn demo_runs_on_built_in_data() {
    let out = cosem_ok(&["demo", "--frames", "8"]);
    assert!(out.contains("robot A (model)") && out.contains("robot B (scene)"), "{out}");
    assert!(out.contains("ground truth T_A_B"), "{out}");
    // The ground truth overlap of two halves of one drive is substantial.
    let line = out.lines().find(|l| l.starts_with("overlap of B in A")).unwrap();
    let pct: f64 = line.split_whitespace().nth(5).unwrap().trim_end_matches('%').parse().unwrap();
    assert!(pct > 40.0, "{line}");
}

#[test]
fn bench_map_prints_numbers() {
    let out = cosem_ok(&["bench", "map", "--repeat", "1", "--frames", "0:2"]);
    assert!(out.contains("M points/s") && out.contains("memory per voxel"), "{out}");
}

/// `cosem bench --json FILE` writes the figures it printed (what
/// docs/results.sh reads): the map's voxels and file size agree with
/// `cosem map`'s, and a clean simulated line delivers both maps.
#[test]
fn bench_writes_its_figures_as_json() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 10, 4);
    let s = |p: &std::path::Path| p.display().to_string();
    let read =
        |p: &std::path::Path| -> serde_json::Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
    let (map_json, link_json, cmap) = (tmp.path().join("m.json"), tmp.path().join("l.json"), tmp.path().join("a.cmap"));
    let out =
        cosem_ok(&["bench", "map", "--data", &s(&seq), "--frames", "0:3", "--repeat", "1", "--json", &s(&map_json)]);
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "0:3", "-o", &s(&cmap)]);
    let (_, map) = cosem_host::maps::cmap::read(&cmap).unwrap();
    let m = read(&map_json);
    assert_eq!(m["voxels"].as_u64(), Some(map.len() as u64), "{m}");
    assert!(out.contains(&format!("({} bytes)", m["file_bytes"])), "{out}\n{m}");
    cosem_ok(&["bench", "link", "--data", &s(&seq), "--seeds", "1", "--error-rates", "0", "--json", &s(&link_json)]);
    let l = read(&link_json);
    assert_eq!(l[0]["delivered"], serde_json::json!([1, 1]), "{l}");
    assert!(l[0]["goodput"].as_f64().unwrap() > 0.5, "{l}");
}

/// A user's scans as PCD or PLY files with their poses (`cosem export
/// scans` writes a folder's) give the folder's map, to the voxel; on the
/// synthetic street and, where present, on real KITTI scans.
#[test]
fn scans_as_pcd_or_ply_files_give_the_folders_map() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 4, 2);
    let mut folders = vec![(seq, "0:4")];
    if let Some(kitti) = cosem_tests::real_data("kitti00") {
        folders.push((kitti, "3:6"));
    }
    let s = |p: &std::path::Path| p.display().to_string();
    for (k, (data, frames)) in folders.iter().enumerate() {
        let want = tmp.path().join(format!("{k}.cmap"));
        cosem_ok(&["map", "--data", &s(data), "--frames", frames, "--voxel", "0.3", "-o", &s(&want)]);
        let (_, want) = cosem_host::maps::cmap::read(&want).unwrap();
        for format in ["pcd", "ply"] {
            let out = tmp.path().join(format!("{k}-{format}"));
            cosem_ok(&["export", "scans", "--data", &s(data), "--frames", frames, "--format", format, "-o", &s(&out)]);
            let mut files: Vec<String> = std::fs::read_dir(&out)
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|x| x == format))
                .map(|p| s(&p))
                .collect();
            files.sort();
            let got = tmp.path().join(format!("{k}-{format}.cmap"));
            let poses = s(&out.join("poses.txt"));
            let mut args = vec!["map", "--format", format, "--poses", &poses, "--voxel", "0.3"];
            args.extend(files.iter().map(String::as_str));
            let got_s = s(&got);
            args.extend(["-o", &got_s]);
            cosem_ok(&args);
            let (_, got) = cosem_host::maps::cmap::read(&got).unwrap();
            assert!(want.len() > 1000, "{}", want.len());
            assert_eq!(got.voxels(), want.voxels(), "{} {frames} as {format}", data.display());
        }
    }
    // Inputs are never written over; a missing pose is a named error.
    let out = tmp.path().join("0-pcd");
    let first = s(&out.join("000000.pcd"));
    let err = cosem_tests::cosem_err(&[
        "map",
        "--format",
        "pcd",
        &first,
        "--poses",
        &s(&out.join("poses.txt")),
        "-o",
        &first,
    ]);
    assert!(err.contains("input"), "{err}");
    let short = tmp.path().join("short.txt");
    std::fs::write(&short, "").unwrap();
    let err = cosem_tests::cosem_err(&[
        "map",
        "--format",
        "pcd",
        &first,
        "--poses",
        &s(&short),
        "-o",
        &s(&tmp.path().join("x.cmap")),
    ]);
    assert!(err.contains("short.txt") && err.contains("0 poses for 1 scans"), "{err}");
}

/// A class table read by every reader: SemanticKITTI's own ids named in a
/// table give the folder's map (from the folder and from PCD files); a
/// table that keeps two classes maps only those; an id the table does not
/// name is an error naming the scan, the point and the id.
#[test]
fn a_class_table_maps_a_users_ids_in_every_reader() {
    use cosem_core::classes::{Class, MovingObjects};
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 3, 4);
    let s = |p: &std::path::Path| p.display().to_string();
    let ids: Vec<u32> = (0..=259).filter(|&id| Class::is_semantic_kitti_id(id)).collect();
    let table = |keep: &dyn Fn(Class) -> bool| {
        let mut t = String::from("# SemanticKITTI's ids\n[ids]\n");
        for &id in &ids {
            let name = Class::from_semantic_kitti(id, MovingObjects::Skip)
                .filter(|&c| keep(c))
                .map_or("unlabeled", Class::name);
            t.push_str(&format!("{id} = \"{name}\"\n"));
        }
        t
    };
    let (same, two) = (tmp.path().join("same.toml"), tmp.path().join("two.toml"));
    std::fs::write(&same, table(&|_| true)).unwrap();
    std::fs::write(&two, table(&|c| c == Class::Road || c == Class::Building)).unwrap();
    let map = |extra: &[&str], out: &str| {
        let out = tmp.path().join(out);
        let mut args = vec!["map", "--voxel", "0.3"];
        args.extend_from_slice(extra);
        let o = s(&out);
        args.extend(["-o", &o]);
        cosem_ok(&args);
        cosem_host::maps::cmap::read(&out).unwrap().1
    };
    let (seq_s, same_s, two_s) = (s(&seq), s(&same), s(&two));
    let want = map(&["--data", &seq_s, "--frames", "0:3"], "want.cmap");
    assert_eq!(map(&["--data", &seq_s, "--frames", "0:3", "--classes", &same_s], "a.cmap").voxels(), want.voxels());
    let scans = tmp.path().join("scans");
    cosem_ok(&["export", "scans", "--data", &seq_s, "--frames", "0:3", "--format", "pcd", "-o", &s(&scans)]);
    let files: Vec<String> = (0..3).map(|i| s(&scans.join(format!("{i:06}.pcd")))).collect();
    let poses = s(&scans.join("poses.txt"));
    let mut args = vec!["--format", "pcd", "--poses", &poses, "--classes", &same_s];
    args.extend(files.iter().map(String::as_str));
    assert_eq!(map(&args, "b.cmap").voxels(), want.voxels());
    let kept = map(&["--data", &seq_s, "--frames", "0:3", "--classes", &two_s], "c.cmap");
    let classes: std::collections::BTreeSet<_> = kept.iter().filter_map(|v| v.class()).collect();
    assert_eq!(classes.into_iter().collect::<Vec<_>>(), vec![Class::Road, Class::Building]);
    // Without the road's id: every reader names the scan, point and id.
    let road = Class::Road.semantic_kitti_id();
    let partial = tmp.path().join("partial.toml");
    let text: String =
        table(&|_| true).lines().filter(|l| !l.starts_with(&format!("{road} ="))).map(|l| format!("{l}\n")).collect();
    std::fs::write(&partial, text).unwrap();
    let partial_s = s(&partial);
    let o = s(&tmp.path().join("d.cmap"));
    let err = cosem_tests::cosem_err(&["map", "--data", &seq_s, "--frames", "0:3", "--classes", &partial_s, "-o", &o]);
    assert!(err.contains(&format!("label id {road} is not in the class table")) && err.contains("frame 0"), "{err}");
    let mut args = vec!["map", "--format", "pcd", "--poses", &poses, "--classes", &partial_s, "-o", &o];
    args.extend(files.iter().map(String::as_str));
    let err = cosem_tests::cosem_err(&args);
    assert!(err.contains("000000.pcd: point") && err.contains(&format!("label id {road}")), "{err}");
}

/// A ROS 2 recording (MCAP: PointCloud2 scans, poses on /tf, zstd chunks)
/// written from a folder's scans gives the folder's map (`cosem export mcap`
/// then `cosem map --mcap`): the same voxel count to 1% and nearly every
/// voxel the same (the pose travels as a quaternion, not the folder's
/// matrix); a recording without the asked frames or topic is a named error.
#[test]
fn a_ros2_recording_gives_the_folders_map() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 4, 6);
    let mut folders = vec![(seq, "0:4")];
    if let Some(kitti) = cosem_tests::real_data("kitti00") {
        folders.push((kitti, "0:5"));
    }
    let s = |p: &std::path::Path| p.display().to_string();
    for (k, (data, frames)) in folders.iter().enumerate() {
        let want = tmp.path().join(format!("{k}.cmap"));
        cosem_ok(&["map", "--data", &s(data), "--frames", frames, "--voxel", "0.5", "-o", &s(&want)]);
        let (_, want) = cosem_host::maps::cmap::read(&want).unwrap();
        let bag = tmp.path().join(format!("{k}.mcap"));
        cosem_ok(&["export", "mcap", "--data", &s(data), "--frames", frames, "-o", &s(&bag)]);
        let n = frames.split(':').nth(1).unwrap().parse::<usize>().unwrap()
            - frames.split(':').next().unwrap().parse::<usize>().unwrap();
        let got = tmp.path().join(format!("{k}-bag.cmap"));
        cosem_ok(&["map", "--mcap", &s(&bag), "--frames", &format!("0:{n}"), "--voxel", "0.5", "-o", &s(&got)]);
        let (_, got) = cosem_host::maps::cmap::read(&got).unwrap();
        // Without --frames: every scan of the topic, the same map.
        let all = tmp.path().join(format!("{k}-all.cmap"));
        cosem_ok(&["map", "--mcap", &s(&bag), "--voxel", "0.5", "-o", &s(&all)]);
        assert_eq!(cosem_host::maps::cmap::read(&all).unwrap().1.voxels(), got.voxels());
        let (a, b) = (want.len() as f64, got.len() as f64);
        assert!((a - b).abs() <= 0.01 * a, "{} voxels from the folder, {} from the recording", a, b);
        let same = got.iter().filter(|v| want.get(v.key).is_some_and(|w| w.class() == v.class())).count();
        assert!(same as f64 >= 0.99 * a, "{same} of {a} voxels the same");
        eprintln!("{}: {} voxels from the folder, {} from the recording, {same} the same", data.display(), a, b);
    }
    let bag = s(&tmp.path().join("0.mcap"));
    let out = s(&tmp.path().join("x.cmap"));
    let err = cosem_tests::cosem_err(&["map", "--mcap", &bag, "--frames", "0:9", "-o", &out]);
    assert!(err.contains("4 messages") && err.contains("0:9"), "{err}");
    let err = cosem_tests::cosem_err(&["map", "--mcap", &bag, "--frames", "0:2", "--pose-frame", "map", "-o", &out]);
    assert!(err.contains("no chain") && err.contains("`map`"), "{err}");
}

/// A recording written by the Python `mcap` and `mcap-ros2-support` writers
/// (a client cosem did not write; zstd chunks, their default, and lz4), with
/// the LiDAR's pose on a chain of /tf_static and /tf transforms, or of
/// /tf_static and /odom odometry (`tests/python/write_recording.py`), gives
/// the folder's map. Skipped,
/// saying why, where Python or those packages are missing (`tests/run`
/// installs them).
#[test]
fn a_recording_written_by_the_python_writers_gives_the_folders_map() {
    let root = cosem_tests::workspace_root();
    let script = root.join("tests/python/write_recording.py");
    let have = std::process::Command::new("python3")
        .args(["-c", "import mcap, mcap_ros2.writer"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !have {
        eprintln!("skipped: python3 with the mcap and mcap-ros2-support packages is missing (pip install mcap mcap-ros2-support)");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 4, 8);
    let mut folders = vec![(seq, "0:4", 4)];
    if let Some(kitti) = cosem_tests::real_data("kitti00") {
        folders.push((kitti, "0:5", 5));
    }
    let s = |p: &std::path::Path| p.display().to_string();
    for (k, (data, frames, n)) in folders.iter().enumerate() {
        let want = tmp.path().join(format!("{k}.cmap"));
        cosem_ok(&["map", "--data", &s(data), "--frames", frames, "--voxel", "0.5", "-o", &s(&want)]);
        let (_, want) = cosem_host::maps::cmap::read(&want).unwrap();
        let scans = tmp.path().join(format!("scans{k}"));
        cosem_ok(&["export", "scans", "--data", &s(data), "--frames", frames, "--format", "pcd", "-o", &s(&scans)]);
        for (compression, odom) in [("zstd", false), ("lz4", false), ("zstd", true)] {
            let bag = tmp.path().join(format!("{k}-{compression}-{odom}.mcap"));
            let mut py = vec![s(&script), s(&scans), s(&bag), compression.into()];
            if odom {
                py.push("odom".into());
            }
            let out = std::process::Command::new("python3").args(&py).output().unwrap();
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            let got = tmp.path().join(format!("{k}-{compression}-{odom}.cmap"));
            let frames = format!("0:{n}");
            let (bag_s, got_s) = (s(&bag), s(&got));
            let mut args = vec!["map", "--mcap", &bag_s, "--points", "/velodyne_points", "--frames", &frames];
            args.extend(["--voxel", "0.5"]);
            if odom {
                // Without the odometry the chain breaks at base_link.
                let err = cosem_tests::cosem_err(&[&args[..], &["-o", &got_s]].concat());
                assert!(err.contains("no chain"), "{err}");
                args.extend(["--odom", "/odom"]);
            }
            args.extend(["-o", &got_s]);
            cosem_ok(&args);
            let (_, got) = cosem_host::maps::cmap::read(&got).unwrap();
            let (a, b) = (want.len() as f64, got.len() as f64);
            assert!((a - b).abs() <= 0.01 * a, "{compression}: {a} voxels from the folder, {b} from the recording");
            let same = got.iter().filter(|v| want.get(v.key).is_some_and(|w| w.class() == v.class())).count();
            assert!(same as f64 >= 0.99 * a, "{compression}: {same} of {a} voxels the same");
            eprintln!(
                "{} {compression} odom {odom}: {a} voxels from the folder, {b} from the Python recording, {same} the same",
                data.display()
            );
        }
    }
}

/// `cosem match --mcap-out` writes the match as a ROS 2 recording: both
/// maps as PointCloud2 (read back by `cosem map --mcap` they are the maps
/// again), the transform on /tf and the result on /cosem/status; where the
/// Python `mcap-ros2-support` decoder is present, it reads every message.
#[test]
fn a_match_is_written_as_a_recording_to_view() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 6, 9);
    let s = |p: &std::path::Path| p.display().to_string();
    let (a, b, bag) = (tmp.path().join("a.cmap"), tmp.path().join("b.cmap"), tmp.path().join("m.mcap"));
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "0:3", "--voxel", "0.5", "-o", &s(&a)]);
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "3:6", "--voxel", "0.5", "-o", &s(&b)]);
    let out = cosem_tests::cosem(&["match", &s(&a), &s(&b), "--mcap-out", &s(&bag)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (_, scene) = cosem_host::maps::cmap::read(&b).unwrap();
    let back = tmp.path().join("back.cmap");
    let args = ["map", "--mcap", &s(&bag), "--points", "/cosem/scene", "--frames", "0:1", "--pose-frame", "model"];
    cosem_ok(&[&args[..], &["--voxel", "0.5", "-o", &s(&back)]].concat());
    let (_, back) = cosem_host::maps::cmap::read(&back).unwrap();
    assert_eq!(back.len(), scene.len());
    let err = cosem_tests::cosem_err(&["match", &s(&a), &s(&b), "--mcap-out", &s(&a)]);
    assert!(err.contains("input"), "{err}");
    let py = "import sys, json\nfrom mcap.reader import make_reader\nfrom mcap_ros2.decoder import DecoderFactory\n\
              r = make_reader(open(sys.argv[1], 'rb'), decoder_factories=[DecoderFactory()])\n\
              seen = {}\nfor schema, channel, message, ros in r.iter_decoded_messages():\n    seen[channel.topic] = ros\n\
              print(json.loads(seen['/cosem/status'].data)['status'], seen['/cosem/scene'].width, seen['/tf'].transforms[0].child_frame_id)\n";
    if let Some(text) = cosem_tests::python_or_skip(py, &[&s(&bag)]) {
        assert_eq!(text.trim(), format!("Converged {} scene", scene.len()), "{text}");
    }
}

/// Every command that reads scans takes a recording or a folder of scan
/// files where it takes a SemanticKITTI folder: the same scans give the
/// same evaluation (PLY files: to the bit; a recording, whose poses are
/// quaternions, the same verdicts), and a team on one recording is placed
/// against the recording's own poses.
#[test]
fn eval_and_team_read_recordings_and_scan_files_as_folders() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 10, 12);
    let s = |p: &std::path::Path| p.display().to_string();
    let (scans, bag) = (tmp.path().join("scans"), tmp.path().join("r.mcap"));
    cosem_ok(&["export", "scans", "--data", &s(&seq), "--frames", "0:10", "--format", "ply", "-o", &s(&scans)]);
    cosem_ok(&["export", "mcap", "--data", &s(&seq), "--frames", "0:10", "-o", &s(&bag)]);
    let eval = |data: &std::path::Path, k: usize| -> serde_json::Value {
        let json = tmp.path().join(format!("e{k}.json"));
        let args = ["eval", "--data", &s(data), "--a", "0:5", "--b", "5:10", "--voxel", "0.5", "--grid", "corners"];
        let mut args = args.to_vec();
        let j = s(&json);
        args.extend(["--json", &j]);
        cosem_ok(&args);
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap()
    };
    let (folder, files, recording) = (eval(&seq, 0), eval(&scans, 1), eval(&bag, 2));
    // Everything but the times.
    let untimed = |v: &serde_json::Value| -> Vec<serde_json::Value> {
        let mut r = v["results"].as_array().unwrap().clone();
        r.iter_mut().for_each(|x| drop(x.as_object_mut().unwrap().remove("time_ms")));
        r
    };
    assert_eq!(untimed(&folder), untimed(&files));
    assert_eq!(folder["ground_truth"], files["ground_truth"]);
    let rate = |v: &serde_json::Value| v["methods"]["cosem"]["success_strict"].as_f64().unwrap();
    assert_eq!(rate(&folder), 1.0, "{}", folder["methods"]);
    assert_eq!(rate(&recording), rate(&folder), "{}", recording["methods"]);
    let (a, b) = (folder["maps"]["b_voxels"].as_f64().unwrap(), recording["maps"]["b_voxels"].as_f64().unwrap());
    assert!((a - b).abs() <= 0.01 * a, "{a} vs {b} voxels");
    // A team of two robots cut from one recording: the truth is its poses.
    let (r0, r1) = (format!("{}:0:5", s(&bag)), format!("{}:5:10", s(&bag)));
    let out = cosem_tests::cosem(&["team", "--robot", &r0, "--robot", &r1, "--voxel", "0.5", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let r = &v["robots"][1];
    assert_eq!(r["placed"], true, "{v}");
    assert!(r["e_t"].as_f64().unwrap() < 0.2 && r["e_r"].as_f64().unwrap() < 0.5, "{r}");
}
