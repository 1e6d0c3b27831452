//! A dataset folder corrupted at random (seeded: truncations, flipped bytes,
//! blank lines, garbage in poses, calibration, scans, labels and times),
//! hundreds of cases: `cosem map` must end with a clear error naming a file
//! of the folder, or build a map; never panic. Corruptions that break a
//! file's structure (a scan or label file cut off mid-record, a blank line
//! before the last pose, a pose or `Tr` that is no longer a rotation) must
//! be errors.

use cosem_host::rng::Rng;
use std::path::{Path, PathBuf};

/// Uniform in `0..n`.
fn pick(rng: &mut Rng, n: usize) -> usize {
    rng.below(n as u64) as usize
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let dst = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &dst);
        } else {
            std::fs::copy(&p, &dst).unwrap();
        }
    }
}

/// Applies one corruption; returns what it did and whether it must be an error.
fn corrupt(dir: &Path, rng: &mut Rng) -> (String, bool) {
    let files: Vec<PathBuf> = ["calib.txt", "poses.txt", "times.txt", "velodyne/000001.bin", "labels/000001.label"]
        .iter()
        .map(|f| dir.join(f))
        .collect();
    let file = &files[pick(rng, files.len())];
    let mut bytes = std::fs::read(file).unwrap();
    let name = file.strip_prefix(dir).unwrap().display().to_string();
    let record = if name.ends_with(".bin") { 16 } else { 4 };
    match pick(rng, 4) {
        0 => {
            let cut = pick(rng, bytes.len());
            bytes.truncate(cut);
            std::fs::write(file, &bytes).unwrap();
            // A binary file cut mid-record, or a text file cut before its
            // last needed line, cannot be read whole.
            let binary = name.ends_with(".bin") || name.ends_with(".label");
            (format!("{name}: truncated at {cut}"), binary && !cut.is_multiple_of(record))
        }
        1 => {
            let at = pick(rng, bytes.len());
            bytes[at] ^= 1 << pick(rng, 8);
            std::fs::write(file, &bytes).unwrap();
            (format!("{name}: bit flipped at {at}"), false)
        }
        2 if name.ends_with(".txt") => {
            let text = String::from_utf8(bytes).unwrap();
            let mut lines: Vec<&str> = text.lines().collect();
            let at = pick(rng, lines.len().saturating_sub(1));
            lines.insert(at, "");
            std::fs::write(file, lines.join("\n") + "\n").unwrap();
            // A blank line before the last pose shifts every later pose.
            (format!("{name}: blank line at {}", at + 1), name == "poses.txt")
        }
        _ => {
            let n = 1 + pick(rng, 9);
            let junk: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            let at = pick(rng, bytes.len());
            bytes.splice(at..at, junk);
            std::fs::write(file, &bytes).unwrap();
            (format!("{name}: {n} garbage bytes at {at}"), false)
        }
    }
}

#[test]
fn corrupted_datasets_are_clear_errors_or_maps_never_panics() {
    let tmp = tempfile::tempdir().unwrap();
    let clean = tmp.path().join("clean");
    cosem_tests::synth(&clean, 3, 9);
    let mut rng = Rng::new(0x0C05_EBAD);
    let (mut errors, mut maps) = (0, 0);
    for case in 0..200 {
        let dir = tmp.path().join(format!("c{case}"));
        copy_dir(&clean, &dir);
        let (what, must_fail) = corrupt(&dir, &mut rng);
        let out = tmp.path().join("out.cmap");
        let o = cosem_tests::cosem(&[
            "map",
            "--data",
            &dir.display().to_string(),
            "--frames",
            "0:3",
            "-o",
            &out.display().to_string(),
        ]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!stderr.contains("panicked"), "case {case} ({what}): {stderr}");
        match o.status.code() {
            Some(0) => {
                assert!(!must_fail, "case {case} ({what}) was accepted");
                maps += 1;
            }
            Some(1) => {
                assert!(stderr.contains(&dir.display().to_string()), "case {case} ({what}): no file named: {stderr}");
                errors += 1;
            }
            c => panic!("case {case} ({what}): exit {c:?}: {stderr}"),
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
    eprintln!("200 corrupted folders: {errors} clear errors, {maps} maps built");
    assert!(errors > 50, "{errors} errors of 200");
}
