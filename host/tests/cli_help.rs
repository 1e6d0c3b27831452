//! The binary starts and lists its subcommands. (Having an integration test
//! here also makes `cargo test` build the `cosem` binary that the
//! end-to-end tests in `tests/` run.)

#[test]
fn help_lists_the_subcommands() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cosem")).arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for cmd in ["map", "info", "export", "synth", "bench", "demo"] {
        assert!(text.contains(cmd), "{cmd} missing from --help:\n{text}");
    }
}
