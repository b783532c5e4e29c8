//! Finding 6 of the third round: `map`, `evaluate`, `export`, `sweep` and `stitch` blocked
//! forever on a FIFO, and `pair` clouds, `--gt` and `--config` naming `/dev/zero` read until
//! memory ran out. Every command now refuses what is not a regular file before opening it
//! (`mireg::io::input_file`), and caps what it reads from files small by nature.

use super::*;
use std::time::{Duration, Instant};

/// Runs mireg with `args`, killing it after `limit`; `None` when it had to be killed.
fn mireg_within(args: &[&str], limit: Duration) -> Option<Output> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("mireg runs");
    let start = Instant::now();
    while start.elapsed() < limit {
        if child.try_wait().unwrap().is_some() {
            return Some(child.wait_with_output().unwrap());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    None
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// Each command, with a FIFO, a device or a directory where it expects a file, ends at once
/// with exit 2 and an error naming that path and what it is; nothing is written.
#[test]
fn special_files_are_refused_before_they_are_opened() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fifo = d.join("in.mcap");
    mkfifo(&fifo);
    let fifo_ply = d.join("cloud.ply");
    mkfifo(&fifo_ply);
    let folder = d.join("folder.toml");
    std::fs::create_dir(&folder).unwrap();
    let fixture = fixture();
    let cloud = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim/rgbd5_00000.ply");
    let (fx, cl) = (fixture.to_str().unwrap(), cloud.to_str().unwrap());
    let (fi, fp, fo) = (
        fifo.to_str().unwrap(),
        fifo_ply.to_str().unwrap(),
        folder.to_str().unwrap(),
    );
    let out = d.join("out");
    let o = out.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str, &str)> = vec![
        (vec!["map", fi, "-o", "x.ply"], fi, "a FIFO"),
        (vec!["map", fo, "-o", "x.ply"], fo, "a directory"),
        (vec!["evaluate", fi], fi, "a FIFO"),
        (vec!["export", fi, "--format", "tum"], fi, "a FIFO"),
        (vec!["sweep", fi, "--quick"], fi, "a FIFO"),
        (vec!["stitch", fx, fi, "-o", o], fi, "a FIFO"),
        (vec!["pair", fp, cl, "--voxel", "0.05"], fp, "a FIFO"),
        (
            vec!["pair", cl, cl, "--gt", "/dev/zero"],
            "/dev/zero",
            "a character device",
        ),
        (vec!["pair", cl, cl, "--gt", fi], fi, "a FIFO"),
        (
            vec!["pair", cl, cl, "--config", "/dev/urandom"],
            "/dev/urandom",
            "a character device",
        ),
        (vec!["register", fx, "-o", o, "--config", fi], fi, "a FIFO"),
        (
            vec!["register", fx, "-o", o, "--config", fo],
            fo,
            "a directory",
        ),
        (
            vec!["evaluate", fx, "--gt", "/dev/zero", "--gt-format", "tum"],
            "/dev/zero",
            "a character device",
        ),
        (
            vec!["evaluate", fx, "--gt", fi, "--gt-format", "kitti"],
            fi,
            "a FIFO",
        ),
    ];
    for (args, path, kind) in cases {
        let run = mireg_within(&args, Duration::from_secs(20))
            .unwrap_or_else(|| panic!("{args:?} still running after 20 s"));
        let e = stderr(&run);
        assert_eq!(run.status.code(), Some(2), "{args:?}: {e}");
        assert!(
            e.contains(&format!("{path}: is {kind}, not a regular file")),
            "{args:?}: {e}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}

/// A configuration of 2 MiB (over [`mireg::io::input_file::MAX_CONFIG_BYTES`]) is refused
/// before it is parsed, naming the file and the limit.
#[test]
fn a_configuration_file_is_read_up_to_its_limit() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("big.toml");
    std::fs::write(&config, "# padding\n".repeat(200_000)).unwrap();
    let cloud = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim/rgbd5_00000.ply");
    let c = cloud.to_str().unwrap();
    let run = mireg(&["pair", c, c, "--config", config.to_str().unwrap()]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(e.contains(config.to_str().unwrap()), "{e}");
    assert!(
        e.contains("more than the 1048576 bytes a configuration file may hold"),
        "{e}"
    );
}

/// A ROS 2 bag whose `metadata.yaml` is a FIFO or a directory said "directory without a
/// metadata.yaml" (finding 8); it now says what the file is.
#[test]
fn a_bag_whose_metadata_is_not_a_file_says_so() {
    let dir = tempfile::tempdir().unwrap();
    for (name, make) in [
        ("fifo_bag", mkfifo as fn(&Path)),
        ("dir_bag", |p: &Path| std::fs::create_dir(p).unwrap()),
    ] {
        let bag = dir.path().join(name);
        std::fs::create_dir(&bag).unwrap();
        make(&bag.join("metadata.yaml"));
        let run = mireg_within(&["info", bag.to_str().unwrap()], Duration::from_secs(20))
            .expect("info ends");
        let e = stderr(&run);
        assert_eq!(run.status.code(), Some(2), "{e}");
        assert!(e.contains("metadata.yaml: is a"), "{e}");
        assert!(!e.contains("without a metadata.yaml"), "{e}");
    }
}
