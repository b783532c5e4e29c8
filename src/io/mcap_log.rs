//! MCAP input and output for `mireg register`: a streaming record reader whose memory is bounded
//! by one chunk, a channel listing from the summary section, and an output writer that copies every
//! input record, adds ours, and only appears at the target path once complete.
//!
//! Pitfalls handled (DESIGN §4): input schema/channel ids are remapped to fresh ids (mixing
//! `Writer::write` with `add_schema` panics on collisions), and since the writer's `Drop` finishes
//! the file, output goes to a temporary file beside the target that is renamed on success and
//! deleted otherwise.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, Write};
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader};

use crate::{Error, Result};

fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn mcap_err(path: &Path, what: &str, e: impl std::fmt::Display) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail: format!("{what}: {e}"),
    }
}

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

/// Channels of `path`, from its summary section when present, else by scanning the records.
pub fn list_channels(path: &Path) -> Result<Vec<ChannelInfo>> {
    if let Some(summary) = read_summary(path)?.filter(|s| !s.channels.is_empty()) {
        let counts = summary.stats.as_ref().map(|s| &s.channel_message_counts);
        let mut out: Vec<ChannelInfo> = summary
            .channels
            .values()
            .map(|c| ChannelInfo {
                id: c.id,
                topic: c.topic.clone(),
                schema_name: c
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                schema_encoding: c
                    .schema
                    .as_ref()
                    .map(|s| s.encoding.clone())
                    .unwrap_or_default(),
                message_encoding: c.message_encoding.clone(),
                message_count: counts.and_then(|m| m.get(&c.id).copied()),
            })
            .collect();
        out.sort_by_key(|c| c.id);
        return Ok(out);
    }
    // No summary (e.g. a log cut short while recording): one pass over the records.
    let mut schemas: HashMap<u16, (String, String)> = HashMap::new();
    let mut out = Vec::new();
    let mut counts: HashMap<u16, u64> = HashMap::new();
    for_each_record(path, |record| {
        match record {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let (name, enc) = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                out.push(ChannelInfo {
                    id: c.id,
                    topic: c.topic,
                    schema_name: name,
                    schema_encoding: enc,
                    message_encoding: c.message_encoding,
                    message_count: None,
                });
            }
            Record::Message { header, .. } => *counts.entry(header.channel_id).or_default() += 1,
            _ => {}
        }
        Ok(())
    })?;
    for c in &mut out {
        c.message_count = Some(counts.get(&c.id).copied().unwrap_or(0));
    }
    Ok(out)
}

/// The summary section of `path`; `None` when the file has none or it cannot be read (a log
/// cut short has no footer: the caller then scans the records, which reports what is wrong).
fn read_summary(path: &Path) -> Result<Option<mcap::Summary>> {
    let mut file = File::open(path).map_err(|e| io_err(path, e))?;
    let mut reader = SummaryReader::new();
    while let Some(event) = reader.next_event() {
        let Ok(event) = event else { return Ok(None) };
        match event {
            SummaryReadEvent::ReadRequest(need) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(|e| io_err(path, e))?;
                reader.notify_read(n);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to).map_err(|e| io_err(path, e))?;
                reader.notify_seeked(pos);
            }
        }
    }
    Ok(reader.finish())
}

/// Calls `f` on every record of the data section of `path` in file order, decompressing chunks
/// one at a time (memory bounded by the largest chunk). Stops at the data-end record; the summary
/// section is not visited. A truncated or corrupt file is an [`Error::Format`] naming the file.
pub fn for_each_record(path: &Path, mut f: impl FnMut(Record<'_>) -> Result<()>) -> Result<()> {
    let file = File::open(path).map_err(|e| io_err(path, e))?;
    let mut source = BufReader::with_capacity(1 << 20, file);
    let mut reader = LinearReader::new_with_options(
        mcap::sans_io::linear_reader::LinearReaderOptions::default().with_validate_chunk_crcs(true),
    );
    let mut data_ended = false;
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| mcap_err(path, "reading MCAP records", e))? {
            LinearReadEvent::ReadRequest(need) => {
                let n = source
                    .read(reader.insert(need))
                    .map_err(|e| io_err(path, e))?;
                if n == 0 {
                    return Err(mcap_err(
                        path,
                        "reading MCAP records",
                        "unexpected end of file (truncated MCAP?)",
                    ));
                }
                reader.notify_read(n);
            }
            LinearReadEvent::Record { data, opcode } => {
                if data_ended {
                    continue;
                }
                let record = mcap::parse_record(opcode, data).map_err(|e| {
                    mcap_err(
                        path,
                        &format!("parsing MCAP record (opcode 0x{opcode:02x})"),
                        e,
                    )
                })?;
                if matches!(record, Record::DataEnd(_)) {
                    data_ended = true;
                    continue;
                }
                f(record)?;
            }
        }
    }
    if !data_ended {
        return Err(mcap_err(
            path,
            "reading MCAP records",
            "no data-end record (truncated MCAP?)",
        ));
    }
    Ok(())
}

/// zstd level of the output chunks: 1 (fastest) keeps pass-through of large non-cloud channels
/// (images, raw sensor data) near copy speed; logs are rarely archived by mireg itself.
pub const OUTPUT_ZSTD_LEVEL: u32 = 1;

/// An MCAP being written to a temporary file beside `target`; [`OutputLog::finish`] renames it.
pub struct OutputLog {
    writer: Option<mcap::Writer<BufWriter<File>>>,
    temp: Option<tempfile::TempPath>,
    target: PathBuf,
    overwrite: bool,
    schema_ids: HashMap<u16, u16>,
    channel_ids: HashMap<u16, u16>,
    sequences: HashMap<u16, u32>,
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
        if target.exists() && !overwrite {
            return Err(Error::InvalidInput(format!(
                "{} exists (use --force to replace it)",
                target.display()
            )));
        }
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let temp = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(".partial")
            .tempfile_in(&dir)
            .map_err(|e| io_err(&dir, e))?;
        let (file, temp) = temp.into_parts();
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(OUTPUT_ZSTD_LEVEL)
            .profile(profile)
            .library(format!("mireg {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| mcap_err(target, "starting MCAP output", e))?;
        Ok(Self {
            writer: Some(writer),
            temp: Some(temp),
            target: target.to_path_buf(),
            overwrite,
            schema_ids: HashMap::new(),
            channel_ids: HashMap::new(),
            sequences: HashMap::new(),
        })
    }

    fn w(&mut self) -> &mut mcap::Writer<BufWriter<File>> {
        self.writer.as_mut().expect("writer present until finish")
    }

    fn wrap<T>(&self, what: &str, r: mcap::McapResult<T>) -> Result<T> {
        r.map_err(|e| mcap_err(&self.target, what, e))
    }

    /// Copies an input record into the output (schemas and channels get fresh ids; messages keep
    /// their bytes, sequence, log and publish times). Other record kinds are ignored (the writer
    /// makes its own chunks, indexes and summary).
    pub fn copy(&mut self, record: &Record<'_>) -> Result<()> {
        match record {
            Record::Schema { header, data } => {
                let r = self.w().add_schema(&header.name, &header.encoding, data);
                let id = self.wrap("copying a schema", r)?;
                self.schema_ids.insert(header.id, id);
            }
            Record::Channel(c) => {
                let schema = if c.schema_id == 0 {
                    0
                } else {
                    *self
                        .schema_ids
                        .get(&c.schema_id)
                        .ok_or_else(|| Error::Format {
                            path: self.target.clone(),
                            detail: format!(
                                "input channel {} ({}) names unknown schema {}",
                                c.id, c.topic, c.schema_id
                            ),
                        })?
                };
                let r = self
                    .w()
                    .add_channel(schema, &c.topic, &c.message_encoding, &c.metadata);
                let id = self.wrap("copying a channel", r)?;
                self.channel_ids.insert(c.id, id);
            }
            Record::Message { header, data } => {
                let channel_id =
                    *self
                        .channel_ids
                        .get(&header.channel_id)
                        .ok_or_else(|| Error::Format {
                            path: self.target.clone(),
                            detail: format!(
                                "input message on unknown channel {}",
                                header.channel_id
                            ),
                        })?;
                let h = MessageHeader {
                    channel_id,
                    ..*header
                };
                let r = self.w().write_to_known_channel(&h, data);
                self.wrap("copying a message", r)?;
            }
            Record::Metadata(m) => {
                let r = self.w().write_metadata(m);
                self.wrap("copying metadata", r)?;
            }
            Record::Attachment { header, data, .. } => {
                let a = mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name.clone(),
                    media_type: header.media_type.clone(),
                    data: std::borrow::Cow::Borrowed(data),
                };
                let r = self.w().attach(&a);
                self.wrap("copying an attachment", r)?;
            }
            _ => {}
        }
        Ok(())
    }

    /// Adds a new channel with its schema; returns the output channel id.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: &[u8],
        message_encoding: &str,
    ) -> Result<u16> {
        let r = self.w().add_schema(schema_name, schema_encoding, schema);
        let schema_id = self.wrap("adding a schema", r)?;
        let r = self
            .w()
            .add_channel(schema_id, topic, message_encoding, &BTreeMap::new());
        self.wrap("adding a channel", r)
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
        let r = self.w().write_to_known_channel(&header, data);
        self.wrap("writing a message", r)
    }

    /// Writes a metadata record.
    pub fn write_metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<()> {
        let r = self.w().write_metadata(&Metadata {
            name: name.into(),
            metadata: entries,
        });
        self.wrap("writing metadata", r)
    }

    /// Finishes the file, syncs it and renames it to the target. On any error nothing is left
    /// at the target path and the temporary file is removed.
    pub fn finish(mut self) -> Result<()> {
        let mut writer = self.writer.take().expect("writer present until finish");
        let r = writer.finish();
        self.wrap("finishing MCAP output", r)?;
        let buf = writer.into_inner();
        let file = buf
            .into_inner()
            .map_err(|e| io_err(&self.target, e.into_error()))?;
        // Temporary files are created private (0600); a finished log is an ordinary file.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            file.set_permissions(std::fs::Permissions::from_mode(0o644))
                .map_err(|e| io_err(&self.target, e))?;
        }
        file.sync_all().map_err(|e| io_err(&self.target, e))?;
        drop(file);
        let temp = self.temp.take().expect("temp path present until finish");
        if self.overwrite {
            temp.persist(&self.target)
                .map_err(|e| io_err(&self.target, e.error))?;
        } else {
            temp.persist_noclobber(&self.target)
                .map_err(|e| io_err(&self.target, e.error))?;
        }
        Ok(())
    }
}

impl Drop for OutputLog {
    fn drop(&mut self) {
        // On an error path: let the writer finish into the temporary file, which the TempPath
        // then deletes. Nothing reaches the target.
        if let Some(mut w) = self.writer.take() {
            let _ = w.finish();
            let _ = w.into_inner().flush();
        }
    }
}
