//! Where a board's firmware is, and building it: a binary at its default
//! path is built (or brought up to date) before a run, so a run never uses
//! a stale build.

use crate::error::Error;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Where `cargo build --release` in firmware/ puts the robot binary.
pub const DEFAULT_FIRMWARE: &str = "firmware/target/thumbv7em-none-eabihf/release/robot";

/// The robot firmware to run: at the default path (from the repository
/// root) it is built, or brought up to date, first (a no-op when it is),
/// so a run never uses a stale build; any other path must exist.
pub fn firmware(path: &Path) -> Result<PathBuf, Error> {
    let dir = PathBuf::from("firmware");
    // A binary at the default place (robot, team) is built first.
    let built_here = Path::new(DEFAULT_FIRMWARE).parent();
    let bin = path.file_name().and_then(|b| b.to_str()).unwrap_or("robot");
    let default = path.parent() == built_here
        && matches!(bin, "robot" | "team" | "stm32f405-robot" | "stm32f405-sender" | "stm32f405-team");
    if !default || !dir.join("Cargo.toml").exists() {
        return if path.exists() {
            Ok(path.to_path_buf())
        } else {
            Err(Error::Invalid(format!(
                "{}: no such firmware (build it with `cargo build --release` in firmware/)",
                path.display()
            )))
        };
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(&cargo)
        .args(["build", "--release", "--bin", bin])
        .current_dir(&dir)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .output()
        .map_err(|source| Error::Io { path: PathBuf::from(cargo), source })?;
    if !out.status.success() || !path.exists() {
        return Err(Error::Invalid(format!("building the firmware failed:\n{}", String::from_utf8_lossy(&out.stderr))));
    }
    Ok(path.to_path_buf())
}
