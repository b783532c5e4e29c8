//! The records of a ROS 1 bag: a header of length-prefixed `name=value` fields and data, read
//! with every length checked against what remains, and the small readers the bag's walk uses.

use std::io::Read;
use std::path::Path;

use crate::io::io_err;
use crate::{Error, Result};

/// A record's header fields (`name` → raw value) and its data.
pub(super) struct RawRecord {
    pub(super) offset: u64,
    pub(super) fields: Vec<(String, Vec<u8>)>,
    pub(super) data: Vec<u8>,
}

impl RawRecord {
    pub(super) fn op(&self) -> Option<u8> {
        self.field("op")
            .and_then(|v| (v.len() == 1).then_some(v[0]))
    }

    pub(super) fn field(&self, name: &str) -> Option<&[u8]> {
        self.fields
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
}

/// Parses `name=value` fields, each prefixed by its `u32` length.
pub(super) fn parse_fields(mut b: &[u8]) -> std::result::Result<Vec<(String, Vec<u8>)>, String> {
    let mut out = Vec::new();
    while !b.is_empty() {
        let Some((len, rest)) = b.split_first_chunk::<4>() else {
            return Err(format!("{} stray bytes after the last field", b.len()));
        };
        let len = u32::from_le_bytes(*len) as usize;
        if len > rest.len() {
            return Err(format!(
                "a field claims {len} bytes, {} remain in the header",
                rest.len()
            ));
        }
        let (field, rest) = rest.split_at(len);
        let eq = field
            .iter()
            .position(|&c| c == b'=')
            .ok_or_else(|| "a header field has no '='".to_string())?;
        let name = String::from_utf8_lossy(&field[..eq]).into_owned();
        out.push((name, field[eq + 1..].to_vec()));
        b = rest;
    }
    Ok(out)
}

/// The next record of the file, as [`Bag::next_record`] finds it.
pub(super) enum Next {
    Whole(RawRecord),
    End,
    Cut(Cut),
}

/// A record the file cuts short.
pub(super) struct Cut {
    /// Where the record starts.
    pub(super) offset: u64,
    /// What is missing, e.g. "record data claims 2000 bytes, 1000 remain (truncated bag?)".
    pub(super) reason: String,
    /// The record with the part of its data that is there, when its header is whole.
    pub(super) partial: Option<RawRecord>,
}

/// A record inside a chunk (or at the top level of an old-style bag).
pub(super) enum Inner {
    Connection(RawRecord),
    Message { conn: u32, time_ns: u64 },
}

impl RawRecord {
    pub(super) fn clone_header(&self) -> RawRecord {
        RawRecord {
            offset: self.offset,
            fields: self.fields.clone(),
            data: Vec::new(),
        }
    }
}

pub(super) fn bag_err(path: &Path, offset: u64, detail: impl std::fmt::Display) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail: format!("ROS 1 bag, record at offset {offset}: {detail}"),
    }
}

/// Reads until `buf` is full or the input ends; returns the bytes read.
pub(crate) fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
}

pub(super) fn read_u32(r: &mut impl Read, path: &Path, offset: u64) -> Result<u32> {
    let mut b = [0u8; 4];
    r.read_exact(&mut b).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            bag_err(
                path,
                offset,
                "the file ends inside the record (truncated bag?)",
            )
        } else {
            io_err(path, e)
        }
    })?;
    Ok(u32::from_le_bytes(b))
}

/// Splits a `u32`-length-prefixed field off the front of `b`.
pub(super) fn split_len_prefixed(b: &[u8]) -> std::result::Result<(&[u8], &[u8]), String> {
    let Some((len, rest)) = b.split_first_chunk::<4>() else {
        return Err(format!(
            "{} stray bytes where a length was expected",
            b.len()
        ));
    };
    let len = u32::from_le_bytes(*len) as usize;
    if len > rest.len() {
        return Err(format!(
            "claims {len} bytes, {} remain in the chunk",
            rest.len()
        ));
    }
    Ok(rest.split_at(len))
}

pub(super) fn u32_field(rec: &RawRecord, name: &str) -> std::result::Result<u32, String> {
    match rec.field(name) {
        Some(v) if v.len() == 4 => Ok(u32::from_le_bytes(v.try_into().expect("4 bytes"))),
        Some(v) => Err(format!("field {name} has {} bytes, not 4", v.len())),
        None => Err(format!("no {name} field")),
    }
}

pub(super) fn u64_field(rec: &RawRecord, name: &str) -> std::result::Result<u64, String> {
    match rec.field(name) {
        Some(v) if v.len() == 8 => Ok(u64::from_le_bytes(v.try_into().expect("8 bytes"))),
        Some(v) => Err(format!("field {name} has {} bytes, not 8", v.len())),
        None => Err(format!("no {name} field")),
    }
}

/// A message record's connection and time (`u32` seconds + `u32` nanoseconds) in nanoseconds.
pub(super) fn message_fields(rec: &RawRecord) -> std::result::Result<(u32, u64), String> {
    let conn = u32_field(rec, "conn")?;
    let t = match rec.field("time") {
        Some(v) if v.len() == 8 => v,
        _ => return Err("message record without an 8-byte time field".into()),
    };
    let sec = u32::from_le_bytes(t[..4].try_into().expect("4 bytes"));
    let nsec = u32::from_le_bytes(t[4..].try_into().expect("4 bytes"));
    Ok((conn, u64::from(sec) * 1_000_000_000 + u64::from(nsec)))
}

/// Reads `r` to its end into `out`, failing past `limit` bytes (a chunk that decompresses to more
/// than it declares never gets the memory).
pub(super) fn read_bounded(r: impl Read, limit: u64, out: &mut Vec<u8>) -> std::io::Result<()> {
    out.reserve(limit as usize);
    r.take(limit + 1).read_to_end(out)?;
    Ok(())
}
