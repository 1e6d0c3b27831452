//! Puts the memory layout where the linker finds it, as memory.x: the 1 MiB
//! budget layout; the pair robot also gets robot-budget.x (512 KiB with its
//! stack).
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    // Every binary holds RAM to 1 MiB.
    fs::copy("memory-budget.x", out.join("memory.x")).expect("copy the memory layout");
    // cortex-m-rt's `device` link script includes device.x (the weak
    // aliases of named interrupt handlers a PAC would give): none here, the
    // vector's entries are in lib.rs.
    fs::write(out.join("device.x"), "/* mps2-an386: interrupt vector in lib.rs */\n").expect("write device.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-budget.x");
    // The pair robot: statics and stack within 512 KiB.
    fs::copy("robot-budget.x", out.join("robot-budget.x")).expect("copy the robot's budget");
    println!("cargo:rustc-link-arg-bin=robot=-Trobot-budget.x");
    println!("cargo:rerun-if-changed=robot-budget.x");
    // defmt's linker script only when its logger is linked in.
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
