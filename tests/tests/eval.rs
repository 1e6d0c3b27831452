//! `cosem eval`: the JSON schema, the plot, and semantics against geometry.

use cosem_tests::{cosem_ok, real_data, synth};
use serde_json::Value;
use std::path::Path;

fn eval(data: &Path, a: &str, b: &str, extra: &[&str]) -> (Value, String) {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("eval.json").display().to_string();
    let plot = tmp.path().join("eval.svg");
    let d = data.display().to_string();
    let mut args = vec!["eval", "--data", d.as_str(), "--a", a, "--b", b, "--json", &json];
    let p = plot.display().to_string();
    args.extend_from_slice(&["--plot", &p]);
    args.extend_from_slice(extra);
    cosem_ok(&args);
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    (v, std::fs::read_to_string(plot).unwrap())
}

fn number(v: &Value, path: &[&str]) -> f64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_f64().unwrap_or_else(|| panic!("{} missing or not a number in {v}", path.join(".")))
}

#[test]
fn synthetic_eval_schema_and_semantics_beat_or_tie_geometry() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 16, 21);
    let (v, svg) = eval(&seq, "0:8", "8:16", &["--grid-stride", "5", "--method", "cosem,geometric", "--threads", "2"]);
    assert_eq!(v["starts"], 27);
    assert_eq!((v["schema_version"].as_u64(), v["mode"].as_str()), (Some(2), Some("grid")));
    assert!(number(&v, &["maps", "a_voxels"]) > 1000.0 && number(&v, &["maps", "b_voxels"]) > 1000.0);
    let overlap = number(&v, &["maps", "overlap"]);
    assert!((0.0..=1.0).contains(&overlap) && overlap > 0.3, "{overlap}");
    for m in ["cosem", "geometric"] {
        for k in [
            "success_strict",
            "success_loose",
            "et_median_m",
            "et_p95_m",
            "er_median_deg",
            "er_p95_deg",
            "time_ms_median",
            "iterations_median",
        ] {
            let x = number(&v, &["methods", m, k]);
            assert!(x.is_finite() && x >= 0.0, "{m}.{k} = {x}");
        }
        let (s, l) = (number(&v, &["methods", m, "success_strict"]), number(&v, &["methods", m, "success_loose"]));
        assert!(s <= l && l <= 1.0, "fractions in 0..1, strict <= loose");
    }
    let results = v["results"].as_array().unwrap();
    assert_eq!(results.len(), 2 * 27);
    for r in results {
        assert_eq!(r["transform"].as_array().unwrap().len(), 16);
        assert!(["Converged", "NotConverged", "Degenerate", "NoOverlap"].contains(&r["status"].as_str().unwrap()));
    }
    let cosem = number(&v, &["methods", "cosem", "success_strict"]);
    let geometric = number(&v, &["methods", "geometric", "success_strict"]);
    assert!(cosem >= geometric, "cosem {cosem} < geometric {geometric}");
    assert_eq!(cosem, 1.0);
    assert!(svg.starts_with("<svg") && svg.contains(">cosem<") && svg.contains(">geometric<"));
}

#[test]
fn eval_on_real_data_with_a_small_limit() {
    let Some(dir) = real_data("kitti07") else { return };
    let (v, _) = eval(&dir, "0:5", "5:10", &["--limit", "12"]);
    assert_eq!(v["starts"], 12);
    assert!(number(&v, &["methods", "cosem", "success_strict"]) >= 0.99);
    assert!(number(&v, &["methods", "cosem", "et_median_m"]) < 0.05);
    assert!(number(&v, &["methods", "cosem", "er_median_deg"]) < 0.1);
}

#[test]
fn eval_4dof_and_bad_arguments() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 8, 5);
    let (v, _) = eval(&seq, "0:4", "4:8", &["--limit", "3", "--dof", "4"]);
    assert_eq!(v["dof"], 4);
    assert_eq!(number(&v, &["methods", "cosem", "success_strict"]), 1.0);
    let d = seq.display().to_string();
    let e = cosem_tests::cosem_usage_err(&["eval", "--data", &d, "--a", "0:4", "--b", "4:8", "--method", "cosem,icp"]);
    assert!(e.contains("'icp'") && e.contains("--method"), "{e}");
    let e = cosem_tests::cosem_usage_err(&["eval", "--data", &d, "--a", "0:4", "--b", "4:8", "--grid", "dense"]);
    assert!(e.contains("'dense'") && e.contains("--grid"), "{e}");
    // Options that cannot go together, or make no run, are refused before any work.
    for bad in [&["--limit", "0"][..], &["--grid-stride", "0"], &["--grid", "corners", "--limit", "3"]] {
        let mut args = vec!["eval", "--data", &d, "--a", "0:4", "--b", "4:8"];
        args.extend_from_slice(bad);
        cosem_tests::cosem_usage_err(&args);
    }
}

/// `cosem eval --global`: the scene map moved by headings all round the
/// circle and offsets up to 50 m, matched with no prior.
#[test]
fn prior_free_eval_goes_round_the_circle() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    cosem_tests::synth(&seq, 10, 5);
    let json = tmp.path().join("g.json");
    let (s, j) = (seq.display().to_string(), json.display().to_string());
    cosem_tests::cosem_ok(&[
        "eval", "--data", &s, "--a", "0:5", "--b", "5:10", "--global", "--limit", "12", "--json", &j,
    ]);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["starts"], 12);
    assert_eq!((v["schema_version"].as_u64(), v["mode"].as_str()), (Some(2), Some("global")));
    let headings: std::collections::BTreeSet<i64> =
        v["results"].as_array().unwrap().iter().map(|r| r["heading_deg"].as_f64().unwrap() as i64).collect();
    assert!(headings.len() >= 10, "{headings:?}");
    // The same summary fields as grid mode.
    assert!(number(&v, &["methods", "cosem", "success_strict"]) >= 0.95, "{v}");
    for k in ["et_median_m", "er_median_deg", "time_ms_median"] {
        number(&v, &["methods", "cosem", k]);
    }
    if let Some(dir) = cosem_tests::real_data("kitti00") {
        let d = dir.display().to_string();
        cosem_tests::cosem_ok(&[
            "eval", "--data", &d, "--a", "0:5", "--b", "5:10", "--global", "--limit", "12", "--json", &j,
        ]);
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert!(number(&v, &["methods", "cosem", "success_strict"]) >= 0.95, "{v}");
    }
}

/// `cosem eval --negatives`: maps of different places (synthetic streets of
/// other seeds, and the shared data's far-apart places where present), every
/// ordered pair with no prior, the identity and a random prior: none may be
/// reported Converged.
#[test]
fn maps_of_different_places_are_never_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let mut places = Vec::new();
    for seed in [31, 32, 33] {
        let dir = tmp.path().join(format!("s{seed}"));
        synth(&dir, 3, seed);
        places.push(format!("{}:0:3", dir.display()));
    }
    for (name, frames) in
        [("kitti00", "0:2"), ("kitti07", "0:2"), ("kitti08-loop", "720:721"), ("kitti00-loop", "850:851")]
    {
        if let Some(dir) = real_data(name) {
            places.push(format!("{}:{frames}", dir.display()));
        }
    }
    let json = tmp.path().join("neg.json").display().to_string();
    let mut args = vec!["eval", "--negatives"];
    args.extend(places.iter().map(String::as_str));
    args.extend_from_slice(&["--random-priors", "1", "--label-noise", "network", "--json", &json]);
    cosem_ok(&args);
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let n = places.len() as u64;
    assert_eq!(v["cases"].as_u64(), Some(n * (n - 1) * 3), "{v}");
    assert_eq!(v["false_accepts"], 0, "{v}");
    for kind in ["none", "identity", "random"] {
        assert_eq!(v["by_prior"][kind]["false_accepts"], 0, "{kind}");
    }
    // And a true pair under the same label noise, with no prior, still aligns.
    let pos = tmp.path().join("pos");
    synth(&pos, 10, 34);
    let (v, _) = eval(&pos, "0:5", "5:10", &["--global", "--limit", "6", "--label-noise", "network"]);
    assert!(number(&v, &["methods", "cosem", "success_strict"]) >= 0.99, "{v}");
}
