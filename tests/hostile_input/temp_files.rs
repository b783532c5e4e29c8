//! Finding 3 of the third round: Ctrl-C or SIGTERM during a `file`-mode decompression left
//! `$TMPDIR/.mireg-bag-*` (1–2.5 GB) behind, and the next run did not remove it. Decompressed
//! copies are now unnamed files (nothing to leave, whatever ends the process); a named
//! directory, where one is needed, carries the process id, and the next run that opens a bag
//! removes those of dead processes.

use super::*;

fn file_mode_fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/bags/icl4_mcap_zstd_file")
}

/// A stale directory of a dead process is removed by the next run, one of a live process kept,
/// and the run leaves nothing named in `$TMPDIR`.
#[test]
fn stale_temporaries_of_dead_processes_are_removed_by_the_next_run() {
    let tmp = tempfile::tempdir().unwrap();
    // Above Linux's largest pid (2^22): no such process.
    let stale = tmp.path().join(".mireg-bag-999999999-Ab3dE9");
    let live = tmp
        .path()
        .join(format!(".mireg-bag-{}-Zx81Qa", std::process::id()));
    let other = tmp.path().join(".mireg-bag-notapid");
    for d in [&stale, &live, &other] {
        std::fs::create_dir(d).unwrap();
        std::fs::write(d.join("bag_0.mcap"), b"left behind").unwrap();
    }
    let run = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(["info", file_mode_fixture().to_str().unwrap()])
        .env("TMPDIR", tmp.path())
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", stderr(&run));
    let mut want = vec![
        ".mireg-bag-notapid".to_string(),
        format!(".mireg-bag-{}-Zx81Qa", std::process::id()),
    ];
    want.sort();
    assert_eq!(listing(tmp.path()), want);
}

/// SIGINT, SIGTERM or SIGKILL while a `file`-mode bag is being read leave nothing in `$TMPDIR`.
#[test]
fn a_signal_during_a_file_mode_run_leaves_no_temporary() {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGKILL] {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        std::fs::create_dir(&out).unwrap();
        let work = tmp.path().join("tmp");
        std::fs::create_dir(&work).unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_mireg"))
            .args([
                "register",
                file_mode_fixture().to_str().unwrap(),
                "-o",
                out.join("o.mcap").to_str().unwrap(),
            ])
            .env("TMPDIR", &work)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(60));
        // SAFETY: signals a child of this process.
        unsafe { libc::kill(child.id() as i32, sig) };
        let run = child.wait_with_output().unwrap();
        assert!(
            !run.status.success() || listing(&out).len() == 1,
            "signal {sig}"
        );
        assert!(
            listing(&work).is_empty(),
            "signal {sig}: {:?}",
            listing(&work)
        );
    }
}
