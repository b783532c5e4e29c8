//! Hostile inputs of the third round (issue 49), written byte by byte: decompression bombs for
//! each container (MCAP chunks, rosbag2 `file` and `message` modes; the ROS 1 chunk bombs are
//! [`super::small_bag`] with a declared size), clouds with glitched per-point times, and the
//! rosbag2 directory layouts of the `rosbag2_compressed` fuzz target. The seeds of the fuzz
//! corpora (examples/make_fuzz_corpus.rs) and the hostile-input tests use them.

use std::io::Write;

use nalgebra::Point3;

use crate::io::codec::{WireWrite, cdr::CdrWriter};

/// `count` zero bytes after `head`, as one zstd frame (streamed through the encoder, never held
/// whole): 256 MiB take about 8 KB.
pub fn zstd_zeros(head: &[u8], count: u64) -> Vec<u8> {
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 1).expect("in memory");
    enc.write_all(head).expect("in memory");
    write_zeros(&mut enc, count);
    enc.finish().expect("in memory")
}

/// `count` zero bytes as one LZ4 frame (the format of MCAP's `lz4` chunks): about 4 KB a MiB.
pub fn lz4_zeros(count: u64) -> Vec<u8> {
    let mut enc = lz4::EncoderBuilder::new()
        .build(Vec::new())
        .expect("in memory");
    write_zeros(&mut enc, count);
    let (out, r) = enc.finish();
    r.expect("in memory");
    out
}

fn write_zeros(w: &mut impl Write, count: u64) {
    let zeros = vec![0u8; 1 << 20];
    let mut left = count;
    while left > 0 {
        let n = left.min(zeros.len() as u64) as usize;
        w.write_all(&zeros[..n]).expect("in memory");
        left -= n as u64;
    }
}

/// A decompression bomb: a chunk record of `count` zero bytes compressed by zstd, claiming
/// `claimed` uncompressed bytes.
pub fn zstd_zero_chunk(count: u64, claimed: u64) -> Vec<u8> {
    chunk_record("zstd", &zstd_zeros(b"", count), claimed)
}

/// [`zstd_zero_chunk`] compressed by LZ4 (frame format).
pub fn lz4_zero_chunk(count: u64, claimed: u64) -> Vec<u8> {
    chunk_record("lz4", &lz4_zeros(count), claimed)
}

/// An MCAP chunk record (start and end time 0, CRC 0: not checked) of compressed `data`.
fn chunk_record(compression: &str, data: &[u8], claimed: u64) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend(0u64.to_le_bytes());
    body.extend(0u64.to_le_bytes());
    body.extend(claimed.to_le_bytes());
    body.extend(0u32.to_le_bytes());
    body.extend((compression.len() as u32).to_le_bytes());
    body.extend(compression.as_bytes());
    body.extend((data.len() as u64).to_le_bytes());
    body.extend(data);
    let mut rec = vec![mcap::records::op::CHUNK];
    rec.extend((body.len() as u64).to_le_bytes());
    rec.extend(body);
    rec
}

/// `log` (a valid MCAP with a chunk) with its first chunk record replaced by `chunk`.
pub fn with_first_chunk(log: &[u8], chunk: &[u8]) -> Vec<u8> {
    let mut at = 8;
    loop {
        let len = u64::from_le_bytes(log[at + 1..at + 9].try_into().expect("8 bytes")) as usize;
        if log[at] == mcap::records::op::CHUNK {
            return [&log[..at], chunk, &log[at + 9 + len..]].concat();
        }
        at += 9 + len;
    }
}

/// A ROS 2 `sensor_msgs/msg/PointCloud2` (cdr, frame `lidar`) with FLOAT32 x, y, z and a FLOAT64
/// `time` (Velodyne's name: seconds after the stamp), one point per `(point, time)`.
pub fn timed_cloud_cdr(stamp_ns: u64, points: &[(Point3<f64>, f64)]) -> Vec<u8> {
    let step = 20u32;
    let mut w = CdrWriter::new();
    w.i32((stamp_ns / 1_000_000_000) as i32);
    w.u32((stamp_ns % 1_000_000_000) as u32);
    w.string("lidar");
    w.u32(1);
    w.u32(points.len() as u32);
    w.sequence_len(4);
    for (name, offset, datatype) in [("x", 0, 7u8), ("y", 4, 7), ("z", 8, 7), ("time", 12, 8)] {
        w.string(name);
        w.u32(offset);
        w.u8(datatype);
        w.u32(1);
    }
    w.bool(false);
    w.u32(step);
    w.u32(step * points.len() as u32);
    w.u32(step * points.len() as u32);
    for (p, t) in points {
        for c in [p.x, p.y, p.z] {
            w.raw(&(c as f32).to_le_bytes());
        }
        w.raw(&t.to_le_bytes());
    }
    w.bool(true);
    w.finish()
}

/// Per-point time glitches: not finite, absurd, or 30 s from the rest of a 0.1 s sweep.
pub const TIME_GLITCHES: [f64; 6] = [
    f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
    1e300,
    -1e300,
    30.0,
];

/// Times of a 0.1 s sweep for `n` points, the first [`TIME_GLITCHES`]`.len()` replaced by the
/// glitches (`all_nan`: every time NaN, a field without a time).
pub fn glitched_times(n: usize, all_nan: bool) -> Vec<f64> {
    (0..n)
        .map(|i| match TIME_GLITCHES.get(i) {
            _ if all_nan => f64::NAN,
            Some(&g) => g,
            None => 0.1 * i as f64 / n as f64,
        })
        .collect()
}

/// `log` (an uncompressed or chunk-compressed MCAP) rewritten as a rosbag2 `message`-mode bag
/// file: every message's payload one zstd frame, the cloud messages on `/points` replaced by
/// `clouds` when given (a bomb). Schemas and channels kept; metadata and attachments dropped.
pub fn message_mode_file(log: &[u8], clouds: Option<&[u8]>) -> Vec<u8> {
    use std::collections::BTreeMap;
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .create(&mut out)
        .expect("writer");
    let mut channels = BTreeMap::new();
    for m in mcap::MessageStream::new(log).expect("a valid log") {
        let m = m.expect("a valid log");
        let id = match channels.get(&m.channel.id) {
            Some(&id) => id,
            None => {
                let schema = m.channel.schema.as_ref().expect("a schema");
                let s = w
                    .add_schema(&schema.name, &schema.encoding, &schema.data)
                    .expect("schema");
                let id = w
                    .add_channel(
                        s,
                        &m.channel.topic,
                        &m.channel.message_encoding,
                        &BTreeMap::new(),
                    )
                    .expect("channel");
                channels.insert(m.channel.id, id);
                id
            }
        };
        let data = match clouds {
            Some(bomb) if m.channel.topic == "/points" => bomb.to_vec(),
            _ => zstd::bulk::compress(&m.data, 1).expect("in memory"),
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: m.sequence,
            log_time: m.log_time,
            publish_time: m.publish_time,
        };
        w.write_to_known_channel(&header, &data).expect("message");
    }
    w.finish().expect("finish");
    drop(w);
    out.into_inner()
}

/// The `metadata.yaml` of a one-file zstd-compressed rosbag2 bag of MCAP storage: `file` mode
/// (`file_mode`, the file `bag_0.mcap.zstd`) or `message` mode (`bag_0.mcap`). Returns the
/// text and the file's name.
pub fn compressed_bag_metadata(file_mode: bool) -> (String, &'static str) {
    let (mode, file) = if file_mode {
        ("file", "bag_0.mcap.zstd")
    } else {
        ("message", "bag_0.mcap")
    };
    let text = format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - {file}\n  compression_format: zstd\n  \
         compression_mode: {mode}\n"
    );
    (text, file)
}
