//! MCAP input and output for `mireg register`: a streaming record reader whose memory is bounded
//! by one chunk, a catalogue of the input's schemas and channels, an output log that copies input
//! records and adds ours, and the pass-through that copies the input's chunks byte for byte.
//!
//! Guarantees (DESIGN §4): input schema and channel ids are kept (copied chunks refer to them) and
//! ours get ids above every input id; the output goes to a temporary file beside the target that
//! is synced and renamed on success and deleted otherwise, so an error never leaves a half-written
//! log. Copied chunks are written as they were read, never re-encoded, but each one is still
//! decompressed once, off the copying thread, to check its CRC: a corrupt input is an error naming
//! the file.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, Sender, SyncSender, TrySendError, channel, sync_channel};

use mcap::records::{Channel, MessageHeader, MessageIndex, Metadata, Record, op};

use super::atomic_file::PendingFile;
use super::mcap_chunk::{self, ChunkContents, ChunkDecoder};
pub use super::mcap_read::for_each_record;
use super::mcap_read::{Source, io_err, mcap_err, read_summary};
use super::mcap_record::parse_record;
use super::mcap_write::{McapWriter, SchemaRecord};
use crate::{Error, Result};

/// A channel of an MCAP file, with its schema's name and encoding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Channel id in the file.
    pub id: u16,
    /// Topic name.
    pub topic: String,
    /// Schema name (empty for schemaless channels).
    pub schema_name: String,
    /// Schema encoding (`ros2msg`, `protobuf`, `jsonschema`, … or empty).
    pub schema_encoding: String,
    /// Message encoding (`cdr`, `protobuf`, `json`, …).
    pub message_encoding: String,
    /// Message count from the summary statistics, when the file has them.
    pub message_count: Option<u64>,
}

/// Every schema and channel of an MCAP file, with their ids, known before its records are read:
/// from the summary section when it lists the channels, else from one pass over the records.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InputCatalog {
    /// Schemas by id.
    pub schemas: BTreeMap<u16, SchemaRecord>,
    /// Channels by id.
    pub channels: BTreeMap<u16, Channel>,
    /// Messages per channel, when known (summary statistics, or the pass over the records).
    pub message_counts: Option<BTreeMap<u16, u64>>,
}

impl InputCatalog {
    /// The catalogue of `path`.
    pub fn read(path: &Path) -> Result<Self> {
        let mut cat = Self::default();
        if let Some(summary) = read_summary(path)?.filter(|s| !s.channels.is_empty()) {
            let schemas = summary
                .schemas
                .values()
                .chain(summary.channels.values().filter_map(|c| c.schema.as_ref()));
            for s in schemas {
                cat.schemas.insert(
                    s.id,
                    SchemaRecord {
                        name: s.name.clone(),
                        encoding: s.encoding.clone(),
                        data: s.data.to_vec(),
                    },
                );
            }
            for c in summary.channels.values() {
                cat.channels.insert(
                    c.id,
                    Channel {
                        id: c.id,
                        schema_id: c.schema.as_ref().map_or(0, |s| s.id),
                        topic: c.topic.clone(),
                        message_encoding: c.message_encoding.clone(),
                        metadata: c.metadata.clone(),
                    },
                );
            }
            cat.message_counts = summary.stats.map(|s| s.channel_message_counts);
            return Ok(cat);
        }
        // No summary (e.g. a log cut short while recording): one pass over the records.
        let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
        for_each_record(path, |record| {
            match record {
                Record::Schema { header, data } => {
                    cat.schemas.entry(header.id).or_insert(SchemaRecord {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    });
                }
                Record::Channel(c) => {
                    cat.channels.entry(c.id).or_insert(c);
                }
                Record::Message { header, .. } => {
                    *counts.entry(header.channel_id).or_default() += 1
                }
                _ => {}
            }
            Ok(())
        })?;
        for &id in cat.channels.keys() {
            counts.entry(id).or_default();
        }
        cat.message_counts = Some(counts);
        Ok(cat)
    }

    /// The channels with their schemas' names and encodings, by id.
    pub fn channel_infos(&self) -> Vec<ChannelInfo> {
        self.channels
            .values()
            .map(|c| {
                let schema = self.schemas.get(&c.schema_id);
                ChannelInfo {
                    id: c.id,
                    topic: c.topic.clone(),
                    schema_name: schema.map(|s| s.name.clone()).unwrap_or_default(),
                    schema_encoding: schema.map(|s| s.encoding.clone()).unwrap_or_default(),
                    message_encoding: c.message_encoding.clone(),
                    message_count: self
                        .message_counts
                        .as_ref()
                        .and_then(|m| m.get(&c.id).copied()),
                }
            })
            .collect()
    }
}

/// Channels of `path`, from its summary section when present, else by scanning the records.
pub fn list_channels(path: &Path) -> Result<Vec<ChannelInfo>> {
    Ok(InputCatalog::read(path)?.channel_infos())
}

/// zstd level of our own output chunks: 1 (fastest). Input chunks are copied as they are.
pub const OUTPUT_ZSTD_LEVEL: u32 = 1;
/// Uncompressed bytes at which a chunk of our own is closed and written.
pub const OUTPUT_CHUNK_SIZE: usize = 1 << 20;

/// An MCAP being written to a temporary file beside `target`; [`OutputLog::finish`] renames it.
///
/// Schema and channel ids of copied records are kept; [`add_channel`](Self::add_channel) takes ids
/// above every id defined so far, so declare the input's first
/// ([`declare_input`](Self::declare_input)).
pub struct OutputLog {
    writer: Option<McapWriter<BufWriter<File>>>,
    pending: Option<PendingFile>,
    target: PathBuf,
    /// Schemas added by `add_channel` (name, encoding, bytes) and their ids, reused when equal.
    own_schemas: HashMap<(String, String, Vec<u8>), u16>,
    sequences: HashMap<u16, u32>,
    writeback: Option<Writeback>,
    /// Bytes reserved on disk by [`reserve`](Self::reserve).
    reserved: u64,
}

/// A thread that pushes the output file's data to disk while it is being written, so that the
/// sync in [`OutputLog::finish`] only waits for the last few megabytes instead of the whole file.
///
/// [`OutputLog::write_behind`] hands it each stretch of [`WRITEBACK_STEP`] bytes that has reached
/// the file, and it asks the kernel to start writing that stretch (`sync_file_range` with
/// `SYNC_FILE_RANGE_WRITE` on Linux: no waiting, and no metadata or durability guarantee; that is
/// still `finish`'s `fsync`). [`OutputLog::start_writeback`] makes it sync the file's data once
/// (`fdatasync`), when the data section is complete, overlapping whatever comes before `finish`.
/// Only an early start of the disk writes: a failure here shows in the final sync.
struct Writeback {
    thread: std::thread::JoinHandle<()>,
    requests: Option<Sender<WritebackRequest>>,
    /// End of the stretches handed on so far.
    requested: u64,
    /// Whether the data sync was requested.
    synced: bool,
}

/// What the writeback thread is asked to do.
enum WritebackRequest {
    /// Start writing `len` bytes at `offset` to disk.
    Range { offset: u64, len: u64 },
    /// Sync the file's data (and wait for it).
    SyncData,
}

/// Bytes of output handed to the writeback thread at a time: large enough that the calls cost
/// nothing next to the copy, small enough that the disk starts early.
const WRITEBACK_STEP: u64 = 8 << 20;

impl Writeback {
    fn start(file: File) -> Self {
        let (tx, rx) = channel::<WritebackRequest>();
        let thread = std::thread::spawn(move || {
            for r in rx {
                match r {
                    WritebackRequest::Range { offset, len } => start_disk_write(&file, offset, len),
                    WritebackRequest::SyncData => {
                        let _ = file.sync_data();
                    }
                }
            }
        });
        Self {
            thread,
            requests: Some(tx),
            requested: 0,
            synced: false,
        }
    }

    fn send(&self, r: WritebackRequest) {
        if let Some(tx) = &self.requests {
            // A thread that is gone only means no early writeback.
            let _ = tx.send(r);
        }
    }

    /// Waits for the thread to finish what it was asked.
    fn join(mut self) {
        drop(self.requests.take());
        let _ = self.thread.join();
    }
}

/// Asks the kernel to start writing `len` bytes of `file` at `offset` to disk, without waiting.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn start_disk_write(file: &File, offset: u64, len: u64) {
    use std::os::fd::AsRawFd;
    let (Ok(offset), Ok(len)) = (i64::try_from(offset), i64::try_from(len)) else {
        return;
    };
    // SAFETY: sync_file_range only reads its integer arguments; the descriptor is open for as
    // long as `file` lives. Its result is advisory here (see `Writeback`).
    unsafe {
        libc::sync_file_range(file.as_raw_fd(), offset, len, libc::SYNC_FILE_RANGE_WRITE);
    }
}

/// Allocates the first `bytes` of `file` on disk (`fallocate`, which also sets its length);
/// whether it did.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn preallocate(file: &File, bytes: u64) -> bool {
    use std::os::fd::AsRawFd;
    let Ok(len) = i64::try_from(bytes) else {
        return false;
    };
    // SAFETY: fallocate only reads its integer arguments; the descriptor is open for as long as
    // `file` lives. Not posix_fallocate, which writes zeros where the file system cannot
    // preallocate.
    unsafe { libc::fallocate(file.as_raw_fd(), 0, 0, len) == 0 }
}

/// Elsewhere space is allocated as the file is written.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn preallocate(_file: &File, _bytes: u64) -> bool {
    false
}

/// Elsewhere the data goes to disk at the final sync.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn start_disk_write(_file: &File, _offset: u64, _len: u64) {}

impl Drop for OutputLog {
    fn drop(&mut self) {
        // Let the writeback thread end before the temporary file is deleted.
        if let Some(w) = self.writeback.take() {
            w.join();
        }
    }
}

impl std::fmt::Debug for OutputLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutputLog")
            .field("target", &self.target)
            .finish()
    }
}

impl OutputLog {
    /// Starts writing towards `target`. Fails if `target` exists and `overwrite` is false.
    pub fn create(target: &Path, overwrite: bool, profile: &str) -> Result<Self> {
        let (file, pending) = PendingFile::create(target, overwrite)?;
        let writer = McapWriter::new(
            BufWriter::with_capacity(1 << 20, file),
            target,
            profile,
            &format!("mireg {}", env!("CARGO_PKG_VERSION")),
            OUTPUT_ZSTD_LEVEL as i32,
            OUTPUT_CHUNK_SIZE,
        )?;
        Ok(Self {
            writer: Some(writer),
            pending: Some(pending),
            target: target.to_path_buf(),
            own_schemas: HashMap::new(),
            sequences: HashMap::new(),
            writeback: None,
            reserved: 0,
        })
    }

    fn w(&mut self) -> &mut McapWriter<BufWriter<File>> {
        self.writer.as_mut().expect("writer present until finish")
    }

    /// Writes every schema and channel of the input (`input` names it in errors), with their ids.
    pub fn declare_input(&mut self, input: &Path, catalog: &InputCatalog) -> Result<()> {
        let in_input = |problem: String| Error::Format {
            path: input.to_path_buf(),
            detail: problem,
        };
        let w = self.w();
        for (&id, s) in &catalog.schemas {
            w.check_schema(id, s).map_err(in_input)?;
            w.define_schema(id, s.clone(), true)?;
        }
        for c in catalog.channels.values() {
            w.check_channel(c).map_err(in_input)?;
            w.define_channel(c.clone(), true)?;
        }
        Ok(())
    }

    /// Copies an input record into the output, keeping schema and channel ids, message bytes,
    /// sequence, log and publish times; messages go into our own chunks. Records the writer makes
    /// itself (header, chunks, indexes, summary) are ignored.
    pub fn copy(&mut self, record: &Record<'_>) -> Result<()> {
        match record {
            Record::Schema { header, data } => self.w().define_schema(
                header.id,
                SchemaRecord {
                    name: header.name.clone(),
                    encoding: header.encoding.clone(),
                    data: data.to_vec(),
                },
                true,
            ),
            Record::Channel(c) => self.w().define_channel(c.clone(), true),
            Record::Message { header, data } => self.w().message(header, data),
            Record::Metadata(m) => self.w().metadata(m),
            Record::Attachment { header, data, .. } => self.w().attachment(header, data),
            _ => Ok(()),
        }
    }

    /// Adds a new channel with its schema (reusing an equal schema added before), with ids above
    /// every id defined so far; returns the output channel id.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: &[u8],
        message_encoding: &str,
    ) -> Result<u16> {
        self.add_channel_with_metadata(
            topic,
            schema_name,
            schema_encoding,
            schema,
            message_encoding,
            BTreeMap::new(),
        )
    }

    /// [`add_channel`](Self::add_channel) with channel metadata (e.g. the ROS 1 profile's
    /// `md5sum`, `callerid`, `latching`).
    pub fn add_channel_with_metadata(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: &[u8],
        message_encoding: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<u16> {
        let key = (
            schema_name.to_string(),
            schema_encoding.to_string(),
            schema.to_vec(),
        );
        let schema_id = match self.own_schemas.get(&key) {
            Some(&id) => id,
            None => {
                let id = self.w().max_schema_id().checked_add(1).ok_or_else(|| {
                    mcap_err(
                        &self.target,
                        "adding a schema",
                        "all 65535 schema ids are taken",
                    )
                })?;
                self.w().define_schema(
                    id,
                    SchemaRecord {
                        name: key.0.clone(),
                        encoding: key.1.clone(),
                        data: key.2.clone(),
                    },
                    true,
                )?;
                self.own_schemas.insert(key, id);
                id
            }
        };
        let id = self.w().max_channel_id().checked_add(1).ok_or_else(|| {
            mcap_err(
                &self.target,
                "adding a channel",
                "all 65535 channel ids are taken",
            )
        })?;
        self.w().define_channel(
            Channel {
                id,
                schema_id,
                topic: topic.to_string(),
                message_encoding: message_encoding.to_string(),
                metadata,
            },
            true,
        )?;
        Ok(id)
    }

    /// Writes one of our messages on an output channel from [`add_channel`](Self::add_channel).
    pub fn write(
        &mut self,
        channel_id: u16,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<()> {
        let seq = self.sequences.entry(channel_id).or_default();
        *seq += 1;
        let header = MessageHeader {
            channel_id,
            sequence: *seq,
            log_time,
            publish_time,
        };
        self.w().message(&header, data)
    }

    /// The writeback thread, started on first use.
    fn writeback(&mut self) -> Result<&mut Writeback> {
        if self.writeback.is_none() {
            let file = self.w().get_ref().get_ref().try_clone();
            let file = file.map_err(|e| io_err(&self.target, e))?;
            self.writeback = Some(Writeback::start(file));
        }
        Ok(self.writeback.as_mut().expect("just started"))
    }

    /// Lets the disk writes of what has reached the file so far start on another thread, once
    /// a further [`WRITEBACK_STEP`] bytes have (see [`Writeback`]). Cheap: call it after each
    /// large write.
    pub fn write_behind(&mut self) -> Result<()> {
        let w = self.w();
        let written = w.position() - w.get_ref().buffer().len() as u64;
        let requested = self.writeback.as_ref().map_or(0, |w| w.requested);
        if written < requested + WRITEBACK_STEP {
            return Ok(());
        }
        let wb = self.writeback()?;
        if !wb.synced {
            wb.send(WritebackRequest::Range {
                offset: requested,
                len: written - requested,
            });
        }
        wb.requested = written;
        Ok(())
    }

    /// Syncs what was written so far to disk on another thread (once; see
    /// [`finish`](Self::finish), which waits for it and syncs the rest).
    pub fn start_writeback(&mut self) -> Result<()> {
        if self.writeback.as_ref().is_some_and(|w| w.synced) {
            return Ok(());
        }
        let r = self.w().flush();
        r?;
        let wb = self.writeback()?;
        wb.send(WritebackRequest::SyncData);
        wb.synced = true;
        Ok(())
    }

    /// Reserves `bytes` of disk space for the file (e.g. the size of a log about to be copied into
    /// it), so that writing it only fills blocks already allocated instead of reserving them
    /// page by page. The file is cut to what was written in [`finish`](Self::finish). Advisory:
    /// does nothing where the file system (or the platform) cannot preallocate.
    pub fn reserve(&mut self, bytes: u64) -> Result<()> {
        if bytes <= self.reserved {
            return Ok(());
        }
        if preallocate(self.w().get_ref().get_ref(), bytes) {
            self.reserved = bytes;
        }
        Ok(())
    }

    /// Writes a metadata record.
    pub fn write_metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<()> {
        self.w().metadata(&Metadata {
            name: name.into(),
            metadata: entries,
        })
    }

    /// Finishes the file, syncs it and renames it to the target. On any error nothing is left
    /// at the target path and the temporary file is removed.
    pub fn finish(mut self) -> Result<()> {
        let writer = self.writer.take().expect("writer present until finish");
        let buf = writer.finish()?;
        if let Some(w) = self.writeback.take() {
            w.join();
        }
        let mut file = buf
            .into_inner()
            .map_err(|e| io_err(&self.target, e.into_error()))?;
        if self.reserved > 0 {
            // Drop the reserved space that was not written.
            let len = std::io::Seek::stream_position(&mut file);
            let len = len.map_err(|e| io_err(&self.target, e))?;
            file.set_len(len).map_err(|e| io_err(&self.target, e))?;
        }
        let pending = self
            .pending
            .take()
            .expect("pending file present until finish");
        pending.commit(file)
    }
}

/// Copied chunks waiting for validation at most (each holds its chunk in memory; when the queue
/// is full the reading thread checks the chunk itself).
const VALIDATION_QUEUE: usize = 2;
/// Chunk buffers kept for reuse.
const BUFFER_POOL: usize = 4;

/// Where a copied chunk record is in the input and the output.
#[derive(Debug, Clone, Copy)]
struct ChunkAt {
    /// Number of the chunk in the output.
    chunk: usize,
    /// Offset of the record in the input.
    offset: u64,
    /// Bytes at the start of the body that were written through the writer's CRC (the header).
    head: usize,
    /// Id of the rest's CRC in the output's data-section CRC.
    crc_id: usize,
}

/// Decodes a copied chunk `body` (checking its CRC); returns what it holds and the CRC of the
/// body after its first `head` bytes (for the output's data-section CRC).
fn check_chunk(
    decoder: &mut ChunkDecoder,
    body: &[u8],
    head: usize,
    index: Option<&[MessageIndex]>,
) -> std::result::Result<(ChunkContents, u32), String> {
    let crc = crc32fast::hash(body.get(head..).unwrap_or_default());
    let contents = ChunkContents::of_chunk(decoder, body)?;
    if let Some(index) = index {
        contents.check_index(index)?;
    }
    Ok((contents, crc))
}

/// A chunk to check off the reading thread: its position and its record body.
struct Job {
    at: ChunkAt,
    body: Vec<u8>,
    /// The message index records that followed it (`None`: none did).
    index: Option<Vec<MessageIndex>>,
}

/// A chunk checked off the reading thread (its buffer comes back for reuse).
struct Checked {
    at: ChunkAt,
    result: std::result::Result<(ChunkContents, u32), String>,
    body: Vec<u8>,
}

fn validate_chunks(jobs: Receiver<Job>, done: Sender<Checked>) {
    let mut decoder = ChunkDecoder::new();
    for Job { at, body, index } in jobs {
        let result = match &mut decoder {
            Ok(d) => check_chunk(d, &body, at.head, index.as_deref()),
            Err(e) => Err(e.clone()),
        };
        if done.send(Checked { at, result, body }).is_err() {
            break;
        }
    }
}

/// A copied chunk whose message-index records are being copied.
struct Group {
    at: ChunkAt,
    /// The chunk record's body.
    body: Vec<u8>,
    /// The message-index records that followed it.
    index: Vec<MessageIndex>,
}

/// State of one pass-through.
struct PassThrough<'a> {
    input: &'a Path,
    wanted: &'a BTreeSet<u16>,
    decoder: ChunkDecoder,
    jobs: Option<SyncSender<Job>>,
    done: Receiver<Checked>,
    sent: usize,
    received: usize,
    pool: Vec<Vec<u8>>,
    messages: u64,
}

type OnMessage<'f> = dyn FnMut(&mut OutputLog, &MessageHeader, &[u8]) -> Result<()> + 'f;

impl PassThrough<'_> {
    fn err(&self, detail: String) -> Error {
        Error::Format {
            path: self.input.to_path_buf(),
            detail,
        }
    }

    /// Checks the schemas and channels a copied chunk holds against those defined (adding new
    /// ones to the summary), and counts its messages.
    fn account(
        &mut self,
        log: &mut OutputLog,
        offset: u64,
        chunk: usize,
        contents: ChunkContents,
    ) -> Result<()> {
        let w = log.w();
        let in_chunk = |problem: String| self.err(format!("chunk at offset {offset}: {problem}"));
        for (id, s) in contents.schemas {
            w.check_schema(id, &s).map_err(in_chunk)?;
            w.define_schema(id, s, false)?;
        }
        for c in contents.channels {
            w.check_channel(&c).map_err(in_chunk)?;
            w.define_channel(c, false)?;
        }
        for &id in contents.counts.keys() {
            if w.channel(id).is_none() {
                return Err(self.err(format!(
                    "chunk at offset {offset} holds messages on channel {id}, which no channel record defines"
                )));
            }
        }
        w.count_copied_messages(chunk, &contents.counts);
        self.messages += contents.counts.values().sum::<u64>();
        Ok(())
    }

    fn checked(&mut self, log: &mut OutputLog, c: Checked) -> Result<()> {
        self.received += 1;
        let (contents, crc) = c
            .result
            .map_err(|e| self.err(format!("chunk at offset {}: {e}", c.at.offset)))?;
        log.w().copied_crc(c.at.crc_id, crc);
        self.account(log, c.at.offset, c.at.chunk, contents)?;
        self.recycle(c.body);
        Ok(())
    }

    fn recycle(&mut self, buf: Vec<u8>) {
        if self.pool.len() < BUFFER_POOL {
            self.pool.push(buf);
        }
    }

    /// Accounts for the chunks validated so far, without waiting.
    fn poll(&mut self, log: &mut OutputLog) -> Result<()> {
        while let Ok(c) = self.done.try_recv() {
            self.checked(log, c)?;
        }
        Ok(())
    }

    /// Once a copied chunk's message indexes are known: a chunk whose message indexes list a
    /// wanted channel (or that has none) is decoded here, its wanted messages handed to
    /// `on_message`; any other is checked by the validating thread, or here when that thread is
    /// behind.
    fn group(
        &mut self,
        log: &mut OutputLog,
        g: Group,
        on_message: &mut OnMessage<'_>,
    ) -> Result<()> {
        let indexed = !g.index.is_empty();
        let here = !indexed || g.index.iter().any(|i| self.wanted.contains(&i.channel_id));
        let Group { at, body, index } = g;
        let index = indexed.then_some(index);
        let body = if here {
            body
        } else {
            let jobs = self
                .jobs
                .as_ref()
                .expect("open until the end of the data section");
            match jobs.try_send(Job { at, body, index }) {
                Ok(()) => {
                    self.sent += 1;
                    return Ok(());
                }
                Err(TrySendError::Full(job)) => {
                    let Job { body, index, .. } = job;
                    return self.check_here(log, at, body, index);
                }
                Err(TrySendError::Disconnected(_)) => {
                    return Err(self.err("chunk validation stopped unexpectedly".into()));
                }
            }
        };
        let offset = at.offset;
        let in_chunk = |e: String| Error::Format {
            path: self.input.to_path_buf(),
            detail: format!("chunk at offset {offset}: {e}"),
        };
        let crc = crc32fast::hash(&body[at.head..]);
        log.w().copied_crc(at.crc_id, crc);
        let (_, records) = self.decoder.decode(&body).map_err(in_chunk)?;
        let mut contents = ChunkContents::default();
        for r in mcap_chunk::records(records) {
            let (at_offset, opcode, record) = r.map_err(in_chunk)?;
            if let Some(id) = contents.add(at_offset, opcode, record).map_err(in_chunk)?
                && self.wanted.contains(&id)
            {
                let (header, data) = mcap_chunk::message(record).map_err(in_chunk)?;
                on_message(log, &header, data)?;
            }
        }
        if let Some(index) = &index {
            contents.check_index(index).map_err(in_chunk)?;
        }
        self.account(log, offset, at.chunk, contents)?;
        self.recycle(body);
        Ok(())
    }

    /// Checks a copied chunk that is not read for messages, on this thread.
    fn check_here(
        &mut self,
        log: &mut OutputLog,
        at: ChunkAt,
        body: Vec<u8>,
        index: Option<Vec<MessageIndex>>,
    ) -> Result<()> {
        let (contents, crc) = check_chunk(&mut self.decoder, &body, at.head, index.as_deref())
            .map_err(|e| self.err(format!("chunk at offset {}: {e}", at.offset)))?;
        log.w().copied_crc(at.crc_id, crc);
        self.account(log, at.offset, at.chunk, contents)?;
        self.recycle(body);
        Ok(())
    }

    /// A record outside chunks.
    fn top_level(
        &mut self,
        log: &mut OutputLog,
        opcode: u8,
        offset: u64,
        body: &[u8],
        on_message: &mut OnMessage<'_>,
    ) -> Result<()> {
        let record = parse_record(opcode, body)
            .map_err(|e| self.err(format!("record at offset {offset}: {e}")))?;
        let w = log.w();
        match record {
            Record::Schema { header, data } => {
                let s = SchemaRecord {
                    name: header.name,
                    encoding: header.encoding,
                    data: data.into_owned(),
                };
                w.check_schema(header.id, &s)
                    .map_err(|p| self.err(format!("{p} (offset {offset})")))?;
                w.define_schema(header.id, s, true)?;
            }
            Record::Channel(c) => {
                w.check_channel(&c)
                    .map_err(|p| self.err(format!("{p} (offset {offset})")))?;
                w.define_channel(c, true)?;
            }
            Record::Message { header, data } => {
                if w.channel(header.channel_id).is_none() {
                    return Err(self.err(format!(
                        "message at offset {offset} on channel {}, which no channel record defines",
                        header.channel_id
                    )));
                }
                w.message(&header, &data)?;
                self.messages += 1;
                if self.wanted.contains(&header.channel_id) {
                    on_message(log, &header, &data)?;
                }
            }
            Record::Attachment { header, data, .. } => {
                w.copy_attachment(body, &header, data.len() as u64)?
            }
            Record::Metadata(m) => w.copy_metadata(body, &m.name)?,
            Record::Unknown { .. } => w.copy_record(opcode, body)?,
            // The writer makes its own header, indexes and summary.
            _ => {}
        }
        Ok(())
    }

    /// The data section, up to and including the data-end record.
    fn run(
        &mut self,
        src: &mut Source<'_>,
        log: &mut OutputLog,
        on_message: &mut OnMessage<'_>,
    ) -> Result<()> {
        let mut small = Vec::new();
        let mut open: Option<Group> = None;
        loop {
            let (opcode, len) = src.prefix()?;
            let offset = src.pos - 9;
            if opcode == op::MESSAGE_INDEX
                && let Some(g) = open.as_mut()
            {
                src.body(opcode, len, &mut small)?;
                match parse_record(opcode, &small) {
                    Ok(Record::MessageIndex(i)) => g.index.push(i),
                    _ => {
                        return Err(
                            self.err(format!("bad message index record at offset {offset}"))
                        );
                    }
                };
                log.w().copied_message_index(&small)?;
                continue;
            }
            if let Some(g) = open.take() {
                self.group(log, g, on_message)?;
            }
            match opcode {
                op::CHUNK => {
                    src.check_len(opcode, len)?;
                    let (head, header) = src.chunk_head(len)?;
                    let chunk = log.w().start_copied_chunk(len, &head, &header)?;
                    // The whole body in one buffer (header, then the rest read from the input).
                    let mut body = self.pool.pop().unwrap_or_default();
                    body.clear();
                    body.extend_from_slice(&head);
                    src.append(opcode, len - head.len() as u64, &mut body)?;
                    let crc_id = log.w().write_copied(&body[head.len()..])?;
                    log.write_behind()?;
                    open = Some(Group {
                        at: ChunkAt {
                            chunk,
                            offset,
                            head: head.len(),
                            crc_id,
                        },
                        body,
                        index: Vec::new(),
                    });
                }
                op::DATA_END => {
                    src.body(opcode, len, &mut small)?;
                    return Ok(());
                }
                op::FOOTER => {
                    return Err(self
                        .err("reading MCAP records: no data-end record (truncated MCAP?)".into()));
                }
                _ => {
                    src.body(opcode, len, &mut small)?;
                    self.top_level(log, opcode, offset, &small, on_message)?;
                }
            }
            self.poll(log)?;
        }
    }
}

/// Copies the data section of `input` into `log`: chunk records and the message-index records
/// after them byte for byte, other records (messages outside chunks into our own chunks,
/// metadata, attachments, schemas and channels not yet defined) one by one. Declare the input's
/// schemas and channels first ([`OutputLog::declare_input`]).
///
/// Each chunk record is read into a buffer and written out as it is. Messages on `wanted`
/// channels are handed to `on_message` in file order: chunks whose message indexes list such a
/// channel (or that have no message index) are decompressed here for that; every other chunk's
/// buffer goes to a second thread (or is checked here, when that thread is behind), which
/// decompresses it only to check its CRC and count its messages for the output's statistics. A
/// corrupt or truncated input is an [`Error::Format`] naming `input` (and the chunk's offset).
/// Returns the number of input messages. Memory: a few chunks (the validation queue is short).
pub fn pass_through(
    input: &Path,
    log: &mut OutputLog,
    wanted: &BTreeSet<u16>,
    mut on_message: impl FnMut(&mut OutputLog, &MessageHeader, &[u8]) -> Result<()>,
) -> Result<u64> {
    let mut src = Source::open(input, 1 << 16)?;
    let size = src.size;
    // The output is about as large as the input.
    log.reserve(size)?;
    let decoder = ChunkDecoder::new().map_err(|e| mcap_err(input, "reading MCAP records", e))?;
    std::thread::scope(|scope| {
        let (jobs, job_rx) = sync_channel(VALIDATION_QUEUE);
        let (done_tx, done) = channel();
        scope.spawn(move || validate_chunks(job_rx, done_tx));
        let mut p = PassThrough {
            input,
            wanted,
            decoder,
            jobs: Some(jobs),
            done,
            sent: 0,
            received: 0,
            pool: Vec::new(),
            messages: 0,
        };
        let read = p.run(&mut src, log, &mut on_message);
        // Closing the queue ends the validating thread once it has checked what it holds.
        drop(p.jobs.take());
        read?;
        // Everything copied is in the page cache: let the disk writes start while the last
        // chunks are checked and the caller finishes its work.
        log.start_writeback()?;
        while let Ok(c) = p.done.recv() {
            p.checked(log, c)?;
        }
        if p.received != p.sent {
            return Err(p.err(format!(
                "only {} of {} chunks were validated",
                p.received, p.sent
            )));
        }
        Ok(p.messages)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};

    /// A log written into reserved space larger than what it ends up holding, with its disk
    /// writes started on the way: the file is cut to its records, which read back unchanged with
    /// the mcap crate's reader (chunk, data-section and summary CRCs checked).
    #[test]
    fn reserved_space_and_early_writeback_leave_an_exact_log() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.mcap");
        let mut log = OutputLog::create(&target, false, "x").unwrap();
        let reserved = 4 * WRITEBACK_STEP;
        log.reserve(reserved).unwrap();
        if cfg!(all(target_os = "linux", target_env = "gnu")) {
            // tmpfs and ext4 both preallocate; the cut at the end is then exercised.
            let file = log.w().get_ref().get_ref().metadata().unwrap();
            assert_eq!(file.len(), reserved);
        }
        let ch = log
            .add_channel("/blob", "", "", &[], "application/octet-stream")
            .unwrap();
        // Incompressible payloads (xorshift), so that the file passes several writeback steps.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut payloads = Vec::new();
        for k in 0..24u64 {
            let data: Vec<u8> = (0..1 << 20)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state as u8
                })
                .collect();
            log.write(ch, k, k, &data).unwrap();
            log.write_behind().unwrap();
            payloads.push(data);
        }
        let requested = log.writeback.as_ref().map_or(0, |w| w.requested);
        assert!(
            requested >= 2 * WRITEBACK_STEP,
            "handed on {requested} bytes"
        );
        log.start_writeback().unwrap();
        log.write_behind().unwrap(); // after the data sync was requested: nothing more to do
        log.finish().unwrap();

        let bytes = std::fs::read(&target).unwrap();
        assert!((bytes.len() as u64) < reserved);
        assert!(bytes.ends_with(mcap::MAGIC));
        let summary = mcap::Summary::read(&bytes).unwrap().expect("summary");
        assert_eq!(summary.stats.as_ref().unwrap().message_count, 24);
        let read: Vec<Vec<u8>> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap().data.into_owned())
            .collect();
        assert!(read == payloads, "payloads differ");
        let mut reader = LinearReader::new_with_options(
            mcap::sans_io::LinearReaderOptions::default()
                .with_validate_chunk_crcs(true)
                .with_validate_data_section_crc(true)
                .with_validate_summary_section_crc(true),
        );
        let mut rest = &bytes[..];
        while let Some(e) = reader.next_event() {
            if let LinearReadEvent::ReadRequest(need) = e.unwrap() {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
        }
    }
}
