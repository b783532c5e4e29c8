//! Hostile input: each class of bad input the hardening issue found, generated here (or
//! committed under `fuzz/regressions/` when minimised, where `cargo test` also replays it
//! through every fuzz target), with the documented outcome asserted —
//! a typed error naming the file (and the offset or message), or a flagged frame with its
//! reason — and never a panic, an abort, a half-written output, or a changed input.
//!
//! Test names say the failure they prevent.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use mcap::records::{MessageHeader, Record};
use mireg::fuzzing::small_log;
use mireg::io::mcap::read::for_each_record;
use mireg::odometry::OdometryConfig;
use mireg::pipeline::PairConfig;
use mireg::register::{RegisterOptions, register_log};
use rand::{RngExt, SeedableRng};

/// The global allocator, recording the largest single allocation each thread asks for, so that
/// a test can assert that a hostile input never drove one (Linux overcommit would otherwise let a
/// 4 GiB reservation pass unnoticed).
struct Largest;

thread_local! {
    static LARGEST: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

// SAFETY: forwards to the system allocator; the thread-local is a const-initialised Cell, whose
// access neither allocates nor runs a destructor.
unsafe impl std::alloc::GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        LARGEST.with(|c| c.set(c.get().max(layout.size())));
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        LARGEST.with(|c| c.set(c.get().max(new_size)));
        unsafe { std::alloc::System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Largest = Largest;

/// The largest single allocation \[bytes\] that `f` made on this thread.
fn largest_allocation<T>(f: impl FnOnce() -> T) -> (T, usize) {
    LARGEST.with(|c| c.set(0));
    let r = f();
    (r, LARGEST.with(|c| c.get()))
}

/// Allocations a hostile input of a few kilobytes may justify: 64 MiB.
const MODEST: usize = 64 << 20;

fn mireg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .output()
        .expect("mireg runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn regression(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions/mcap_records")
        .join(name)
}

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

/// [`options`] that refuse a damaged log (`--strict`).
fn strict(input: &Path, output: &Path) -> RegisterOptions {
    RegisterOptions {
        read_policy: mireg::io::damage::ReadPolicy::STRICT,
        ..options(input, output)
    }
}

fn options(input: &Path, output: &Path) -> RegisterOptions {
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.05,
            seed: 1,
            ..Default::default()
        },
        ..Default::default()
    };
    RegisterOptions {
        force: true,
        command_line: "test".into(),
        ..RegisterOptions::new(input, output, config)
    }
}

/// The small seed log, zstd chunks of 8 KiB (several chunks, with message indexes and summary).
fn small(frames: usize) -> Vec<u8> {
    small_log(
        frames,
        mcap::WriteOptions::new()
            .chunk_size(Some(8 << 10))
            .compression(Some(mcap::Compression::Zstd)),
    )
}

/// Names of the files in `dir`.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Top-level records of an MCAP: (offset, opcode, body length).
fn top_level_records(bytes: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() - 8 {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        out.push((at, bytes[at], len));
        at += 9 + len;
    }
    out
}

/// A log's messages as (topic, log time, payload), its schemas and channels, in file order.
struct Messages {
    channels: BTreeMap<u16, (String, String, String, Vec<u8>, String)>,
    messages: Vec<(u16, u64, Vec<u8>)>,
}

fn messages(path: &Path) -> Messages {
    let mut schemas = BTreeMap::new();
    let mut m = Messages {
        channels: BTreeMap::new(),
        messages: Vec::new(),
    };
    for_each_record(path, |r| {
        match r {
            Record::Schema { header, data } => {
                schemas.insert(header.id, (header.name, header.encoding, data.to_vec()));
            }
            Record::Channel(c) => {
                let (n, e, d) = schemas[&c.schema_id].clone();
                m.channels
                    .insert(c.id, (c.topic, n, e, d, c.message_encoding));
            }
            Record::Message { header, data } => {
                m.messages
                    .push((header.channel_id, header.log_time, data.to_vec()))
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    m
}

/// Writes `m`'s messages in the order `order` (indexes into `m.messages`), with writer options.
fn rewrite(m: &Messages, order: &[usize], opts: mcap::WriteOptions) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = opts.profile("ros2").create(&mut out).unwrap();
    let mut ids = BTreeMap::new();
    for (&id, (topic, name, enc, data, menc)) in &m.channels {
        let s = w.add_schema(name, enc, data).unwrap();
        ids.insert(id, w.add_channel(s, topic, menc, &BTreeMap::new()).unwrap());
    }
    for (k, &i) in order.iter().enumerate() {
        let (c, t, data) = &m.messages[i];
        let header = MessageHeader {
            channel_id: ids[c],
            sequence: k as u32,
            log_time: *t,
            publish_time: *t,
        };
        w.write_to_known_channel(&header, data).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    out.into_inner()
}

/// The JSON objects on `/mireg/stats` of a registered log.
fn stats(path: &Path) -> Vec<serde_json::Value> {
    let m = messages(path);
    m.messages
        .iter()
        .filter(|(c, _, _)| m.channels[c].0 == "/mireg/stats")
        .map(|(_, _, d)| serde_json::from_slice(d).unwrap())
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Finding 1: record lengths
// ---------------------------------------------------------------------------------------------

/// A 37-byte file whose header record claims 2^60 bytes aborted `evaluate` and `export` (and
/// `register` without a readable summary) with "memory allocation of … bytes failed".
#[test]
fn record_length_past_the_end_is_an_error_not_an_abort() {
    let dir = tempfile::tempdir().unwrap();
    let input = regression("record_length_2e60.mcap");
    let out = dir.path().join("out.mcap");
    let runs = [
        mireg(&[
            "register",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]),
        mireg(&["evaluate", input.to_str().unwrap()]),
        mireg(&["export", input.to_str().unwrap(), "--format", "tum"]),
    ];
    for run in &runs {
        let e = stderr(run);
        assert_eq!(run.status.code(), Some(2), "{e}");
        assert!(e.contains("record_length_2e60.mcap"), "{e}");
        assert!(e.contains("claims 1152921504606846976 bytes"), "{e}");
    }
    assert!(listing(dir.path()).is_empty());
    // The same lie after a valid start, in a log whose summary is cut off.
    let mut bytes = small(2);
    let recs = top_level_records(&bytes);
    let data_end = recs
        .iter()
        .position(|r| r.1 == mcap::records::op::DATA_END)
        .unwrap();
    let (at, _, _) = recs[data_end / 2];
    bytes.truncate(at);
    bytes.push(0x05);
    bytes.extend((1u64 << 60).to_le_bytes());
    bytes.extend([0u8; 20]);
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes).unwrap();
    let (results, largest) = largest_allocation(|| {
        [
            mireg::io::mcap::log::list_channels(&cut).map(|_| ()),
            for_each_record(&cut, |_| Ok(())),
        ]
    });
    assert!(largest < MODEST, "allocated {largest} bytes at once");
    for r in results
        .into_iter()
        .chain([register_log(&strict(&cut, &out)).map(|_| ())])
    {
        let e = r.unwrap_err().to_string();
        assert!(e.contains("cut.mcap") && e.contains("claims"), "{e}");
    }
    assert!(!out.exists());
    // Read as a log cut short (the default): the messages before the lie, the lie named.
    let (summary, largest) = largest_allocation(|| register_log(&options(&cut, &out)));
    assert!(largest < MODEST, "allocated {largest} bytes at once");
    let damage = summary.unwrap().input_damage.expect("damage reported");
    assert_eq!(damage.cut_at, Some(at as u64));
    assert!(damage.cut_reason.unwrap().contains("claims"));
    assert!(out.exists());
}

/// A 27 KB log whose attachment name claims 4 GiB made the mcap crate's parser reserve 4 GiB (the
/// `mcap_records` fuzz target's out-of-memory); every string length is now checked against its
/// record first. In the summary section, such a record makes the summary unreadable, and the
/// data section is read instead.
#[test]
fn a_string_longer_than_its_record_is_refused_before_allocation() {
    // The second: a metadata map whose last key has no value inside the map (3.7 GB).
    for name in ["attachment_name_4gib.mcap", "map_key_without_value.mcap"] {
        let input = regression(name);
        let (r, largest) = largest_allocation(|| for_each_record(&input, |_| Ok(())));
        assert!(
            largest < MODEST,
            "{name}: allocated {largest} bytes at once"
        );
        let e = r.unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("runs past its end"), "{e}");
    }
    let dir = tempfile::tempdir().unwrap();
    let mut log = small(2);
    let recs = top_level_records(&log);
    let data_end = recs
        .iter()
        .position(|r| r.1 == mcap::records::op::DATA_END)
        .unwrap();
    let (at, _, _) = *recs[data_end..]
        .iter()
        .find(|r| r.1 == mcap::records::op::CHANNEL)
        .unwrap();
    // Channel: opcode, length, id (2), schema id (2), topic length (4).
    log[at + 9 + 4..at + 9 + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let path = dir.path().join("summary.mcap");
    std::fs::write(&path, &log).unwrap();
    let (channels, largest) = largest_allocation(|| mireg::io::mcap::log::list_channels(&path));
    assert!(largest < MODEST, "allocated {largest} bytes at once");
    let topics: Vec<String> = channels.unwrap().into_iter().map(|c| c.topic).collect();
    assert_eq!(topics, ["/points", "/ground_truth/pose", "/notes"]);
}

/// Every cut of a valid log at a record boundary, and inside each record, is with `--strict` an
/// error naming the file (or, once the data section is complete, a full output); by default it is
/// read as far as it goes, or, when that holds no cloud to register, an error naming the file.
/// Never a panic or an output left by an error.
#[test]
fn truncation_at_every_record_boundary_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = small(2);
    let input = dir.path().join("cut.mcap");
    let out = dir.path().join("out.mcap");
    let data_end = top_level_records(&bytes)
        .iter()
        .find(|r| r.1 == mcap::records::op::DATA_END)
        .map(|r| r.0 + 9 + r.2)
        .unwrap();
    for (at, _, len) in top_level_records(&bytes) {
        for cut in [at, at + 5, at + 9 + len / 2] {
            std::fs::write(&input, &bytes[..cut]).unwrap();
            let _ = std::fs::remove_file(&out);
            let scanned = for_each_record(&input, |_| Ok(()));
            let registered = register_log(&strict(&input, &out));
            if cut < data_end {
                let e = scanned.unwrap_err().to_string();
                assert!(e.contains("cut.mcap"), "cut at {cut}: {e}");
                let e = registered.unwrap_err().to_string();
                assert!(e.contains("cut.mcap"), "cut at {cut}: {e}");
                assert!(!out.exists(), "cut at {cut}: output left behind");
                match register_log(&options(&input, &out)) {
                    Ok(summary) => {
                        let damage = summary.input_damage.expect("damage reported");
                        assert!(
                            damage.cut_at.is_some_and(|c| c <= cut as u64),
                            "cut at {cut}"
                        );
                        assert!(out.exists(), "cut at {cut}");
                    }
                    Err(e) => {
                        let e = e.to_string();
                        assert!(e.contains("cut.mcap"), "cut at {cut}: {e}");
                        assert!(!out.exists(), "cut at {cut}: output left behind");
                    }
                }
            } else {
                assert!(scanned.is_ok() && registered.is_ok(), "cut at {cut}");
            }
            assert!(
                listing(dir.path())
                    .iter()
                    .all(|n| n == "cut.mcap" || n == "out.mcap")
            );
        }
    }
}

/// Single random byte changes of a valid log (as the campaign's 1 500 mutations, 14 of which
/// crashed): each read path returns, with or without chunk CRCs to catch the change first.
#[test]
fn random_byte_changes_never_crash_a_reader() {
    let with_crc = small(2);
    // Uncompressed chunks whose CRC is 0 (not checked): changes reach the record parsers.
    let mut without_crc = small_log(
        2,
        mcap::WriteOptions::new()
            .chunk_size(Some(8 << 10))
            .compression(None),
    );
    for (at, op, _) in top_level_records(&without_crc.clone()) {
        if op == mcap::records::op::CHUNK {
            without_crc[at + 9 + 24..at + 9 + 28].fill(0); // uncompressed_crc
        }
    }
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(13);
    for (k, base) in [with_crc, without_crc].iter().enumerate() {
        for n in 0..600 {
            let mut b = base.clone();
            let i = rng.random_range(8..b.len() - 8);
            b[i] = match n % 3 {
                0 => b[i] ^ (1 << rng.random_range(0..8)),
                1 => 0xff,
                _ => rng.random(),
            };
            mireg::fuzzing::mcap_records(&b);
            if n % 20 == k {
                mireg::fuzzing::register_input(&b);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Findings 2–5: outputs
// ---------------------------------------------------------------------------------------------

/// `mireg export out.mcap -o out.mcap` replaced the log by TUM text (also through a hard link).
#[test]
fn export_never_overwrites_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.mcap");
    std::fs::write(&log, small(2)).unwrap();
    let reg = dir.path().join("r.mcap");
    register_log(&options(&log, &reg)).unwrap();
    let before = std::fs::read(&reg).unwrap();
    let link = dir.path().join("link.mcap");
    std::fs::hard_link(&reg, &link).unwrap();
    for target in [&reg, &link] {
        let run = mireg(&[
            "export",
            reg.to_str().unwrap(),
            "--format",
            "tum",
            "-o",
            target.to_str().unwrap(),
        ]);
        assert_eq!(run.status.code(), Some(2));
        assert!(stderr(&run).contains("is the input"), "{}", stderr(&run));
        assert_eq!(std::fs::read(&reg).unwrap(), before);
    }
}

/// `export` wrote in place: on a full disk a truncated file stayed at the target, and the error
/// said "(output stream)". A file size limit (`RLIMIT_FSIZE`, with `SIGXFSZ` ignored) fails the
/// writes the same way a full disk does.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn export_on_a_full_disk_leaves_no_file_and_names_it() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.mcap");
    std::fs::write(&log, small(40)).unwrap();
    let reg = dir.path().join("r.mcap");
    register_log(&options(&log, &reg)).unwrap();
    let est = dir.path().join("est.tum");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mireg"));
    cmd.args([
        "export",
        reg.to_str().unwrap(),
        "--format",
        "tum",
        "-o",
        est.to_str().unwrap(),
    ]);
    // SAFETY: only async-signal-safe calls (setrlimit, signal) between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 1000,
                rlim_max: 1000,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &limit);
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let run = cmd.output().unwrap();
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(e.contains("est.tum") && !e.contains("output stream"), "{e}");
    assert_eq!(listing(dir.path()), ["a.mcap", "r.mcap"]);
}

/// `register -o FIFO --force` replaced the FIFO (as root, `-o /dev/null --force` replaced
/// /dev/null) with a regular file.
#[cfg(unix)]
#[test]
fn force_never_replaces_a_special_file() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.mcap");
    std::fs::write(&input, small(2)).unwrap();
    let log = dir.path().join("a.mcap");
    register_log(&options(&input, &log)).unwrap();
    let fifo = dir.path().join("fifo");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    for args in [
        vec![
            "register",
            log.to_str().unwrap(),
            "-o",
            fifo.to_str().unwrap(),
            "--force",
        ],
        vec![
            "export",
            log.to_str().unwrap(),
            "--format",
            "tum",
            "-o",
            fifo.to_str().unwrap(),
        ],
    ] {
        let run = mireg(&args);
        assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
        assert!(stderr(&run).contains("is a FIFO"), "{}", stderr(&run));
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
    }
    let dir_out = dir.path().join("sub");
    std::fs::create_dir(&dir_out).unwrap();
    let run = mireg(&[
        "register",
        log.to_str().unwrap(),
        "-o",
        dir_out.to_str().unwrap(),
        "--force",
    ]);
    assert!(stderr(&run).contains("is a directory"), "{}", stderr(&run));
    assert!(dir_out.is_dir());
}

/// SIGINT, SIGTERM and SIGKILL left a hidden `.OUT.XXXX.partial` beside the output, preallocated
/// to the input's size. Now: exit 130 / 143 with one line, and nothing at or beside the target
/// after any of the three.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn interrupted_register_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    for (sig, code) in [
        (libc::SIGINT, Some(130)),
        (libc::SIGTERM, Some(143)),
        (libc::SIGKILL, None),
    ] {
        let child = Command::new(env!("CARGO_BIN_EXE_mireg"))
            .args([
                "register",
                fixture().to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--quiet",
            ])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Let it get into the pass-through (the whole run takes over a second).
        std::thread::sleep(std::time::Duration::from_millis(300));
        // SAFETY: signals a child of this process.
        unsafe { libc::kill(child.id() as i32, sig) };
        let run = child.wait_with_output().unwrap();
        assert_eq!(run.status.code(), code, "signal {sig}: {}", stderr(&run));
        if code.is_some() {
            let e = stderr(&run);
            assert_eq!(e.lines().count(), 1, "{e}");
            assert!(e.contains("no output written"), "{e}");
        }
        assert!(
            listing(dir.path()).is_empty(),
            "signal {sig}: {:?}",
            listing(dir.path())
        );
    }
}

#[path = "../common/walls_room.rs"]
mod walls_room;
use walls_room::walls_room;

mod decompression_bombs;
mod far_points;
mod later_findings;
mod messages;
mod non_finite_times;
mod special_files;
mod stitch_checks;
mod temp_files;
mod wal_bags;
