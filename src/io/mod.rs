//! File readers: point clouds (PLY, PCD, NumPy `.npy`, KITTI `.bin`) and poses (4×4 text
//! matrices, Redwood/3DMatch `.log`, Stanford `bun.conf`).
//!
//! Readers parse from byte slices or strings with a path used only for error messages, so
//! they can be tested without files; the `read_*` functions add the file system on top.

pub mod atomic_file;
pub mod bag;
pub mod cloud_file;
pub mod codec;
pub mod damage;
pub mod fingerprint;
pub mod input_file;
pub mod input_log;
pub mod log_order;
mod magic;
pub mod mcap;
pub mod point_time;
pub mod pose_file;
pub mod poses;
mod scalar;

use std::path::Path;

use crate::{Error, Result};

/// Largest uncompressed chunk accepted, in bytes: 1 GiB. A chunk's declared uncompressed size is
/// checked against it before any buffer is allocated, and decompression never writes past the
/// declared size, so a decompression bomb (a few kilobytes claiming gigabytes of zeros) is an error
/// instead of an allocation. Recorders write chunks of a few megabytes (MCAP's default is 768 KiB,
/// rosbag2's 4 MiB); one chunk holds at least one whole message, so the limit is also the largest
/// message a chunked log may carry.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Largest ratio of decompressed to compressed bytes accepted above [`EXPANSION_FLOOR_BYTES`]:
/// 1000. Point clouds and logs compress 2–20× (a cloud all NaN or zeros, a few hundred times);
/// a decompression bomb (zeros compressed by zstd or bz2) 10⁴–10⁶×. Every decompression of an
/// input — an MCAP or ROS 1 bag chunk, a rosbag2 message or file — stops at
/// [`expansion_limit`] of its compressed size, before the excess is held or written.
pub const MAX_EXPANSION_RATIO: u64 = 1000;

/// Decompressed bytes always accepted whatever the ratio \[bytes\]: 64 MiB (a chunk or message
/// of a normal log is smaller).
pub const EXPANSION_FLOOR_BYTES: u64 = 64 << 20;

/// The most bytes `compressed` compressed bytes may decompress to:
/// max([`MAX_EXPANSION_RATIO`] × `compressed`, [`EXPANSION_FLOOR_BYTES`]).
pub fn expansion_limit(compressed: u64) -> u64 {
    compressed
        .saturating_mul(MAX_EXPANSION_RATIO)
        .max(EXPANSION_FLOOR_BYTES)
}

/// "claims N uncompressed bytes from M compressed …" when a compressed block of `compressed`
/// bytes claims more than [`expansion_limit`] of them; `Ok` otherwise.
pub(crate) fn check_expansion(compressed: u64, claimed: u64) -> std::result::Result<(), String> {
    if claimed > expansion_limit(compressed) {
        return Err(format!(
            "claims {claimed} uncompressed bytes from {compressed} compressed, more than \
             {MAX_EXPANSION_RATIO} times as many (and than {EXPANSION_FLOOR_BYTES}): a \
             decompression bomb or a corrupt header"
        ));
    }
    Ok(())
}

/// Builds an [`Error::Io`] for `path`.
pub(crate) fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Builds an [`Error::Format`] for `path`.
pub(crate) fn format_err(path: &Path, detail: impl Into<String>) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail: detail.into(),
    }
}

/// Reads a whole trajectory or pose file (a regular file of at most
/// [`input_file::MAX_TRAJECTORY_BYTES`]), naming it in the error.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    input_file::read_limited_text(
        path,
        input_file::MAX_TRAJECTORY_BYTES,
        "a trajectory or pose file",
    )
}

/// What kind of file `meta` describes, for messages: "a directory", "a FIFO", ….
pub(crate) fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    let t = meta.file_type();
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else if t.is_symlink() {
        "a symbolic link"
    } else if t.is_file() {
        "a regular file"
    } else {
        "a special file"
    }
}
