//! The declared `rust-version` is true: no locked dependency of the
//! workspace or of the firmware declares a newer one. (Our own code is held
//! to it by clippy's `incompatible_msrv` lint, which reads the same field.)

use std::path::Path;
use std::process::Command;

/// `major.minor.patch` as numbers (missing parts 0).
fn version(v: &str) -> (u64, u64, u64) {
    let mut n = v.trim().split('.').map(|p| p.parse::<u64>().unwrap_or(0));
    (n.next().unwrap_or(0), n.next().unwrap_or(0), n.next().unwrap_or(0))
}

/// The host's target triple (what `rustc -vV` says).
fn host_triple() -> String {
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let out = Command::new(rustc).arg("-vV").output().expect("run rustc -vV");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    text.lines().find_map(|l| l.strip_prefix("host: ")).expect("rustc -vV names the host").trim().to_string()
}

/// Every package of a lock file that builds for the host or the firmware's
/// target, with the rust-version it declares, and the root package's own.
/// (Only those: on a fresh machine the registry holds no crate of another
/// platform, such as a Windows console crate, and the test is offline.)
fn declared(dir: &Path) -> Vec<(String, String)> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let host = host_triple();
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked", "--offline"])
        .args(["--filter-platform", &host, "--filter-platform", "thumbv7em-none-eabihf"])
        .current_dir(dir)
        .output()
        .expect("run cargo metadata");
    assert!(out.status.success(), "cargo metadata in {}: {}", dir.display(), String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    v["packages"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|p| {
            Some((
                format!("{} {}", p["name"].as_str()?, p["version"].as_str()?),
                p["rust_version"].as_str()?.to_string(),
            ))
        })
        .collect()
}

#[test]
fn declared_rust_version_covers_every_locked_dependency() {
    let root = cosem_tests::workspace_root();
    for dir in [root.clone(), root.join("firmware")] {
        let packages = declared(&dir);
        let ours = packages
            .iter()
            .find(|(name, _)| name.starts_with("cosem-core "))
            .map(|(_, v)| version(v))
            .expect("cosem-core declares a rust-version");
        for (name, rv) in &packages {
            assert!(version(rv) <= ours, "{}: {name} needs Rust {rv}, newer than the declared {ours:?}", dir.display());
        }
    }
}
