//! Reading MCAP files whose lengths cannot be trusted: every length, count or size read from the
//! file is checked against what the file can hold (the rest of the record, the chunk, the file)
//! or a documented limit ([`crate::io::MAX_CHUNK_BYTES`]) before it drives an allocation.
//!
//! `Source` reads top-level records of the data section; [`for_each_record`] walks them and the
//! records inside chunks (the streaming read of `mireg evaluate`/`export`, and the catalogue of a
//! log without a summary); `read_summary` reads the summary section with the same bounds. The
//! pass-through of `mireg register` ([`super::log`]) reads with `Source` too, so every input path
//! shares one set of checks.

use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;

use binrw::BinRead;
use mcap::records::{ChunkHeader, Record, op};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};

use super::chunk::{self, ChunkDecoder};
use super::record::{check_lengths, parse_record};
use super::salvage::decompress_prefix;
use crate::io::damage::{Damage, ReadPolicy};
use crate::io::input_file::open_regular;
use crate::io::{MAX_CHUNK_BYTES, io_err};
use crate::{Error, Result};

pub(crate) fn mcap_err(path: &Path, what: &str, e: impl std::fmt::Display) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail: format!("{what}: {e}"),
    }
}

/// An MCAP input, read record by record from the front, with its position and size.
pub(crate) struct Source<'a> {
    reader: BufReader<File>,
    /// Bytes read so far (the offset of the next byte).
    pub pos: u64,
    /// File size in bytes.
    pub size: u64,
    /// The file, for errors.
    pub path: &'a Path,
}

impl<'a> Source<'a> {
    /// Opens `path` and reads its magic and header record; the next record is the first of the
    /// data section. `buffer` is the read buffer's size in bytes.
    pub fn open(path: &'a Path, buffer: usize) -> Result<Self> {
        let (file, meta) = open_regular(path)?;
        let mut src = Source {
            reader: BufReader::with_capacity(buffer, file),
            pos: 0,
            size: meta.len(),
            path,
        };
        if src.size < (mcap::MAGIC.len() + 9) as u64 {
            return Err(mcap_err(
                path,
                "reading MCAP records",
                format!(
                    "not an MCAP file: {} bytes, shorter than the magic and a header",
                    src.size
                ),
            ));
        }
        let mut magic = [0u8; 8];
        src.read_exact(&mut magic)?;
        if magic != mcap::MAGIC {
            return Err(mcap_err(
                path,
                "reading MCAP records",
                "not an MCAP file (bad magic)",
            ));
        }
        let (opcode, len) = src.prefix()?;
        if opcode != op::HEADER {
            return Err(mcap_err(
                path,
                "reading MCAP records",
                format!("the first record has opcode 0x{opcode:02x}, not a header"),
            ));
        }
        src.body(opcode, len, &mut Vec::new())?;
        Ok(src)
    }

    /// A format error "truncated MCAP?" naming the file.
    pub fn truncated(&self, what: String) -> Error {
        mcap_err(
            self.path,
            "reading MCAP records",
            format!("{what} (truncated MCAP?)"),
        )
    }

    /// Fills `buf`; the end of the file is a [`truncated`](Self::truncated) error.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<()> {
        match self.reader.read_exact(buf) {
            Ok(()) => {
                self.pos += buf.len() as u64;
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                Err(self.truncated("unexpected end of file".into()))
            }
            Err(e) => Err(io_err(self.path, e)),
        }
    }

    /// The next record's opcode and body length.
    pub fn prefix(&mut self) -> Result<(u8, u64)> {
        let mut p = [0u8; 9];
        self.read_exact(&mut p)?;
        Ok((
            p[0],
            u64::from_le_bytes(p[1..].try_into().expect("8 bytes")),
        ))
    }

    /// Fails unless a body of `len` bytes fits in the rest of the file.
    pub fn check_len(&self, opcode: u8, len: u64) -> Result<()> {
        let left = self.size.saturating_sub(self.pos);
        if len > left {
            return Err(self.truncated(format!(
                "record at offset {} (opcode 0x{opcode:02x}) claims {len} bytes, {left} remain",
                self.pos - 9
            )));
        }
        Ok(())
    }

    /// Reads a record body of `len` bytes into `buf` (replacing its content).
    pub fn body(&mut self, opcode: u8, len: u64, buf: &mut Vec<u8>) -> Result<()> {
        buf.clear();
        self.append(opcode, len, buf)
    }

    /// Reads the next `len` bytes of a record's body onto the end of `buf`; `len` is checked
    /// against the rest of the file before anything is allocated.
    pub fn append(&mut self, opcode: u8, len: u64, buf: &mut Vec<u8>) -> Result<()> {
        self.check_len(opcode, len)?;
        buf.try_reserve_exact(len as usize)
            .map_err(|_| self.truncated(format!("record of {len} bytes")))?;
        let n = (&mut self.reader)
            .take(len)
            .read_to_end(buf)
            .map_err(|e| io_err(self.path, e))?;
        self.pos += n as u64;
        if n as u64 != len {
            return Err(self.truncated("unexpected end of file".into()));
        }
        Ok(())
    }

    /// Reads the header at the start of a chunk record body of `len` bytes: its bytes, parsed.
    /// Its compressed size must fit in the record and its uncompressed size in
    /// [`MAX_CHUNK_BYTES`].
    pub fn chunk_head(&mut self, len: u64) -> Result<(Vec<u8>, ChunkHeader)> {
        const FIXED: u64 = 8 + 8 + 8 + 4; // start and end time, uncompressed size, CRC
        let offset = self.pos - 9;
        let bad = |what: &str| {
            mcap_err(
                self.path,
                "reading MCAP records",
                format!("chunk at offset {offset}: {what}"),
            )
        };
        if len < FIXED + 4 + 8 {
            return Err(bad("record shorter than a chunk header"));
        }
        let mut head = vec![0u8; (FIXED + 4) as usize];
        self.read_exact(&mut head)?;
        let name_len = u32::from_le_bytes(head[FIXED as usize..].try_into().expect("4 bytes"));
        let head_len = FIXED + 4 + u64::from(name_len) + 8;
        if head_len > len {
            return Err(bad("compression name longer than the record"));
        }
        head.resize(head_len as usize, 0);
        self.read_exact(&mut head[(FIXED + 4) as usize..])?;
        let header = ChunkHeader::read_le(&mut std::io::Cursor::new(&head))
            .map_err(|e| bad(&format!("bad chunk header: {e}")))?;
        if header.compressed_size > len - head_len {
            return Err(bad(&format!(
                "compressed size {} exceeds the record",
                header.compressed_size
            )));
        }
        if header.uncompressed_size > MAX_CHUNK_BYTES {
            return Err(bad(&format!(
                "claims {} uncompressed bytes, more than the limit of {MAX_CHUNK_BYTES}",
                header.uncompressed_size
            )));
        }
        if !header.compression.is_empty() {
            crate::io::check_expansion(header.compressed_size, header.uncompressed_size)
                .map_err(|e| bad(&e))?;
        }
        Ok((head, header))
    }
}

/// Calls `f` on every record of the data section of `path` in file order, and on the records
/// inside each chunk in their order, decompressing chunks one at a time (memory bounded by the
/// largest chunk and [`MAX_CHUNK_BYTES`]). Stops at the data-end record; the summary section is
/// not visited. A truncated or corrupt file (a record longer than what follows it, a chunk whose
/// CRC or size does not match, a chunk inside a chunk) is an [`Error::Format`] naming the file
/// and the record's offset.
pub fn for_each_record(path: &Path, mut f: impl FnMut(Record<'_>) -> Result<()>) -> Result<()> {
    for_each_record_until(path, |r| f(r).map(|()| std::ops::ControlFlow::Continue(())))
}

/// [`for_each_record`] that stops as soon as `f` says [`std::ops::ControlFlow::Break`], without reading further (e.g. for the first cloud of a log).
pub fn for_each_record_until(
    path: &Path,
    f: impl FnMut(Record<'_>) -> Result<std::ops::ControlFlow<()>>,
) -> Result<()> {
    for_each_record_with(path, ReadPolicy::STRICT, f).map(|_| ())
}

/// [`for_each_record_until`] under `policy` ([`super::salvage`]): unless it is strict, a log
/// that stops short is read up to its last whole record, the records of a chunk cut short
/// included, and the returned [`Damage`] says where it was cut; with `skip_corrupt`, a chunk that
/// fails its CRC or does not decompress is skipped and listed.
pub fn for_each_record_with(
    path: &Path,
    policy: ReadPolicy,
    mut f: impl FnMut(Record<'_>) -> Result<std::ops::ControlFlow<()>>,
) -> Result<Damage> {
    use std::ops::ControlFlow::Break;
    let mut src = Source::open(path, 1 << 20)?;
    let mut damage = Damage::new(src.size);
    let salvage = !policy.strict;
    let mut decoder = ChunkDecoder::new().map_err(|e| mcap_err(path, "reading MCAP records", e))?;
    let mut body = Vec::new();
    loop {
        let left = src.size - src.pos;
        if salvage && left < 9 {
            let reason = if left == 0 {
                "the file ends without a data-end record".to_string()
            } else {
                format!(
                    "the file ends {left} bytes into the opcode and length of a record at offset {}",
                    src.pos
                )
            };
            damage.cut(src.pos, reason);
            return Ok(damage);
        }
        let (opcode, len) = src.prefix()?;
        let offset = src.pos - 9;
        if salvage && len > src.size - src.pos {
            let left = src.size - src.pos;
            if opcode == op::CHUNK {
                damage.partial_messages = salvage_chunk(&mut src, &mut f)?;
            }
            let what = match opcode {
                op::CHUNK => "the chunk".to_string(),
                _ => format!("the record (opcode 0x{opcode:02x})"),
            };
            damage.cut(
                offset,
                format!(
                    "{what} at offset {offset} claims {len} bytes, the file holds {left} of them"
                ),
            );
            return Ok(damage);
        }
        match opcode {
            op::DATA_END => {
                src.body(opcode, len, &mut body)?;
                return Ok(damage);
            }
            op::FOOTER => {
                return Err(mcap_err(
                    path,
                    "reading MCAP records",
                    "no data-end record (truncated MCAP?)",
                ));
            }
            op::CHUNK => {
                src.check_len(opcode, len)?;
                let (head, _) = src.chunk_head(len)?;
                body.clear();
                body.extend_from_slice(&head);
                src.append(opcode, len - head.len() as u64, &mut body)?;
                let in_chunk = |e: String| mcap_err(path, &format!("chunk at offset {offset}"), e);
                let records = match decoder.decode(&body) {
                    Ok((_, records)) => records,
                    Err(e) if policy.skip_corrupt => {
                        damage.skipped_chunks.push((offset, e));
                        continue;
                    }
                    Err(e) => {
                        return Err(in_chunk(format!(
                            "{e} (--skip-corrupt skips corrupt chunks)"
                        )));
                    }
                };
                for r in chunk::records(records) {
                    let (_, opcode, b) = r.map_err(in_chunk)?;
                    chunk::check_chunk_opcode(opcode).map_err(in_chunk)?;
                    let record = parse_record(opcode, b).map_err(in_chunk)?;
                    if let Break(()) = f(record)? {
                        return Ok(damage);
                    }
                }
            }
            _ => {
                src.body(opcode, len, &mut body)?;
                let record = parse_record(opcode, &body)
                    .map_err(|e| mcap_err(path, &format!("record at offset {offset}"), e))?;
                if let Break(()) = f(record)? {
                    return Ok(damage);
                }
            }
        }
    }
}

/// The whole records at the start of a chunk that the file cuts short (its opcode and length
/// read, the rest of the file its body's first bytes), handed to `f`; returns how many were
/// messages. Nothing when even the chunk's header is cut.
fn salvage_chunk(
    src: &mut Source<'_>,
    f: &mut impl FnMut(Record<'_>) -> Result<std::ops::ControlFlow<()>>,
) -> Result<u64> {
    let left = src.size - src.pos;
    let mut rest = Vec::new();
    src.append(op::CHUNK, left, &mut rest)?;
    let Some((header, data)) = partial_chunk_header(&rest) else {
        return Ok(0);
    };
    let records = decompress_prefix(&header, data);
    let mut messages = 0;
    for r in chunk::records(&records) {
        let Ok((_, opcode, b)) = r else { break };
        if chunk::check_chunk_opcode(opcode).is_err() {
            break;
        }
        let Ok(record) = parse_record(opcode, b) else {
            break;
        };
        messages += u64::from(matches!(record, Record::Message { .. }));
        if f(record)?.is_break() {
            break;
        }
    }
    Ok(messages)
}

/// The header of a chunk record whose body is cut short to `body`, and the compressed bytes
/// after it that are there.
fn partial_chunk_header(body: &[u8]) -> Option<(ChunkHeader, &[u8])> {
    const FIXED: usize = 8 + 8 + 8 + 4; // start and end time, uncompressed size, CRC
    let name_len = u32::from_le_bytes(body.get(FIXED..FIXED + 4)?.try_into().ok()?) as usize;
    let head_len = FIXED + 4 + name_len + 8;
    let head = body.get(..head_len)?;
    let header = ChunkHeader::read_le(&mut std::io::Cursor::new(head)).ok()?;
    Some((header, &body[head_len..]))
}

/// The summary section of `path`; `None` when the file has none or it cannot be read (a log cut
/// short has no footer: the caller then scans the records, which reports what is wrong). No
/// record of the summary may claim more bytes than the file holds, nor hold a string longer than
/// itself ([`check_lengths`]: the summary reader would allocate what it claims).
pub(crate) fn read_summary(path: &Path) -> Result<Option<mcap::Summary>> {
    let (mut file, meta) = open_regular(path)?;
    let size = meta.len();
    if !summary_lengths_hold(&mut file, size).map_err(|e| io_err(path, e))? {
        return Ok(None);
    }
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(size)
            .with_record_length_limit(usize::try_from(size).unwrap_or(usize::MAX)),
    );
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

/// Whether every record between the summary start (from the footer) and the footer fits in the
/// section and passes [`check_lengths`]; `true` when there is no footer or no summary (the
/// summary reader then finds nothing to allocate for).
fn summary_lengths_hold(file: &mut File, size: u64) -> std::io::Result<bool> {
    use std::io::SeekFrom;
    const FOOTER: u64 = 9 + 8 + 8 + 4; // opcode, length, summary start, offset start, CRC
    let Some(footer_at) = size.checked_sub(FOOTER + mcap::MAGIC.len() as u64) else {
        return Ok(true);
    };
    let mut footer = [0u8; FOOTER as usize];
    file.seek(SeekFrom::Start(footer_at))?;
    file.read_exact(&mut footer)?;
    let start = u64::from_le_bytes(footer[9..17].try_into().expect("8 bytes"));
    if footer[0] != op::FOOTER || start == 0 || start > footer_at {
        return Ok(true);
    }
    let mut section = vec![0u8; (footer_at - start) as usize];
    file.seek(SeekFrom::Start(start))?;
    file.read_exact(&mut section)?;
    let mut rest = &section[..];
    while !rest.is_empty() {
        if rest.len() < 9 {
            return Ok(false);
        }
        let len = u64::from_le_bytes(rest[1..9].try_into().expect("8 bytes"));
        let Some(body) = usize::try_from(len).ok().and_then(|l| rest[9..].get(..l)) else {
            return Ok(false);
        };
        if check_lengths(rest[0], body).is_err() {
            return Ok(false);
        }
        rest = &rest[9 + body.len()..];
    }
    Ok(true)
}
