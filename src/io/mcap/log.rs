//! MCAP input and output for `mireg register`: a streaming record reader whose memory is bounded
//! by one chunk, a catalogue of the input's schemas and channels, an output log that copies input
//! records and adds ours, and the pass-through that copies the input's chunks byte for byte.
//!
//! Guarantees (../shared/docs/DESIGN.md §4): input schema and channel ids are kept (copied
//! chunks refer to them) and ours get ids above every input id; the output goes to a temporary
//! file beside the target that is synced and renamed on success and deleted otherwise, so an
//! error never leaves a half-written log. Copied chunks are written as they were read, never
//! re-encoded, but each one is still decompressed once, off the copying thread, to check its CRC:
//! a corrupt input is an error naming the file.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Sender, channel};

use mcap::records::{Channel, MessageHeader, Metadata, Record};

pub use super::read::for_each_record;
use super::read::{for_each_record_with, mcap_err, read_summary};
use super::write::{McapWriter, SchemaRecord};
use crate::io::atomic_file::PendingFile;
use crate::io::codec::cdr;
use crate::io::damage::{Damage, ReadPolicy};
use crate::io::io_err;
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
    /// The catalogue of `path`; a log cut short or corrupt is an error.
    pub fn read(path: &Path) -> Result<Self> {
        Self::read_with(path, ReadPolicy::STRICT).map(|(cat, _)| cat)
    }

    /// The catalogue of `path` under `policy`, and what was wrong with the file (nothing when it
    /// has a summary and `policy` does not ask for corrupt chunks to be skipped: the summary is
    /// written last, so a file that has one was not cut; a corrupt chunk is then found when it is
    /// read).
    pub fn read_with(path: &Path, policy: ReadPolicy) -> Result<(Self, Damage)> {
        let mut cat = Self::default();
        // With `skip_corrupt` every chunk is scanned to find the corrupt ones: no summary read.
        let summary = if policy.skip_corrupt {
            None
        } else {
            read_summary(path)?.filter(|s| !s.channels.is_empty())
        };
        if let Some(summary) = summary {
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
            let size = std::fs::metadata(path).map_err(|e| io_err(path, e))?.len();
            return Ok((cat, Damage::new(size)));
        }
        // No summary (e.g. a log cut short while recording): one pass over the records.
        let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
        let damage = for_each_record_with(path, policy, |record| {
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
            Ok(std::ops::ControlFlow::Continue(()))
        })?;
        for &id in cat.channels.keys() {
            counts.entry(id).or_default();
        }
        cat.message_counts = Some(counts);
        Ok((cat, damage))
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

    /// A channel of JSON messages (`json`) whose schema `schema_name` is the JSON schema
    /// `schema` (`jsonschema`), as Foxglove reads them.
    pub fn add_json_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &serde_json::Value,
    ) -> Result<u16> {
        let text = serde_json::to_string(schema).expect("schema JSON");
        self.add_channel(topic, schema_name, "jsonschema", text.as_bytes(), "json")
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

    /// [`add_channel`](Self::add_channel) for a ROS 2 message type in CDR, e.g.
    /// `log.add_cdr_channel("/points", cdr::POINT_CLOUD2)`.
    pub fn add_cdr_channel(&mut self, topic: &str, message: cdr::MessageType) -> Result<u16> {
        self.add_channel(
            topic,
            message.name,
            cdr::SCHEMA_ENCODING,
            message.schema.as_bytes(),
            cdr::MESSAGE_ENCODING,
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

mod pass_through;
pub use pass_through::pass_through;

#[cfg(test)]
mod tests;
