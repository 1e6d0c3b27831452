//! Maps of real SemanticKITTI frames (skipped with a reason when absent).

use cosem_tests::{cosem_ok, real_data};
use serde_json::Value;
use std::collections::HashSet;

/// Raw ids the standard learning map keeps (moving objects skipped).
const KEPT_IDS: [u32; 23] =
    [10, 11, 13, 15, 16, 18, 20, 30, 31, 32, 40, 44, 48, 49, 50, 51, 60, 70, 71, 72, 80, 81, 0xFFFF_FFFF];

fn read_3x4(line: &str) -> [[f64; 4]; 4] {
    let v: Vec<f64> = line.split_whitespace().map(|t| t.parse().unwrap()).collect();
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..4 {
            m[r][c] = v[r * 4 + c];
        }
    }
    m[3][3] = 1.0;
    m
}

fn mul(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for r in 0..4 {
        for c in 0..4 {
            m[r][c] = (0..4).map(|k| a[r][k] * b[k][c]).sum();
        }
    }
    m
}

fn rigid_inv(a: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c] = a[c][r];
        }
        m[r][3] = -(0..3).map(|k| a[k][r] * a[k][3]).sum::<f64>();
    }
    m[3][3] = 1.0;
    m
}

/// Distinct 0.2 m cells of the kept points of frames 0..10 in the anchor
/// frame, computed here from the raw files without the project's reader.
fn independent_cell_count(dir: &std::path::Path, frames: std::ops::Range<usize>, voxel: f64) -> usize {
    let calib = std::fs::read_to_string(dir.join("calib.txt")).unwrap();
    let tr = read_3x4(calib.lines().find_map(|l| l.strip_prefix("Tr:")).unwrap());
    let poses: Vec<_> = std::fs::read_to_string(dir.join("poses.txt")).unwrap().lines().map(read_3x4).collect();
    let velo = |i: usize| mul(&mul(&rigid_inv(&tr), &poses[i]), &tr);
    let anchor_inv = rigid_inv(&velo(frames.start));
    let mut cells = HashSet::new();
    for i in frames {
        let t = mul(&anchor_inv, &velo(i));
        let bin = std::fs::read(dir.join(format!("velodyne/{i:06}.bin"))).unwrap();
        let lab = std::fs::read(dir.join(format!("labels/{i:06}.label"))).unwrap();
        for (p, l) in bin.chunks_exact(16).zip(lab.chunks_exact(4)) {
            let id = u32::from_le_bytes(l.try_into().unwrap()) & 0xFFFF;
            if !KEPT_IDS.contains(&id) {
                continue;
            }
            let f = |k: usize| f32::from_le_bytes(p[4 * k..4 * k + 4].try_into().unwrap()) as f64;
            let (x, y, z) = (f(0), f(1), f(2));
            let q: Vec<i64> =
                (0..3).map(|r| ((t[r][0] * x + t[r][1] * y + t[r][2] * z + t[r][3]) / voxel).floor() as i64).collect();
            cells.insert((q[0], q[1], q[2]));
        }
    }
    cells.len()
}

#[test]
fn kitti00_map_matches_an_independent_count() {
    let Some(dir) = real_data("kitti00") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let map = tmp.path().join("k00.cmap");
    cosem_ok(&[
        "map",
        "--data",
        &dir.display().to_string(),
        "--frames",
        "0:10",
        "--voxel",
        "0.2",
        "-o",
        &map.display().to_string(),
    ]);
    let info: Value = serde_json::from_str(&cosem_ok(&["info", &map.display().to_string(), "--json"])).unwrap();
    let voxels = info["voxels"].as_u64().unwrap() as f64;
    let expected = independent_cell_count(&dir, 0..10, 0.2) as f64;
    let rel = (voxels - expected).abs() / expected;
    eprintln!("kitti00 0:10 at 0.2 m: {voxels} voxels, independent count {expected}");
    assert!(rel < 0.01, "map has {voxels} voxels, independent count {expected} ({:.3}% apart)", rel * 100.0);
    let mut classes: Vec<(String, u64)> =
        info["classes"].as_object().unwrap().iter().map(|(k, v)| (k.clone(), v.as_u64().unwrap())).collect();
    classes.sort_by_key(|c| std::cmp::Reverse(c.1));
    let mut top: Vec<&str> = classes.iter().take(5).map(|(k, _)| k.as_str()).collect();
    top.sort();
    assert_eq!(top, ["building", "road", "sidewalk", "terrain", "vegetation"], "{classes:?}");
}

#[test]
fn every_shared_sequence_maps_cleanly() {
    for (name, frames) in
        [("kitti00", "0:5"), ("kitti07", "0:10"), ("kitti00-loop", "52:53"), ("kitti08-loop", "1500:1501")]
    {
        let Some(dir) = real_data(name) else { continue };
        let tmp = tempfile::tempdir().unwrap();
        let map = tmp.path().join("m.cmap");
        cosem_ok(&["map", "--data", &dir.display().to_string(), "--frames", frames, "-o", &map.display().to_string()]);
        let info: Value = serde_json::from_str(&cosem_ok(&["info", &map.display().to_string(), "--json"])).unwrap();
        assert!(info["voxels"].as_u64().unwrap() > 10_000, "{name}: {info}");
        // The compact encoding: at most 4 bytes per voxel on 0.2 m KITTI maps.
        let wire = info["wire_bytes_per_voxel"].as_f64().unwrap();
        assert!(wire <= 4.0, "{name}: {wire} bytes/voxel");
    }
}
