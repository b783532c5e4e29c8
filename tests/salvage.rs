//! Logs cut off while recording, and corrupt chunks (issue 33): the fixture MCAP files and the
//! ROS 1 bag fixtures cut at every 1 % of their length are read up to their last whole message,
//! every message before the cut byte-identical to the whole log's; `--strict` refuses them; a
//! corrupt chunk is an error naming it, or skipped with `--skip-corrupt`.
//!
//! The oracles are independent of mireg's readers: the official `mcap` crate's message stream
//! (which yields the messages of every whole chunk before it stops at the cut), and the bags'
//! own index data records, which count each chunk's messages.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mireg::io::damage::{Damage, ReadPolicy};
use mireg::io::input_log::InputLog;

#[path = "common/cli.rs"]
mod cli;
#[path = "common/log_contents.rs"]
mod log_contents;

/// A message as (channel id, log time, publish time, bytes).
type Msg = (u16, u64, u64, Vec<u8>);

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// Every message of `path` read by mireg under `policy`, in file order, and the damage found.
fn read(path: &Path, policy: ReadPolicy) -> mireg::Result<(Vec<Msg>, Option<Damage>)> {
    let (log, _) = InputLog::open_with(path, policy)?;
    let mut out = Vec::new();
    log.for_each_message_until(|h, data| {
        out.push((h.channel_id, h.log_time, h.publish_time, data.to_vec()));
        Ok(ControlFlow::Continue(()))
    })?;
    Ok((out, log.damage().cloned()))
}

/// The messages the official `mcap` crate streams out of `bytes` before it stops.
fn mcap_crate_messages(bytes: &[u8]) -> Vec<Msg> {
    let Ok(stream) = mcap::MessageStream::new(bytes) else {
        return Vec::new();
    };
    stream
        .map_while(|m| m.ok())
        .map(|m| (m.channel.id, m.log_time, m.publish_time, m.data.to_vec()))
        .collect()
}

/// The first `k` percent of `bytes`, as a file in `dir`.
fn cut(dir: &Path, name: &str, bytes: &[u8], k: usize) -> (PathBuf, usize) {
    let at = bytes.len() * k / 100;
    let path = dir.join(name);
    std::fs::write(&path, &bytes[..at]).unwrap();
    (path, at)
}

#[test]
fn mcap_fixtures_cut_at_every_percent_keep_every_message_before_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["icl_livingroom1.mcap", "ouster_os1_ros1.mcap"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let (whole, damage) = read(&fixture(name), ReadPolicy::default()).unwrap();
        assert!(damage.is_none(), "{name}: whole, yet {damage:?}");
        assert_eq!(whole, mcap_crate_messages(&bytes), "{name}");
        let mut last = 0;
        for k in 1..100 {
            let (path, at) = cut(dir.path(), name, &bytes, k);
            let (got, damage) = read(&path, ReadPolicy::default())
                .unwrap_or_else(|e| panic!("{name} cut at {k} %: {e}"));
            let damage = damage.unwrap_or_else(|| panic!("{name} cut at {k} %: no damage"));
            assert_eq!(damage.file_size, at as u64);
            assert!(damage.cut_at.is_some_and(|c| c <= at as u64), "{damage:?}");
            // Byte-identical to the whole log's first messages, at least every message of the
            // chunks the cut left whole, and never fewer for a later cut.
            assert_eq!(got[..], whole[..got.len()], "{name} cut at {k} %");
            let whole_chunks = mcap_crate_messages(&bytes[..at]);
            assert!(got.len() >= whole_chunks.len(), "{name} cut at {k} %");
            assert!(got.len() >= last, "{name} cut at {k} %");
            last = got.len();
            let e = read(&path, ReadPolicy::STRICT).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
        // The messages of a chunk cut short are recovered (zstd decodes block by block): cut at
        // 99 %, little more than the last percent's worth of bytes is lost, not the last chunk.
        let bytes_of = |m: &[Msg]| m.iter().map(|m| m.3.len()).sum::<usize>();
        let (kept, all) = (bytes_of(&whole[..last]), bytes_of(&whole));
        eprintln!(
            "{name}: cut at 99 %, {last} of {} messages, {kept} of {all} bytes",
            whole.len()
        );
        assert!(kept * 100 >= all * 90, "{name}: {kept} of {all} bytes");
    }
}

/// A top-level record of a ROS 1 bag: (offset, op, end, header fields).
type BagRecord = (usize, u8, usize, Vec<(String, Vec<u8>)>);

/// The top-level records of a ROS 1 bag.
fn bag_records(b: &[u8]) -> Vec<BagRecord> {
    let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap()) as usize;
    let mut out = Vec::new();
    let mut pos = 13; // "#ROSBAG V2.0\n"
    while pos < b.len() {
        let header_len = u32_at(pos);
        let (mut h, data_len) = (pos + 4, u32_at(pos + 4 + header_len));
        let mut fields = Vec::new();
        while h < pos + 4 + header_len {
            let len = u32_at(h);
            let f = &b[h + 4..h + 4 + len];
            let eq = f.iter().position(|&c| c == b'=').unwrap();
            fields.push((
                String::from_utf8_lossy(&f[..eq]).into_owned(),
                f[eq + 1..].to_vec(),
            ));
            h += 4 + len;
        }
        let op = fields.iter().find(|(n, _)| n == "op").unwrap().1[0];
        let end = pos + 8 + header_len + data_len;
        out.push((pos, op, end, fields));
        pos = end;
    }
    out
}

/// How many messages the chunks that end at or before `at` hold, by the index data records
/// (op 0x04) that follow each chunk (their `count` field).
fn messages_in_whole_chunks(records: &[BagRecord], at: usize) -> usize {
    let mut n = 0;
    let mut chunk_whole = false;
    for (_, op, end, fields) in records {
        match op {
            0x05 => chunk_whole = *end <= at,
            0x04 if chunk_whole => {
                let count = &fields.iter().find(|(n, _)| n == "count").unwrap().1;
                n += u32::from_le_bytes(count[..4].try_into().unwrap()) as usize;
            }
            _ => {}
        }
    }
    n
}

#[test]
fn bags_cut_at_every_percent_keep_every_message_before_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["icl4_none.bag", "icl4_bz2.bag", "icl4_lz4.bag"] {
        let path = fixture("bags").join(name);
        let bytes = std::fs::read(&path).unwrap();
        let records = bag_records(&bytes);
        let (whole, damage) = read(&path, ReadPolicy::default()).unwrap();
        assert!(damage.is_none(), "{name}: whole, yet {damage:?}");
        assert_eq!(whole.len(), messages_in_whole_chunks(&records, bytes.len()));
        let mut last = 0;
        let mut recovered_from_a_cut_chunk = false;
        for k in 1..100 {
            let (cut_path, at) = cut(dir.path(), name, &bytes, k);
            let got = match read(&cut_path, ReadPolicy::default()) {
                Ok((got, damage)) => {
                    let damage = damage.unwrap_or_else(|| panic!("{name} at {k} %: no damage"));
                    assert!(damage.cut_at.is_some_and(|c| c <= at as u64), "{damage:?}");
                    recovered_from_a_cut_chunk |= damage.partial_messages > 0;
                    got
                }
                // Cut before the first connection record: nothing to read, said clearly.
                Err(e) => {
                    let e = e.to_string();
                    assert!(e.contains(name), "{name} at {k} %: {e}");
                    Vec::new()
                }
            };
            assert_eq!(got[..], whole[..got.len()], "{name} cut at {k} %");
            let floor = messages_in_whole_chunks(&records, at);
            assert!(
                got.len() >= floor,
                "{name} at {k} %: {} < {floor}",
                got.len()
            );
            assert!(got.len() >= last, "{name} cut at {k} %");
            last = got.len();
            let e = read(&cut_path, ReadPolicy::STRICT).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains("truncated"), "{e}");
        }
        // bz2 decodes whole 900 kB blocks only: a chunk (one block) cut short gives nothing.
        if !name.contains("bz2") {
            assert!(
                recovered_from_a_cut_chunk,
                "{name}: no cut chunk gave up a message"
            );
        }
    }
}

#[test]
fn a_bag_cut_inside_its_index_keeps_every_message() {
    let dir = tempfile::tempdir().unwrap();
    let path = fixture("bags").join("icl4_lz4.bag");
    let bytes = std::fs::read(&path).unwrap();
    let (whole, _) = read(&path, ReadPolicy::default()).unwrap();
    let (cut_path, at) = cut(dir.path(), "index.bag", &bytes[..bytes.len() - 10], 100);
    let (got, damage) = read(&cut_path, ReadPolicy::default()).unwrap();
    assert_eq!(got, whole);
    let damage = damage.unwrap();
    assert!(damage.cut_at.is_some_and(|c| c < at as u64));
    assert!(damage.cut_reason.unwrap().starts_with("the index"));
    assert!(read(&cut_path, ReadPolicy::STRICT).is_err());
}

/// `mireg register` on a log cut at half its length: a warning naming the file, a complete and
/// valid output holding every message read, byte-identical, and the damage in its metadata;
/// `--strict` fails and writes nothing.
#[test]
fn register_writes_a_complete_log_of_what_a_cut_log_holds() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["icl_livingroom1.mcap", "bags/icl4_bz2.bag"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let (input, at) = cut(dir.path(), "cut.log", &bytes, 60);
        let out = dir.path().join("out.mcap");
        let (input_arg, out_arg) = (input.to_str().unwrap(), out.to_str().unwrap());
        let run = cli::mireg(&["register", "--force", "--quiet", "-o", out_arg, input_arg]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(run.status.success(), "{name}: {stderr}");
        assert!(
            stderr.contains("cut.log") && stderr.contains("damaged"),
            "{stderr}"
        );
        // The output is whole: the official crate streams it to the end, summary included.
        let out_bytes = std::fs::read(&out).unwrap();
        let summary = mcap::Summary::read(&out_bytes).unwrap().expect("a summary");
        let streamed = mcap::MessageStream::new(&out_bytes)
            .unwrap()
            .collect::<Result<Vec<_>, _>>()
            .unwrap();
        let stats = summary.stats.expect("statistics");
        assert_eq!(stats.message_count, streamed.len() as u64);
        // Every message read from the cut input is in it, unchanged.
        let (read_in, _) = read(&input, ReadPolicy::default()).unwrap();
        assert!(!read_in.is_empty());
        for (_, log_time, publish_time, data) in &read_in {
            assert!(
                streamed.iter().any(|m| m.log_time == *log_time
                    && m.publish_time == *publish_time
                    && m.data[..] == data[..]),
                "{name}: a message at {log_time} is missing or altered"
            );
        }
        let meta = log_contents::contents(&out).metadata;
        let mireg_meta = &meta.iter().find(|(n, _)| n == "mireg").unwrap().1;
        let damage: serde_json::Value = serde_json::from_str(&mireg_meta["input_damage"]).unwrap();
        assert_eq!(damage["file_size"], at as u64);
        assert!(damage["cut_at"].as_u64().unwrap() <= at as u64);

        std::fs::remove_file(&out).unwrap();
        let run = cli::mireg(&["register", "--strict", "--quiet", "-o", out_arg, input_arg]);
        assert_eq!(run.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&run.stderr).contains("cut.log"));
        assert!(!out.exists());
    }
}

/// A byte changed inside the Ouster fixture's second chunk: an error naming the chunk and
/// `--skip-corrupt` by default; with it, the first chunk's messages and the chunk named.
#[test]
fn a_corrupt_chunk_is_named_and_skipped_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(fixture("ouster_os1_ros1.mcap")).unwrap();
    // Top-level records: opcode (1) and length (8) after the 8-byte magic.
    let mut chunks = Vec::new();
    let mut pos = 8;
    while pos < bytes.len() - 8 {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == 0x06 {
            chunks.push((pos, pos + 9 + len));
        }
        pos += 9 + len;
    }
    assert_eq!(chunks.len(), 2);
    let (second, end) = chunks[1];
    let first_chunk_only = mcap_crate_messages(&bytes[..second]);
    assert!(!first_chunk_only.is_empty());
    bytes[(second + end) / 2] ^= 0x5a;
    let path = dir.path().join("flipped.mcap");
    std::fs::write(&path, &bytes).unwrap();

    let e = read(&path, ReadPolicy::default()).unwrap_err().to_string();
    assert!(e.contains("flipped.mcap"), "{e}");
    assert!(e.contains(&format!("chunk at offset {second}")), "{e}");
    assert!(e.contains("--skip-corrupt"), "{e}");

    let skip = ReadPolicy {
        skip_corrupt: true,
        ..ReadPolicy::default()
    };
    let (got, damage) = read(&path, skip).unwrap();
    assert_eq!(got, first_chunk_only);
    let damage = damage.unwrap();
    assert_eq!(damage.skipped_chunks.len(), 1);
    assert_eq!(damage.skipped_chunks[0].0, second as u64);
    assert_eq!(damage.cut_at, None);
}
