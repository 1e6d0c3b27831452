//! Puts the memory layout where the linker finds it, as memory.x: the 1 MiB
//! budget layout, or with the `bench` feature the 4 MiB one.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    // The budget build holds RAM to 1 MiB; the benchmark build may use 4 MiB.
    let layout = if env::var_os("CARGO_FEATURE_BENCH").is_some() { "memory-bench.x" } else { "memory-budget.x" };
    fs::copy(layout, out.join("memory.x")).expect("copy the memory layout");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-budget.x");
    println!("cargo:rerun-if-changed=memory-bench.x");
    // defmt's linker script only when its logger is linked in.
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
