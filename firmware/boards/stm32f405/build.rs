//! The memory layout (memory.x) for QEMU or for hardware, the main SRAM's
//! section, and the matching and team robots' stack budgets.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    let layout = if env::var_os("CARGO_FEATURE_HARDWARE").is_some() { "memory-hardware.x" } else { "memory-qemu.x" };
    fs::copy(layout, out.join("memory.x")).expect("copy the memory layout");
    fs::copy("sram.x", out.join("sram.x")).expect("copy the SRAM section");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg=-Tsram.x");
    // The matching robot: statics and stack within 192 KiB.
    fs::copy("robot-budget.x", out.join("robot-budget.x")).expect("copy the robot's budget");
    println!("cargo:rustc-link-arg-bin=stm32f405-robot=-Trobot-budget.x");
    // The team robot: its statics leave the pose graph's stack.
    fs::copy("team-budget.x", out.join("team-budget.x")).expect("copy the team robot's budget");
    println!("cargo:rustc-link-arg-bin=stm32f405-team=-Tteam-budget.x");
    for f in ["memory-qemu.x", "memory-hardware.x", "sram.x", "robot-budget.x", "team-budget.x"] {
        println!("cargo:rerun-if-changed={f}");
    }
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
