//! Decoding one MCAP chunk record: decompression (none, zstd, lz4), the CRC check of the
//! uncompressed records, and a walk over the records inside. Used by the pass-through of
//! `mireg register` to validate and count chunks that are copied without being re-encoded.
//!
//! Errors are plain descriptions; the caller adds the file and the chunk's offset.

use std::collections::BTreeMap;
use std::io::Read;

use mcap::records::{Channel, ChunkHeader, MessageHeader, MessageIndex, Record, op};

use super::record::parse_record;
use super::write::SchemaRecord;
use crate::io::MAX_CHUNK_BYTES;

/// Decompresses chunks into a buffer reused from one chunk to the next.
pub struct ChunkDecoder {
    zstd: zstd::bulk::Decompressor<'static>,
    buf: Vec<u8>,
}

impl std::fmt::Debug for ChunkDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChunkDecoder").finish_non_exhaustive()
    }
}

/// The header of a chunk record, parsed from its body (everything after opcode and length).
pub fn chunk_header(body: &[u8]) -> Result<ChunkHeader, String> {
    match parse_record(op::CHUNK, body)? {
        Record::Chunk { header, .. } => Ok(header),
        _ => Err("not a chunk record".into()),
    }
}

impl ChunkDecoder {
    /// A decoder (fails only if zstd cannot allocate its context).
    pub fn new() -> Result<Self, String> {
        Ok(Self {
            zstd: zstd::bulk::Decompressor::new()
                .map_err(|e| format!("starting zstd decompression: {e}"))?,
            buf: Vec::new(),
        })
    }

    /// The uncompressed records of the chunk whose record body is `body`, with their CRC checked
    /// (unless the chunk stores none, i.e. 0), and the chunk header.
    pub fn decode<'a>(&'a mut self, body: &'a [u8]) -> Result<(ChunkHeader, &'a [u8]), String> {
        let (header, data) = match parse_record(op::CHUNK, body)? {
            Record::Chunk { header, data } => match data {
                std::borrow::Cow::Borrowed(d) => (header, d),
                std::borrow::Cow::Owned(_) => return Err("chunk data not borrowed".into()),
            },
            _ => return Err("not a chunk record".into()),
        };
        let size = header.uncompressed_size;
        if size > MAX_CHUNK_BYTES {
            return Err(format!(
                "chunk claims {size} uncompressed bytes, more than the limit of {MAX_CHUNK_BYTES}"
            ));
        }
        let records: &[u8] = match header.compression.as_str() {
            "" => data,
            "zstd" | "lz4" => {
                crate::io::check_expansion(data.len() as u64, size)
                    .map_err(|e| format!("chunk {e}"))?;
                self.buf.clear();
                let n = usize::try_from(size).map_err(|_| format!("chunk of {size} bytes"))?;
                self.buf.try_reserve_exact(n).map_err(|_| {
                    format!("chunk claims {size} uncompressed bytes (corrupt header?)")
                })?;
                if header.compression == "zstd" {
                    self.zstd
                        .decompress_to_buffer(data, &mut self.buf)
                        .map_err(|e| format!("zstd decompression failed: {e}"))?;
                } else {
                    let mut dec = lz4::Decoder::new(data)
                        .map_err(|e| format!("lz4 decompression failed: {e}"))?;
                    (&mut dec)
                        .take(size)
                        .read_to_end(&mut self.buf)
                        .map_err(|e| format!("lz4 decompression failed: {e}"))?;
                    let mut extra = [0u8; 1];
                    if dec.read(&mut extra).map_err(|e| e.to_string())? != 0 {
                        return Err(format!("lz4 data holds more than {size} bytes"));
                    }
                }
                &self.buf
            }
            other => return Err(format!("unsupported chunk compression {other:?}")),
        };
        if records.len() as u64 != size {
            return Err(format!(
                "decompressed to {} bytes, the chunk header says {size}",
                records.len()
            ));
        }
        if header.uncompressed_crc != 0 {
            let crc = crc32fast::hash(records);
            if crc != header.uncompressed_crc {
                return Err(format!(
                    "CRC mismatch (stored 0x{:08x}, computed 0x{crc:08x}): the chunk is corrupt",
                    header.uncompressed_crc
                ));
            }
        }
        Ok((header, records))
    }
}

/// The records of an uncompressed chunk: `(offset, opcode, body)` with the record's offset in
/// the chunk's uncompressed data, or an error for a record that runs past the end.
pub fn records(all: &[u8]) -> impl Iterator<Item = Result<(u64, u8, &[u8]), String>> {
    let mut rest = all;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let offset = (all.len() - rest.len()) as u64;
        if rest.len() < 9 {
            rest = &[];
            return Some(Err("truncated record inside the chunk".into()));
        }
        let opcode = rest[0];
        let len = u64::from_le_bytes(rest[1..9].try_into().expect("8 bytes"));
        let body = &rest[9..];
        match usize::try_from(len).ok().filter(|&l| l <= body.len()) {
            Some(l) => {
                rest = &body[l..];
                Some(Ok((offset, opcode, &body[..l])))
            }
            None => {
                rest = &[];
                Some(Err(format!(
                    "record (opcode 0x{opcode:02x}) at offset {offset} of {len} bytes runs past the end of the chunk"
                )))
            }
        }
    })
}

/// Fails for a record that may not appear inside a chunk (MCAP specification: only schema,
/// channel and message records do; records of unknown opcodes are allowed and skipped).
pub fn check_chunk_opcode(opcode: u8) -> Result<(), String> {
    match opcode {
        op::SCHEMA | op::CHANNEL | op::MESSAGE => Ok(()),
        op::HEADER
        | op::FOOTER
        | op::CHUNK
        | op::MESSAGE_INDEX
        | op::CHUNK_INDEX
        | op::ATTACHMENT
        | op::ATTACHMENT_INDEX
        | op::STATISTICS
        | op::METADATA
        | op::METADATA_INDEX
        | op::SUMMARY_OFFSET
        | op::DATA_END => Err(format!(
            "holds a record of opcode 0x{opcode:02x}, which may not appear inside a chunk"
        )),
        _ => Ok(()),
    }
}

/// The header and payload of a message record body.
pub fn message(body: &[u8]) -> Result<(MessageHeader, &[u8]), String> {
    match parse_record(op::MESSAGE, body)? {
        Record::Message { header, data } => match data {
            std::borrow::Cow::Borrowed(d) => Ok((header, d)),
            std::borrow::Cow::Owned(_) => Err("message data not borrowed".into()),
        },
        _ => Err("not a message record".into()),
    }
}

/// What a chunk holds besides message payloads: message counts per channel and the schema and
/// channel records inside it.
#[derive(Debug, Default)]
pub struct ChunkContents {
    /// Messages per channel id.
    pub counts: BTreeMap<u16, u64>,
    /// Schema records (id, schema).
    pub schemas: Vec<(u16, SchemaRecord)>,
    /// Channel records.
    pub channels: Vec<Channel>,
    /// Every message record: (offset in the uncompressed chunk, channel id, log time \[ns\]), in
    /// offset order.
    pub messages: Vec<(u64, u16, u64)>,
}

impl ChunkContents {
    /// Accounts for one record of the chunk; returns the channel id of a message record.
    pub fn add(&mut self, offset: u64, opcode: u8, body: &[u8]) -> Result<Option<u16>, String> {
        check_chunk_opcode(opcode)?;
        match opcode {
            op::MESSAGE => {
                // channel id (2), sequence (4), log time (8), publish time (8)
                let (Some(id), Some(t)) = (body.get(..2), body.get(6..14)) else {
                    return Err(format!(
                        "message record at offset {offset} shorter than its header"
                    ));
                };
                let id = u16::from_le_bytes([id[0], id[1]]);
                let log_time = u64::from_le_bytes(t.try_into().expect("8 bytes"));
                *self.counts.entry(id).or_default() += 1;
                self.messages.push((offset, id, log_time));
                return Ok(Some(id));
            }
            op::SCHEMA | op::CHANNEL => match parse_record(opcode, body)? {
                Record::Schema { header, data } => self.schemas.push((
                    header.id,
                    SchemaRecord {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    },
                )),
                Record::Channel(c) => self.channels.push(c),
                _ => {}
            },
            _ => {}
        }
        Ok(None)
    }

    /// Decodes, checks and accounts for a whole chunk.
    pub fn of_chunk(decoder: &mut ChunkDecoder, body: &[u8]) -> Result<Self, String> {
        let (_, recs) = decoder.decode(body)?;
        let mut contents = Self::default();
        for r in records(recs) {
            let (offset, opcode, body) = r?;
            contents.add(offset, opcode, body)?;
        }
        Ok(contents)
    }

    /// Checks the message index records that followed the chunk against its messages (MCAP
    /// specification): exactly one record per channel with messages in the chunk, listing each of
    /// that channel's messages once, by the offset of its record and its log time. A reader that
    /// seeks by the index then finds exactly the messages a linear read finds.
    pub fn check_index(&self, index: &[MessageIndex]) -> Result<(), String> {
        let mut seen = BTreeMap::new();
        for i in index {
            if seen.insert(i.channel_id, ()).is_some() {
                return Err(format!(
                    "two message index records for channel {}",
                    i.channel_id
                ));
            }
            let expected = self.counts.get(&i.channel_id).copied().unwrap_or(0);
            if i.records.len() as u64 != expected {
                return Err(format!(
                    "message index of channel {} lists {} messages, the chunk holds {expected}",
                    i.channel_id,
                    i.records.len()
                ));
            }
            let mut offsets = Vec::with_capacity(i.records.len());
            for e in &i.records {
                let found = self
                    .messages
                    .binary_search_by_key(&e.offset, |m| m.0)
                    .ok()
                    .map(|k| self.messages[k]);
                if found != Some((e.offset, i.channel_id, e.log_time)) {
                    return Err(format!(
                        "message index of channel {} points at offset {} (log time {}), where the chunk holds no such message",
                        i.channel_id, e.offset, e.log_time
                    ));
                }
                offsets.push(e.offset);
            }
            offsets.sort_unstable();
            if offsets.windows(2).any(|w| w[0] == w[1]) {
                return Err(format!(
                    "message index of channel {} lists a message twice",
                    i.channel_id
                ));
            }
        }
        if let Some((id, _)) = self
            .counts
            .iter()
            .find(|(id, n)| **n > 0 && !seen.contains_key(*id))
        {
            return Err(format!(
                "holds messages on channel {id} that its message index records do not list"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chunk_body(compression: &str, records: &[u8], crc: u32) -> Vec<u8> {
        let data = match compression {
            "zstd" => zstd::bulk::compress(records, 1).unwrap(),
            "lz4" => {
                let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
                std::io::Write::write_all(&mut enc, records).unwrap();
                enc.finish().0
            }
            _ => records.to_vec(),
        };
        let mut body = Vec::new();
        body.extend(1u64.to_le_bytes());
        body.extend(2u64.to_le_bytes());
        body.extend((records.len() as u64).to_le_bytes());
        body.extend(crc.to_le_bytes());
        body.extend((compression.len() as u32).to_le_bytes());
        body.extend(compression.as_bytes());
        body.extend((data.len() as u64).to_le_bytes());
        body.extend(data);
        body
    }

    fn message_record(channel: u16, payload: &[u8]) -> Vec<u8> {
        let mut r = vec![op::MESSAGE];
        r.extend((22 + payload.len() as u64).to_le_bytes());
        r.extend(channel.to_le_bytes());
        r.extend(7u32.to_le_bytes());
        r.extend(1u64.to_le_bytes());
        r.extend(2u64.to_le_bytes());
        r.extend(payload);
        r
    }

    #[test]
    fn decodes_counts_and_rejects_corruption() {
        let mut recs = message_record(3, b"abc");
        recs.extend(message_record(3, b""));
        recs.extend(message_record(5, &[9; 100]));
        let crc = crc32fast::hash(&recs);
        let mut dec = ChunkDecoder::new().unwrap();
        for compression in ["", "zstd", "lz4"] {
            let body = chunk_body(compression, &recs, crc);
            let c = ChunkContents::of_chunk(&mut dec, &body).unwrap();
            assert_eq!(c.counts, BTreeMap::from([(3, 2), (5, 1)]), "{compression}");
            // No CRC stored: still decoded.
            assert!(ChunkContents::of_chunk(&mut dec, &chunk_body(compression, &recs, 0)).is_ok());
            let err = ChunkContents::of_chunk(&mut dec, &chunk_body(compression, &recs, crc ^ 1))
                .unwrap_err();
            assert!(err.contains("CRC mismatch"), "{err}");
        }
        let err = ChunkContents::of_chunk(&mut dec, &chunk_body("brotli", &recs, crc)).unwrap_err();
        assert!(err.contains("unsupported"), "{err}");
        // A record running past the end of the chunk.
        let cut = &recs[..recs.len() - 1];
        let err = ChunkContents::of_chunk(&mut dec, &chunk_body("", cut, 0)).unwrap_err();
        assert!(err.contains("past the end"), "{err}");
        // A lying uncompressed size.
        let mut body = chunk_body("zstd", &recs, crc);
        body[16..24].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
        assert!(ChunkContents::of_chunk(&mut dec, &body).is_err());
        let rec = message_record(4, b"xy");
        // Record offsets inside the chunk.
        let offsets: Vec<u64> = records(&recs).map(|r| r.unwrap().0).collect();
        assert_eq!(offsets, [0, 9 + 25, 2 * 9 + 25 + 22]);
        let (h, d) = message(&rec[9..]).unwrap();
        assert_eq!((h.channel_id, h.sequence, d), (4, 7, &b"xy"[..]));
    }
}
