//! File signatures shared by the log readers, in a module of their own below them, so that
//! `input_log.rs` (which tells the formats apart) and the bag readers (which check what they
//! decompressed or opened) both import them without importing each other.

/// The first bytes of every SQLite 3 database (a ROS 2 bag's `.db3` storage).
pub(crate) const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";
