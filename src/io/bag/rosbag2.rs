//! ROS 2 bag directories (rosbag2): a `metadata.yaml` naming the storage plugin and the bag's
//! files in order, each an MCAP (`mcap` storage) or an SQLite 3 database (`sqlite3` storage,
//! `.db3`). A bag split into several files is one log.
//!
//! The files' topics become one catalogue of MCAP channels: a channel per distinct (topic, type,
//! serialization format), numbered from 1 in order of first appearance, so that a topic keeps one
//! channel across the files of a split bag. Schemas:
//! - `mcap` storage: the files' own schemas;
//! - `sqlite3` storage: the `message_definitions` table where the bag has one (rosbag2 since
//!   Iron); else our own full definition for the types we write ourselves
//!   (`sensor_msgs/msg/PointCloud2`, `geometry_msgs/msg/PoseStamped`, `tf2_msgs/msg/TFMessage`);
//!   else a `ros2msg` schema named after the type with an empty definition, so that the type
//!   name and every message are kept even though no reader can decode them without the
//!   definition (docs/INPUTS.md).
//!
//! SQLite files are never written, nor is anything created beside them ([`SqliteFile`]): a
//! database without a write-ahead log beside it is opened in SQLite's immutable mode (no lock, no
//! `-shm` or `-wal` file, so a bag in a read-only directory reads too); one with a non-empty
//! `-wal` (a WAL-mode bag, rosbag2's `resilient` preset, whose recorder has not checkpointed, e.g.
//! because it crashed) or a hot `-journal` is copied with it into a private temporary directory
//! (`$TMPDIR/.mireg-bag-*`, removed when the bag is dropped) and the copy opened, so that the log's
//! last messages are read as SQLite would read them. Errors name the user's file, never the copy.
//! Compressed bags (`compression_mode: file` or `message`, zstd) are read through
//! [`super::compression`].

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::{Channel, MessageHeader, Record};
use rusqlite::{Connection as Db, OpenFlags};

use super::compression::{Compression, MessageDecompressor, decompress_file};
use super::temp::TempFiles;

mod metadata;
use crate::io::codec::cdr;
use crate::io::mcap::log::InputCatalog;
use crate::io::mcap::read::for_each_record_until;
use crate::io::mcap::write::SchemaRecord;
use crate::{Error, Result};
pub(crate) use metadata::parse_metadata;

/// The storage of a bag's files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// MCAP files.
    Mcap,
    /// SQLite 3 databases (`.db3`).
    Sqlite3,
}

/// A ROS 2 bag: its files in order and, once read, how their channel ids map to ours.
#[derive(Debug, Clone)]
pub struct Rosbag2 {
    dir: PathBuf,
    /// Storage plugin of every file.
    pub storage: Storage,
    /// The bag's files, in the order `metadata.yaml` lists them.
    pub files: Vec<PathBuf>,
    size: u64,
    /// Per file: its channel (MCAP) or topic (SQLite) id → our channel id.
    channel_maps: Vec<BTreeMap<i64, u16>>,
    /// How the bag is compressed. With [`Compression::File`], `files` are the decompressed
    /// copies in `decompressed`.
    pub compression: Compression,
    /// The decompressed files of a file-compressed bag (shared by clones; [`TempFiles`]).
    decompressed: Option<Arc<TempFiles>>,
    /// The user's files, parallel to `files` (which may be decompressed copies), named in errors.
    names: Vec<PathBuf>,
    /// SQLite storage: how each of `files` is opened ([`SqliteFile`]); empty for MCAP storage.
    sqlite: Vec<SqliteFile>,
    /// The private copies of `.db3` files with a write-ahead log or hot journal (shared by
    /// clones).
    private_copies: Option<Arc<TempFiles>>,
}

/// How one `.db3` file of a bag is opened without altering it (see the module doc).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct SqliteFile {
    /// The file as the user gave it (a `.db3`, or the `.db3.zstd` it was decompressed from),
    /// named in every error.
    pub(crate) name: PathBuf,
    /// The file SQLite opens: the `.db3` itself, in immutable mode, or (`private`) our copy of it
    /// with its `-wal` or `-journal`, read-write so that SQLite can apply them.
    pub(crate) open: PathBuf,
    /// Whether `open` is our private copy.
    pub(crate) private: bool,
}

fn format_err(path: &Path, detail: impl Into<String>) -> Error {
    crate::io::format_err(path, detail)
}

fn sql_err(path: &Path, what: &str, e: rusqlite::Error) -> Error {
    format_err(path, format!("SQLite 3 storage, {what}: {e}"))
}

impl Rosbag2 {
    /// Reads `dir/metadata.yaml` and checks that every file it names exists; the files of a
    /// file-compressed bag are decompressed into a temporary directory.
    ///
    /// # Errors
    /// [`Error::Format`] naming `metadata.yaml` when it lists no files, names an unknown storage
    /// or compression, or names a file that is missing; naming a compressed file that is corrupt.
    pub fn open(dir: &Path) -> Result<Self> {
        let meta_path = dir.join("metadata.yaml");
        let text = crate::io::input_file::read_limited_text(
            &meta_path,
            crate::io::input_file::MAX_METADATA_BYTES,
            "a rosbag2 metadata.yaml",
        )?;
        let meta = parse_metadata(&text);
        let compression = Compression::from_metadata(
            &meta_path,
            &meta.compression_mode,
            &meta.compression_format,
        )?;
        if meta.relative_file_paths.is_empty() {
            let detail = if text.contains("rosbag2_bagfile_information") {
                "lists no files (relative_file_paths is missing or empty)"
            } else {
                "is not a rosbag2 metadata.yaml (no rosbag2_bagfile_information; unreadable or \
                 not YAML?); `ros2 bag reindex` rebuilds it from the bag's files"
            };
            return Err(format_err(&meta_path, detail));
        }
        let mut seen = std::collections::BTreeSet::new();
        if let Some(twice) = meta
            .relative_file_paths
            .iter()
            .find(|f| !seen.insert(f.as_str()))
        {
            return Err(format_err(
                &meta_path,
                format!(
                    "relative_file_paths lists {twice} twice: every message would be read twice; \
                     list each file once"
                ),
            ));
        }
        let files: Vec<PathBuf> = meta
            .relative_file_paths
            .iter()
            .map(|f| dir.join(f))
            .collect();
        let storage = match meta.storage_identifier.as_deref() {
            Some("mcap") => Storage::Mcap,
            Some("sqlite3") => Storage::Sqlite3,
            Some(other) => {
                return Err(format_err(
                    &meta_path,
                    format!("storage_identifier {other:?} is not supported (mcap, sqlite3)"),
                ));
            }
            // Older metadata may omit it: the files' extension says.
            None if files.iter().all(|f| {
                let name = f.to_string_lossy();
                name.ends_with(".db3") || name.ends_with(".db3.zstd")
            }) =>
            {
                Storage::Sqlite3
            }
            None => Storage::Mcap,
        };
        let mut size = 0;
        for f in &files {
            match std::fs::metadata(f) {
                Ok(m) if m.is_file() => size += m.len(),
                _ => {
                    return Err(format_err(
                        &meta_path,
                        format!("lists {}, which is not a file in the bag", f.display()),
                    ));
                }
            }
        }
        let mut bag = Self {
            dir: dir.to_path_buf(),
            storage,
            files,
            size,
            channel_maps: Vec::new(),
            compression,
            decompressed: None,
            names: Vec::new(),
            sqlite: Vec::new(),
            private_copies: None,
        };
        let names = bag.files.clone();
        if compression == Compression::File {
            bag.decompress_files()?;
        }
        if storage == Storage::Sqlite3 {
            bag.open_sqlite_files(&names)?;
        }
        Ok(bag)
    }

    /// Replaces `files` by their decompressed copies in a new temporary directory.
    fn decompress_files(&mut self) -> Result<()> {
        let mut temp = TempFiles::default();
        self.names.clone_from(&self.files);
        for f in &mut self.files {
            *f = decompress_file(f, &mut temp)?;
        }
        self.decompressed = Some(Arc::new(temp));
        Ok(())
    }

    /// A zstd-compressed storage file given on its own (`x.mcap.zstd`, `x.db3.zstd`), read as a
    /// file-compressed bag of that one file; what it holds (SQLite 3 or MCAP) is read from its
    /// decompressed first bytes.
    pub fn single_compressed(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path)
            .map_err(|e| crate::io::io_err(path, e))?
            .len();
        let mut bag = Self {
            dir: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            storage: Storage::Mcap,
            files: vec![path.to_path_buf()],
            size,
            channel_maps: Vec::new(),
            compression: Compression::File,
            decompressed: None,
            names: Vec::new(),
            sqlite: Vec::new(),
            private_copies: None,
        };
        bag.decompress_files()?;
        let mut head = [0u8; 16];
        let n = std::fs::File::open(&bag.files[0])
            .and_then(|mut f| super::ros1::read_up_to(&mut f, &mut head))
            .map_err(|e| crate::io::io_err(&bag.files[0], e))?;
        if head[..n] == crate::io::magic::SQLITE_MAGIC[..] {
            bag.storage = Storage::Sqlite3;
            bag.open_sqlite_files(&[path.to_path_buf()])?;
        }
        Ok(bag)
    }

    /// A single `.db3` file given on its own, read as a bag of that one file.
    pub fn single_db3(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path)
            .map_err(|source| Error::Io {
                path: path.to_path_buf(),
                source,
            })?
            .len();
        let mut bag = Self {
            dir: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            storage: Storage::Sqlite3,
            files: vec![path.to_path_buf()],
            size,
            channel_maps: Vec::new(),
            compression: Compression::None,
            decompressed: None,
            names: Vec::new(),
            sqlite: Vec::new(),
            private_copies: None,
        };
        bag.open_sqlite_files(&[path.to_path_buf()])?;
        Ok(bag)
    }

    /// Decides how each of `files` (SQLite storage; `names` are the user's files they stand for)
    /// is opened: as it is, immutable, or, when a non-empty `-wal` or `-journal` lies beside it,
    /// through a private copy of it with that file (see the module doc).
    fn open_sqlite_files(&mut self, names: &[PathBuf]) -> Result<()> {
        let mut sqlite = Vec::with_capacity(self.files.len());
        for (i, (file, name)) in self.files.iter().zip(names).enumerate() {
            let mut companions = Vec::new();
            for suffix in ["-wal", "-journal"] {
                let mut companion = file.as_os_str().to_owned();
                companion.push(suffix);
                let companion = PathBuf::from(companion);
                match std::fs::metadata(&companion) {
                    Ok(m) if m.is_file() && m.len() > 0 => companions.push((suffix, companion)),
                    Ok(m) if m.is_file() => {}
                    Ok(m) => {
                        return Err(format_err(
                            &companion,
                            format!(
                                "is {}, not the regular file SQLite keeps the recent changes of {} in",
                                crate::io::file_kind(&m),
                                name.display()
                            ),
                        ));
                    }
                    Err(_) => {}
                }
            }
            if companions.is_empty() {
                sqlite.push(SqliteFile {
                    name: name.clone(),
                    open: file.clone(),
                    private: false,
                });
                continue;
            }
            if self.private_copies.is_none() {
                let mut temp = TempFiles::default();
                temp.dir()?;
                self.private_copies = Some(Arc::new(temp));
            }
            let dir = self
                .private_copies
                .as_ref()
                .and_then(|t| t.path())
                .expect("made above");
            let copy = dir.join(format!("{i}.db3"));
            copy_file(file, &copy, name)?;
            for (suffix, companion) in &companions {
                copy_file(companion, &dir.join(format!("{i}.db3{suffix}")), name)?;
            }
            sqlite.push(SqliteFile {
                name: name.clone(),
                open: copy,
                private: true,
            });
        }
        self.sqlite = sqlite;
        Ok(())
    }

    /// The bag directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Total size of the bag's files, in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// `e`, an error about file `i`, naming the user's file where it names a decompressed copy.
    fn as_input(&self, e: Error, i: usize) -> Error {
        let (Some(copy), Some(name)) = (self.files.get(i), self.names.get(i)) else {
            return e;
        };
        let rename = |path: PathBuf| if &path == copy { name.clone() } else { path };
        match e {
            Error::Format { path, detail } => Error::Format {
                path: rename(path),
                detail: format!("{detail} (in its decompressed copy)"),
            },
            Error::Io { path, source } => Error::Io {
                path: rename(path),
                source,
            },
            Error::InvalidInput(m) => {
                Error::InvalidInput(m.replace(&*copy.to_string_lossy(), &name.to_string_lossy()))
            }
            e => e,
        }
    }

    /// The merged catalogue of every file (see the module doc); also fixes how each file's ids
    /// map to its channels.
    pub fn catalog(&mut self) -> Result<InputCatalog> {
        let mut m = Merge::default();
        self.channel_maps.clear();
        for (i, f) in self.files.iter().enumerate() {
            let map = match self.storage {
                Storage::Mcap => m.add_mcap(f).map_err(|e| self.as_input(e, i))?,
                Storage::Sqlite3 => m.add_sqlite(&self.sqlite[i])?,
            };
            self.channel_maps.push(map);
        }
        Ok(m.cat)
    }

    /// Calls `f` on every message of every file, file after file, each file in its own order
    /// (MCAP: file order; SQLite: by timestamp), with the header on our channel ids and the
    /// message's bytes (decompressed in a message-compressed bag), until `f` breaks.
    /// [`catalog`](Self::catalog) must have been read.
    pub fn for_each_message(
        &self,
        mut f: impl FnMut(&MessageHeader, &[u8]) -> Result<ControlFlow<()>>,
    ) -> Result<()> {
        assert_eq!(self.channel_maps.len(), self.files.len(), "catalog() first");
        let mut unzip = MessageDecompressor::default();
        for (i, (file, map)) in self.files.iter().zip(&self.channel_maps).enumerate() {
            let name = self
                .sqlite
                .get(i)
                .map_or(file.as_path(), |s| s.name.as_path());
            let mut f = |h: &MessageHeader, data: &[u8]| match self.compression {
                Compression::Message => f(h, unzip.decompress(name, h.log_time, data)?),
                Compression::None | Compression::File => f(h, data),
            };
            let flow = match self.storage {
                Storage::Mcap => {
                    mcap_messages(file, map, &mut f).map_err(|e| self.as_input(e, i))?
                }
                Storage::Sqlite3 => sqlite_messages(&self.sqlite[i], map, &mut f)?,
            };
            if flow.is_break() {
                break;
            }
        }
        Ok(())
    }
}

fn mcap_messages(
    file: &Path,
    map: &BTreeMap<i64, u16>,
    f: &mut impl FnMut(&MessageHeader, &[u8]) -> Result<ControlFlow<()>>,
) -> Result<ControlFlow<()>> {
    let mut flow = ControlFlow::Continue(());
    for_each_record_until(file, |r| {
        if let Record::Message { header, data } = r {
            let channel_id = *map.get(&i64::from(header.channel_id)).ok_or_else(|| {
                format_err(
                    file,
                    format!(
                        "a message is on channel {}, which the file never defines",
                        header.channel_id
                    ),
                )
            })?;
            flow = f(
                &MessageHeader {
                    channel_id,
                    ..header
                },
                &data,
            )?;
        }
        Ok(flow)
    })?;
    Ok(flow)
}

/// Copies `src` to `dst` (a new file in our private directory, writable whatever `src`'s
/// permissions), naming `name`, the user's file, in errors.
fn copy_file(src: &Path, dst: &Path, name: &Path) -> Result<()> {
    let copy = || -> std::io::Result<()> {
        let mut from = std::fs::File::open(src)?;
        let mut to = std::fs::File::create(dst)?;
        std::io::copy(&mut from, &mut to)?;
        Ok(())
    };
    copy().map_err(|e| {
        format_err(
            name,
            format!(
                "copying {} into a private temporary directory (to read its write-ahead log or journal without altering the bag; TMPDIR sets where): {e}",
                src.display()
            ),
        )
    })
}

/// An SQLite URI (`file://…?immutable=1`) for the file at `path`: its absolute path with every
/// byte other than ASCII letters, digits and `/._~-` percent-encoded (so `?`, `#` and `%` in a
/// name stay part of the path).
pub(crate) fn immutable_uri(path: &Path) -> String {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut uri = String::from("file://");
    for &b in absolute.as_os_str().as_encoded_bytes() {
        if b.is_ascii_alphanumeric() || b"/._~-".contains(&b) {
            uri.push(char::from(b));
        } else {
            uri.push_str(&format!("%{b:02X}"));
        }
    }
    uri.push_str("?immutable=1");
    uri
}

fn open_db(file: &SqliteFile) -> Result<Db> {
    let name = file.name.as_path();
    let db = if file.private {
        // Our own copy: SQLite applies its write-ahead log or rolls its journal back in place.
        Db::open_with_flags(
            &file.open,
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
    } else {
        // The user's file, which nothing (not even a lock or a `-shm` file) may alter.
        Db::open_with_flags(
            immutable_uri(&file.open),
            OpenFlags::SQLITE_OPEN_READ_ONLY
                | OpenFlags::SQLITE_OPEN_URI
                | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
    }
    .map_err(|e| sql_err(name, "opening", e))?;
    // Fail here, naming the file, if it is not a database at all.
    db.query_row("SELECT count(*) FROM sqlite_master", [], |_| Ok(()))
        .map_err(|e| sql_err(name, "reading its tables", e))?;
    Ok(db)
}

fn sqlite_messages(
    db_file: &SqliteFile,
    map: &BTreeMap<i64, u16>,
    f: &mut impl FnMut(&MessageHeader, &[u8]) -> Result<ControlFlow<()>>,
) -> Result<ControlFlow<()>> {
    let db = open_db(db_file)?;
    let file = db_file.name.as_path();
    let mut stmt = db
        .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(|e| sql_err(file, "reading the messages table", e))?;
    let mut rows = stmt
        .query([])
        .map_err(|e| sql_err(file, "reading the messages table", e))?;
    while let Some(row) = rows
        .next()
        .map_err(|e| sql_err(file, "reading a message", e))?
    {
        let topic_id: i64 = row
            .get(0)
            .map_err(|e| sql_err(file, "messages.topic_id", e))?;
        let t: i64 = row
            .get(1)
            .map_err(|e| sql_err(file, "messages.timestamp", e))?;
        let data = row
            .get_ref(2)
            .and_then(|v| v.as_blob().map_err(rusqlite::Error::from))
            .map_err(|e| sql_err(file, "messages.data", e))?;
        let channel_id = *map.get(&topic_id).ok_or_else(|| {
            format_err(
                file,
                format!("a message at {t} ns is on topic id {topic_id}, which the topics table does not define"),
            )
        })?;
        let log_time = u64::try_from(t).map_err(|_| {
            format_err(
                file,
                format!("a message on topic id {topic_id} has a negative timestamp {t}"),
            )
        })?;
        let header = MessageHeader {
            channel_id,
            sequence: 0,
            log_time,
            publish_time: log_time,
        };
        if f(&header, data)?.is_break() {
            return Ok(ControlFlow::Break(()));
        }
    }
    Ok(ControlFlow::Continue(()))
}

/// The catalogue being merged from the files of one bag.
#[derive(Default)]
struct Merge {
    cat: InputCatalog,
    schemas: BTreeMap<(String, String, Vec<u8>), u16>,
    channels: BTreeMap<(String, String, u16), u16>,
}

impl Merge {
    fn schema(&mut self, s: SchemaRecord) -> u16 {
        let key = (s.name.clone(), s.encoding.clone(), s.data.clone());
        let next = self.schemas.len() as u16 + 1;
        let id = *self.schemas.entry(key).or_insert(next);
        self.cat.schemas.entry(id).or_insert(s);
        id
    }

    fn channel(
        &mut self,
        file: &Path,
        topic: &str,
        message_encoding: &str,
        schema_id: u16,
        metadata: BTreeMap<String, String>,
        count: u64,
    ) -> Result<u16> {
        let key = (topic.to_string(), message_encoding.to_string(), schema_id);
        let next = self.channels.len() + 1;
        if next >= usize::from(u16::MAX) && !self.channels.contains_key(&key) {
            return Err(format_err(file, "more than 65534 channels"));
        }
        let id = *self.channels.entry(key).or_insert(next as u16);
        self.cat.channels.entry(id).or_insert_with(|| Channel {
            id,
            schema_id,
            topic: topic.to_string(),
            message_encoding: message_encoding.to_string(),
            metadata,
        });
        *self
            .cat
            .message_counts
            .get_or_insert_with(BTreeMap::new)
            .entry(id)
            .or_default() += count;
        Ok(id)
    }

    fn add_mcap(&mut self, file: &Path) -> Result<BTreeMap<i64, u16>> {
        let cat = InputCatalog::read(file)?;
        let mut map = BTreeMap::new();
        for c in cat.channels.values() {
            let schema_id = match cat.schemas.get(&c.schema_id) {
                Some(s) => self.schema(s.clone()),
                None => 0,
            };
            let count = cat
                .message_counts
                .as_ref()
                .and_then(|m| m.get(&c.id).copied())
                .unwrap_or(0);
            let id = self.channel(
                file,
                &c.topic,
                &c.message_encoding,
                schema_id,
                c.metadata.clone(),
                count,
            )?;
            map.insert(i64::from(c.id), id);
        }
        Ok(map)
    }

    fn add_sqlite(&mut self, db_file: &SqliteFile) -> Result<BTreeMap<i64, u16>> {
        let db = open_db(db_file)?;
        let file = db_file.name.as_path();
        let has_table = |name: &str| -> Result<bool> {
            db.query_row(
                "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = ?1",
                [name],
                |r| r.get::<_, i64>(0),
            )
            .map(|n| n > 0)
            .map_err(|e| sql_err(file, "reading its tables", e))
        };
        if !has_table("topics")? || !has_table("messages")? {
            return Err(format_err(
                file,
                "SQLite 3 storage: no topics or messages table, so not a rosbag2 database",
            ));
        }
        let mut definitions: BTreeMap<String, (String, String)> = BTreeMap::new();
        if has_table("message_definitions")? {
            let mut stmt = db
                .prepare("SELECT topic_type, encoding, encoded_message_definition FROM message_definitions")
                .map_err(|e| sql_err(file, "reading message_definitions", e))?;
            let rows = stmt
                .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
                .map_err(|e| sql_err(file, "reading message_definitions", e))?;
            for row in rows {
                let (t, enc, text): (String, String, String) =
                    row.map_err(|e| sql_err(file, "reading message_definitions", e))?;
                if !text.is_empty() {
                    definitions.insert(t, (enc, text));
                }
            }
        }
        let has_qos = db
            .prepare("SELECT offered_qos_profiles FROM topics LIMIT 0")
            .is_ok();
        let sql = if has_qos {
            "SELECT id, name, type, serialization_format, offered_qos_profiles, \
             (SELECT count(*) FROM messages WHERE topic_id = topics.id) FROM topics ORDER BY id"
        } else {
            "SELECT id, name, type, serialization_format, '', \
             (SELECT count(*) FROM messages WHERE topic_id = topics.id) FROM topics ORDER BY id"
        };
        let mut stmt = db
            .prepare(sql)
            .map_err(|e| sql_err(file, "reading the topics table", e))?;
        type TopicRow = (i64, String, String, String, String, i64);
        let rows: Vec<TopicRow> = stmt
            .query_map([], |r| {
                Ok((
                    r.get(0)?,
                    r.get(1)?,
                    r.get(2)?,
                    r.get(3)?,
                    r.get(4)?,
                    r.get(5)?,
                ))
            })
            .and_then(|rows| rows.collect())
            .map_err(|e| sql_err(file, "reading the topics table", e))?;
        let mut map = BTreeMap::new();
        for (topic_id, name, ty, format, qos, count) in rows {
            let schema = match definitions.get(&ty) {
                Some((enc, text)) => SchemaRecord {
                    name: ty.clone(),
                    encoding: enc.clone(),
                    data: text.as_bytes().to_vec(),
                },
                None => SchemaRecord {
                    name: ty.clone(),
                    encoding: cdr::SCHEMA_ENCODING.to_string(),
                    data: builtin_definition(&ty).unwrap_or("").as_bytes().to_vec(),
                },
            };
            let schema_id = self.schema(schema);
            let metadata = if qos.is_empty() {
                BTreeMap::new()
            } else {
                BTreeMap::from([("offered_qos_profiles".to_string(), qos)])
            };
            let id = self.channel(
                file,
                &name,
                &format,
                schema_id,
                metadata,
                u64::try_from(count).unwrap_or(0),
            )?;
            map.insert(topic_id, id);
        }
        Ok(map)
    }
}

/// Our own full `ros2msg` definition of a type, for `.db3` bags that store none.
fn builtin_definition(ty: &str) -> Option<&'static str> {
    match ty {
        cdr::POINT_CLOUD2_SCHEMA_NAME => Some(cdr::POINT_CLOUD2_SCHEMA),
        cdr::POSE_STAMPED_SCHEMA_NAME => Some(cdr::POSE_STAMPED_SCHEMA),
        cdr::TF_MESSAGE_SCHEMA_NAME => Some(cdr::TF_MESSAGE_SCHEMA),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn immutable_uris_keep_query_and_fragment_characters_in_the_path() {
        assert_eq!(
            immutable_uri(Path::new("/a b/x?y#z%1é.db3")),
            "file:///a%20b/x%3Fy%23z%251%C3%A9.db3?immutable=1"
        );
        // A path starting with two slashes is not read as a URI authority.
        assert!(immutable_uri(Path::new("//srv/b.db3")).starts_with("file:////srv/"));
    }

    /// Every kind of awkward name opens, immutable, and nothing appears beside it.
    #[test]
    fn a_db3_under_any_name_opens_immutable_and_nothing_is_created() {
        let dir = tempfile::tempdir().unwrap();
        for name in [
            "plain.db3",
            "q?x=1.db3",
            "h#frag.db3",
            "p%41.db3",
            "sp ace é.db3",
        ] {
            let path = dir.path().join(name);
            let db = Db::open(&path).unwrap();
            db.execute_batch(
                "PRAGMA journal_mode=WAL; CREATE TABLE t(x); INSERT INTO t VALUES (7);",
            )
            .unwrap();
            drop(db);
            let before = std::fs::read_dir(dir.path()).unwrap().count();
            let file = SqliteFile {
                name: path.clone(),
                open: path.clone(),
                private: false,
            };
            let db = open_db(&file).unwrap();
            let x: i64 = db.query_row("SELECT x FROM t", [], |r| r.get(0)).unwrap();
            assert_eq!(x, 7, "{name}");
            drop(db);
            assert_eq!(
                std::fs::read_dir(dir.path()).unwrap().count(),
                before,
                "{name}"
            );
        }
    }
}
