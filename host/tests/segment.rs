//! `cosem segment` on the real KITTI images with the real network (feature
//! `segment`; skipped with a reason where `../shared` is absent): the Rust
//! inference against onnxruntime on the same inputs, the labels it gives
//! the LiDAR points against SemanticKITTI's truth, and bad models named.
#![cfg(feature = "segment")]

use std::path::{Path, PathBuf};
use std::process::Command;

fn shared() -> PathBuf {
    match std::env::var_os("COSEM_DATA") {
        Some(d) => PathBuf::from(d).join(".."),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"),
    }
}

/// The model and a sequence's folder, or why the test skips.
fn real(seq: &str) -> Option<(PathBuf, PathBuf)> {
    let model = shared().join("models/espnetv2-cityscapes-s2.0-512x1024.onnx");
    let data = match std::env::var_os("COSEM_DATA") {
        Some(d) => PathBuf::from(d).join(seq),
        None => shared().join("data").join(seq),
    };
    if model.exists() && data.join("image_2").is_dir() {
        Some((model, data))
    } else {
        eprintln!("skipping: {} or {}/image_2 not found (set COSEM_DATA)", model.display(), data.display());
        None
    }
}

fn cosem(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cosem")).args(args).output().expect("run cosem")
}

fn ok(args: &[&str]) -> String {
    let out = cosem(args);
    assert!(out.status.success(), "cosem {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Whether python3 imports `modules` (space-separated); says why a test
/// skips when not.
fn python_has(modules: &str) -> bool {
    let import = format!("import {}", modules.replace(' ', ", "));
    let have = Command::new("python3").args(["-c", &import]).output().is_ok_and(|o| o.status.success());
    if !have {
        eprintln!("skipping: python3 with {modules} is missing (pip install {modules})");
    }
    have
}

/// `cosem segment` of frame 0 of `images` with `model` into `tmp`/o.
fn segment_first_frame(model: &Path, images: &Path, tmp: &Path) -> std::process::Output {
    let out = tmp.join("o");
    cosem(&["segment", "--model", &s(model), "--images", &s(images), "--out", &s(&out), "--frames", "0:1"])
}

/// The Rust inference (tract) gives onnxruntime's labels on the same input
/// tensors of real KITTI images, on at least 99.9% of the pixels.
#[test]
fn tract_agrees_with_onnxruntime_on_real_images() {
    let Some((model, data)) = real("kitti00") else { return };
    if !python_has("onnxruntime numpy") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (out, check) = (tmp.path().join("seg"), tmp.path().join("check"));
    let images = data.join("image_2");
    ok(&[
        "segment",
        "--model",
        &s(&model),
        "--images",
        &s(&images),
        "--out",
        &s(&out),
        "--frames",
        "0:3:2",
        "--fit",
        "squash",
        "--check-dir",
        &s(&check),
        "--overlay",
    ]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/segment_reference.py");
    let run = Command::new("python3").args([s(&script), s(&model), s(&check)]).output().unwrap();
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{text}{}", String::from_utf8_lossy(&run.stderr));
    let all: f64 = text.lines().find_map(|l| l.strip_prefix("all ")).unwrap().trim().parse().unwrap();
    eprintln!("{text}");
    assert!(all >= 0.999, "agreement with onnxruntime {all}");
    // The PNGs are at the camera image's own size, ids 0-18 or 255; the
    // overlay too.
    for f in ["000000.png", "000002.png", "000000.overlay.png"] {
        let d = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(out.join(f)).unwrap()));
        let mut r = d.read_info().unwrap();
        let mut buf = vec![0u8; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (1241, 376), "{f}");
        if info.color_type == png::ColorType::Grayscale {
            assert!(buf.iter().all(|&v| v < 19 || v == 255), "{f}");
        }
    }
}

/// Labels from the network on the camera's points of kitti00 agree with
/// SemanticKITTI's truth on at least 70% (as Cityscapes can say them:
/// parking is road, trunk is vegetation), and on kitti07 too; kitti00 in
/// two steps (`segment`, then `label --seg`), kitti07 in one (`label
/// --model`, which keeps the segmentation in OUT/seg_2/); the per-class
/// figures add up.
#[test]
fn network_labels_agree_with_the_truth() {
    for (seq, frames, one_step) in [("kitti00", "0:10", false), ("kitti07", "0:10", true)] {
        let Some((model, data)) = real(seq) else { return };
        let tmp = tempfile::tempdir().unwrap();
        let (seg, lab) = (tmp.path().join("seg"), tmp.path().join("lab"));
        let images = data.join("image_2");
        let (data, model, images) = (s(&data), s(&model), s(&images));
        let json = if one_step {
            ok(&[
                "label",
                "--data",
                &data,
                "--model",
                &model,
                "--images",
                &images,
                "--frames",
                frames,
                "--out",
                &s(&lab),
                "--json",
            ])
        } else {
            ok(&["segment", "--model", &model, "--images", &images, "--out", &s(&seg), "--frames", frames]);
            ok(&["label", "--data", &data, "--seg", &s(&seg), "--frames", frames, "--out", &s(&lab), "--json"])
        };
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        let agree = v["agreement_in_class_set"].as_f64().unwrap();
        eprintln!(
            "{seq} {frames}: {:.1}% of the camera's points right ({:.1}% by exact class)",
            100.0 * agree,
            100.0 * v["agreement"].as_f64().unwrap()
        );
        assert!(agree >= 0.70, "{seq}: {agree}");
        if one_step {
            assert!(lab.join("seg_2/000009.png").exists() && lab.join("labels/000009.label").exists());
        }
        // Per class: the truth's points add up to the compared points, and
        // road (most of what a car's camera sees) is mostly found.
        let classes = v["per_class"].as_array().unwrap();
        let truth: u64 = classes.iter().map(|c| c["truth_points"].as_u64().unwrap()).sum();
        assert_eq!(truth, v["compared"].as_u64().unwrap());
        let road = classes.iter().find(|c| c["class"] == "road").unwrap();
        assert!(road["recall"].as_f64().unwrap() > 0.8, "{road}");
        // The maps of these labels match: prior-free (360 starts at 0.5 m)
        // and from the paper's full grid (1,331 starts at 0.2 m).
        let (file, lab) = (s(&tmp.path().join("eval.json")), s(&lab));
        for protocol in [&["--global", "--voxel", "0.5"][..], &[][..]] {
            let mut args = vec!["eval", "--data", &lab, "--a", "0:5", "--b", "5:10", "--json", &file];
            args.extend_from_slice(protocol);
            ok(&args);
            let e: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
            let (mode, starts) = (e["mode"].as_str().unwrap(), e["starts"].as_u64().unwrap());
            let rate = e["methods"]["cosem"]["success_strict"].as_f64().unwrap();
            eprintln!("{seq} camera labels, {mode}: {:.1}% strict of {starts} starts", 100.0 * rate);
            assert!(rate >= 0.99 && starts >= 360, "{seq} {mode}: {rate} of {starts}");
        }
    }
}

/// A file that is not a network, and one whose input is not an image
/// tensor, are typed errors naming the file (and the shapes).
#[test]
fn bad_models_are_named() {
    let Some((_, data)) = real("kitti00") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let junk = tmp.path().join("junk.onnx");
    std::fs::write(&junk, b"not a protobuf at all").unwrap();
    let images = data.join("image_2");
    let out = segment_first_frame(&junk, &images, tmp.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("junk.onnx"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// `cosem bench segment` prints milliseconds per image on one core and on all.
#[test]
fn bench_segment_prints_times_per_image() {
    let Some((model, data)) = real("kitti00") else { return };
    let images = data.join("image_2");
    let out = ok(&["bench", "segment", "--model", &s(&model), "--images", &s(&images), "--frames", "0:1"]);
    assert_eq!(out.lines().filter(|l| l.contains("ms per image")).count(), 2, "{out}");
}

/// A valid ONNX network that breaks the contract (one channel in, one
/// out) is refused, naming the shapes it has and the ones it needs.
#[test]
fn a_network_of_the_wrong_shapes_is_refused_naming_them() {
    let Some((_, data)) = real("kitti00") else { return };
    if !python_has("onnx") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("gray.onnx");
    let py = "import onnx, sys\n\
from onnx import helper, TensorProto\n\
i = helper.make_tensor_value_info('image', TensorProto.FLOAT, [1, 1, 16, 24])\n\
o = helper.make_tensor_value_info('logits', TensorProto.FLOAT, [1, 1, 16, 24])\n\
g = helper.make_graph([helper.make_node('Identity', ['image'], ['logits'])], 'g', [i], [o])\n\
onnx.save(helper.make_model(g, opset_imports=[helper.make_opsetid('', 13)]), sys.argv[1])\n";
    let made = Command::new("python3").args(["-c", py, &s(&model)]).output().unwrap();
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let images = data.join("image_2");
    let out = segment_first_frame(&model, &images, tmp.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("gray.onnx") && err.contains("1,1,16,24") && err.contains("[1, 3, H, W]"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
