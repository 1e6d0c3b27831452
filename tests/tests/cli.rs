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
