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
    cosem_tests::cosem_usage_err(&["map", "--data", &d, "--frames", "0:1", "--voxel", "0", "-o", &o]);
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
