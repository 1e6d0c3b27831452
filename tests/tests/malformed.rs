//! Every malformed input gets an error naming the file and what is wrong.

use cosem_tests::{cosem_err, synth};
use std::fs;
use std::path::Path;

fn fresh(tmp: &Path) -> std::path::PathBuf {
    let seq = tmp.join("seq");
    synth(&seq, 3, 5);
    seq
}

fn map_err(seq: &Path, frames: &str) -> String {
    let out = seq.parent().unwrap().join("out.cmap");
    cosem_err(&["map", "--data", &seq.display().to_string(), "--frames", frames, "-o", &out.display().to_string()])
}

#[test]
fn scan_size_not_a_multiple_of_16() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let f = seq.join("velodyne/000001.bin");
    let mut b = fs::read(&f).unwrap();
    b.truncate(b.len() - 5);
    fs::write(&f, b).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("000001.bin") && e.contains("multiple of 16"), "{e}");
}

#[test]
fn label_count_differs_from_scan() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let f = seq.join("labels/000002.label");
    let mut b = fs::read(&f).unwrap();
    b.truncate(b.len() - 8);
    fs::write(&f, b).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("000002.label") && e.contains("labels for"), "{e}");
}

#[test]
fn missing_pose_line() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let poses = fs::read_to_string(seq.join("poses.txt")).unwrap();
    fs::write(seq.join("poses.txt"), poses.lines().next().unwrap()).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("poses.txt") && e.contains("frame 1"), "{e}");
}

#[test]
fn malformed_pose_line() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let poses = fs::read_to_string(seq.join("poses.txt")).unwrap();
    fs::write(seq.join("poses.txt"), poses.replacen(' ', " x ", 1)).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("poses.txt:1") && e.contains("not a number"), "{e}");
}

#[test]
fn calib_without_tr() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let calib = fs::read_to_string(seq.join("calib.txt")).unwrap();
    let kept: Vec<&str> = calib.lines().filter(|l| !l.starts_with("Tr:")).collect();
    fs::write(seq.join("calib.txt"), kept.join("\n")).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("calib.txt") && e.contains("Tr"), "{e}");
}

#[test]
fn missing_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    fs::remove_file(seq.join("velodyne/000002.bin")).unwrap();
    let e = map_err(&seq, "0:3");
    assert!(e.contains("000002.bin") && e.contains("frame 2 is missing"), "{e}");
    // Beyond the end of the sequence: no pose and no scan.
    let e = map_err(&seq, "0:9");
    assert!(e.contains("poses.txt") || e.contains("missing"), "{e}");
}

#[test]
fn non_finite_coordinate_names_the_byte_offset() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let f = seq.join("velodyne/000000.bin");
    let mut b = fs::read(&f).unwrap();
    b[16 * 10 + 4..16 * 10 + 8].copy_from_slice(&f32::NAN.to_le_bytes());
    fs::write(&f, b).unwrap();
    let e = map_err(&seq, "0:1");
    assert!(e.contains("000000.bin") && e.contains("byte offset 164"), "{e}");
}

#[test]
fn bad_frame_range() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    for r in ["3:1", "1", "0:3:0", "a:b"] {
        let out = cosem_tests::cosem(&["map", "--data", &seq.display().to_string(), "--frames", r, "-o", "/dev/null"]);
        assert!(!out.status.success());
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(e.contains("START:END"), "{r}: {e}");
    }
}

#[test]
fn corrupted_map_file() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let map = tmp.path().join("robot.cmap");
    cosem_tests::cosem_ok(&[
        "map",
        "--data",
        &seq.display().to_string(),
        "--frames",
        "0:1",
        "-o",
        &map.display().to_string(),
    ]);
    let mut b = fs::read(&map).unwrap();
    let mid = b.len() / 2;
    b[mid] ^= 0x40;
    fs::write(&map, &b).unwrap();
    let e = cosem_err(&["info", &map.display().to_string()]);
    assert!(e.contains("robot.cmap") && e.contains("checksum"), "{e}");
    fs::write(&map, &b[..20]).unwrap();
    let e = cosem_err(&["info", &map.display().to_string()]);
    assert!(e.contains("robot.cmap") && e.contains("truncated"), "{e}");
    // Cut anywhere in the chunks: truncated, with where.
    fs::write(&map, &b[..mid]).unwrap();
    let e = cosem_err(&["info", &map.display().to_string()]);
    assert!(e.contains("robot.cmap") && e.contains("truncated") && e.contains("byte offset"), "{e}");
    fs::write(&map, b"not a map").unwrap();
    let e = cosem_err(&["info", &map.display().to_string()]);
    assert!(e.contains("robot.cmap") && e.contains("magic"), "{e}");
}

/// Numbers that make no map or no run are usage errors, not panics or empty
/// results: a NaN or zero range, a NaN timeout, a huge timeout.
#[test]
fn nonsense_numbers_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let (d, o) = (seq.display().to_string(), tmp.path().join("m.cmap").display().to_string());
    for r in ["0", "-5", "NaN", "inf"] {
        cosem_tests::cosem_usage_err(&["map", "--data", &d, "--frames", "0:1", "--max-range", r, "-o", &o]);
    }
    // One voxel range for every command: what map writes, match takes.
    let (ra, rb) = (format!("{d}:0:1"), format!("{d}:1:2"));
    for (command, v) in
        [("map", "0"), ("map", "0.01"), ("map", "11"), ("eval", "0.01"), ("robots", "0.01"), ("team", "20")]
    {
        let args: Vec<&str> = match command {
            "map" => vec!["map", "--data", &d, "--frames", "0:1", "--voxel", v, "-o", &o],
            "eval" => vec!["eval", "--data", &d, "--a", "0:1", "--b", "1:2", "--voxel", v],
            "robots" => vec!["robots", "--data", &d, "--a", "0:1", "--b", "1:2", "--voxel", v],
            _ => vec!["team", "--robot", &ra, "--robot", &rb, "--voxel", v],
        };
        let e = cosem_tests::cosem_usage_err(&args);
        assert!(e.contains("--voxel") && e.contains("0.02 to 10 m"), "{command} --voxel {v}: {e}");
    }
    cosem_tests::cosem_usage_err(&["link", "--map", &o, "--tcp", "127.0.0.1:1", "--connect-timeout", "NaN"]);
    let e = cosem_tests::cosem_usage_err(&["robots", "--data", &d, "--a", "0:1", "--b", "1:2", "--timeout", "NaN"]);
    assert!(e.contains("positive number"), "{e}");
    // A map written into its input folder is refused, the folder untouched.
    let inside = seq.join("m.cmap").display().to_string();
    let e = cosem_err(&["map", "--data", &d, "--frames", "0:1", "-o", &inside]);
    assert!(e.contains("never written") && !seq.join("m.cmap").exists(), "{e}");
}

/// Output over an input is refused: `match --merged` naming a map,
/// `export ply -o` naming the map it reads.
#[test]
fn outputs_never_overwrite_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let m = tmp.path().join("m.cmap");
    let (d, ms) = (seq.display().to_string(), m.display().to_string());
    cosem_tests::cosem_ok(&["map", "--data", &d, "--frames", "0:1", "-o", &ms]);
    let before = fs::read(&m).unwrap();
    let detour = tmp.path().join(".").join("m.cmap").display().to_string();
    let e = cosem_err(&["match", &ms, &ms, "--init", "0,0,0,0,0,0", "--merged", &detour]);
    assert!(e.contains("never overwritten"), "{e}");
    let e = cosem_err(&["export", "ply", &ms, "-o", &detour]);
    assert!(e.contains("never overwritten"), "{e}");
    assert_eq!(fs::read(&m).unwrap(), before);
}

/// A device or another kind of file is refused by its first bytes, not read
/// to its end.
#[test]
fn info_refuses_a_device_at_once() {
    if std::path::Path::new("/dev/zero").exists() {
        let e = cosem_err(&["info", "/dev/zero"]);
        assert!(e.contains("bad magic"), "{e}");
    }
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Scans as PCD files with their poses (`cosem export scans`).
fn pcd_scans(tmp: &Path) -> (Vec<String>, std::path::PathBuf) {
    let seq = fresh(tmp);
    let scans = tmp.join("scans");
    cosem_tests::cosem_ok(&[
        "export",
        "scans",
        "--data",
        &s(&seq),
        "--frames",
        "0:2",
        "--format",
        "pcd",
        "-o",
        &s(&scans),
    ]);
    ((0..2).map(|i| s(&scans.join(format!("{i:06}.pcd")))).collect(), scans.join("poses.txt"))
}

/// Labels that are not SemanticKITTI ids and no class table: an error
/// saying why every point stayed out, not an empty map.
#[test]
fn a_map_that_would_be_empty_is_an_error_saying_why() {
    let tmp = tempfile::tempdir().unwrap();
    let (files, poses) = pcd_scans(tmp.path());
    for f in &files {
        let mut text = fs::read(f).unwrap();
        let at = text.windows(12).position(|w| w == b"DATA binary\n").unwrap() + 12;
        for rec in text[at..].chunks_exact_mut(16) {
            rec[12..16].copy_from_slice(&1000u32.to_le_bytes());
        }
        fs::write(f, text).unwrap();
    }
    let (out, poses) = (s(&tmp.path().join("m.cmap")), s(&poses));
    let mut args = vec!["map", "--format", "pcd", "--poses", &poses, "-o", &out];
    args.extend(files.iter().map(String::as_str));
    let e = cosem_err(&args);
    assert!(
        e.contains("empty") && e.contains("not SemanticKITTI's") && e.contains("1000") && e.contains("--classes"),
        "{e}"
    );
    assert!(!Path::new(&out).exists());
}

/// A pose scaled by 2 would make a map four times too large: refused.
#[test]
fn poses_that_are_not_rigid_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (files, poses) = pcd_scans(tmp.path());
    let text = fs::read_to_string(&poses).unwrap();
    let scaled: Vec<String> = text
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            v.iter()
                .enumerate()
                .map(|(i, x)| if i % 4 == 3 { x.to_string() } else { (2.0 * x).to_string() })
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    fs::write(&poses, scaled.join("\n")).unwrap();
    let (out, poses) = (s(&tmp.path().join("m.cmap")), s(&poses));
    let mut args = vec!["map", "--format", "pcd", "--poses", &poses, "-o", &out];
    args.extend(files.iter().map(String::as_str));
    let e = cosem_err(&args);
    assert!(e.contains("poses.txt") && e.contains("line 1") && e.contains("rigid"), "{e}");
}

/// No input is ever overwritten: not the class table, not a file reached
/// through a hard link; a refused command leaves every file as it was.
#[test]
fn no_output_overwrites_an_input_by_any_name() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let table = tmp.path().join("classes.toml");
    fs::write(&table, "[ids]\n40 = \"road\"\n50 = \"building\"\n0 = \"unlabeled\"\n").unwrap();
    let before = fs::read(&table).unwrap();
    let e = cosem_err(&["map", "--data", &s(&seq), "--frames", "0:2", "--classes", &s(&table), "-o", &s(&table)]);
    assert!(e.contains("is the input"), "{e}");
    assert_eq!(fs::read(&table).unwrap(), before);
    // Through a hard link: map -o, match --mcap-out / --merged, export ply -o.
    let (a, b) = (tmp.path().join("a.cmap"), tmp.path().join("b.cmap"));
    cosem_tests::cosem_ok(&["map", "--data", &s(&seq), "--frames", "0:2", "--voxel", "0.5", "-o", &s(&a)]);
    cosem_tests::cosem_ok(&["map", "--data", &s(&seq), "--frames", "1:3", "--voxel", "0.5", "-o", &s(&b)]);
    let link = tmp.path().join("elsewhere.bin");
    fs::hard_link(&a, &link).unwrap();
    let a_bytes = fs::read(&a).unwrap();
    let (a_s, b_s, link_s) = (s(&a), s(&b), s(&link));
    for args in [
        vec!["match", &a_s, &b_s, "--mcap-out", &link_s],
        vec!["match", &a_s, &b_s, "--merged", &link_s],
        vec!["export", "ply", &a_s, "-o", &link_s],
    ] {
        let e = cosem_err(&args);
        assert!(e.contains("is the input"), "{args:?}: {e}");
        assert_eq!(fs::read(&a).unwrap(), a_bytes, "{args:?}");
    }
    let (files, poses) = pcd_scans(&tmp.path().join("p"));
    let plink = tmp.path().join("poses-link.txt");
    fs::hard_link(&poses, &plink).unwrap();
    let poses_bytes = fs::read(&poses).unwrap();
    let (poses_s, plink_s) = (s(&poses), s(&plink));
    let mut args = vec!["map", "--format", "pcd", "--poses", &poses_s, "-o", &plink_s];
    args.extend(files.iter().map(String::as_str));
    let e = cosem_err(&args);
    assert!(e.contains("is the input"), "{e}");
    assert_eq!(fs::read(&poses).unwrap(), poses_bytes);
}

/// Exports never replace scans or poses without --force, and a failed
/// export leaves no partial file.
#[test]
fn exports_never_replace_scans_and_leave_nothing_when_they_fail() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let other = tmp.path().join("other");
    synth(&other, 2, 9);
    let poses = fs::read(other.join("poses.txt")).unwrap();
    let e = cosem_err(&["export", "scans", "--data", &s(&seq), "--frames", "0:2", "--format", "ply", "-o", &s(&other)]);
    assert!(e.contains("already holds") && e.contains("--force"), "{e}");
    assert_eq!(fs::read(other.join("poses.txt")).unwrap(), poses);
    let out = tmp.path().join("x");
    cosem_tests::cosem_ok(&[
        "export",
        "scans",
        "--data",
        &s(&seq),
        "--frames",
        "0:2",
        "--format",
        "ply",
        "-o",
        &s(&out),
    ]);
    cosem_err(&["export", "scans", "--data", &s(&seq), "--frames", "0:2", "--format", "ply", "-o", &s(&out)]);
    cosem_tests::cosem_ok(&[
        "export",
        "scans",
        "--data",
        &s(&seq),
        "--frames",
        "0:2",
        "--format",
        "ply",
        "-o",
        &s(&out),
        "--force",
    ]);
    // Frame 7 does not exist: the recording is not left half written.
    let bag = tmp.path().join("r.mcap");
    cosem_err(&["export", "mcap", "--data", &s(&seq), "--frames", "0:8", "-o", &s(&bag)]);
    assert!(!bag.exists());
    assert!(fs::read_dir(tmp.path()).unwrap().flatten().all(|e| !e.file_name().to_string_lossy().ends_with(".tmp")));
}

/// Options that make no sense are usage errors naming the option.
#[test]
fn nonsense_options_are_usage_errors() {
    let e = cosem_tests::cosem_usage_err(&["link", "--map", "x.cmap", "--listen", "0", "--baud", "0"]);
    assert!(e.contains("--baud") && e.contains("baud rate"), "{e}");
    let e =
        cosem_tests::cosem_usage_err(&["team", "--robot", "a:0:1", "--robot", "b:0:1", "--prior-noise", "1e300,1e300"]);
    assert!(e.contains("--prior-noise") && e.contains("METRES"), "{e}");
}

/// With --json, a command that fails still prints a JSON object naming the
/// error (exit 1), for scripts that read standard output.
#[test]
fn with_json_an_error_is_json_too() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = s(&tmp.path().join("missing"));
    let robot = format!("{missing}:0:2");
    for args in [
        vec!["team", "--robot", &robot, "--robot", &robot, "--json"],
        vec!["link", "--map", &missing, "--listen", "0", "--json"],
        vec!["match", &missing, &missing, "--json"],
    ] {
        let out = cosem_tests::cosem(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{args:?}: {e}"));
        assert!(j["error"].as_str().is_some_and(|e| e.contains("missing")), "{args:?}: {j}");
        assert_eq!(j["command"], args[0]);
    }
}

/// `cosem synth` and `cosem demo --out` never write over a folder holding
/// other data (a user's SemanticKITTI folder); an earlier synthetic
/// sequence may be replaced.
#[test]
fn synth_never_writes_over_other_data() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    cosem_tests::cosem_ok(&["synth", "--out", &s(&seq), "--frames", "2"]);
    let user = tmp.path().join("user");
    fs::create_dir(&user).unwrap();
    fs::write(user.join("poses.txt"), "1 0 0 0 0 1 0 0 0 0 1 0\n").unwrap();
    let e = cosem_err(&["synth", "--out", &s(&user), "--frames", "2"]);
    assert!(e.contains("not an earlier `cosem synth` output"), "{e}");
    cosem_err(&["demo", "--frames", "4", "--out", &s(&user)]);
    assert_eq!(fs::read_to_string(user.join("poses.txt")).unwrap(), "1 0 0 0 0 1 0 0 0 0 1 0\n");
    assert_eq!(fs::read_dir(&user).unwrap().count(), 1);
}

/// A recording cut in the middle (no footer) is read up to its last whole
/// record with a warning naming the byte offset and what was read;
/// `--strict` makes it an error.
#[test]
fn a_recording_cut_short_warns_and_strict_refuses_it() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = fresh(tmp.path());
    let (rec, cut) = (tmp.path().join("r.mcap"), tmp.path().join("cut.mcap"));
    cosem_tests::cosem_ok(&["export", "mcap", "--data", &s(&seq), "--frames", "0:3", "-o", &s(&rec)]);
    let bytes = fs::read(&rec).unwrap();
    fs::write(&cut, &bytes[..bytes.len() * 4 / 5]).unwrap();
    let out = cosem_tests::cosem(&["map", "--data", &s(&cut), "-o", &s(&tmp.path().join("m.cmap"))]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("warning") && stderr.contains("cut short at byte offset"), "{stderr}");
    assert!(stderr.contains("read the 2 messages"), "{stderr}");
    let e = cosem_err(&["map", "--data", &s(&cut), "--strict", "-o", &s(&tmp.path().join("n.cmap"))]);
    assert!(e.contains("cut short at byte offset") && e.contains("cut.mcap"), "{e}");
    assert!(!tmp.path().join("n.cmap").exists());
    // The whole recording: no warning.
    let out = cosem_tests::cosem(&["map", "--data", &s(&rec), "-o", &s(&tmp.path().join("w.cmap"))]);
    assert!(out.status.success() && !String::from_utf8_lossy(&out.stderr).contains("warning"));
}

/// The data-loss repro: an output spelled through a folder that
/// does not exist yet (`D/new/../k00`) is the input, and is refused before
/// anything is written; with `--copy-scans` the labels stay as they were.
#[test]
fn label_never_replaces_its_input_through_a_missing_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("D");
    let seq = d.join("k00");
    cosem_tests::cosem_ok(&["synth", "--out", &s(&seq), "--frames", "3", "--seg", "cityscapes"]);
    let snapshot = |dir: &Path| {
        let mut v: Vec<(String, Vec<u8>)> = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(p) = stack.pop() {
            for e in fs::read_dir(&p).unwrap().flatten() {
                let meta = fs::symlink_metadata(e.path()).unwrap();
                if meta.is_dir() {
                    stack.push(e.path());
                } else {
                    v.push((e.path().display().to_string(), fs::read(e.path()).unwrap_or_default()));
                }
            }
        }
        v.sort();
        v
    };
    let before = snapshot(&d);
    let (seg, data) = (s(&seq.join("seg_2")), s(&seq));
    for out in [d.join("new/../k00"), d.join("new/../k00/seg_2"), seq.join("seg_2/new/..")] {
        for extra in [&[][..], &["--copy-scans"][..]] {
            let mut args = vec!["label", "--data", &data, "--seg", &seg, "--frames", "0:2"];
            args.extend_from_slice(extra);
            let o = s(&out);
            args.extend(["--out", &o]);
            let e = cosem_err(&args);
            assert!(e.contains("--out") && e.contains("input"), "{args:?}: {e}");
            assert!(!d.join("new").exists(), "{args:?}: made D/new");
            assert_eq!(snapshot(&d), before, "{args:?}: an input changed");
        }
    }
}
