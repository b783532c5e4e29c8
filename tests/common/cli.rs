//! Running the `mireg` binary from an integration test.

#![allow(dead_code)]

/// `mireg ARGS`, run to completion: its output, whatever its exit status.
pub fn mireg(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .output()
        .unwrap()
}

/// [`mireg`], which must succeed (its stderr is the failure's message).
pub fn mireg_ok(args: &[&str]) -> std::process::Output {
    let run = mireg(args);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    run
}
