//! Compressed ROS 2 bags: rosbag2's `compression_mode` with `compression_format: zstd`.
//!
//! - `file`: every storage file is one zstd stream (`x.mcap.zstd`, `x.db3.zstd`). It is
//!   decompressed once, streaming (memory bounded by zstd's window, at most 128 MiB by the format
//!   and a few MiB as rosbag2 writes it), into a temporary file in `$TMPDIR`
//!   ([`super::temp`]: unnamed for MCAP, freed on any exit), because SQLite and the MCAP summary
//!   need a seekable file; its size is bounded ([`decompress_file`]). The user's files are only
//!   read.
//! - `message`: every message's bytes are one zstd frame, decompressed as the message is read
//!   into one reused buffer.
//!
//! A zstd file given on its own (`mireg register x.mcap.zstd`) is read as a bag of that one file in
//! `file` mode ([`super::rosbag2::Rosbag2::single_compressed`]).

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::temp::TempFiles;
use crate::io::{MAX_CHUNK_BYTES, MAX_EXPANSION_RATIO, expansion_limit, format_err, io_err};
use crate::{Error, Result};

/// The first bytes of every zstd frame (RFC 8878 §3.1.1), little-endian 0xFD2FB528.
pub const ZSTD_MAGIC: [u8; 4] = [0x28, 0xb5, 0x2f, 0xfd];

/// How a bag's data is compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// Not compressed.
    None,
    /// Each storage file is one zstd stream.
    File,
    /// Each message's bytes are one zstd frame.
    Message,
}

impl Compression {
    /// The compression `metadata.yaml` (at `meta_path`) declares with `compression_mode` and
    /// `compression_format` (empty when absent).
    ///
    /// # Errors
    /// [`Error::Format`] naming `meta_path` and the field for a mode other than none, file or
    /// message, or a format other than zstd (the only one rosbag2 ships).
    pub fn from_metadata(meta_path: &Path, mode: &str, format: &str) -> Result<Self> {
        let mode = match mode.to_ascii_lowercase().as_str() {
            "" | "none" => return Ok(Self::None),
            "file" => Self::File,
            "message" => Self::Message,
            other => {
                return Err(format_err(
                    meta_path,
                    format!("compression_mode {other:?} is not one of none, file, message"),
                ));
            }
        };
        if !format.eq_ignore_ascii_case("zstd") {
            return Err(format_err(
                meta_path,
                format!(
                    "compression_format {format:?} is not supported (zstd, the format rosbag2 writes)"
                ),
            ));
        }
        Ok(mode)
    }
}

fn zstd_err(path: &Path, what: &str, e: impl std::fmt::Display) -> Error {
    format_err(path, format!("zstd {what}: {e} (corrupt or truncated?)"))
}

/// Disk space left free in `$TMPDIR` by a file-mode decompression \[bytes\]: 256 MiB.
pub const TEMP_RESERVE_BYTES: u64 = 256 << 20;

/// Decompresses the zstd file `src` into a new temporary file of `temp` (named after `src`
/// without its `.zstd` where it has a name); returns the path it is read through. Streaming:
/// memory is bounded by zstd's window, not by the file; disk by [`expansion_limit`] of `src`'s
/// size and by the free space of `$TMPDIR` less [`TEMP_RESERVE_BYTES`]. The first bytes must be
/// those of an MCAP or SQLite file, checked before the rest is decompressed.
///
/// # Errors
/// [`Error::Format`] naming `src` when it is not zstd, its stream is corrupt or cut short, it
/// holds neither an MCAP nor an SQLite file, or it expands past either bound; [`Error::Io`] for
/// reading `src`, or naming `src` for writing its copy.
pub fn decompress_file(src: &Path, temp: &mut TempFiles) -> Result<PathBuf> {
    let name = src
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let inner = name.strip_suffix(".zstd").unwrap_or(&name);
    let (input, meta) = crate::io::input_file::open_regular(src)?;
    let mut decoder = zstd::stream::read::Decoder::new(BufReader::with_capacity(1 << 16, input))
        .map_err(|e| io_err(src, e))?;
    let mut head = [0u8; 16];
    let got =
        super::ros1::read_up_to(&mut decoder, &mut head).map_err(|e| zstd_err(src, "stream", e))?;
    let head = &head[..got];
    if !(head.starts_with(mcap::MAGIC) || head == crate::io::magic::SQLITE_MAGIC) {
        return Err(format_err(
            src,
            format!(
                "decompresses to neither an MCAP nor an SQLite file (first bytes {head:02x?}); \
                 a file-compressed bag holds one of them"
            ),
        ));
    }
    let tmp = std::env::temp_dir();
    let by_ratio = expansion_limit(meta.len());
    let free = free_bytes(&tmp).map(|b| b.saturating_sub(TEMP_RESERVE_BYTES));
    let limit = free.map_or(by_ratio, |f| f.min(by_ratio));
    let too_big = || {
        let why = match free {
            Some(f) if f < by_ratio => format!(
                "the {f} bytes free in {} (less {TEMP_RESERVE_BYTES} kept free); TMPDIR sets \
                 where it is decompressed",
                tmp.display()
            ),
            _ => format!(
                "{MAX_EXPANSION_RATIO} times its {} bytes (a decompression bomb?)",
                meta.len()
            ),
        };
        format_err(
            src,
            format!("decompresses to more than {limit} bytes: {why}"),
        )
    };
    if (got as u64) > limit {
        return Err(too_big());
    }
    let unnamed = head.starts_with(mcap::MAGIC);
    let (out, dst) = temp.create(if inner.is_empty() { "file" } else { inner }, unnamed)?;
    let write_err = |e: std::io::Error| {
        format_err(
            src,
            format!(
                "writing its decompressed copy into {} (TMPDIR sets where): {e}",
                tmp.display()
            ),
        )
    };
    let mut out = BufWriter::with_capacity(1 << 20, out);
    out.write_all(head).map_err(write_err)?;
    let mut written = got as u64;
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = match decoder.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(zstd_err(src, "stream", e)),
        };
        written += n as u64;
        if written > limit {
            return Err(too_big());
        }
        out.write_all(&buf[..n]).map_err(write_err)?;
    }
    out.flush().map_err(write_err)?;
    Ok(dst)
}

/// Bytes available to us on the file system of `dir`; `None` where unknown.
fn free_bytes(dir: &Path) -> Option<u64> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
        let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
        // SAFETY: a NUL-terminated path and a buffer of the right type; read only on success.
        if unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) } != 0 {
            return None;
        }
        // SAFETY: statvfs succeeded, so it filled `st`.
        let st = unsafe { st.assume_init() };
        // fsblkcnt_t and c_ulong are u64 here, u32 on 32-bit targets.
        #[allow(clippy::useless_conversion)]
        Some(u64::from(st.f_bavail).saturating_mul(u64::from(st.f_frsize)))
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        let _ = dir;
        None
    }
}

/// Decompresses message-mode bags' messages, one zstd frame each, into one reused buffer.
#[derive(Default)]
pub struct MessageDecompressor {
    buf: Vec<u8>,
}

impl MessageDecompressor {
    /// The bytes of the zstd frame `data`, a message of `file` at log time `t_ns`; at most
    /// [`expansion_limit`] of its size and [`MAX_CHUNK_BYTES`] of them.
    ///
    /// # Errors
    /// [`Error::Format`] naming `file` and the message's time when `data` is not a whole zstd
    /// frame or decompresses to more than the limit.
    pub fn decompress(&mut self, file: &Path, t_ns: u64, data: &[u8]) -> Result<&[u8]> {
        let bad = |e: String| {
            format_err(
                file,
                format!("message at {t_ns} ns: zstd message compression: {e}"),
            )
        };
        if !data.starts_with(&ZSTD_MAGIC) {
            return Err(bad("not a zstd frame".into()));
        }
        self.buf.clear();
        let limit = expansion_limit(data.len() as u64).min(MAX_CHUNK_BYTES);
        let mut decoder = zstd::stream::read::Decoder::with_buffer(data)
            .map_err(|e| bad(e.to_string()))?
            .single_frame();
        let n = (&mut decoder)
            .take(limit + 1)
            .read_to_end(&mut self.buf)
            .map_err(|e| bad(format!("{e} (corrupt or truncated?)")))?;
        if n as u64 > limit {
            return Err(bad(format!(
                "decompresses to more than {limit} bytes ({MAX_EXPANSION_RATIO} times its {} \
                 bytes, at least {} MiB, at most {MAX_CHUNK_BYTES}; a decompression bomb?)",
                data.len(),
                crate::io::EXPANSION_FLOOR_BYTES >> 20
            )));
        }
        Ok(&self.buf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_and_formats() {
        let p = Path::new("metadata.yaml");
        assert_eq!(
            Compression::from_metadata(p, "", "").unwrap(),
            Compression::None
        );
        assert_eq!(
            Compression::from_metadata(p, "FILE", "zstd").unwrap(),
            Compression::File
        );
        assert_eq!(
            Compression::from_metadata(p, "message", "zstd").unwrap(),
            Compression::Message
        );
        let e = Compression::from_metadata(p, "message", "lz4").unwrap_err();
        assert!(e.to_string().contains("compression_format \"lz4\""), "{e}");
        let e = Compression::from_metadata(p, "storage", "zstd").unwrap_err();
        assert!(
            e.to_string().contains("compression_mode \"storage\""),
            "{e}"
        );
    }

    #[test]
    fn message_frames_round_trip_and_bad_frames_fail() {
        let msg: Vec<u8> = (0..10_000u32)
            .flat_map(|i| (i % 251).to_le_bytes())
            .collect();
        let frame = zstd::bulk::compress(&msg, 3).unwrap();
        let mut d = MessageDecompressor::default();
        assert_eq!(d.decompress(Path::new("b"), 5, &frame).unwrap(), &msg[..]);
        let e = d
            .decompress(Path::new("b"), 5, &frame[..frame.len() / 2])
            .unwrap_err();
        assert!(e.to_string().contains("message at 5 ns"), "{e}");
        let e = d.decompress(Path::new("b"), 6, &msg).unwrap_err();
        assert!(e.to_string().contains("not a zstd frame"), "{e}");
    }

    #[test]
    fn files_decompress_streaming_and_cut_files_fail() {
        let dir = tempfile::tempdir().unwrap();
        let mut data = crate::io::magic::SQLITE_MAGIC.to_vec();
        data.extend((0..3_000_000u32).map(|i| (i / 7) as u8));
        let z = dir.path().join("a.db3.zstd");
        std::fs::write(&z, zstd::encode_all(&data[..], 3).unwrap()).unwrap();
        let mut temp = TempFiles::default();
        let got = decompress_file(&z, &mut temp).unwrap();
        assert_eq!(std::fs::read(&got).unwrap(), data);
        let bytes = std::fs::read(&z).unwrap();
        std::fs::write(&z, &bytes[..bytes.len() - 10]).unwrap();
        let e = decompress_file(&z, &mut temp).unwrap_err();
        assert!(e.to_string().contains("a.db3.zstd"), "{e}");
    }
}
