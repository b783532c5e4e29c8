//! What a new user met (issue 47, item 5), at the process boundary: each wrong input gets a
//! message that names it, says what the command reads and what to run first; an output in a
//! missing folder is refused by its own path before anything is read or written; `--help` says
//! what the defaults really are.

use std::path::{Path, PathBuf};

#[path = "common/cli.rs"]
mod cli;
use cli::mireg;

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// `mireg ARGS`, which must fail with exit code 2: its stderr.
fn refused(args: &[&str]) -> String {
    let run = mireg(args);
    let e = String::from_utf8_lossy(&run.stderr).into_owned();
    assert_eq!(run.status.code(), Some(2), "{args:?}: {e}");
    e
}

/// Names of the files in `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// `evaluate`, `export` and `map` on a raw ROS 1 bag, a ROS 2 bag directory and an MCAP that
/// was never registered: each names the input, what it is, and `mireg register INPUT` to run
/// first, with the output that writes.
#[test]
fn commands_on_unregistered_logs_say_to_run_register_first() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("map.ply");
    let map = map.to_str().unwrap();
    let inputs = [
        ("fixtures/bags/icl4_none.bag", "a ROS 1 bag"),
        ("fixtures/bags/icl4_db3", "a ROS 2 bag directory"),
        ("fixtures/icl_livingroom1.mcap", "has no /mireg/pose topic"),
    ];
    for (rel, what) in inputs {
        let input = fixture(rel);
        let input = input.to_str().unwrap();
        let stem = Path::new(rel).file_stem().unwrap().to_str().unwrap();
        for (command, args) in [
            ("evaluate", vec!["evaluate", input]),
            ("export", vec!["export", input, "--format", "tum"]),
            ("map", vec!["map", input, "-o", map]),
        ] {
            let e = refused(&args);
            assert!(e.contains(input) && e.contains(what), "{command}: {e}");
            assert!(
                e.contains(&format!("run `mireg register {input}` first")),
                "{command}: {e}"
            );
            assert!(e.contains(&format!("{stem}.mireg.mcap")), "{command}: {e}");
            assert!(e.contains(&format!("`mireg {command}`")), "{command}: {e}");
            assert!(!e.contains("bad magic"), "{command}: {e}");
        }
    }
    assert_eq!(listing(dir.path()), Vec::<String>::new(), "no map written");
    // A log with a reference: evaluate and export also say which topic could be named instead.
    let e = refused(&[
        "evaluate",
        fixture("fixtures/icl_livingroom1.mcap").to_str().unwrap(),
    ]);
    assert!(e.contains("--est-topic: /ground_truth/pose"), "{e}");
}

/// `evaluate DIR` said only "Is a directory": it now says what it reads, and names the MCAP
/// files the directory holds.
#[test]
fn evaluate_on_a_directory_says_what_it_expected() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let e = refused(&["evaluate", d]);
    assert!(e.contains(&format!("{d}: is a directory")), "{e}");
    assert!(
        e.contains("reads the MCAP file that `mireg register` writes"),
        "{e}"
    );
    std::fs::write(dir.path().join("drive.mireg.mcap"), b"").unwrap();
    let e = refused(&["evaluate", d]);
    assert!(e.contains("in it: drive.mireg.mcap"), "{e}");
}

/// A text file named `.bag` said "not an MCAP file": it now says it is no ROS 1 bag, shows how
/// it starts, and what `register` reads.
#[test]
fn a_text_file_named_bag_is_refused_as_no_bag() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("drive.bag");
    std::fs::write(&bag, "timestamp,x,y,z\n0,1,2,3\n").unwrap();
    let bag = bag.to_str().unwrap();
    for args in [
        vec!["register", bag],
        vec!["info", bag],
        vec!["evaluate", bag],
    ] {
        let e = refused(&args);
        assert!(e.contains(bag), "{args:?}: {e}");
        assert!(e.contains("not a ROS 1 bag"), "{args:?}: {e}");
        assert!(e.contains("#ROSBAG V2.0"), "{args:?}: {e}");
        assert!(e.contains("the text \"timestamp,x,y,z"), "{args:?}: {e}");
        assert!(e.contains("ROS 2 bag"), "what is accepted: {e}");
    }
    assert_eq!(listing(dir.path()), ["drive.bag"]);
}

/// An output in a missing folder named the internal temporary file (`.out.mcap.mireg-…partial`):
/// now the user's path and its folder, before the input is read, for every command that writes.
#[test]
fn an_output_in_a_missing_folder_is_named_by_the_users_path() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("results");
    let input = fixture("fixtures/bags/icl4_none.bag");
    let input = input.to_str().unwrap();
    let out = missing.join("out.mcap");
    let out = out.to_str().unwrap();
    let e = refused(&["register", input, "-o", out, "--no-loops"]);
    let folder = missing.to_str().unwrap();
    let says = |e: &str| {
        assert!(
            e.contains(&format!("its folder {folder} does not exist")),
            "{e}"
        );
        assert!(!e.contains(".partial") && !e.contains("os error"), "{e}");
    };
    says(&e);
    assert!(e.contains(out), "{e}");

    // A run output to map and export from.
    let run = dir.path().join("run.mcap");
    let fixture_log = fixture("fixtures/icl_livingroom1.mcap");
    cli::mireg_ok(&[
        "register",
        fixture_log.to_str().unwrap(),
        "-o",
        run.to_str().unwrap(),
        "--no-loops",
        "--quiet",
        "--end",
        "4",
    ]);
    let run = run.to_str().unwrap();
    let ply = missing.join("map.ply");
    says(&refused(&["map", run, "-o", ply.to_str().unwrap()]));
    let tum = missing.join("est.tum");
    says(&refused(&[
        "export",
        run,
        "--format",
        "tum",
        "-o",
        tum.to_str().unwrap(),
    ]));
    let stitched = missing.join("stitched.mcap");
    says(&refused(&[
        "stitch",
        fixture_log.to_str().unwrap(),
        run,
        "-o",
        stitched.to_str().unwrap(),
    ]));
    assert!(!missing.exists());
    assert_eq!(listing(dir.path()), ["run.mcap"]);
}

/// The help text of one option of `mireg register --help`: its line and the lines after it up
/// to the next option.
fn help_of(help: &str, option: &str) -> String {
    let mut lines = help
        .lines()
        .skip_while(|l| !l.trim_start().starts_with(option));
    let first = lines.next().unwrap_or_default().to_string();
    let rest: Vec<&str> = lines
        .take_while(|l| !l.trim_start().starts_with('-') && !l.trim_start().starts_with('<'))
        .collect();
    format!("{first} {}", rest.join(" "))
}

/// `--help` said `--voxel [default: 0.05]` (the default derives from the first cloud) and
/// `<INPUT>` "Input MCAP log" (bags and ROS 2 bag directories work too).
#[test]
fn register_help_says_the_true_defaults() {
    let run = cli::mireg_ok(&["register", "--help"]);
    let help = String::from_utf8_lossy(&run.stdout).into_owned();
    let voxel = help_of(&help, "--voxel");
    assert!(!voxel.contains("0.05"), "{voxel}");
    assert!(
        voxel.contains("first cloud") && voxel.contains("median range"),
        "{voxel}"
    );
    let input = help_of(&help, "<INPUT>");
    for accepted in ["MCAP", "ROS 1 bag", "ROS 2 bag directory"] {
        assert!(input.contains(accepted), "{input}");
    }
    // `pair` has no cloud stream to derive it from: its default stays 0.05 m.
    let run = cli::mireg_ok(&["pair", "--help"]);
    let pair = help_of(&String::from_utf8_lossy(&run.stdout), "--voxel");
    assert!(pair.contains("0.05"), "{pair}");
}

/// A reader that stops reading (`mireg export RUN --format tum | head -1`) ends the process by
/// SIGPIPE, as any Unix filter ends, not by a panic or an error in the printing: 3,000 poses are
/// more than a pipe buffers, so `mireg` is still writing when the reader goes.
#[cfg(unix)]
#[test]
fn a_reader_that_stops_ends_the_process_quietly() {
    use mireg::io::codec::{Header, Time, cdr};
    use mireg::io::mcap::log::OutputLog;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use std::io::Read;
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("poses.mcap");
    let mut out = OutputLog::create(&log, false, "ros2").unwrap();
    let channel = out.add_cdr_channel("/pose", cdr::POSE_STAMPED).unwrap();
    for k in 0..3000u64 {
        let t = 1_700_000_000_000_000_000 + k * 100_000_000;
        let header = Header {
            stamp: Time::from_ns(t as i64).unwrap(),
            frame_id: "map".into(),
        };
        let pose = Isometry3::from_parts(
            Translation3::new(0.1 * k as f64, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        out.write(channel, t, t, &cdr::encode_pose_stamped(&header, &pose))
            .unwrap();
    }
    out.finish().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(["export", log.to_str().unwrap(), "--format", "tum"])
        .args(["--topic", "/pose"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 64];
    let mut stdout = child.stdout.take().unwrap();
    stdout.read_exact(&mut first).unwrap();
    drop(stdout);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.is_empty(), "{err}");
    assert_eq!(out.status.signal(), Some(libc::SIGPIPE), "{:?}", out.status);
}
