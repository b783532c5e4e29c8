//! Record-level checks of the output: input chunks copied byte for byte, CRCs, and a summary
//! that matches a brute-force count.

use super::*;

/// Top-level records of an MCAP file, walked independently of mireg and of the `mcap` crate:
/// (offset, opcode, body), from the header to the footer.
fn walk_records(bytes: &[u8]) -> Vec<(u64, u8, &[u8])> {
    assert_eq!(&bytes[..8], mcap::MAGIC, "leading magic");
    assert_eq!(&bytes[bytes.len() - 8..], mcap::MAGIC, "trailing magic");
    let mut out = Vec::new();
    let mut pos = 8usize;
    loop {
        let opcode = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((pos as u64, opcode, &bytes[pos + 9..pos + 9 + len]));
        pos += 9 + len;
        if opcode == mcap::records::op::FOOTER {
            assert_eq!(pos, bytes.len() - 8, "footer followed by the magic");
            return out;
        }
    }
}

/// Each chunk record of the data section with the message-index records right after it, as raw
/// bytes (opcode, length and body of each record).
fn chunk_groups(bytes: &[u8]) -> Vec<Vec<u8>> {
    use mcap::records::op;
    let mut groups: Vec<Vec<u8>> = Vec::new();
    let mut in_group = false;
    for (offset, opcode, body) in walk_records(bytes) {
        let raw = &bytes[offset as usize..offset as usize + 9 + body.len()];
        match opcode {
            op::CHUNK => {
                groups.push(raw.to_vec());
                in_group = true;
            }
            op::MESSAGE_INDEX if in_group => groups.last_mut().unwrap().extend_from_slice(raw),
            op::DATA_END => break,
            _ => in_group = false,
        }
    }
    groups
}

/// Every CRC of the file (chunks, data section, summary section) checked by the `mcap` crate's
/// linear reader.
fn check_crcs(bytes: &[u8]) {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true),
    );
    let mut rest = bytes;
    while let Some(event) = reader.next_event() {
        match event.expect("valid MCAP with matching CRCs") {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { .. } => {}
        }
    }
}

/// Checks that `output`'s summary section agrees with its records: statistics against a
/// brute-force count of the messages, chunk indexes against the chunk and message-index records
/// they point at, the channel and schema lists against the records of the data section, and that
/// reading through the indexes finds every message.
fn check_summary(output: &Path) {
    use mcap::records::{ChunkHeader, MessageIndex, op};
    let bytes = std::fs::read(output).unwrap();
    check_crcs(&bytes);
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let stats = summary.stats.as_ref().expect("statistics");

    // Brute force: every message of the file, linearly.
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    let (mut first, mut last) = (u64::MAX, 0u64);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        *counts.entry(m.channel.id).or_default() += 1;
        first = first.min(m.log_time);
        last = last.max(m.log_time);
    }
    let total: u64 = counts.values().sum();
    assert!(total > 0);
    assert_eq!(stats.message_count, total);
    assert_eq!(stats.channel_message_counts, counts);
    assert_eq!(
        (stats.message_start_time, stats.message_end_time),
        (first, last)
    );

    // Schemas and channels: every record of the data section is listed, identical.
    let records = walk_records(&bytes);
    let (mut schemas, mut channels, mut chunks, mut metadata, mut attachments) =
        (BTreeMap::new(), BTreeMap::new(), 0u32, 0u32, 0u32);
    for &(_, opcode, body) in records.iter().take_while(|r| r.1 != op::DATA_END) {
        match mcap::parse_record(opcode, body).unwrap() {
            Record::Schema { header, data } => {
                schemas.insert(header.id, (header.name, header.encoding, data.to_vec()));
            }
            Record::Channel(c) => {
                channels.insert(c.id, c);
            }
            Record::Chunk { header, data } => {
                chunks += 1;
                for r in mcap::read::ChunkReader::new(header, &data).unwrap() {
                    match r.unwrap() {
                        Record::Schema { header, data } => {
                            schemas
                                .insert(header.id, (header.name, header.encoding, data.to_vec()));
                        }
                        Record::Channel(c) => {
                            channels.insert(c.id, c);
                        }
                        _ => {}
                    }
                }
            }
            Record::Metadata(_) => metadata += 1,
            Record::Attachment { .. } => attachments += 1,
            _ => {}
        }
    }
    assert_eq!(stats.channel_count as usize, channels.len());
    assert_eq!(stats.schema_count as usize, schemas.len());
    assert_eq!(
        (
            stats.chunk_count,
            stats.metadata_count,
            stats.attachment_count
        ),
        (chunks, metadata, attachments)
    );
    for (id, c) in &channels {
        let s = &summary.channels[id];
        assert_eq!(
            (&s.topic, &s.message_encoding, &s.metadata),
            (&c.topic, &c.message_encoding, &c.metadata)
        );
        assert_eq!(s.schema.as_ref().map_or(0, |s| s.id), c.schema_id);
    }
    for (id, (name, encoding, data)) in &schemas {
        let s = &summary.schemas[id];
        assert_eq!(
            (&s.name, &s.encoding, &s.data[..]),
            (name, encoding, &data[..])
        );
    }

    // Chunk indexes point at the chunk records and their message indexes.
    assert_eq!(summary.chunk_indexes.len() as u32, chunks);
    let at: BTreeMap<u64, (u8, &[u8])> = records.iter().map(|&(o, op, b)| (o, (op, b))).collect();
    let mut indexed = 0u64;
    for ci in &summary.chunk_indexes {
        let (opcode, body) = at[&ci.chunk_start_offset];
        assert_eq!(opcode, op::CHUNK);
        assert_eq!(ci.chunk_length, 9 + body.len() as u64);
        let Record::Chunk { header, .. } = mcap::parse_record(opcode, body).unwrap() else {
            unreachable!()
        };
        let ChunkHeader {
            message_start_time,
            message_end_time,
            uncompressed_size,
            compression,
            compressed_size,
            ..
        } = header;
        assert_eq!(
            (
                ci.message_start_time,
                ci.message_end_time,
                ci.uncompressed_size,
                &ci.compression,
                ci.compressed_size
            ),
            (
                message_start_time,
                message_end_time,
                uncompressed_size,
                &compression,
                compressed_size
            )
        );
        let mut index_bytes = 0;
        for (&channel, &offset) in &ci.message_index_offsets {
            let (opcode, body) = at[&offset];
            assert_eq!(opcode, op::MESSAGE_INDEX);
            let Record::MessageIndex(MessageIndex { channel_id, .. }) =
                mcap::parse_record(opcode, body).unwrap()
            else {
                unreachable!()
            };
            assert_eq!(channel_id, channel);
            index_bytes += 9 + body.len() as u64;
        }
        assert_eq!(ci.message_index_length, index_bytes);
        let in_chunk = summary.stream_chunk(&bytes, ci).unwrap().count() as u64;
        // Message indexes are optional (an unindexed input's chunks have none).
        if !ci.message_index_offsets.is_empty() {
            let through_index = summary
                .read_message_indexes(&bytes, ci)
                .unwrap()
                .values()
                .map(|v| v.len() as u64)
                .sum::<u64>();
            assert_eq!(
                through_index, in_chunk,
                "message index of chunk at {}",
                ci.chunk_start_offset
            );
        }
        indexed += in_chunk;
    }
    assert_eq!(indexed, total, "reading through the chunk indexes");
    // Metadata and attachment indexes point at their records.
    for mi in &summary.metadata_indexes {
        let m = mcap::read::metadata(&bytes, mi).unwrap();
        assert_eq!(m.name, mi.name);
    }
    for ai in &summary.attachment_indexes {
        let a = mcap::read::attachment(&bytes, ai).unwrap();
        assert_eq!(
            (a.name.as_str(), a.data.len() as u64),
            (ai.name.as_str(), ai.data_size)
        );
    }
}

/// Input chunks (with their message indexes) appear in the output byte for byte, in order.
fn assert_chunks_copied(input: &Path, output: &Path) {
    let (a, b) = (
        std::fs::read(input).unwrap(),
        std::fs::read(output).unwrap(),
    );
    let (ins, outs) = (chunk_groups(&a), chunk_groups(&b));
    assert!(!ins.is_empty(), "{} has chunks", input.display());
    let mut next = 0;
    for (k, g) in ins.iter().enumerate() {
        let found = outs[next..]
            .iter()
            .position(|o| o == g)
            .unwrap_or_else(|| panic!("input chunk {k} is not in the output byte for byte"));
        next += found + 1;
    }
}

#[test]
fn input_chunks_are_copied_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fixture_out.mcap");
    register_log(&options(&fixture(), &out, 0.05)).unwrap();
    assert_chunks_copied(&fixture(), &out);
    check_summary(&out);
    for (name, compression) in [
        ("zstd", Some(mcap::Compression::Zstd)),
        ("lz4", Some(mcap::Compression::Lz4)),
        ("none", None),
    ] {
        let (input, out) = (
            dir.path().join(format!("{name}.mcap")),
            dir.path().join(format!("{name}_out.mcap")),
        );
        write_log_with(&input, 4, |o| {
            o.compression(compression).chunk_size(Some(4096))
        });
        let summary = register_log(&options(&input, &out, 0.1)).unwrap();
        assert_eq!((summary.frames, summary.failed_frames), (4, 0), "{name}");
        assert_chunks_copied(&input, &out);
        assert_superset(&contents(&input), &contents(&out));
        check_summary(&out);
    }
}

#[test]
fn output_summary_matches_a_brute_force_count() {
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("in.mcap"), dir.path().join("out.mcap"));
    write_synthetic_log(&input, 5);
    let summary = register_log(&options(&input, &out, 0.1)).unwrap();
    check_summary(&out);
    let bytes = std::fs::read(&out).unwrap();
    let s = mcap::Summary::read(&bytes).unwrap().unwrap();
    // 5 frames: 5 messages on each of the 3 input channels and on each of ours.
    let by_topic: BTreeMap<String, u64> = s
        .channels
        .values()
        .map(|c| {
            (
                c.topic.clone(),
                s.stats
                    .as_ref()
                    .unwrap()
                    .channel_message_counts
                    .get(&c.id)
                    .copied()
                    .unwrap_or(0),
            )
        })
        .collect();
    for topic in [
        "/sensor/points",
        "/notes",
        "/raw",
        "/tf",
        "/mireg/pose",
        "/mireg/stats",
    ] {
        assert_eq!(by_topic[topic], 5, "{topic}");
    }
    assert_eq!(summary.messages_copied, 15);
    // The input's channel ids are kept; ours come after them.
    let input_bytes = std::fs::read(&input).unwrap();
    let s_in = mcap::Summary::read(&input_bytes).unwrap().unwrap();
    for (id, c) in &s_in.channels {
        assert_eq!(s.channels[id].topic, c.topic);
    }
    let max_in = *s_in.channels.keys().max().unwrap();
    for c in s
        .channels
        .values()
        .filter(|c| c.topic.starts_with("/mireg") || c.topic == "/tf")
    {
        assert!(c.id > max_in, "{} has id {}", c.topic, c.id);
    }
}

#[test]
fn unchunked_unindexed_and_summaryless_inputs_pass_through() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["unchunked", "unindexed", "no summary"] {
        let (input, out) = (
            dir.path().join(format!("{name}.mcap")),
            dir.path().join(format!("{name}_out.mcap")),
        );
        write_log_with(&input, 4, |o| match name {
            "unchunked" => o.use_chunks(false),
            "unindexed" => o.emit_message_indexes(false).chunk_size(Some(4096)),
            _ => o
                .chunk_size(Some(4096))
                .emit_summary_records(false)
                .emit_statistics(false)
                .emit_chunk_indexes(false)
                .emit_attachment_indexes(false)
                .emit_metadata_indexes(false)
                .emit_summary_offsets(false),
        });
        let bytes = std::fs::read(&input).unwrap();
        let records = walk_records(&bytes);
        let count = |opcode| records.iter().filter(|r| r.1 == opcode).count();
        use mcap::records::op;
        let intended = match name {
            "unchunked" => count(op::CHUNK) == 0 && count(op::MESSAGE) == 12,
            "unindexed" => count(op::CHUNK) > 0 && count(op::MESSAGE_INDEX) == 0,
            // Channels only inside chunks, none in a summary: found by a pre-scan.
            _ => count(op::CHUNK) > 0 && count(op::CHANNEL) == 0 && count(op::CHUNK_INDEX) == 0,
        };
        assert!(intended, "{name}: the input is as intended");
        let summary = register_log(&options(&input, &out, 0.1)).unwrap();
        assert_eq!((summary.frames, summary.failed_frames), (4, 0), "{name}");
        assert_eq!(summary.messages_copied, 12, "{name}");
        let (a, b) = (contents(&input), contents(&out));
        assert_superset(&a, &b);
        assert_eq!(b.metadata.len(), a.metadata.len() + 1);
        check_summary(&out);
        if name != "unchunked" {
            assert_chunks_copied(&input, &out);
        }
    }
}

#[test]
fn corrupt_chunk_that_is_only_copied_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.mcap");
    // Uncompressed chunks: a flipped payload byte can only be caught by the chunk CRC.
    write_log_with(&input, 4, |o| o.compression(None).chunk_size(Some(4096)));
    let bytes = std::fs::read(&input).unwrap();
    // The last chunk holding a /raw message and no cloud: only copied and validated.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let raw = summary
        .channels
        .values()
        .find(|c| c.topic == "/raw")
        .unwrap()
        .id;
    let clouds = summary
        .channels
        .values()
        .find(|c| c.topic == "/sensor/points")
        .unwrap()
        .id;
    let ci = summary
        .chunk_indexes
        .iter()
        .rev()
        .find(|ci| {
            ci.message_index_offsets.contains_key(&raw)
                && !ci.message_index_offsets.contains_key(&clouds)
        })
        .expect("a chunk without clouds");
    let mut corrupt = bytes.clone();
    let last_byte = (ci.chunk_start_offset + ci.chunk_length - 1) as usize;
    corrupt[last_byte] ^= 0x01;
    let path = dir.path().join("corrupt.mcap");
    std::fs::write(&path, &corrupt).unwrap();
    let out = dir.path().join("out.mcap");
    let err = register_log(&options(&path, &out, 0.1))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&path.display().to_string()) && err.contains("CRC"),
        "{err}"
    );
    assert!(!out.exists());
    no_partial_files(dir.path());
}
