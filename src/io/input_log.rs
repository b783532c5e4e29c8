//! The logs `mireg register` reads, behind one interface: an MCAP file, a ROS 1 bag, or a ROS 2
//! bag directory. Each container gives a catalogue of MCAP schemas and channels
//! ([`InputCatalog`]) and a stream of messages on them, so that everything downstream (topic
//! choice, decoding, the output log) is the same for every kind.
//!
//! MCAP inputs keep their chunks: [`InputLog::pass_through`] copies them byte for byte. The other
//! containers have no MCAP chunks to copy: their messages are written, bytes unchanged, into the
//! output's own chunks.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Record};

use super::bag::compression::{Compression, ZSTD_MAGIC};
use super::bag::ros1::{self, Bag};
use super::bag::rosbag2::{Rosbag2, Storage};
use super::log_order::ChunkTimes;
use super::magic::SQLITE_MAGIC;
use super::mcap::log::{InputCatalog, OutputLog, pass_through};
use super::mcap::read::for_each_record_with;
use crate::io::damage::{Damage, ReadPolicy};
use crate::{Error, Result};

/// What `register` accepts, for messages.
pub const ACCEPTED: &str = "mireg register reads an MCAP file (.mcap), a ROS 1 bag (.bag), or a ROS 2 bag directory (metadata.yaml with .mcap or .db3 files, maybe zstd-compressed)";

/// An MCAP input: its path, how damage is treated, and what was found wrong with it.
#[derive(Debug)]
pub struct McapInput {
    /// The file.
    pub path: PathBuf,
    /// How damage is treated when reading it.
    pub policy: ReadPolicy,
    /// What was wrong with it (cut short, corrupt chunks skipped), found when it was opened.
    pub damage: Damage,
}

impl McapInput {
    /// Whether its chunks can be copied byte for byte: it is whole and no corrupt chunk is to be
    /// skipped (a skipped chunk must not reach the output).
    fn copies_chunks(&self) -> bool {
        !self.damage.any() && !self.policy.skip_corrupt
    }
}

/// An opened input log.
#[derive(Debug)]
pub enum InputLog {
    /// An MCAP file.
    Mcap(McapInput),
    /// A ROS 1 bag (format 2.0).
    Bag(Bag),
    /// A ROS 2 bag directory.
    Rosbag2(Rosbag2),
}

impl InputLog {
    /// Opens `path` as whichever container it is: a directory with a `metadata.yaml` (or that
    /// `metadata.yaml` itself) is a ROS 2 bag (one of a single MCAP file is read as that MCAP file); a file starting with `#ROSBAG`
    /// is a ROS 1 bag; an SQLite database is a rosbag2 `.db3` file on its own, and a zstd file a
    /// compressed rosbag2 storage file on its own (`x.mcap.zstd`, `x.db3.zstd`); anything else is
    /// read as MCAP (whose reader names what is wrong with a file that is not one).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a missing path, a directory without `metadata.yaml` or a
    /// special file, saying once what is wrong and what is accepted; the containers' errors for
    /// malformed files.
    pub fn open(path: &Path) -> Result<(Self, InputCatalog)> {
        Self::open_with(path, ReadPolicy::default())
    }

    /// [`open`](Self::open) with damage treated by `policy` ([`crate::io::mcap::salvage`]):
    /// by default an MCAP file cut short is read up to its last whole record, and
    /// [`damage`](Self::damage) says where it was cut.
    pub fn open_with(path: &Path, policy: ReadPolicy) -> Result<(Self, InputCatalog)> {
        let meta = match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(Error::InvalidInput(format!(
                    "{}: no such file or directory; {ACCEPTED}",
                    path.display()
                )));
            }
            Err(source) => {
                return Err(Error::Io {
                    path: path.to_path_buf(),
                    source,
                });
            }
            Ok(m) => m,
        };
        if meta.is_file() && path.file_name().is_some_and(|n| n == "metadata.yaml") {
            // A ROS 2 bag named by its metadata file: the bag is the directory.
            let dir = path.parent().filter(|p| !p.as_os_str().is_empty());
            return Self::open_with(dir.unwrap_or(Path::new(".")), policy);
        }
        if meta.is_dir() {
            let meta_path = path.join("metadata.yaml");
            match std::fs::metadata(&meta_path) {
                Ok(m) if m.is_file() => {}
                Ok(m) => {
                    return Err(Error::InvalidInput(format!(
                        "{}: is {}, not the regular file a ROS 2 bag describes itself in",
                        meta_path.display(),
                        super::file_kind(&m)
                    )));
                }
                Err(_) => {
                    return Err(Error::InvalidInput(format!(
                        "{}: is a directory without a metadata.yaml, so not a ROS 2 bag; {ACCEPTED}",
                        path.display()
                    )));
                }
            }
            let mut bag = Rosbag2::open(path)?;
            if let (Storage::Mcap, Compression::None, [file]) =
                (bag.storage, bag.compression, bag.files.as_slice())
            {
                // One MCAP file: read it as such, so that its chunks are copied byte for byte.
                return Self::open_mcap(file, policy);
            }
            let catalog = bag.catalog()?;
            return Ok((InputLog::Rosbag2(bag), catalog));
        }
        if !meta.is_file() {
            return Err(Error::InvalidInput(format!(
                "{}: is {}; {ACCEPTED}",
                path.display(),
                super::file_kind(&meta)
            )));
        }
        match file_kind(path)? {
            FileKind::Ros1Bag => {
                let bag = Bag::open_with(path, policy)?;
                let catalog = bag.catalog();
                Ok((InputLog::Bag(bag), catalog))
            }
            FileKind::Db3 => {
                // A rosbag2 `.db3` file on its own.
                let mut bag = Rosbag2::single_db3(path)?;
                let catalog = bag.catalog()?;
                Ok((InputLog::Rosbag2(bag), catalog))
            }
            FileKind::Zstd => {
                // A zstd-compressed rosbag2 storage file on its own (`x.mcap.zstd`, `x.db3.zstd`).
                let mut bag = Rosbag2::single_compressed(path)?;
                let catalog = bag.catalog()?;
                Ok((InputLog::Rosbag2(bag), catalog))
            }
            FileKind::Mcap => Self::open_mcap(path, policy),
            FileKind::Other(head) => Err(Error::InvalidInput(format!(
                "{}: {}; {ACCEPTED}",
                path.display(),
                not_a_log(path, &head)
            ))),
        }
    }

    fn open_mcap(path: &Path, policy: ReadPolicy) -> Result<(Self, InputCatalog)> {
        let (catalog, damage) = InputCatalog::read_with(path, policy)?;
        let input = McapInput {
            path: path.to_path_buf(),
            policy,
            damage,
        };
        Ok((InputLog::Mcap(input), catalog))
    }

    /// What was wrong with the input and read anyway; `None` when nothing was.
    pub fn damage(&self) -> Option<&Damage> {
        match self {
            InputLog::Mcap(m) => Some(&m.damage),
            InputLog::Bag(bag) => Some(bag.damage()),
            InputLog::Rosbag2(_) => None,
        }
        .filter(|d| d.any())
    }

    /// The chunks' time ranges, for restoring log-time order ([`ChunkTimes`]); only MCAP files
    /// have them.
    pub fn chunk_times(&self) -> Result<Option<ChunkTimes>> {
        match self {
            InputLog::Mcap(m) => ChunkTimes::read(&m.path),
            InputLog::Bag(_) | InputLog::Rosbag2(_) => Ok(None),
        }
    }

    /// Calls `f` on every message (its header as an MCAP message header on the catalogue's
    /// channels, and its bytes) in file order until `f` breaks.
    pub fn for_each_message_until(
        &self,
        mut f: impl FnMut(&MessageHeader, &[u8]) -> Result<ControlFlow<()>>,
    ) -> Result<()> {
        match self {
            InputLog::Mcap(m) => for_each_record_with(&m.path, m.policy, |r| match r {
                Record::Message { header, data } => f(&header, &data),
                _ => Ok(ControlFlow::Continue(())),
            })
            .map(|_| ()),
            InputLog::Bag(bag) => {
                bag.for_each_message(|conn, t, data| f(&bag_header(conn, t), data))
            }
            InputLog::Rosbag2(bag) => bag.for_each_message(|h, data| f(h, data)),
        }
    }

    /// Copies every input message into `log` (bytes, channel ids and times unchanged), calling
    /// `on_message` for those on `wanted` channels, in file order; returns the number of
    /// messages copied. `log` must have declared the catalogue's schemas and channels.
    ///
    /// With `only = Some(range)`, only the messages whose log time lies in `range` are copied
    /// (an MCAP input's chunks are then re-chunked; its metadata records and attachments are
    /// still all copied), and `on_message` sees only those.
    pub fn pass_through(
        &self,
        log: &mut OutputLog,
        wanted: &BTreeSet<u16>,
        only: Option<std::ops::Range<u64>>,
        mut on_message: impl FnMut(&mut OutputLog, &MessageHeader, &[u8]) -> Result<()>,
    ) -> Result<u64> {
        let input_bytes = match (self, &only) {
            (InputLog::Mcap(m), None) if m.copies_chunks() => {
                return pass_through(&m.path, log, wanted, on_message);
            }
            (InputLog::Mcap(m), _) => m.damage.file_size,
            (InputLog::Bag(bag), _) => bag.size(),
            (InputLog::Rosbag2(bag), _) => bag.size(),
        };
        log.reserve(input_bytes)?;
        let mut copied = 0u64;
        let mut copy = |log: &mut OutputLog, header: &MessageHeader, data: &[u8]| -> Result<()> {
            if only.as_ref().is_some_and(|r| !r.contains(&header.log_time)) {
                return Ok(());
            }
            log.copy(&Record::Message {
                header: *header,
                data: Cow::Borrowed(data),
            })?;
            copied += 1;
            if wanted.contains(&header.channel_id) {
                on_message(log, header, data)?;
            }
            log.write_behind()
        };
        match self {
            InputLog::Mcap(m) => {
                for_each_record_with(&m.path, m.policy, |r| {
                    match r {
                        Record::Message { header, data } => copy(log, &header, &data)?,
                        r @ (Record::Metadata(_) | Record::Attachment { .. }) => log.copy(&r)?,
                        _ => {}
                    }
                    Ok(ControlFlow::Continue(()))
                })?;
            }
            InputLog::Bag(bag) => bag.for_each_message(|conn, t, data| {
                copy(log, &bag_header(conn, t), data)?;
                Ok(ControlFlow::Continue(()))
            })?,
            InputLog::Rosbag2(bag) => bag.for_each_message(|h, data| {
                copy(log, h, data)?;
                Ok(ControlFlow::Continue(()))
            })?,
        }
        log.start_writeback()?;
        Ok(copied)
    }
}

/// The MCAP header of a bag message: channel = connection, log and publish time = the bag's
/// receive time, sequence 0 (bags record none).
fn bag_header(conn: u32, time_ns: u64) -> MessageHeader {
    MessageHeader {
        channel_id: conn as u16, // < u16::MAX, checked when the bag was opened
        sequence: 0,
        log_time: time_ns,
        publish_time: time_ns,
    }
}

/// What a regular file holds, by its first bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FileKind {
    /// An MCAP file (its magic, or a file too short to hold it whose bytes begin it: the MCAP
    /// reader then says how it is cut).
    Mcap,
    /// A ROS 1 bag (`#ROSBAG V`).
    Ros1Bag,
    /// An SQLite database: a rosbag2 `.db3` storage file.
    Db3,
    /// A zstd frame: a compressed rosbag2 storage file.
    Zstd,
    /// None of these; its first bytes (at most [`HEAD_BYTES`]), for messages.
    Other(Vec<u8>),
}

/// Bytes read to tell a file's kind ([`file_kind`]): 16, the longest magic (SQLite's).
pub const HEAD_BYTES: usize = 16;

/// The kind of the regular file `path`, by its first [`HEAD_BYTES`] bytes.
///
/// # Errors
/// Those of [`crate::io::input_file::open_regular`] (a path that is not a regular file, or
/// cannot be read), naming `path`.
pub fn file_kind(path: &Path) -> Result<FileKind> {
    let (mut f, _) = crate::io::input_file::open_regular(path)?;
    let mut head = [0u8; HEAD_BYTES];
    let got = ros1::read_up_to(&mut f, &mut head).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let head = &head[..got];
    Ok(if head.starts_with(&ros1::MAGIC[..9]) {
        FileKind::Ros1Bag
    } else if head.starts_with(SQLITE_MAGIC) {
        FileKind::Db3
    } else if head.starts_with(&ZSTD_MAGIC) {
        FileKind::Zstd
    } else if head.starts_with(mcap::MAGIC) || !head.is_empty() && mcap::MAGIC.starts_with(head) {
        FileKind::Mcap
    } else {
        FileKind::Other(head.to_vec())
    })
}

/// Why a file of [`FileKind::Other`] whose first bytes are `head` is no log: "not an MCAP file,
/// a ROS 1 bag nor ROS 2 bag storage: it is empty" or "…: it starts with the text "hello"",
/// and, for a file named `.bag`, that a ROS 1 bag starts with `#ROSBAG V2.0`.
pub fn not_a_log(path: &Path, head: &[u8]) -> String {
    let named = |ext: &str| path.extension().is_some_and(|e| e == ext);
    let what = if named("bag") {
        "named .bag, but not a ROS 1 bag (those start with `#ROSBAG V2.0`)"
    } else if named("mcap") {
        "named .mcap, but not an MCAP file (no MCAP magic at its start)"
    } else {
        "not an MCAP file, a ROS 1 bag nor ROS 2 bag storage"
    };
    if head.is_empty() {
        return format!("{what}: it is empty");
    }
    let text = std::str::from_utf8(head).ok().filter(|t| {
        t.chars()
            .all(|c| !c.is_control() || c.is_ascii_whitespace())
    });
    match text {
        Some(t) => format!("{what}: it starts with the text {t:?}"),
        None => {
            let hex: Vec<String> = head.iter().map(|b| format!("{b:02x}")).collect();
            format!("{what}: it starts with the bytes {}", hex.join(" "))
        }
    }
}
