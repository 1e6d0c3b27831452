//! The firmware runs the core's mapping on a Cortex-M4F under QEMU.
//! Skipped, with the reason printed, where QEMU or the target is missing.

use std::process::Command;

fn have(cmd: &str, arg: &str) -> bool {
    Command::new(cmd).arg(arg).output().map(|o| o.status.success()).unwrap_or(false)
}

#[test]
fn firmware_maps_on_the_target() {
    if !have("qemu-system-arm", "--version") {
        eprintln!("skipping: qemu-system-arm not found (tests/run installs it)");
        return;
    }
    let firmware = cosem_tests::workspace_root().join("firmware");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["run", "--release", "--locked"])
        .current_dir(&firmware)
        .env_remove("CARGO_TARGET_DIR")
        .output()
        .expect("cargo run in firmware/");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    if stderr.contains("target may not be installed") {
        eprintln!("skipping: thumbv7em-none-eabihf not installed (tests/run installs it)");
        return;
    }
    assert!(out.status.success(), "firmware failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("60 voxels, 20 pole voxels"), "{stdout}\n{stderr}");
}
