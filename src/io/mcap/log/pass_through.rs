//! The pass-through of `mireg register`: the input's chunk records copied into the output byte for
//! byte, each decompressed once (here or on a second thread) to check its CRC, and the messages
//! of the wanted channels handed on in file order.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::mpsc::{Receiver, Sender, SyncSender, TrySendError, channel, sync_channel};

use mcap::records::{MessageHeader, MessageIndex, Record, op};

use super::OutputLog;
use crate::io::mcap::chunk::{self, ChunkContents, ChunkDecoder};
use crate::io::mcap::read::{Source, mcap_err};
use crate::io::mcap::record::parse_record;
use crate::io::mcap::write::SchemaRecord;
use crate::{Error, Result};

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
        for r in chunk::records(records) {
            let (at_offset, opcode, record) = r.map_err(in_chunk)?;
            if let Some(id) = contents.add(at_offset, opcode, record).map_err(in_chunk)?
                && self.wanted.contains(&id)
            {
                let (header, data) = chunk::message(record).map_err(in_chunk)?;
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
