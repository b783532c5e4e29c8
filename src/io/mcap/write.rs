//! A record-level MCAP writer: the output side of `mireg register`.
//!
//! `mcap::Writer` re-chunks every message it is given (decompress, recompress), and has no way to
//! copy a chunk as it is. [`McapWriter`] writes the file record by record instead, so a chunk of
//! the input (with the message-index records after it) can be copied byte for byte, while
//! messages written one by one go into chunks of our own (zstd, CRC of the uncompressed records,
//! message-index records after each). [`McapWriter::finish`] writes the data-end record (with the
//! data-section CRC) and a full summary section: schemas, channels, statistics, chunk indexes,
//! attachment and metadata indexes, summary offsets, then the footer (with the summary CRC).
//!
//! Schema and channel ids are the caller's: copied chunks refer to their input's ids, so they are
//! kept, and a second definition of an id must be identical to the first. Record layouts follow the
//! MCAP specification; the records themselves are serialised with `mcap::records`' own encoders.

use std::collections::BTreeMap;
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use binrw::BinWrite;
use mcap::records::{
    AttachmentHeader, AttachmentIndex, Channel, ChunkHeader, ChunkIndex, DataEnd, Footer,
    MessageHeader, MessageIndex, MessageIndexEntry, Metadata, MetadataIndex, SchemaHeader,
    Statistics, SummaryOffset, op,
};

use crate::{Error, Result};

/// Bytes before a record's body: the opcode and the little-endian `u64` body length.
pub const RECORD_PREFIX: u64 = 9;

/// A schema's name, encoding and bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaRecord {
    /// Schema name.
    pub name: String,
    /// Schema encoding (`ros2msg`, `jsonschema`, …).
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
}

/// A part of the data section's CRC.
enum CrcPart {
    /// Bytes written through the writer.
    Written(crc32fast::Hasher),
    /// `len` bytes of a copied chunk, with their CRC once supplied.
    Copied { len: u64, crc: Option<u32> },
}

/// A chunk of our own being filled.
#[derive(Default)]
struct OpenChunk {
    /// Serialised message records (the chunk's uncompressed content).
    records: Vec<u8>,
    /// Per channel: (log time, offset in `records`) of each message.
    index: BTreeMap<u16, Vec<MessageIndexEntry>>,
    start: u64,
    end: u64,
}

/// An MCAP file being written record by record to `W`. See the module documentation.
pub struct McapWriter<W: Write> {
    out: W,
    /// The file being written, for error messages.
    path: PathBuf,
    /// Bytes written so far (the offset of the next record).
    pos: u64,
    /// CRC of what was written since the last part of `data_crc_parts` (in the data section),
    /// or of the summary section so far.
    crc: crc32fast::Hasher,
    /// The data section's CRC in parts: bytes written through this writer, and bytes copied from
    /// copied chunks ([`write_copied`](Self::write_copied)), whose CRC the caller supplies later.
    data_crc_parts: Vec<CrcPart>,
    /// The copied chunk that message-index records may still follow, and the bytes of its body
    /// still to be copied.
    copied_chunk: Option<(usize, u64)>,
    schemas: BTreeMap<u16, SchemaRecord>,
    channels: BTreeMap<u16, Channel>,
    chunk_indexes: Vec<ChunkIndex>,
    attachment_indexes: Vec<AttachmentIndex>,
    metadata_indexes: Vec<MetadataIndex>,
    message_counts: BTreeMap<u16, u64>,
    /// First and last message log time over all chunks with messages.
    times: Option<(u64, u64)>,
    chunk: OpenChunk,
    chunk_size: usize,
    compressor: zstd::bulk::Compressor<'static>,
    compressed: Vec<u8>,
}

impl<W: Write> std::fmt::Debug for McapWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapWriter")
            .field("path", &self.path)
            .field("pos", &self.pos)
            .finish()
    }
}

/// `value` serialised with its `mcap::records` encoder.
fn encode<T>(value: &T) -> std::io::Result<Vec<u8>>
where
    T: for<'a> BinWrite<Args<'a> = ()>,
{
    let mut cur = Cursor::new(Vec::new());
    value
        .write_le(&mut cur)
        .map_err(|e| std::io::Error::other(e.to_string()))?;
    Ok(cur.into_inner())
}

/// The body of a schema record.
fn schema_body(id: u16, s: &SchemaRecord) -> std::io::Result<Vec<u8>> {
    let mut body = encode(&SchemaHeader {
        id,
        name: s.name.clone(),
        encoding: s.encoding.clone(),
    })?;
    let len = u32::try_from(s.data.len())
        .map_err(|_| std::io::Error::other(format!("schema {id} is larger than 4 GiB")))?;
    body.extend_from_slice(&len.to_le_bytes());
    body.extend_from_slice(&s.data);
    Ok(body)
}

impl<W: Write> McapWriter<W> {
    /// Starts a file on `out` (named `path` in errors): magic and header record. Messages written
    /// with [`message`](Self::message) go into zstd chunks of about `chunk_size` uncompressed bytes.
    pub fn new(
        out: W,
        path: &Path,
        profile: &str,
        library: &str,
        zstd_level: i32,
        chunk_size: usize,
    ) -> Result<Self> {
        let compressor = zstd::bulk::Compressor::new(zstd_level).map_err(|e| Error::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        let mut w = Self {
            out,
            path: path.to_path_buf(),
            pos: 0,
            crc: crc32fast::Hasher::new(),
            data_crc_parts: Vec::new(),
            copied_chunk: None,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            chunk_indexes: Vec::new(),
            attachment_indexes: Vec::new(),
            metadata_indexes: Vec::new(),
            message_counts: BTreeMap::new(),
            times: None,
            chunk: OpenChunk::default(),
            chunk_size: chunk_size.max(1),
            compressor,
            compressed: Vec::new(),
        };
        w.put(mcap::MAGIC)?;
        let header = w.io(encode(&mcap::records::Header {
            profile: profile.to_string(),
            library: library.to_string(),
        }))?;
        w.record(op::HEADER, &[&header])?;
        Ok(w)
    }

    fn io<T>(&self, r: std::io::Result<T>) -> Result<T> {
        r.map_err(|source| Error::Io {
            path: self.path.clone(),
            source,
        })
    }

    fn format_err(&self, detail: String) -> Error {
        Error::Format {
            path: self.path.clone(),
            detail,
        }
    }

    /// Writes raw bytes, counting them into the position and the section CRC.
    fn put(&mut self, bytes: &[u8]) -> Result<()> {
        let r = self.out.write_all(bytes);
        self.io(r)?;
        self.crc.update(bytes);
        self.pos += bytes.len() as u64;
        Ok(())
    }

    /// Writes a record whose body is the concatenation of `parts`; returns its offset.
    fn record(&mut self, opcode: u8, parts: &[&[u8]]) -> Result<u64> {
        let len: usize = parts.iter().map(|p| p.len()).sum();
        let start = self.record_prefix(opcode, len as u64)?;
        for p in parts {
            self.put(p)?;
        }
        Ok(start)
    }

    /// Writes a record's opcode and body length; returns its offset.
    fn record_prefix(&mut self, opcode: u8, len: u64) -> Result<u64> {
        self.end_copied_chunk(opcode)?;
        let start = self.pos;
        let mut prefix = [0u8; RECORD_PREFIX as usize];
        prefix[0] = opcode;
        prefix[1..].copy_from_slice(&len.to_le_bytes());
        self.put(&prefix)?;
        Ok(start)
    }

    /// Flushes the underlying writer.
    pub fn flush(&mut self) -> Result<()> {
        let r = self.out.flush();
        self.io(r)
    }

    /// The underlying writer.
    pub fn get_ref(&self) -> &W {
        &self.out
    }

    /// Offset of the next record.
    pub fn position(&self) -> u64 {
        self.pos
    }

    /// The schema with this id, if defined.
    pub fn schema(&self, id: u16) -> Option<&SchemaRecord> {
        self.schemas.get(&id)
    }

    /// The channel with this id, if defined.
    pub fn channel(&self, id: u16) -> Option<&Channel> {
        self.channels.get(&id)
    }

    /// The highest schema id defined so far (0 if none).
    pub fn max_schema_id(&self) -> u16 {
        self.schemas.keys().next_back().copied().unwrap_or(0)
    }

    /// The highest channel id defined so far (0 if none).
    pub fn max_channel_id(&self) -> u16 {
        self.channels.keys().next_back().copied().unwrap_or(0)
    }

    /// Whether schema `id` may be defined with `schema`: `Ok(true)` when it already is, with the
    /// same content; `Ok(false)` when it is new; `Err` with the problem when `id` is 0 or is
    /// defined with other content. Callers reading an input use it to report the problem against
    /// the input.
    pub fn check_schema(
        &self,
        id: u16,
        schema: &SchemaRecord,
    ) -> std::result::Result<bool, String> {
        if id == 0 {
            return Err(format!(
                "schema {:?} has id 0, which MCAP reserves for \"no schema\"",
                schema.name
            ));
        }
        match self.schemas.get(&id) {
            Some(known) if known == schema => Ok(true),
            Some(known) => Err(format!(
                "schema id {id} defined twice with different content ({:?} and {:?})",
                known.name, schema.name
            )),
            None => Ok(false),
        }
    }

    /// [`check_schema`](Self::check_schema) for a channel, whose schema must be defined already
    /// (or be 0, schemaless).
    pub fn check_channel(&self, channel: &Channel) -> std::result::Result<bool, String> {
        match self.channels.get(&channel.id) {
            Some(known) if known == channel => Ok(true),
            Some(known) => Err(format!(
                "channel id {} defined twice with different content ({:?} and {:?})",
                channel.id, known.topic, channel.topic
            )),
            None if channel.schema_id != 0 && !self.schemas.contains_key(&channel.schema_id) => {
                Err(format!(
                    "channel {} ({}) names schema {}, which is not defined",
                    channel.id, channel.topic, channel.schema_id
                ))
            }
            None => Ok(false),
        }
    }

    /// Defines schema `id`, writing a schema record when `write` (else it only goes into the
    /// summary, e.g. because a copied chunk holds it). Defining an id again with the same content
    /// is a no-op; with other content, or id 0, an error ([`check_schema`](Self::check_schema)).
    pub fn define_schema(&mut self, id: u16, schema: SchemaRecord, write: bool) -> Result<()> {
        if self
            .check_schema(id, &schema)
            .map_err(|p| self.format_err(p))?
        {
            return Ok(());
        }
        if write {
            let body = self.io(schema_body(id, &schema))?;
            self.record(op::SCHEMA, &[&body])?;
        }
        self.schemas.insert(id, schema);
        Ok(())
    }

    /// Defines a channel, like [`define_schema`](Self::define_schema)
    /// ([`check_channel`](Self::check_channel)).
    pub fn define_channel(&mut self, channel: Channel, write: bool) -> Result<()> {
        if self
            .check_channel(&channel)
            .map_err(|p| self.format_err(p))?
        {
            return Ok(());
        }
        if write {
            let body = self.io(encode(&channel))?;
            self.record(op::CHANNEL, &[&body])?;
        }
        self.channels.insert(channel.id, channel);
        Ok(())
    }

    /// Adds a message to the current chunk of our own (written once it reaches the chunk size).
    pub fn message(&mut self, header: &MessageHeader, data: &[u8]) -> Result<()> {
        if !self.channels.contains_key(&header.channel_id) {
            return Err(self.format_err(format!(
                "message on channel {}, which is not defined",
                header.channel_id
            )));
        }
        let c = &mut self.chunk;
        if c.records.is_empty() {
            (c.start, c.end) = (header.log_time, header.log_time);
        } else {
            c.start = c.start.min(header.log_time);
            c.end = c.end.max(header.log_time);
        }
        c.index
            .entry(header.channel_id)
            .or_default()
            .push(MessageIndexEntry {
                log_time: header.log_time,
                offset: c.records.len() as u64,
            });
        c.records.push(op::MESSAGE);
        c.records
            .extend_from_slice(&(22 + data.len() as u64).to_le_bytes());
        c.records
            .extend_from_slice(&header.channel_id.to_le_bytes());
        c.records.extend_from_slice(&header.sequence.to_le_bytes());
        c.records.extend_from_slice(&header.log_time.to_le_bytes());
        c.records
            .extend_from_slice(&header.publish_time.to_le_bytes());
        c.records.extend_from_slice(data);
        *self.message_counts.entry(header.channel_id).or_default() += 1;
        if self.chunk.records.len() >= self.chunk_size {
            self.flush_chunk()?;
        }
        Ok(())
    }

    fn extend_times(&mut self, start: u64, end: u64) {
        self.times = Some(match self.times {
            Some((a, b)) => (a.min(start), b.max(end)),
            None => (start, end),
        });
    }

    /// Writes the current chunk of our own, if it holds anything, with its message indexes.
    pub fn flush_chunk(&mut self) -> Result<()> {
        if self.chunk.records.is_empty() {
            return Ok(());
        }
        let mut chunk = std::mem::take(&mut self.chunk);
        self.compressed.clear();
        self.compressed
            .reserve(zstd::zstd_safe::compress_bound(chunk.records.len()));
        let r = self
            .compressor
            .compress_to_buffer(&chunk.records, &mut self.compressed);
        self.io(r)?;
        let header = ChunkHeader {
            message_start_time: chunk.start,
            message_end_time: chunk.end,
            uncompressed_size: chunk.records.len() as u64,
            uncompressed_crc: crc32fast::hash(&chunk.records),
            compression: "zstd".into(),
            compressed_size: self.compressed.len() as u64,
        };
        let head = self.io(encode(&header))?;
        let compressed = std::mem::take(&mut self.compressed);
        let chunk_start = self.record(op::CHUNK, &[&head, &compressed])?;
        self.compressed = compressed;
        let chunk_length = self.pos - chunk_start;
        let mut offsets = BTreeMap::new();
        for (channel_id, mut records) in std::mem::take(&mut chunk.index) {
            records.sort_by_key(|e| e.log_time);
            let body = self.io(encode(&MessageIndex {
                channel_id,
                records,
            }))?;
            offsets.insert(channel_id, self.record(op::MESSAGE_INDEX, &[&body])?);
        }
        self.extend_times(chunk.start, chunk.end);
        self.chunk_indexes.push(ChunkIndex {
            message_start_time: chunk.start,
            message_end_time: chunk.end,
            chunk_start_offset: chunk_start,
            chunk_length,
            message_index_offsets: offsets,
            message_index_length: self.pos - chunk_start - chunk_length,
            compression: header.compression,
            compressed_size: header.compressed_size,
            uncompressed_size: header.uncompressed_size,
        });
        // Keep the allocation for the next chunk.
        chunk.records.clear();
        self.chunk.records = chunk.records;
        Ok(())
    }

    /// A copied chunk is complete once its body has been copied; message-index records may
    /// follow it until any other record is written.
    fn end_copied_chunk(&mut self, next_opcode: u8) -> Result<()> {
        match self.copied_chunk {
            Some((_, left)) if left > 0 => Err(self.format_err(format!(
                "chunk record left incomplete ({left} bytes of its body not copied)"
            ))),
            Some(_) if next_opcode != op::MESSAGE_INDEX => {
                self.copied_chunk = None;
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Starts copying a chunk record byte for byte: `len` is its body length, `head` the first
    /// bytes of its body (at least the chunk header, `header` parsed from them). The rest of the
    /// body comes from [`write_copied`](Self::write_copied), and the message-index records that followed
    /// the chunk from [`copied_message_index`](Self::copied_message_index). Returns the chunk's
    /// number, for [`count_copied_messages`](Self::count_copied_messages).
    pub fn start_copied_chunk(
        &mut self,
        len: u64,
        head: &[u8],
        header: &ChunkHeader,
    ) -> Result<usize> {
        let Some(rest) = len.checked_sub(head.len() as u64) else {
            return Err(self.format_err("chunk record shorter than its header".into()));
        };
        let chunk_start = self.record_prefix(op::CHUNK, len)?;
        self.put(head)?;
        self.chunk_indexes.push(ChunkIndex {
            message_start_time: header.message_start_time,
            message_end_time: header.message_end_time,
            chunk_start_offset: chunk_start,
            chunk_length: RECORD_PREFIX + len,
            message_index_offsets: BTreeMap::new(),
            message_index_length: 0,
            compression: header.compression.clone(),
            compressed_size: header.compressed_size,
            uncompressed_size: header.uncompressed_size,
        });
        let chunk = self.chunk_indexes.len() - 1;
        self.copied_chunk = Some((chunk, rest));
        Ok(chunk)
    }

    /// Writes the next bytes of a chunk started with
    /// [`start_copied_chunk`](Self::start_copied_chunk) (the rest of its body, as read from the
    /// input). They are not hashed here: whoever checks the chunk computes their CRC, off this
    /// thread, and supplies it with [`copied_crc`](Self::copied_crc) and the returned id.
    pub fn write_copied(&mut self, bytes: &[u8]) -> Result<usize> {
        let n = bytes.len() as u64;
        match &mut self.copied_chunk {
            Some((_, left)) if *left >= n => *left -= n,
            _ => {
                return Err(
                    self.format_err("copying more bytes than the open chunk record holds".into())
                );
            }
        }
        let r = self.out.write_all(bytes);
        self.io(r)?;
        let written = std::mem::take(&mut self.crc);
        self.data_crc_parts.push(CrcPart::Written(written));
        self.data_crc_parts
            .push(CrcPart::Copied { len: n, crc: None });
        self.pos += n;
        Ok(self.data_crc_parts.len() - 1)
    }

    /// Supplies the CRC of bytes written by [`write_copied`](Self::write_copied) (its returned id). A
    /// CRC never supplied makes the data section's CRC 0 ("not available").
    pub fn copied_crc(&mut self, id: usize, crc32: u32) {
        if let Some(CrcPart::Copied { crc, .. }) = self.data_crc_parts.get_mut(id) {
            *crc = Some(crc32);
        }
    }

    /// Copies a message-index record (`body`: everything after its opcode and length) that
    /// followed the chunk being copied.
    pub fn copied_message_index(&mut self, body: &[u8]) -> Result<()> {
        let Some((chunk, 0)) = self.copied_chunk else {
            return Err(
                self.format_err("message index record without a copied chunk before it".into())
            );
        };
        let Some(id) = body.get(..2) else {
            return Err(self.format_err("message index record shorter than its channel id".into()));
        };
        let channel_id = u16::from_le_bytes([id[0], id[1]]);
        let offset = self.record(op::MESSAGE_INDEX, &[body])?;
        let index = &mut self.chunk_indexes[chunk];
        index.message_index_offsets.insert(channel_id, offset);
        index.message_index_length = self.pos - index.chunk_start_offset - index.chunk_length;
        Ok(())
    }

    /// Adds the messages found in copied chunk `chunk` (per channel) to the statistics.
    pub fn count_copied_messages(&mut self, chunk: usize, counts: &BTreeMap<u16, u64>) {
        let total: u64 = counts.values().sum();
        for (&id, &n) in counts {
            *self.message_counts.entry(id).or_default() += n;
        }
        if total > 0
            && let Some((s, e)) = self
                .chunk_indexes
                .get(chunk)
                .map(|c| (c.message_start_time, c.message_end_time))
        {
            self.extend_times(s, e);
        }
    }

    /// Copies an attachment record byte for byte (`body`: everything after its opcode and length;
    /// `header` and `data_size` parsed from it).
    pub fn copy_attachment(
        &mut self,
        body: &[u8],
        header: &AttachmentHeader,
        data_size: u64,
    ) -> Result<()> {
        let offset = self.record(op::ATTACHMENT, &[body])?;
        self.attachment_indexes.push(AttachmentIndex {
            offset,
            length: self.pos - offset,
            log_time: header.log_time,
            create_time: header.create_time,
            data_size,
            name: header.name.clone(),
            media_type: header.media_type.clone(),
        });
        Ok(())
    }

    /// Writes an attachment (with the CRC of its record).
    pub fn attachment(&mut self, header: &AttachmentHeader, data: &[u8]) -> Result<()> {
        let mut body = self.io(encode(header))?;
        body.extend_from_slice(&(data.len() as u64).to_le_bytes());
        body.extend_from_slice(data);
        let crc = crc32fast::hash(&body);
        body.extend_from_slice(&crc.to_le_bytes());
        self.copy_attachment(&body, header, data.len() as u64)
    }

    /// Copies a metadata record byte for byte (`body`: everything after its opcode and length).
    pub fn copy_metadata(&mut self, body: &[u8], name: &str) -> Result<()> {
        let offset = self.record(op::METADATA, &[body])?;
        self.metadata_indexes.push(MetadataIndex {
            offset,
            length: self.pos - offset,
            name: name.to_string(),
        });
        Ok(())
    }

    /// Writes a metadata record.
    pub fn metadata(&mut self, metadata: &Metadata) -> Result<()> {
        let body = self.io(encode(metadata))?;
        self.copy_metadata(&body, &metadata.name)
    }

    /// Copies a record this writer has no index for (e.g. an application extension) as it is.
    pub fn copy_record(&mut self, opcode: u8, body: &[u8]) -> Result<()> {
        self.record(opcode, &[body]).map(|_| ())
    }

    /// Writes one summary group (records of one opcode); returns its summary offset, if any.
    fn group(&mut self, opcode: u8, bodies: &[Vec<u8>]) -> Result<Option<SummaryOffset>> {
        if bodies.is_empty() {
            return Ok(None);
        }
        let group_start = self.pos;
        for b in bodies {
            self.record(opcode, &[b])?;
        }
        Ok(Some(SummaryOffset {
            group_opcode: opcode,
            group_start,
            group_length: self.pos - group_start,
        }))
    }

    /// Ends the data section and writes the summary section, the footer and the closing magic;
    /// returns the underlying writer (flushed).
    pub fn finish(mut self) -> Result<W> {
        self.flush_chunk()?;
        self.end_copied_chunk(op::DATA_END)?;
        let mut data_crc = crc32fast::Hasher::new();
        let mut known = true;
        for part in std::mem::take(&mut self.data_crc_parts) {
            match part {
                CrcPart::Written(h) => data_crc.combine(&h),
                CrcPart::Copied { len, crc: Some(c) } => {
                    data_crc.combine(&crc32fast::Hasher::new_with_initial_len(c, len))
                }
                CrcPart::Copied { crc: None, .. } => known = false,
            }
        }
        data_crc.combine(&std::mem::take(&mut self.crc));
        let data_crc = if known { data_crc.finalize() } else { 0 };
        let body = self.io(encode(&DataEnd {
            data_section_crc: data_crc,
        }))?;
        self.record(op::DATA_END, &[&body])?;

        // The summary section's CRC starts here.
        self.crc = crc32fast::Hasher::new();
        let summary_start = self.pos;
        let schemas = self
            .schemas
            .iter()
            .map(|(&id, s)| schema_body(id, s))
            .collect::<std::io::Result<Vec<_>>>();
        let schemas = self.io(schemas)?;
        let channels = self.channels.values().map(encode).collect();
        let channels = self.io(channels)?;
        let (message_start_time, message_end_time) = self.times.unwrap_or((0, 0));
        let stats = Statistics {
            message_count: self.message_counts.values().sum(),
            schema_count: self.schemas.len() as u16,
            channel_count: self.channels.len() as u32,
            attachment_count: self.attachment_indexes.len() as u32,
            metadata_count: self.metadata_indexes.len() as u32,
            chunk_count: self.chunk_indexes.len() as u32,
            message_start_time,
            message_end_time,
            channel_message_counts: self
                .message_counts
                .iter()
                .filter(|(_, n)| **n > 0)
                .map(|(&id, &n)| (id, n))
                .collect(),
        };
        let stats = self.io(encode(&stats))?;
        let chunk_indexes = self.chunk_indexes.iter().map(encode).collect();
        let chunk_indexes = self.io(chunk_indexes)?;
        let attachment_indexes = self.attachment_indexes.iter().map(encode).collect();
        let attachment_indexes = self.io(attachment_indexes)?;
        let metadata_indexes = self.metadata_indexes.iter().map(encode).collect();
        let metadata_indexes = self.io(metadata_indexes)?;

        let mut offsets = Vec::new();
        for (opcode, bodies) in [
            (op::SCHEMA, &schemas),
            (op::CHANNEL, &channels),
            (op::STATISTICS, &vec![stats]),
            (op::CHUNK_INDEX, &chunk_indexes),
            (op::ATTACHMENT_INDEX, &attachment_indexes),
            (op::METADATA_INDEX, &metadata_indexes),
        ] {
            offsets.extend(self.group(opcode, bodies)?);
        }
        let summary_offset_start = self.pos;
        for o in &offsets {
            let body = self.io(encode(o))?;
            self.record(op::SUMMARY_OFFSET, &[&body])?;
        }
        // The footer's CRC covers the summary section up to and including its own
        // summary_offset_start field.
        let mut footer = Footer {
            summary_start,
            summary_offset_start,
            summary_crc: 0,
        };
        let body = self.io(encode(&footer))?;
        let mut crc = std::mem::take(&mut self.crc);
        crc.update(&[op::FOOTER]);
        crc.update(&(body.len() as u64).to_le_bytes());
        crc.update(&body[..16]);
        footer.summary_crc = crc.finalize();
        let body = self.io(encode(&footer))?;
        self.record(op::FOOTER, &[&body])?;
        self.put(mcap::MAGIC)?;
        let r = self.out.flush();
        self.io(r)?;
        Ok(self.out)
    }
}

#[cfg(test)]
mod tests;
