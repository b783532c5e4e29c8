//! A small ROS 1 bag (format 2.0) written record by record: the seed of the `ros1_bag` fuzz
//! corpus and the input of the bag tests that need to break one part of a bag (a chunk's declared
//! size, its compression). Third-party-written bags for the main tests are in fixtures/bags.

use crate::io::codec::{self, ros1};

/// How [`small_bag`] writes its chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChunkCompression {
    /// `none`.
    None,
    /// `bz2`.
    Bz2,
    /// `lz4` (the LZ4 frame format, as `roslz4` writes).
    Lz4,
}

impl ChunkCompression {
    fn name(self) -> &'static str {
        match self {
            ChunkCompression::None => "none",
            ChunkCompression::Bz2 => "bz2",
            ChunkCompression::Lz4 => "lz4",
        }
    }

    fn compress(self, data: &[u8]) -> Vec<u8> {
        use std::io::Write;
        match self {
            ChunkCompression::None => data.to_vec(),
            ChunkCompression::Bz2 => {
                let mut e = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
                e.write_all(data).expect("in memory");
                e.finish().expect("in memory")
            }
            ChunkCompression::Lz4 => {
                let mut e = lz4::EncoderBuilder::new()
                    .build(Vec::new())
                    .expect("in memory");
                e.write_all(data).expect("in memory");
                let (out, r) = e.finish();
                r.expect("in memory");
                out
            }
        }
    }
}

/// One record: header fields, then data.
fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
    let mut header = Vec::new();
    for (name, value) in fields {
        header.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
        header.extend(name.as_bytes());
        header.push(b'=');
        header.extend(*value);
    }
    let mut out = Vec::with_capacity(8 + header.len() + data.len());
    out.extend((header.len() as u32).to_le_bytes());
    out.extend(header);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    out
}

fn time(ns: u64) -> [u8; 8] {
    let mut t = [0u8; 8];
    t[..4].copy_from_slice(&((ns / 1_000_000_000) as u32).to_le_bytes());
    t[4..].copy_from_slice(&((ns % 1_000_000_000) as u32).to_le_bytes());
    t
}

/// A bag of `frames` clouds of the [`super::small_log`] room on `/points` (ROS 1
/// `sensor_msgs/PointCloud2`, connection 0, callerid `/seed`), one chunk per frame, with its
/// index. `declared_size` replaces every chunk's declared uncompressed size (to test the bounds).
pub fn small_bag(
    frames: usize,
    compression: ChunkCompression,
    declared_size: Option<u32>,
) -> Vec<u8> {
    let connection = connection_record();
    let world = super::small_scene();
    let mut body = Vec::new();
    let mut infos = Vec::new();
    for k in 0..frames {
        let chunk_pos = (ros1_bag_magic().len() + body.len()) as u64;
        let (records, info) = frame_records(
            k,
            &world,
            &connection,
            compression,
            declared_size,
            chunk_pos,
        );
        body.extend(records);
        infos.push(info);
    }
    // The bag header comes first, so its length is fixed before the offsets are: a header of
    // fixed fields, padded like rosbag pads it.
    let header_len = bag_header(0, 0).len();
    let index_pos = (ros1_bag_magic().len() + header_len + body.len()) as u64;
    let mut out = ros1_bag_magic().to_vec();
    out.extend(bag_header(index_pos, frames as u32));
    // Chunk positions were counted from the end of the magic without the bag header.
    let shift = header_len as u64;
    out.extend(body);
    out.extend(connection);
    for mut info in infos {
        shift_chunk_pos(&mut info, shift);
        out.extend(info);
    }
    out
}

/// The bag header record: the index at `index_pos`, one connection, `chunks` chunks, padded
/// like rosbag pads it.
fn bag_header(index_pos: u64, chunks: u32) -> Vec<u8> {
    record(
        &[
            ("op", &[0x03]),
            ("index_pos", &index_pos.to_le_bytes()),
            ("conn_count", &1u32.to_le_bytes()),
            ("chunk_count", &chunks.to_le_bytes()),
        ],
        &[b' '; 64],
    )
}

/// The connection record of `/points` (connection 0).
fn connection_record() -> Vec<u8> {
    let mut d = Vec::new();
    for (k, v) in [
        ("topic", "/points"),
        ("type", ros1::POINT_CLOUD2_SCHEMA_NAME),
        ("md5sum", ros1::POINT_CLOUD2_MD5),
        ("message_definition", ros1::POINT_CLOUD2_SCHEMA),
        ("callerid", "/seed"),
        ("latching", "0"),
    ] {
        d.extend(((k.len() + 1 + v.len()) as u32).to_le_bytes());
        d.extend(k.as_bytes());
        d.push(b'=');
        d.extend(v.as_bytes());
    }
    record(
        &[
            ("op", &[0x07]),
            ("conn", &0u32.to_le_bytes()),
            ("topic", b"/points"),
        ],
        &d,
    )
}

/// Frame `k`'s chunk (the connection record first in frame 0's) and index data record, and its
/// chunk info record, for a chunk at `chunk_pos` (counted from the end of the magic): `world`
/// (the room's points) seen from the frame's camera.
fn frame_records(
    k: usize,
    world: &[nalgebra::Point3<f64>],
    connection: &[u8],
    compression: ChunkCompression,
    declared_size: Option<u32>,
    chunk_pos: u64,
) -> (Vec<u8>, Vec<u8>) {
    let conn = 0u32.to_le_bytes();
    let t = 1_700_000_000_000_000_000u64 + k as u64 * 100_000_000;
    let camera_from_world = super::small_camera(k).inverse();
    let pts: Vec<_> = world.iter().map(|p| camera_from_world * p).collect();
    let header = codec::Header {
        stamp: codec::Time::from_ns(t as i64).expect("in range"),
        frame_id: "camera".into(),
    };
    let cloud = ros1::encode_point_cloud2(&header, &pts, None);
    let mut chunk = if k == 0 {
        connection.to_vec()
    } else {
        Vec::new()
    };
    let msg_offset = chunk.len() as u32;
    chunk.extend(record(
        &[("op", &[0x02]), ("conn", &conn), ("time", &time(t))],
        &cloud,
    ));
    let size = declared_size.unwrap_or(chunk.len() as u32).to_le_bytes();
    let mut records = record(
        &[
            ("op", &[0x05]),
            ("compression", compression.name().as_bytes()),
            ("size", &size),
        ],
        &compression.compress(&chunk),
    );
    let mut index = time(t).to_vec();
    index.extend(msg_offset.to_le_bytes());
    records.extend(record(
        &[
            ("op", &[0x04]),
            ("ver", &1u32.to_le_bytes()),
            ("conn", &conn),
            ("count", &1u32.to_le_bytes()),
        ],
        &index,
    ));
    let mut pairs = conn.to_vec();
    pairs.extend(1u32.to_le_bytes());
    let info = record(
        &[
            ("op", &[0x06]),
            ("ver", &1u32.to_le_bytes()),
            ("chunk_pos", &chunk_pos.to_le_bytes()),
            ("start_time", &time(t)),
            ("end_time", &time(t)),
            ("count", &1u32.to_le_bytes()),
        ],
        &pairs,
    );
    (records, info)
}

fn ros1_bag_magic() -> &'static [u8] {
    crate::io::bag::ros1::MAGIC
}

/// Adds `shift` to the `chunk_pos` field of a chunk info record.
fn shift_chunk_pos(info: &mut [u8], shift: u64) {
    let key = b"chunk_pos=";
    let at = info
        .windows(key.len())
        .position(|w| w == key)
        .expect("chunk info has chunk_pos")
        + key.len();
    let v = u64::from_le_bytes(info[at..at + 8].try_into().expect("8 bytes")) + shift;
    info[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
