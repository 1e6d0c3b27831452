//! `cosem label`: LiDAR labels from camera segmentation images, on the
//! project's synthetic streets (whose `cosem synth` renders camera 2's
//! segmentation). Two robots split the sequence (frames 0:N/2 and N/2:N).

use cosem_tests::{cosem_err, cosem_ok};
use serde_json::Value;
use std::path::Path;

const FRAMES: &str = "10";

fn synth(dir: &Path, seed: &str, extra: &[&str]) {
    let d = dir.display().to_string();
    let mut args = vec!["synth", "--out", d.as_str(), "--frames", FRAMES, "--seed", seed];
    args.extend_from_slice(extra);
    cosem_ok(&args);
}

fn label(data: &Path, out: &Path, extra: &[&str]) -> Value {
    let (d, s, o) = (data.display().to_string(), data.join("seg_2").display().to_string(), out.display().to_string());
    let mut args = vec!["label", "--data", d.as_str(), "--seg", s.as_str(), "--out", o.as_str(), "--json"];
    args.extend_from_slice(extra);
    serde_json::from_str(&cosem_ok(&args)).unwrap()
}

fn strict_rate(data: &Path) -> f64 {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("eval.json").display().to_string();
    let d = data.display().to_string();
    cosem_ok(&["eval", "--data", &d, "--a", "0:5", "--b", "5:10", "--grid-stride", "2", "--json", &json]);
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["methods"]["cosem"]["success_strict"].as_f64().unwrap()
}

#[test]
fn perfect_images_label_the_lidar_like_the_ground_truth() {
    let tmp = tempfile::tempdir().unwrap();
    // Learning-map ids: the class set says every class.
    let seq = tmp.path().join("seq");
    synth(&seq, "5", &["--seg", "semantickitti"]);
    let v = label(&seq, &tmp.path().join("out"), &["--classes", "semantickitti"]);
    let agreement = v["agreement"].as_f64().unwrap();
    eprintln!("semantickitti ids: agreement {agreement:.4} over {} in-view points", v["compared"]);
    assert!(agreement >= 0.97, "{v}");
    assert!(v["in_view"].as_u64().unwrap() > 50_000, "{v}");
    // Points hidden from the camera (seen by the LiDAR past an object's
    // edge) are left out by default; labelling them too costs agreement.
    let all = label(&seq, &tmp.path().join("all"), &["--classes", "semantickitti", "--keep-occluded"]);
    eprintln!("with occluded points: agreement {} over {} points", all["agreement"], all["compared"]);
    assert_eq!(all["occluded"], 0);
    assert!(all["in_view"].as_u64() > v["in_view"].as_u64() && v["occluded"].as_u64().unwrap() > 0, "{all}\n{v}");
    assert!(all["agreement"].as_f64().unwrap() < agreement, "{all}\n{v}");
    assert!(all["agreement"].as_f64().unwrap() >= 0.97, "{all}");
    // Out-of-view points stay unlabelled; in-view ones carry SemanticKITTI ids.
    let out = tmp.path().join("out");
    let labels = std::fs::read(out.join("labels/000003.label")).unwrap();
    let ids: Vec<u32> = labels.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let zero = ids.iter().filter(|&&l| l == 0).count();
    assert!(zero > ids.len() / 2 && zero < ids.len(), "{zero} of {}", ids.len());
    for f in ["calib.txt", "poses.txt", "times.txt", "velodyne/000003.bin", "PROVENANCE.md"] {
        assert!(out.join(f).exists(), "{f}");
    }
    // Scans are relative links: the two folders may move together.
    let link = std::fs::read_link(out.join("velodyne/000003.bin")).unwrap();
    assert!(link.is_relative(), "{}", link.display());
    let moved = tmp.path().join("moved");
    std::fs::create_dir(&moved).unwrap();
    std::fs::rename(&seq, moved.join("seq")).unwrap();
    std::fs::rename(&out, moved.join("out")).unwrap();
    assert!(moved.join("out/velodyne/000003.bin").metadata().is_ok());
    std::fs::rename(moved.join("seq"), &seq).unwrap();
    std::fs::rename(moved.join("out"), &out).unwrap();
    // Cityscapes ids (the paper's network): trunks become vegetation.
    let seq = tmp.path().join("cs");
    synth(&seq, "5", &[]);
    let v = label(&seq, &tmp.path().join("cs_out"), &[]);
    let in_set = v["agreement_in_class_set"].as_f64().unwrap();
    eprintln!("cityscapes ids: agreement {} ({in_set:.4} as Cityscapes can say it)", v["agreement"]);
    assert!(in_set >= 0.97, "{v}");
    assert!(v["points_per_second"].as_f64().unwrap() > 0.0);
}

#[test]
fn corrupted_camera_labels_still_match() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, "5", &["--seg-corrupt"]);
    let out = tmp.path().join("out");
    let v = label(&seq, &out, &[]);
    let agreement = v["agreement"].as_f64().unwrap();
    // The corruption is real: a tenth or less of the points change class.
    assert!((0.85..0.96).contains(&agreement), "{v}");
    let rate = strict_rate(&out);
    eprintln!("corrupted camera labels: agreement {agreement:.3}, strict success {rate:.3}");
    assert!(rate >= 0.99, "strict success {rate}");
}

#[test]
fn unlabelled_points_become_geometry_of_an_unknown_class_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, "5", &[]);
    let out = tmp.path().join("out");
    label(&seq, &out, &[]);
    let d = out.display().to_string();
    let info = |mode: &str| -> Value {
        let file = tmp.path().join(format!("{mode}.cmap")).display().to_string();
        cosem_ok(&["map", "--data", &d, "--frames", "0:5", "--unlabeled", mode, "-o", &file]);
        serde_json::from_str(&cosem_ok(&["info", &file, "--json"])).unwrap()
    };
    let (drop, geometry) = (info("drop"), info("geometry"));
    let classed = |v: &Value| v["classes"].as_object().unwrap().values().map(|n| n.as_u64().unwrap()).sum::<u64>();
    let (n_drop, n_geo) = (drop["voxels"].as_u64().unwrap(), geometry["voxels"].as_u64().unwrap());
    eprintln!(
        "voxels: {n_drop} labelled only, {n_geo} with unlabelled geometry ({} unknown)",
        geometry["unknown_class"]
    );
    // The camera sees a fraction of each scan: most of the map's geometry
    // is outside its view.
    assert!(n_geo > 2 * n_drop, "{drop}\n{geometry}");
    assert_eq!(drop["unknown_class"], 0);
    assert_eq!(classed(&geometry) + geometry["unknown_class"].as_u64().unwrap(), n_geo);
    // A voxel the camera labelled keeps its label.
    assert!(classed(&geometry) >= n_drop, "{drop}\n{geometry}");
    // Such maps match.
    let json = tmp.path().join("eval.json").display().to_string();
    cosem_ok(&[
        "eval",
        "--data",
        &d,
        "--a",
        "0:5",
        "--b",
        "5:10",
        "--grid-stride",
        "2",
        "--unlabeled",
        "geometry",
        "--json",
        &json,
    ]);
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rate = v["methods"]["cosem"]["success_strict"].as_f64().unwrap();
    assert!(rate >= 0.99, "strict success with unknown-class geometry {rate}");
    let e =
        cosem_tests::cosem_usage_err(&["map", "--data", &d, "--frames", "0:5", "--unlabeled", "keep", "-o", "x.cmap"]);
    assert!(e.contains("--unlabeled") && e.contains("drop, geometry"), "{e}");
}

#[test]
fn probability_maps_become_label_evidence() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, "7", &["--seg-corrupt", "--seg-probabilities"]);
    let (hard, soft) = (tmp.path().join("hard"), tmp.path().join("soft"));
    let h = label(&seq, &hard, &[]);
    let s = label(&seq, &soft, &["--probabilities"]);
    eprintln!("agreement: hard {} probabilities {}", h["agreement"], s["agreement"]);
    assert!(s["agreement"].as_f64().unwrap() >= h["agreement"].as_f64().unwrap() - 0.01, "{h}\n{s}");
    let ev = std::fs::metadata(soft.join("evidence/000002.bin")).unwrap().len();
    let pts = std::fs::metadata(soft.join("velodyne/000002.bin")).unwrap().len() / 16;
    assert_eq!(ev, pts * 8);
    // Maps fuse the evidence and still match.
    let rate = strict_rate(&soft);
    assert!(rate >= 0.99, "strict success with probabilities {rate}");
}

#[test]
fn malformed_inputs_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    cosem_ok(&["synth", "--out", &seq.display().to_string(), "--frames", "3", "--seed", "2"]);
    let seg = seq.join("seg_2");
    let run = |out: &str, extra: &[&str]| {
        let (d, s, o) = (seq.display().to_string(), seg.display().to_string(), tmp.path().join(out));
        let o = o.display().to_string();
        let mut args = vec!["label", "--data", d.as_str(), "--seg", s.as_str(), "--out", o.as_str()];
        args.extend_from_slice(extra);
        cosem_err(&args)
    };
    // A missing image.
    let f1 = seg.join("000001.png");
    let kept = std::fs::read(&f1).unwrap();
    std::fs::remove_file(&f1).unwrap();
    let e = run("o1", &[]);
    assert!(e.contains("000001.png") && e.contains("missing"), "{e}");
    // A wrong size.
    let small = cosem_host::camera::label::SegImage { width: 20, height: 10, ids: vec![0; 200] };
    cosem_host::camera::label::write_seg_png(&f1, &small).unwrap();
    let e = run("o2", &[]);
    assert!(e.contains("000001.png") && e.contains("20x10") && e.contains("1241x376"), "{e}");
    // An unknown class id (40 is no Cityscapes training id) at a named pixel.
    std::fs::write(&f1, kept).unwrap();
    let mut im = cosem_host::camera::label::read_seg_png(&seg.join("000002.png")).unwrap();
    im.ids[3 * 1241 + 7] = 40;
    cosem_host::camera::label::write_seg_png(&seg.join("000002.png"), &im).unwrap();
    let e = run("o3", &[]);
    assert!(e.contains("000002.png") && e.contains("(7, 3)") && e.contains("class id 40"), "{e}");
    // Not a PNG; a missing probability map; a camera calib.txt lacks; an unknown class set.
    std::fs::write(seg.join("000002.png"), b"not an image").unwrap();
    let e = run("o4", &[]);
    assert!(e.contains("000002.png") && e.contains("PNG"), "{e}");
    let e = run("o5", &["--probabilities"]);
    assert!(e.contains("000000.npy") && e.contains("missing"), "{e}");
    let e = run("o7", &["--camera", "7", "--frames", "0:1"]);
    assert!(e.contains("calib.txt") && e.contains("P7"), "{e}");
    let (d, s8) = (seq.display().to_string(), seg.display().to_string());
    let o8 = tmp.path().join("o8").display().to_string();
    let e = cosem_tests::cosem_usage_err(&["label", "--data", &d, "--seg", &s8, "--out", &o8, "--classes", "ade20k"]);
    assert!(e.contains("ade20k"), "{e}");
    // A folder with no scans.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(empty.join("velodyne")).unwrap();
    for f in ["calib.txt", "poses.txt"] {
        std::fs::copy(seq.join(f), empty.join(f)).unwrap();
    }
    let (d, s, o) =
        (empty.display().to_string(), seg.display().to_string(), tmp.path().join("o9").display().to_string());
    let e = cosem_err(&["label", "--data", &d, "--seg", &s, "--out", &o]);
    assert!(e.contains("velodyne") && e.contains("no scans"), "{e}");
}

/// Every byte of every file under `dir` (links followed), by relative path.
fn snapshot(dir: &std::path::Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// `--out` naming the input folder, by an absolute path, a `..` detour or a
/// symbolic link, or a folder inside it, is refused and the input is left
/// byte for byte as it was; an existing folder that is not an earlier
/// output is refused too; an earlier output is replaced.
#[test]
fn label_never_writes_into_its_input() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    cosem_ok(&["synth", "--out", &seq.display().to_string(), "--frames", "2", "--seed", "3"]);
    let before = snapshot(&seq);
    let seg = seq.join("seg_2").display().to_string();
    let link = tmp.path().join("link");
    #[cfg(unix)]
    std::os::unix::fs::symlink(&seq, &link).unwrap();
    let detour = tmp.path().join("seq").join("..").join("seq");
    let mut outs = vec![std::fs::canonicalize(&seq).unwrap(), detour, seq.join("labels_out"), seq.join("seg_2")];
    if link.exists() {
        outs.push(link.clone());
    }
    for out in &outs {
        let o = out.display().to_string();
        let e = cosem_err(&["label", "--data", &seq.display().to_string(), "--seg", &seg, "--out", &o]);
        assert!(e.contains("never written"), "{o}: {e}");
    }
    assert!(snapshot(&seq) == before, "the input folder changed");
    let other = tmp.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("keep.txt"), b"mine").unwrap();
    let e = cosem_err(&[
        "label",
        "--data",
        &seq.display().to_string(),
        "--seg",
        &seg,
        "--out",
        &other.display().to_string(),
    ]);
    assert!(e.contains("not an earlier"), "{e}");
    assert_eq!(std::fs::read(other.join("keep.txt")).unwrap(), b"mine");
    let out = tmp.path().join("out").display().to_string();
    for _ in 0..2 {
        cosem_ok(&["label", "--data", &seq.display().to_string(), "--seg", &seg, "--out", &out]);
    }
    assert!(snapshot(&seq) == before, "the input folder changed");
}

/// Segmentation at a network's output size (1024x512) instead of the
/// camera's (1241x376): refused naming both sizes, or, asked, the
/// projection scaled to it (said in the output) with about the agreement
/// of full-size images.
#[test]
fn segmentation_of_another_size_is_refused_or_scaled_when_asked() {
    use cosem_host::camera::label::{read_seg_png, write_seg_png, SegImage};
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, "6", &[]);
    let full = label(&seq, &tmp.path().join("full"), &[]);
    // Nearest-neighbour resize of every image to 1024x512.
    let (w, h) = (1024u32, 512u32);
    for e in std::fs::read_dir(seq.join("seg_2")).unwrap().flatten() {
        if e.path().extension().is_some_and(|x| x == "png") {
            let im = read_seg_png(&e.path()).unwrap();
            let mut ids = Vec::with_capacity((w * h) as usize);
            for v in 0..h {
                for u in 0..w {
                    let (su, sv) = (
                        ((u as f64 + 0.5) * im.width as f64 / w as f64) as u32,
                        ((v as f64 + 0.5) * im.height as f64 / h as f64) as u32,
                    );
                    ids.push(im.ids[(sv * im.width + su) as usize]);
                }
            }
            write_seg_png(&e.path(), &SegImage { width: w, height: h, ids }).unwrap();
        }
    }
    let (d, s) = (seq.display().to_string(), seq.join("seg_2").display().to_string());
    let o = tmp.path().join("small").display().to_string();
    let e = cosem_err(&["label", "--data", &d, "--seg", &s, "--out", &o]);
    assert!(e.contains("1024x512") && e.contains("--scale-to-images"), "{e}");
    let e = cosem_err(&["label", "--data", &d, "--seg", &s, "--out", &o, "--image-size", "1241x376"]);
    assert!(e.contains("1024x512") && e.contains("1241x376"), "{e}");
    let scaled = label(&seq, &tmp.path().join("scaled"), &["--image-size", "1241x376", "--scale-to-images"]);
    assert_eq!(scaled["scaled_from_image_size"], serde_json::json!([1241, 376]));
    let (a, b) = (full["agreement_in_class_set"].as_f64().unwrap(), scaled["agreement_in_class_set"].as_f64().unwrap());
    eprintln!("agreement: camera-size images {a:.4}, 1024x512 scaled {b:.4}");
    assert!(b > a - 0.03, "scaled {b} vs full {a}");
}

/// Probability maps of 19 classes and a void channel: refused with what to
/// say, read with --void-channel last (the same labels when void is 0).
#[test]
fn a_void_channel_is_taken_when_named() {
    use cosem_host::camera::label::{read_probabilities, write_probabilities, ProbabilityMap};
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, "7", &["--seg-probabilities"]);
    let want = label(&seq, &tmp.path().join("a"), &["--probabilities"]);
    for e in std::fs::read_dir(seq.join("seg_2")).unwrap().flatten() {
        if e.path().extension().is_some_and(|x| x == "npy") {
            let p = read_probabilities(&e.path(), 19).unwrap();
            let values = p.values.chunks_exact(19).flat_map(|px| px.iter().copied().chain([0.0])).collect();
            write_probabilities(&e.path(), &ProbabilityMap { channels: 20, values, ..p }).unwrap();
        }
    }
    let (d, s) = (seq.display().to_string(), seq.join("seg_2").display().to_string());
    let o = tmp.path().join("b").display().to_string();
    let e = cosem_err(&["label", "--data", &d, "--seg", &s, "--out", &o, "--probabilities"]);
    assert!(e.contains("--void-channel last"), "{e}");
    let got = label(&seq, &tmp.path().join("c"), &["--probabilities", "--void-channel", "last"]);
    assert_eq!(
        (got["labelled"].clone(), got["agreeing"].clone()),
        (want["labelled"].clone(), want["agreeing"].clone())
    );
}
