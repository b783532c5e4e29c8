//! ROS 1 bag files, format 2.0 (wiki.ros.org/Bags/Format/2.0): uncompressed, bz2 and lz4
//! chunks, read in one forward pass with memory bounded by one chunk.
//!
//! A bag is `#ROSBAG V2.0\n` and a sequence of records, each `header_len: u32`, a header of
//! `field_len: u32` + `name=value` fields, `data_len: u32`, data. The header's `op` field says
//! what the record is: the bag header (0x03, with the offset of the index), chunks (0x05: a
//! compressed run of connection (0x07) and message (0x02) records, each followed by index data
//! (0x04)), then at the index offset every connection again and one chunk info (0x06) per chunk.
//!
//! The catalogue (connections and message counts) comes from the index; a bag whose index was
//! never written (`index_pos` 0: the recorder was killed) is scanned once instead.
//!
//! A bag cut short (a power loss or crash while recording: the index missing or cut, a last
//! record or chunk that stops short) is read, unless [`ReadPolicy::strict`], up to its last whole
//! record, and the messages of a chunk cut short are recovered from the compressed bytes that
//! reached the disk (bz2 and lz4 decode block by block) up to its last whole record; [`Damage`]
//! says where it was cut. With [`ReadPolicy::skip_corrupt`] a chunk that does not decompress is
//! skipped and named instead of failing the read. Every length
//! read from the file is checked against what remains of the file or the chunk, and a chunk's
//! declared uncompressed size against [`MAX_CHUNK_BYTES`], before it drives an allocation.
//!
//! Each connection becomes an MCAP channel of the ROS 1 profile: id = the connection id, message
//! encoding `ros1`, a `ros1msg` schema holding the connection's `message_definition`, and channel
//! metadata `md5sum`, `topic`, and `callerid` / `latching` where the connection has them.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mcap::records::Channel;

mod record;
pub(crate) use record::read_up_to;
use record::{
    Cut, Inner, Next, RawRecord, bag_err, message_fields, parse_fields, read_bounded, read_u32,
    split_len_prefixed, u32_field, u64_field,
};

use crate::io::codec::ros1;
use crate::io::damage::{Damage, ReadPolicy, read_prefix};
use crate::io::mcap::log::InputCatalog;
use crate::io::mcap::write::SchemaRecord;
use crate::io::{MAX_CHUNK_BYTES, io_err};
use crate::{Error, Result};

/// The first bytes of every bag of format 2.0.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

/// Largest record header accepted, in bytes: 16 MiB. Headers hold a few fields; the largest are
/// connection records' message definitions (tens of kilobytes).
const MAX_HEADER_BYTES: u32 = 1 << 24;

mod op {
    pub const MSG_DATA: u8 = 0x02;
    pub const BAG_HEADER: u8 = 0x03;
    pub const INDEX_DATA: u8 = 0x04;
    pub const CHUNK: u8 = 0x05;
    pub const CHUNK_INFO: u8 = 0x06;
    pub const CONNECTION: u8 = 0x07;
}

/// One connection of a bag: a topic with its type and publisher.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Connection {
    /// Connection id (`conn`).
    pub id: u32,
    /// Topic the messages were recorded on.
    pub topic: String,
    /// Message type, e.g. `sensor_msgs/PointCloud2`.
    pub msg_type: String,
    /// MD5 sum of the type.
    pub md5sum: String,
    /// Full message definition (`gendeps --cat` text).
    pub definition: String,
    /// Publisher node, when recorded.
    pub callerid: Option<String>,
    /// `"1"` for a latched topic, when recorded.
    pub latching: Option<String>,
}

/// A ROS 1 bag opened for reading: its connections and message counts.
#[derive(Debug, Clone)]
pub struct Bag {
    path: PathBuf,
    size: u64,
    /// Offset of the first record after the bag header.
    data_start: u64,
    /// Offset of the index (0 when the bag has none); records from here on are not data.
    index_pos: u64,
    /// Where the data records end: the index, or the end of the file when the index is missing,
    /// or the start of the record the file cuts short.
    data_end: u64,
    /// How damage is treated.
    policy: ReadPolicy,
    /// What was found wrong when the bag was opened.
    damage: Damage,
    /// Connections by id.
    pub connections: BTreeMap<u32, Connection>,
    /// Messages per connection (from the chunk infos, or the scan).
    pub message_counts: BTreeMap<u32, u64>,
}

impl Bag {
    fn err(&self, offset: u64, detail: impl std::fmt::Display) -> Error {
        bag_err(&self.path, offset, detail)
    }

    /// Opens `path`, checks the format and reads the catalogue (from the index, or by one scan
    /// when the bag has none); a bag cut short is read up to its last whole message
    /// ([`Bag::open_with`] with the default [`ReadPolicy`]).
    ///
    /// # Errors
    /// [`Error::Format`] naming the file and the offset for anything that is not a well-formed
    /// bag 2.0 (another version, a connection id above 65 535, a corrupt chunk).
    pub fn open(path: &Path) -> Result<Self> {
        Self::open_with(path, ReadPolicy::default())
    }

    /// [`Bag::open`] with damage treated by `policy`: with [`ReadPolicy::strict`], a truncated
    /// file or an index beyond the end is an error too.
    pub fn open_with(path: &Path, policy: ReadPolicy) -> Result<Self> {
        let (file, meta) = crate::io::input_file::open_regular(path)?;
        let size = meta.len();
        let mut r = BufReader::with_capacity(1 << 16, file);
        let mut magic = [0u8; 13];
        let got = read_up_to(&mut r, &mut magic).map_err(|e| io_err(path, e))?;
        if &magic[..got] != MAGIC {
            let detail = if magic.starts_with(b"#ROSBAG V") {
                format!(
                    "bag format {:?} is not supported (only 2.0, what ROS 1 has written since 2010); `rosbag fix` upgrades it",
                    String::from_utf8_lossy(&magic[9..got]).trim()
                )
            } else {
                "not a ROS 1 bag: it does not start with \"#ROSBAG V2.0\"".to_string()
            };
            return Err(bag_err(path, 0, detail));
        }
        let mut bag = Bag {
            path: path.to_path_buf(),
            size,
            data_start: 0,
            index_pos: 0,
            data_end: size,
            policy,
            damage: Damage::new(size),
            connections: BTreeMap::new(),
            message_counts: BTreeMap::new(),
        };
        let mut pos = MAGIC.len() as u64;
        let header = bag
            .read_record(&mut r, &mut pos, Vec::new())?
            .ok_or_else(|| bag.err(pos, "no bag header record (empty bag)"))?;
        if header.op() != Some(op::BAG_HEADER) {
            return Err(bag.err(header.offset, "the first record is not the bag header"));
        }
        bag.index_pos = u64_field(&header, "index_pos").map_err(|e| bag.err(header.offset, e))?;
        bag.data_start = pos;
        if bag.index_pos != 0 && (bag.index_pos < pos || bag.index_pos >= size) {
            if policy.strict {
                return Err(bag.err(
                    header.offset,
                    format!(
                        "the index is at offset {}, beyond the file's {size} bytes: the bag is truncated (rosbag reindex rebuilds its index; without --strict mireg reads what is there)",
                        bag.index_pos
                    ),
                ));
            }
            // Cut after the data or inside it: the data records run to the end of the file.
            bag.index_pos = 0;
        }
        if bag.index_pos == 0 || policy.skip_corrupt {
            // No index, or every chunk is to be decompressed once to find the corrupt ones.
            bag.data_end = if bag.index_pos == 0 {
                size
            } else {
                bag.index_pos
            };
            bag.scan_catalog(&mut r, pos)?;
        } else {
            bag.data_end = bag.index_pos;
            if let Some(cut) = bag.read_index(&mut r)? {
                // The index stops short, so its counts do not cover every chunk; the data
                // before it is whole.
                bag.connections.clear();
                bag.message_counts.clear();
                bag.scan_catalog(&mut r, pos)?;
                bag.damage.cut(
                    cut.offset,
                    format!("the index is cut short: {}", cut.reason),
                );
            }
        }
        Ok(bag)
    }

    /// What was wrong with the bag and read anyway (nothing when it is whole).
    pub fn damage(&self) -> &Damage {
        &self.damage
    }

    /// The record at `*pos`, or the end of the file, or how the file cuts it short (with the
    /// part of it that is there when its header is whole). Lengths that no cut explains (a
    /// header beyond [`MAX_HEADER_BYTES`], fields that do not parse) are errors.
    fn next_record(&self, r: &mut BufReader<File>, pos: &mut u64, buf: Vec<u8>) -> Result<Next> {
        let offset = *pos;
        if offset == self.size {
            return Ok(Next::End);
        }
        let remain = self.size - offset;
        let cut = |reason: String, partial: Option<RawRecord>| {
            Ok(Next::Cut(Cut {
                offset,
                reason,
                partial,
            }))
        };
        if remain < 4 {
            return cut(
                "the file ends inside the record (truncated bag?)".into(),
                None,
            );
        }
        let header_len = u64::from(read_u32(r, &self.path, offset)?);
        if header_len > u64::from(MAX_HEADER_BYTES) {
            return Err(self.err(
                offset,
                format!("record header claims {header_len} bytes, more than the limit of {MAX_HEADER_BYTES}"),
            ));
        }
        if header_len + 8 > remain {
            return cut(
                format!(
                    "record header claims {header_len} bytes; with the two lengths that is {} bytes, and {remain} remain (truncated bag?)",
                    header_len + 8
                ),
                None,
            );
        }
        let mut header = vec![0u8; header_len as usize];
        r.read_exact(&mut header)
            .map_err(|e| io_err(&self.path, e))?;
        let fields = parse_fields(&header).map_err(|e| self.err(offset, e))?;
        let data_len = u64::from(read_u32(r, &self.path, offset)?);
        let left = remain - 8 - header_len;
        let mut rec = RawRecord {
            offset,
            fields,
            data: buf,
        };
        rec.data.clear();
        // Read without zero-filling first; at most what remains of the file.
        (&mut *r)
            .take(data_len.min(left))
            .read_to_end(&mut rec.data)
            .map_err(|e| io_err(&self.path, e))?;
        if data_len > left {
            return cut(
                format!("record data claims {data_len} bytes, {left} remain (truncated bag?)"),
                Some(rec),
            );
        }
        if rec.data.len() as u64 != data_len {
            return Err(self.err(offset, "the file ends inside the record (truncated bag?)"));
        }
        *pos = offset + 8 + header_len + data_len;
        Ok(Next::Whole(rec))
    }

    /// Reads the record at `*pos` (`None` at the end of the file), its data into `buf` (whose
    /// allocation is reused: pass the previous record's data back); a record the file cuts short
    /// is an error.
    fn read_record(
        &self,
        r: &mut BufReader<File>,
        pos: &mut u64,
        buf: Vec<u8>,
    ) -> Result<Option<RawRecord>> {
        match self.next_record(r, pos, buf)? {
            Next::Whole(rec) => Ok(Some(rec)),
            Next::End => Ok(None),
            Next::Cut(cut) => Err(self.err(cut.offset, cut.reason)),
        }
    }

    fn add_connection(&mut self, rec: &RawRecord, data: &[u8]) -> Result<()> {
        let id = u32_field(rec, "conn").map_err(|e| self.err(rec.offset, e))?;
        if id >= u32::from(u16::MAX) {
            return Err(self.err(
                rec.offset,
                format!("connection id {id} does not fit an MCAP channel id (at most 65534)"),
            ));
        }
        let fields = parse_fields(data).map_err(|e| self.err(rec.offset, e))?;
        let get = |name: &str| {
            fields
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| String::from_utf8_lossy(v).into_owned())
        };
        let topic = rec
            .field("topic")
            .map(|v| String::from_utf8_lossy(v).into_owned())
            .or_else(|| get("topic"))
            .ok_or_else(|| self.err(rec.offset, format!("connection {id} has no topic")))?;
        let need = |name: &str| {
            get(name).ok_or_else(|| {
                self.err(
                    rec.offset,
                    format!("connection {id} ({topic}) has no {name} field"),
                )
            })
        };
        let c = Connection {
            id,
            msg_type: need("type")?,
            md5sum: need("md5sum")?,
            definition: get("message_definition").unwrap_or_default(),
            callerid: get("callerid"),
            latching: get("latching"),
            topic,
        };
        self.connections.entry(id).or_insert(c);
        Ok(())
    }

    /// The index: every connection and chunk info from `index_pos` to the end; how the file
    /// cuts it short, unless [`ReadPolicy::strict`] makes that an error.
    fn read_index(&mut self, r: &mut BufReader<File>) -> Result<Option<Cut>> {
        r.seek(SeekFrom::Start(self.index_pos))
            .map_err(|e| io_err(&self.path, e))?;
        let mut pos = self.index_pos;
        loop {
            let rec = match self.next_record(r, &mut pos, Vec::new())? {
                Next::Whole(rec) => rec,
                Next::End => return Ok(None),
                Next::Cut(cut) if self.policy.strict => {
                    return Err(self.err(cut.offset, cut.reason));
                }
                Next::Cut(cut) => return Ok(Some(cut)),
            };
            match rec.op() {
                Some(op::CONNECTION) => self.add_connection(&rec, &rec.data)?,
                Some(op::CHUNK_INFO) => {
                    for pair in rec.data.chunks(8) {
                        let [c0, c1, c2, c3, n0, n1, n2, n3] = pair.try_into().map_err(|_| {
                            self.err(rec.offset, "chunk info data is not a list of (conn, count)")
                        })?;
                        let conn = u32::from_le_bytes([c0, c1, c2, c3]);
                        let n = u32::from_le_bytes([n0, n1, n2, n3]);
                        *self.message_counts.entry(conn).or_default() += u64::from(n);
                    }
                }
                _ => {}
            }
        }
    }

    /// The catalogue of a bag without an index: one pass over every chunk, which also finds
    /// where the file is cut and the chunks to skip ([`Bag::damage`]).
    fn scan_catalog(&mut self, r: &mut BufReader<File>, start: u64) -> Result<()> {
        r.seek(SeekFrom::Start(start))
            .map_err(|e| io_err(&self.path, e))?;
        let mut conns = Vec::new();
        let mut counts: BTreeMap<u32, u64> = BTreeMap::new();
        let mut skipped = Vec::new();
        let cut = self.walk(r, start, &mut skipped, &mut |rec, data| {
            match rec {
                Inner::Connection(rec) => conns.push((rec, data.to_vec())),
                Inner::Message { conn, .. } => *counts.entry(conn).or_default() += 1,
            }
            Ok(ControlFlow::Continue(()))
        })?;
        for (rec, data) in conns {
            self.add_connection(&rec, &data)?;
        }
        self.message_counts = counts;
        self.damage.skipped_chunks = skipped;
        if let Some((cut, partial_messages)) = cut {
            self.data_end = cut.offset;
            self.damage.cut(cut.offset, cut.reason);
            self.damage.partial_messages = partial_messages;
        }
        Ok(())
    }

    /// Calls `f` on every connection and message record of every chunk from `start`, in file
    /// order, until it breaks. Corrupt chunks skipped ([`ReadPolicy::skip_corrupt`]) are added to
    /// `skipped`. Returns where the file cuts the data short, unless strict, with the messages
    /// recovered from a chunk cut short.
    fn walk(
        &self,
        r: &mut BufReader<File>,
        start: u64,
        skipped: &mut Vec<(u64, String)>,
        f: &mut InnerVisitor<'_>,
    ) -> Result<Option<(Cut, u64)>> {
        let end = self.data_end;
        let mut pos = start;
        // Both buffers are reused from chunk to chunk.
        let (mut chunk, mut spare) = (Vec::new(), Vec::new());
        // A cut is met at `data_end` (where the scan that found it set both) when this is not
        // the pass that found it.
        while pos < end || self.damage.cut_at == Some(pos) {
            let rec = match self.next_record(r, &mut pos, std::mem::take(&mut spare))? {
                Next::Whole(rec) => rec,
                Next::End => break,
                Next::Cut(cut) if self.policy.strict => {
                    return Err(self.err(cut.offset, cut.reason));
                }
                Next::Cut(cut) => {
                    let messages = match &cut.partial {
                        Some(rec) if rec.op() == Some(op::CHUNK) => {
                            let records = partial_chunk(rec);
                            self.walk_chunk(rec, &records, true, f)?.1
                        }
                        _ => 0,
                    };
                    return Ok(Some((cut, messages)));
                }
            };
            match rec.op() {
                Some(op::CHUNK) => {
                    let records = match self.decompress(&rec, &mut chunk) {
                        Ok(records) => records,
                        Err(Error::Format { detail, .. }) if self.policy.skip_corrupt => {
                            skipped.push((rec.offset, detail));
                            spare = rec.data;
                            continue;
                        }
                        Err(e) => return Err(e),
                    };
                    if self.walk_chunk(&rec, records, false, f)?.0.is_break() {
                        return Ok(None);
                    }
                }
                Some(op::CONNECTION) => {
                    if f(Inner::Connection(rec.clone_header()), &rec.data)?.is_break() {
                        return Ok(None);
                    }
                }
                Some(op::MSG_DATA) => {
                    let (conn, time_ns) =
                        message_fields(&rec).map_err(|e| self.err(rec.offset, e))?;
                    if f(Inner::Message { conn, time_ns }, &rec.data)?.is_break() {
                        return Ok(None);
                    }
                }
                Some(op::INDEX_DATA | op::CHUNK_INFO | op::BAG_HEADER) => {}
                Some(other) => {
                    return Err(self.err(rec.offset, format!("unknown record op 0x{other:02x}")));
                }
                None => return Err(self.err(rec.offset, "record without an op field")),
            }
            spare = rec.data;
        }
        Ok(None)
    }

    /// The records inside one decompressed chunk, and how many were messages. When `partial`
    /// (the first bytes of a chunk the file cuts short), the records stop quietly at the first
    /// that is not whole.
    fn walk_chunk(
        &self,
        chunk_rec: &RawRecord,
        mut b: &[u8],
        partial: bool,
        f: &mut InnerVisitor<'_>,
    ) -> Result<(ControlFlow<()>, u64)> {
        let in_chunk = |at: usize, e: String| {
            self.err(
                chunk_rec.offset,
                format!("chunk, at byte {at} of its records: {e}"),
            )
        };
        let total = b.len();
        let mut messages = 0;
        while !b.is_empty() {
            let at = total - b.len();
            let parsed = split_len_prefixed(b).and_then(|(header, rest)| {
                let (data, rest) = split_len_prefixed(rest)?;
                let fields = parse_fields(header)?;
                Ok((fields, data, rest))
            });
            let (fields, data, rest) = match parsed {
                Ok(p) => p,
                Err(_) if partial => break,
                Err(e) => return Err(in_chunk(at, e)),
            };
            let rec = RawRecord {
                offset: chunk_rec.offset,
                fields,
                data: Vec::new(),
            };
            let inner = match rec.op() {
                Some(op::MSG_DATA) => {
                    message_fields(&rec).map(|(conn, time_ns)| Inner::Message { conn, time_ns })
                }
                Some(op::CONNECTION) => Ok(Inner::Connection(rec)),
                Some(other) => Err(format!("op 0x{other:02x} does not belong in a chunk")),
                None => Err("record without an op field".into()),
            };
            let inner = match inner {
                Ok(inner) => inner,
                Err(_) if partial => break,
                Err(e) => return Err(in_chunk(at, e)),
            };
            messages += u64::from(matches!(inner, Inner::Message { .. }));
            b = rest;
            let flow = f(inner, data)?;
            if flow.is_break() {
                return Ok((flow, messages));
            }
        }
        Ok((ControlFlow::Continue(()), messages))
    }

    /// A chunk's records: its data itself when uncompressed, else decompressed into `out`; the
    /// declared size is checked either way.
    fn decompress<'a>(&self, rec: &'a RawRecord, out: &'a mut Vec<u8>) -> Result<&'a [u8]> {
        let size = u64::from(u32_field(rec, "size").map_err(|e| self.err(rec.offset, e))?);
        if size > MAX_CHUNK_BYTES {
            return Err(self.err(
                rec.offset,
                format!("chunk claims {size} uncompressed bytes, more than the limit of {MAX_CHUNK_BYTES}"),
            ));
        }
        let compression = rec
            .field("compression")
            .map(|v| String::from_utf8_lossy(v).into_owned())
            .unwrap_or_default();
        if compression != "none" {
            crate::io::check_expansion(rec.data.len() as u64, size)
                .map_err(|e| self.err(rec.offset, format!("chunk {e}")))?;
        }
        out.clear();
        let result = match compression.as_str() {
            "none" if rec.data.len() as u64 == size => return Ok(&rec.data),
            "none" => {
                return Err(self.err(
                    rec.offset,
                    format!(
                        "uncompressed chunk holds {} bytes, but declares {size}",
                        rec.data.len()
                    ),
                ));
            }
            "bz2" => read_bounded(bzip2::read::BzDecoder::new(&rec.data[..]), size, out),
            "lz4" => lz4::Decoder::new(&rec.data[..]).and_then(|d| read_bounded(d, size, out)),
            other => {
                return Err(self.err(
                    rec.offset,
                    format!("chunk compression {other:?} is not supported (none, bz2, lz4)"),
                ));
            }
        };
        result.map_err(|e| self.err(rec.offset, format!("{compression} chunk: {e}")))?;
        if out.len() as u64 != size {
            return Err(self.err(
                rec.offset,
                format!(
                    "{compression} chunk decompresses to {}{} bytes, but declares {size}",
                    if out.len() as u64 > size {
                        "more than "
                    } else {
                        ""
                    },
                    out.len()
                ),
            ));
        }
        Ok(out)
    }

    /// Calls `f(connection id, time [ns since the epoch], message bytes)` for every message, in
    /// file order, until `f` breaks. One chunk is held in memory at a time.
    pub fn for_each_message(
        &self,
        mut f: impl FnMut(u32, u64, &[u8]) -> Result<ControlFlow<()>>,
    ) -> Result<()> {
        let (file, _) = crate::io::input_file::open_regular(&self.path)?;
        let mut r = BufReader::with_capacity(1 << 20, file);
        r.seek(SeekFrom::Start(self.data_start))
            .map_err(|e| io_err(&self.path, e))?;
        let path = &self.path;
        let connections = &self.connections;
        let mut skipped = Vec::new();
        self.walk(&mut r, self.data_start, &mut skipped, &mut |rec, data| match rec {
            Inner::Message { conn, time_ns } => {
                if !connections.contains_key(&conn) {
                    return Err(Error::Format {
                        path: path.clone(),
                        detail: format!(
                            "a message at {time_ns} ns is on connection {conn}, which the bag never defines"
                        ),
                    });
                }
                f(conn, time_ns, data)
            }
            Inner::Connection(_) => Ok(ControlFlow::Continue(())),
        })
        .map(|_| ())
    }

    /// Total size of the bag file, in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// The bag as an MCAP catalogue of the ROS 1 profile (see the module doc).
    pub fn catalog(&self) -> InputCatalog {
        let mut cat = InputCatalog::default();
        let mut schema_ids: BTreeMap<(&str, &str), u16> = BTreeMap::new();
        for c in self.connections.values() {
            let next = schema_ids.len() as u16 + 1;
            let schema_id = *schema_ids
                .entry((c.msg_type.as_str(), c.definition.as_str()))
                .or_insert(next);
            cat.schemas
                .entry(schema_id)
                .or_insert_with(|| SchemaRecord {
                    name: c.msg_type.clone(),
                    encoding: ros1::SCHEMA_ENCODING.to_string(),
                    data: c.definition.as_bytes().to_vec(),
                });
            let mut metadata = BTreeMap::from([
                ("md5sum".to_string(), c.md5sum.clone()),
                ("topic".to_string(), c.topic.clone()),
            ]);
            if let Some(v) = &c.callerid {
                metadata.insert("callerid".into(), v.clone());
            }
            if let Some(v) = &c.latching {
                metadata.insert("latching".into(), v.clone());
            }
            let id = c.id as u16; // < u16::MAX, checked when read
            cat.channels.insert(
                id,
                Channel {
                    id,
                    schema_id,
                    topic: c.topic.clone(),
                    message_encoding: ros1::MESSAGE_ENCODING.to_string(),
                    metadata,
                },
            );
        }
        let counts = self
            .connections
            .keys()
            .map(|&id| {
                (
                    id as u16,
                    self.message_counts.get(&id).copied().unwrap_or(0),
                )
            })
            .collect();
        cat.message_counts = Some(counts);
        cat
    }
}

/// The records that the first bytes of a chunk cut short decode to: its data itself when
/// uncompressed, else what bz2 or lz4 decode before the stream stops (both decode block by
/// block), at most its declared size (and [`MAX_CHUNK_BYTES`]). Nothing for other compressions.
fn partial_chunk(rec: &RawRecord) -> Vec<u8> {
    let size = u32_field(rec, "size")
        .map_or(0, u64::from)
        .min(MAX_CHUNK_BYTES)
        .min(crate::io::expansion_limit(rec.data.len() as u64));
    let mut out = Vec::new();
    match rec.field("compression") {
        Some(b"none") => read_prefix(&rec.data[..], size, &mut out),
        Some(b"bz2") => read_prefix(bzip2::read::BzDecoder::new(&rec.data[..]), size, &mut out),
        Some(b"lz4") => {
            if let Ok(d) = lz4::Decoder::new(&rec.data[..]) {
                read_prefix(d, size, &mut out);
            }
        }
        _ => {}
    }
    out
}

/// What [`Bag::walk`] calls on each inner record and its data.
type InnerVisitor<'a> = dyn FnMut(Inner, &[u8]) -> Result<ControlFlow<()>> + 'a;
