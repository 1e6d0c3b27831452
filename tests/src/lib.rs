//! Helpers for the end-to-end tests: find the `cosem` binary and the data.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_default()
}

/// Path of the `cosem` binary of this build: `COSEM_BIN`, else the one in
/// the test executable's profile folder, brought up to date once per test
/// process with `cargo build` (a no-op when it is), so a test never runs a
/// stale binary.
pub fn cosem_bin() -> PathBuf {
    if let Some(p) = std::env::var_os("COSEM_BIN") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe.parent().and_then(Path::parent).expect("target/<profile>/deps");
    static BUILD: std::sync::Once = std::sync::Once::new();
    BUILD.call_once(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args(["build", "--quiet", "-p", "cosem-host", "--bin", "cosem"]).current_dir(workspace_root());
        if profile_dir.file_name().is_some_and(|n| n == "release") {
            cmd.arg("--release");
        }
        let status = cmd.status().expect("run cargo build");
        assert!(status.success(), "cargo build of the cosem binary failed");
    });
    profile_dir.join(format!("cosem{}", std::env::consts::EXE_SUFFIX))
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

/// Runs `cosem` with arguments it must refuse as a usage error (exit 2,
/// no panic); returns stderr.
pub fn cosem_usage_err(args: &[&str]) -> String {
    let out = cosem(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "cosem {args:?}: exit status {:?}\n{stderr}", out.status);
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

/// Builds the firmware (all its binaries, release) once per test process and
/// returns the folder of its ELF files, or `None` after printing why the
/// test is skipped (no `qemu-system-arm` or no ARM target; `tests/run`
/// installs both).
pub fn firmware_elves() -> Option<PathBuf> {
    let have_qemu = Command::new("qemu-system-arm").arg("--version").output().map(|o| o.status.success());
    if !have_qemu.unwrap_or(false) {
        eprintln!("skipping: qemu-system-arm not found (tests/run installs it)");
        return None;
    }
    let firmware = workspace_root().join("firmware");
    static BUILD: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let built = BUILD.get_or_init(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let out = Command::new(cargo)
            .args(["build", "--release", "--locked", "--bins"])
            .current_dir(&firmware)
            .env_remove("CARGO_TARGET_DIR")
            .env_remove("RUSTFLAGS")
            .output()
            .map_err(|e| format!("cargo build in firmware/: {e}"))?;
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        if out.status.success() {
            Ok(())
        } else {
            Err(stderr)
        }
    });
    match built {
        Ok(()) => Some(firmware.join("target/thumbv7em-none-eabihf/release")),
        Err(e) if e.contains("target may not be installed") => {
            eprintln!("skipping: thumbv7em-none-eabihf not installed (tests/run installs it)");
            None
        }
        Err(e) => panic!("firmware build failed:\n{e}"),
    }
}

/// Runs `cmd` (a QEMU) to its end and returns what it printed; kills it
/// and fails the test when it runs past `limit` (a hung firmware must not
/// hang the tests). A panicking or faulting firmware exits at once with
/// its own code (see the firmware's `exit` module).
pub fn run_within(cmd: &mut Command, limit: std::time::Duration) -> Output {
    use std::io::Read;
    use std::process::Stdio;
    let mut child = cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start");
    let drain = |r: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut r) = r {
                let _ = r.read_to_end(&mut buf);
            }
            buf
        })
    };
    let out = drain(child.stdout.take().map(|s| Box::new(s) as Box<dyn Read + Send>));
    let err = drain(child.stderr.take().map(|s| Box::new(s) as Box<dyn Read + Send>));
    let deadline = std::time::Instant::now() + limit;
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            let stdout = out.join().unwrap_or_default();
            panic!("{cmd:?} still running after {limit:?}: killed\n{}", String::from_utf8_lossy(&stdout));
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    Output { status, stdout: out.join().unwrap_or_default(), stderr: err.join().unwrap_or_default() }
}

/// The mps2-an386 QEMU command line (firmware/qemu/, as the firmware's
/// cargo runner and the host use it) for `elf`, without `-serial` options.
pub fn qemu(elf: &Path) -> Command {
    cosem_host::boards::board::Board::Mps2An386.qemu_command(elf, &[])
}

/// Runs a Python script with `args` and gives its standard output, or
/// `None` after printing why it was skipped (no python3, or a module it
/// imports missing); any other failure fails the test.
pub fn python_or_skip(script: &str, args: &[&str]) -> Option<String> {
    match Command::new("python3").arg("-c").arg(script).args(args).output() {
        Ok(o) if o.status.success() => Some(String::from_utf8_lossy(&o.stdout).into_owned()),
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(err.contains("No module named"), "the Python script failed: {err}");
            eprintln!("skipped the Python script: {err}");
            None
        }
        Err(e) => {
            eprintln!("skipped the Python script: {e}");
            None
        }
    }
}
