//! The firmware runs the core's self-test (mapping, wire, matching) on a
//! Cortex-M4F under QEMU; every figure must equal, to the bit, the same
//! code's run on this host. Skipped, with the reason printed, where QEMU or
//! the ARM target is missing (`tests/run` installs both).

use cosem_core::map::MapConfig;
use cosem_core::selftest::{self, FOOTPRINT_WORDS, MAP_VOXELS, PYRAMID_ENTRIES, RESOLUTION};
use cosem_host::align::HeapPyramidStorage;
use cosem_host::mapping::new_map;
use std::process::Command;

fn have(cmd: &str, arg: &str) -> bool {
    Command::new(cmd).arg(arg).output().map(|o| o.status.success()).unwrap_or(false)
}

/// The self-test's report lines as the firmware prints them, computed here.
fn host_lines() -> Vec<String> {
    let config = MapConfig::with_resolution(RESOLUTION);
    let (mut a, mut b, mut r) = (
        new_map(MAP_VOXELS, config).unwrap(),
        new_map(MAP_VOXELS, config).unwrap(),
        new_map(MAP_VOXELS, config).unwrap(),
    );
    let mut scratch = vec![0u32; MAP_VOXELS];
    let mut chunk = [0u8; 240];
    let pa = HeapPyramidStorage::with_capacity(PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let pb = HeapPyramidStorage::with_capacity(PYRAMID_ENTRIES, FOOTPRINT_WORDS);
    let report = selftest::run(&mut a, &mut b, &mut r, &mut scratch, &mut chunk, pa, pb, |_| {}).unwrap();
    report.to_string().lines().map(str::to_string).collect()
}

#[test]
fn firmware_matches_the_host_bit_for_bit() {
    if !have("qemu-system-arm", "--version") {
        eprintln!("skipping: qemu-system-arm not found (tests/run installs it)");
        return;
    }
    let firmware = cosem_tests::workspace_root().join("firmware");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let build = Command::new(cargo)
        .args(["build", "--release", "--locked"])
        .current_dir(&firmware)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .output()
        .expect("cargo build in firmware/");
    let stderr = String::from_utf8_lossy(&build.stderr);
    if stderr.contains("target may not be installed") {
        eprintln!("skipping: thumbv7em-none-eabihf not installed (tests/run installs it)");
        return;
    }
    assert!(build.status.success(), "firmware build failed:\n{stderr}");
    // Run it as firmware/.cargo/config.toml's runner does, with UART0 to a file.
    let tmp = tempfile::tempdir().unwrap();
    let uart0 = tmp.path().join("uart0.txt");
    let elf = firmware.join("target/thumbv7em-none-eabihf/release/cosem-firmware");
    let out = Command::new("qemu-system-arm")
        .args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-display", "none", "-icount", "shift=0"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-serial")
        .arg(format!("file:{}", uart0.display()))
        .arg("-kernel")
        .arg(&elf)
        .output()
        .expect("run qemu-system-arm");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "firmware failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let target: Vec<&str> = stdout.lines().filter(|l| l.starts_with("selftest ")).collect();
    let host = host_lines();
    for line in &host {
        assert!(target.contains(&line.as_str()), "target differs from host on\n  {line}\ntarget said:\n{stdout}");
    }
    assert!(host.iter().any(|l| l.contains("status=Converged")), "{host:?}");
    // The onboard work is measured (and printed for the closing note).
    let work = target.iter().find(|l| l.contains("match_instructions=")).expect("instruction count");
    eprintln!("{work}");
    // The UART driver carried the verdict out of UART0.
    let uart = std::fs::read_to_string(&uart0).unwrap();
    let digest_b =
        host.iter().find_map(|l| l.strip_prefix("selftest digests=")).and_then(|d| d.split(',').nth(1)).unwrap();
    assert_eq!(uart, format!("cosem selftest Converged {digest_b}\n"));
}

/// The core's allocation-free map-file reader (used on the chip) reads what
/// the host writes: the same voxels.
#[test]
fn core_reads_the_hosts_map_files() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    cosem_tests::synth(&seq, 2, 21);
    let file = tmp.path().join("m.cmap");
    cosem_tests::cosem_ok(&[
        "map",
        "--data",
        &seq.display().to_string(),
        "--frames",
        "0:2",
        "--voxel",
        "0.5",
        "-o",
        &file.display().to_string(),
    ]);
    let bytes = std::fs::read(&file).unwrap();
    let (header, host_map) = cosem_host::cmap::read(&file).unwrap();
    let mut core_map = new_map(header.voxel_count as usize, MapConfig::with_resolution(0.5)).unwrap();
    let info = cosem_core::wire::mapfile::read_into(&bytes, &mut core_map).unwrap();
    assert_eq!(info.voxel_count as usize, host_map.len());
    assert_eq!(core_map.voxels(), host_map.voxels());
    let mut bad = bytes.clone();
    bad[bytes.len() / 2] ^= 1;
    assert_eq!(
        cosem_core::wire::mapfile::read_into(&bad, &mut core_map),
        Err(cosem_core::wire::mapfile::MapFileError::Checksum)
    );
}
