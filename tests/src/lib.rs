//! Helpers for the end-to-end tests: find the `cosem` binary and the data.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_default()
}

/// Path of the `cosem` binary of this build: `COSEM_BIN`, else next to the
/// test executable's profile folder (cargo builds it for the host crate's
/// integration tests in the same run).
pub fn cosem_bin() -> PathBuf {
    if let Some(p) = std::env::var_os("COSEM_BIN") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe.parent().and_then(Path::parent).expect("target/<profile>/deps");
    let bin = profile_dir.join(format!("cosem{}", std::env::consts::EXE_SUFFIX));
    assert!(bin.exists(), "{} not built: run the tests with `cargo test --workspace`", bin.display());
    bin
}

/// Runs `cosem` with arguments from the workspace root.
pub fn cosem(args: &[&str]) -> Output {
    Command::new(cosem_bin()).args(args).current_dir(workspace_root()).output().expect("run cosem")
}

/// Runs `cosem` and asserts success; returns stdout.
pub fn cosem_ok(args: &[&str]) -> String {
    let out = cosem(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "cosem {args:?} failed:\n{stderr}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `cosem`, asserts it fails cleanly (no panic), returns stderr.
pub fn cosem_err(args: &[&str]) -> String {
    let out = cosem(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "cosem {args:?} should have failed");
    assert_eq!(out.status.code(), Some(1), "cosem {args:?}: exit status {:?}\n{stderr}", out.status);
    assert!(!stderr.contains("panicked"), "cosem {args:?} panicked:\n{stderr}");
    stderr
}

/// A real-data folder (`$COSEM_DATA/NAME`, default `../shared/data/NAME`),
/// or `None` after printing why the test is skipped.
pub fn real_data(name: &str) -> Option<PathBuf> {
    let root = match std::env::var_os("COSEM_DATA") {
        Some(d) => PathBuf::from(d),
        None => workspace_root().join("../shared/data"),
    };
    let dir = root.join(name);
    if dir.join("poses.txt").exists() {
        Some(dir)
    } else {
        eprintln!("skipping: real data {} not found (set COSEM_DATA)", dir.display());
        None
    }
}

/// Synthesises a sequence into `dir` with `cosem synth`.
pub fn synth(dir: &Path, frames: usize, seed: u64) {
    cosem_ok(&[
        "synth",
        "--out",
        &dir.display().to_string(),
        "--frames",
        &frames.to_string(),
        "--seed",
        &seed.to_string(),
    ]);
}
