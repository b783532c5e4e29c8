//! Finding 1 of the third round: a WAL-mode `.db3` (rosbag2's `resilient` preset) was altered —
//! `mireg info` created `-shm` and `-wal` files beside it — could not be read at all in a
//! read-only directory ("attempt to write a readonly database"), and a hot `-wal` left by a
//! crashed recorder gave "unable to open database file".

use super::*;
use mireg::io::codec::cdr;
use rusqlite::{Connection, OpenFlags};

/// The ROS 2 `.db3` fixture bag (4 clouds, 4 reference poses).
fn db3_bag() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/bags/icl4_db3")
}

const DB3: &str = "icl4_db3.db3";

/// Every file of `dir` with its bytes, by name.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    listing(dir)
        .into_iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).unwrap();
            (n, bytes)
        })
        .collect()
}

fn set_mode(path: &Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// A WAL-mode copy of the fixture bag in `dir/bag`: its database switched to
/// `journal_mode=WAL` and closed (so, as a recorder leaves it after a clean stop, no `-wal`).
fn wal_bag(dir: &Path) -> PathBuf {
    let bag = dir.join("bag");
    std::fs::create_dir(&bag).unwrap();
    for f in ["metadata.yaml", DB3] {
        std::fs::copy(db3_bag().join(f), bag.join(f)).unwrap();
    }
    let db = Connection::open(bag.join(DB3)).unwrap();
    let mode: String = db
        .query_row("PRAGMA journal_mode=WAL", [], |r| r.get(0))
        .unwrap();
    assert_eq!(mode, "wal");
    drop(db);
    // The header's read and write versions (bytes 18, 19) are 2 in a WAL-mode database.
    assert_eq!(std::fs::read(bag.join(DB3)).unwrap()[18..20], [2, 2]);
    assert_eq!(listing(&bag), ["icl4_db3.db3", "metadata.yaml"]);
    bag
}

/// Clouds in the `.db3` at `path` alone, read without its `-wal` (immutable: alters nothing).
fn clouds_without_wal(path: &Path) -> i64 {
    let uri = format!("file:{}?immutable=1", path.display());
    let db = Connection::open_with_flags(
        uri,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_URI,
    )
    .unwrap();
    db.query_row(
        "SELECT count(*) FROM messages JOIN topics ON topics.id = topic_id \
         WHERE topics.name = '/camera/depth/points'",
        [],
        |r| r.get(0),
    )
    .unwrap()
}

/// How a test runs `mireg` on a bag in a read-only directory: as this user when a read-only
/// directory stops it from creating files, else (root) as `nobody`, for whom it does; as root
/// itself when even that cannot be arranged (the read-only part is then skipped, and what is
/// left checked is that nothing was changed).
struct Runner {
    as_nobody: bool,
}

const NOBODY: u32 = 65534;

impl Runner {
    /// Decides for `ro_dir`, already made read-only; `dir` is the test's temporary directory.
    fn for_read_only(dir: &Path, ro_dir: &Path) -> Self {
        let probe = ro_dir.join(".probe");
        if std::fs::write(&probe, b"").is_err() {
            return Self { as_nobody: false };
        }
        std::fs::remove_file(&probe).unwrap();
        // Root: let `nobody` through the test's directory (0700 as made) and run it as them.
        set_mode(dir, 0o755);
        let ok = std::process::Command::new(env!("CARGO_BIN_EXE_mireg"))
            .arg("--version")
            .uid(NOBODY)
            .gid(NOBODY)
            .output()
            .is_ok_and(|o| o.status.success());
        if !ok {
            eprintln!(
                "running as root and cannot run mireg as uid {NOBODY}: the read-only directory \
                 part is skipped; checking only that the bag is left unchanged"
            );
        }
        Self { as_nobody: ok }
    }

    /// `mireg ARGS` with `TMPDIR` set to `tmp`.
    fn run(&self, tmp: &Path, args: &[&str]) -> Output {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_mireg"));
        cmd.args(args).env("TMPDIR", tmp);
        if self.as_nobody {
            cmd.uid(NOBODY).gid(NOBODY);
        }
        cmd.output().expect("mireg runs")
    }
}

use std::os::unix::process::CommandExt;

/// `info` and `register` on `bag` (made read-only here), which must succeed, leave every file of
/// it as it was, and leave nothing in their temporary directory; returns `info`'s output and the
/// registered log's messages.
fn read_only_runs(dir: &Path, bag: &Path) -> (String, Messages) {
    let before = snapshot(bag);
    set_mode(bag, 0o555);
    let runner = Runner::for_read_only(dir, bag);
    let out_dir = dir.join("out");
    std::fs::create_dir(&out_dir).unwrap();
    set_mode(&out_dir, 0o777);
    let tmp = dir.join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    set_mode(&tmp, 0o777);
    let out = out_dir.join("out.mcap");
    let b = bag.to_str().unwrap();
    let info = runner.run(&tmp, &["info", b]);
    let register = runner.run(
        &tmp,
        &[
            "register",
            b,
            "-o",
            out.to_str().unwrap(),
            "--voxel",
            "0.05",
            "--no-loops",
            "--quiet",
        ],
    );
    set_mode(bag, 0o755);
    assert!(info.status.success(), "info: {}", stderr(&info));
    assert!(register.status.success(), "register: {}", stderr(&register));
    assert_eq!(snapshot(bag), before, "the bag directory is unchanged");
    assert!(
        listing(&tmp).is_empty(),
        "temporary files left: {:?}",
        listing(&tmp)
    );
    (
        String::from_utf8_lossy(&info.stdout).into_owned(),
        messages(&out),
    )
}

/// The poses on `/mireg/pose`, each checked finite.
fn finite_poses(m: &Messages) -> usize {
    let mut n = 0;
    for (c, t, data) in &m.messages {
        if m.channels[c].0 == "/mireg/pose" {
            let (_, pose) = cdr::decode_pose_stamped(data).unwrap();
            let v = pose.to_homogeneous();
            assert!(v.iter().all(|x| x.is_finite()), "pose at {t}: {v}");
            n += 1;
        }
    }
    n
}

fn count_on(m: &Messages, topic: &str) -> usize {
    m.messages
        .iter()
        .filter(|(c, _, _)| m.channels[c].0 == topic)
        .count()
}

#[test]
fn a_wal_bag_in_a_read_only_directory_is_read_and_never_altered() {
    let dir = tempfile::tempdir().unwrap();
    let bag = wal_bag(dir.path());
    let (info, out) = read_only_runs(dir.path(), &bag);
    assert!(info.contains("4 messages"), "{info}");
    assert_eq!(finite_poses(&out), 4);
    assert_eq!(count_on(&out, "/camera/depth/points"), 4);
}

/// A copy of the fixture bag in `dir/bag` as a recorder killed mid-run leaves it: its last cloud
/// only in a non-empty `icl4_db3.db3-wal` beside the database (which, alone, holds 3 clouds).
pub(crate) fn hot_wal_bag(dir: &Path) -> PathBuf {
    let bag = wal_bag(dir);
    // The recorder: its database without the last cloud, checkpointed; then the last cloud
    // written into the write-ahead log and never checkpointed.
    let recorder_dir = dir.join("recorder");
    std::fs::create_dir(&recorder_dir).unwrap();
    let recording = recorder_dir.join(DB3);
    std::fs::rename(bag.join(DB3), &recording).unwrap();
    let db = Connection::open(&recording).unwrap();
    let (id, topic_id, stamp, data): (i64, i64, i64, Vec<u8>) = db
        .query_row(
            "SELECT messages.id, topic_id, timestamp, data FROM messages \
             JOIN topics ON topics.id = topic_id WHERE topics.name = '/camera/depth/points' \
             ORDER BY timestamp DESC LIMIT 1",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
        )
        .unwrap();
    db.execute("DELETE FROM messages WHERE id = ?1", [id])
        .unwrap();
    db.execute_batch("PRAGMA wal_checkpoint(TRUNCATE); PRAGMA wal_autocheckpoint=0;")
        .unwrap();
    db.execute(
        "INSERT INTO messages (id, topic_id, timestamp, data) VALUES (?1, ?2, ?3, ?4)",
        rusqlite::params![id, topic_id, stamp, data],
    )
    .unwrap();
    // What the crash leaves: the database and its log, copied while the recorder holds them.
    let mut wal = recording.as_os_str().to_owned();
    wal.push("-wal");
    assert!(
        std::fs::metadata(&wal).unwrap().len() > 0,
        "the cloud is in the -wal"
    );
    std::fs::copy(&recording, bag.join(DB3)).unwrap();
    std::fs::copy(&wal, bag.join("icl4_db3.db3-wal")).unwrap();
    drop(db);
    assert_eq!(clouds_without_wal(&bag.join(DB3)), 3);
    assert_eq!(
        listing(&bag),
        ["icl4_db3.db3", "icl4_db3.db3-wal", "metadata.yaml"]
    );
    bag
}

/// A recorder killed mid-run leaves its last messages in the `-wal`: they are read (the bag's 4th
/// cloud is only there), through a private copy, and the bag is left as it was.
#[test]
fn a_hot_wal_left_by_a_crashed_recorder_is_read_and_never_altered() {
    let dir = tempfile::tempdir().unwrap();
    let bag = hot_wal_bag(dir.path());
    let (info, out) = read_only_runs(dir.path(), &bag);
    assert!(
        info.contains("/camera/depth/points  sensor_msgs/msg/PointCloud2 (cdr), 4 messages"),
        "{info}"
    );
    assert_eq!(count_on(&out, "/camera/depth/points"), 4);
    assert_eq!(finite_poses(&out), 4);
}
