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

/// The `.mireg-bag-*` directories in `dir`.
fn bag_temporaries(dir: &Path) -> Vec<String> {
    listing(dir)
        .into_iter()
        .filter(|n| n.starts_with(".mireg-bag-"))
        .collect()
}

/// A WAL bag with a hot `-wal` is read through a private copy of its `.db3` and `-wal` in a
/// named directory `$TMPDIR/.mireg-bag-PID-*` (SQLite opens files by name). SIGINT or SIGTERM
/// while the copy is open left it behind ("no output written" said nothing of it); now the
/// signal handler removes it. After SIGKILL it stays, and the next run removes it.
#[test]
fn a_signal_while_a_wal_bag_is_read_through_a_private_copy_leaves_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let bag = super::wal_bags::hot_wal_bag(dir.path());
    for (sig, code) in [
        (libc::SIGINT, Some(130)),
        (libc::SIGTERM, Some(143)),
        (libc::SIGKILL, None),
    ] {
        let work = dir.path().join(format!("tmp{sig}"));
        std::fs::create_dir(&work).unwrap();
        let out = dir.path().join("o.mcap");
        let mut child = Command::new(env!("CARGO_BIN_EXE_mireg"))
            .args([
                "register",
                bag.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--voxel",
                "0.05",
            ])
            .env("TMPDIR", &work)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // The signal goes once the private copy is being written into its directory (made when
        // the bag is opened, kept until the run ends: registering the four clouds takes far
        // longer than this wait).
        let copying = || {
            bag_temporaries(&work)
                .iter()
                .any(|d| std::fs::read_dir(work.join(d)).is_ok_and(|mut e| e.next().is_some()))
        };
        while !copying() {
            assert!(child.try_wait().unwrap().is_none(), "ended before copying");
            std::thread::yield_now();
        }
        // SAFETY: signals a child of this process.
        unsafe { libc::kill(child.id() as i32, sig) };
        let run = child.wait_with_output().unwrap();
        assert_eq!(run.status.code(), code, "signal {sig}: {}", stderr(&run));
        assert!(!out.exists(), "signal {sig}");
        if code.is_some() {
            assert!(
                listing(&work).is_empty(),
                "signal {sig}: {:?}",
                listing(&work)
            );
        } else {
            // Killed: the copy stays until the next run that opens a bag.
            assert_eq!(bag_temporaries(&work).len(), 1, "{:?}", listing(&work));
            let info = Command::new(env!("CARGO_BIN_EXE_mireg"))
                .args(["info", bag.to_str().unwrap()])
                .env("TMPDIR", &work)
                .output()
                .unwrap();
            assert!(info.status.success(), "{}", stderr(&info));
            assert!(listing(&work).is_empty(), "{:?}", listing(&work));
        }
    }
}
