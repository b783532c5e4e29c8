//! Opening what the user names as an input file: only a regular file is ever opened, and files
//! that are small by nature (a configuration, a trajectory, a bag's `metadata.yaml`) are read
//! up to a documented size.
//!
//! A FIFO would block the open (or the first read) until something writes to it, and a device
//! (`/dev/zero`, `/dev/urandom`) never ends: every command reads its inputs through
//! [`open_regular`], which checks the file's type before opening it, opens without blocking, and
//! checks again on the open file (the path may have been replaced in between). A directory
//! where a file is expected gets the same error, before any read.

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::Path;

use super::{format_err, io_err};
use crate::{Error, Result};

/// Largest configuration file (`--config`, TOML) read \[bytes\]: 1 MiB (every field of the
/// configuration takes a few kilobytes).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// Largest trajectory or pose file read (`--gt`, TUM, KITTI, Redwood `.log`/`.info`, 4×4
/// matrices, `bun.conf`) \[bytes\]: 256 MiB, over a million poses of a few hundred bytes.
pub const MAX_TRAJECTORY_BYTES: u64 = 256 << 20;

/// Largest rosbag2 `metadata.yaml` read \[bytes\]: 16 MiB (recorders write a few kilobytes, a
/// few hundred bytes per topic and file).
pub const MAX_METADATA_BYTES: u64 = 16 << 20;

/// "PATH: is a FIFO, not a regular file" for an input that is a directory, FIFO, device or socket.
pub(crate) fn not_a_regular_file(path: &Path, meta: &Metadata) -> Error {
    Error::InvalidInput(format!(
        "{}: is {}, not a regular file",
        path.display(),
        super::file_kind(meta)
    ))
}

/// Opens `path` for reading when it is a regular file (a symbolic link to one is followed), with
/// its metadata; never blocks and never reads from anything else.
///
/// # Errors
/// [`Error::InvalidInput`] naming `path` and what it is when it is a directory, FIFO, device or
/// socket, checked before it is opened; [`Error::Io`] naming `path` when it cannot be read.
pub fn open_regular(path: &Path) -> Result<(File, Metadata)> {
    let meta = std::fs::metadata(path).map_err(|e| io_err(path, e))?;
    if !meta.is_file() {
        return Err(not_a_regular_file(path, &meta));
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // A FIFO swapped in after the check must not block the open; on a regular file the flag
        // changes nothing.
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(|e| io_err(path, e))?;
    let meta = file.metadata().map_err(|e| io_err(path, e))?;
    if !meta.is_file() {
        return Err(not_a_regular_file(path, &meta));
    }
    Ok((file, meta))
}

/// The bytes of the regular file `path`, at most `limit` of them; `what` names the kind of file
/// in the error ("a configuration file").
///
/// # Errors
/// Those of [`open_regular`]; [`Error::Format`] naming `path` when it holds more than `limit`
/// bytes (checked on its size, and on what is read, should it grow meanwhile).
pub fn read_limited(path: &Path, limit: u64, what: &str) -> Result<Vec<u8>> {
    let (file, meta) = open_regular(path)?;
    let too_big = |n: u64| {
        format_err(
            path,
            format!(
                "holds {n} bytes, more than the {limit} bytes {what} may hold; is it the right file?"
            ),
        )
    };
    if meta.len() > limit {
        return Err(too_big(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| io_err(path, e))?;
    if bytes.len() as u64 > limit {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The text of the regular file `path`, at most `limit` bytes of UTF-8; `what` as in
/// [`read_limited`].
///
/// # Errors
/// Those of [`read_limited`]; [`Error::Format`] naming `path` and the byte offset when it is not
/// UTF-8.
pub fn read_limited_text(path: &Path, limit: u64, what: &str) -> Result<String> {
    String::from_utf8(read_limited(path, limit, what)?).map_err(|e| {
        format_err(
            path,
            format!(
                "not UTF-8 text (byte {}); {what} is text",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// The whole regular file `path` (its size bounds what is read: a file growing meanwhile is read
/// up to the size it had when opened).
///
/// # Errors
/// Those of [`open_regular`].
pub fn read_regular(path: &Path) -> Result<Vec<u8>> {
    let (file, meta) = open_regular(path)?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(meta.len())
        .read_to_end(&mut bytes)
        .map_err(|e| io_err(path, e))?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_directory_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_limited(dir.path(), 10, "a test file").unwrap_err();
        assert!(
            e.to_string().contains("is a directory, not a regular file"),
            "{e}"
        );
    }

    #[test]
    fn a_file_over_its_limit_is_refused_with_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("big.toml");
        std::fs::write(&p, [b'a'; 11]).unwrap();
        let e = read_limited(&p, 10, "a configuration file").unwrap_err();
        assert!(
            e.to_string().contains("holds 11 bytes, more than the 10"),
            "{e}"
        );
        assert_eq!(read_limited_text(&p, 11, "x").unwrap(), "a".repeat(11));
    }

    #[test]
    fn a_device_is_refused() {
        let e = read_regular(Path::new("/dev/zero")).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
    }
}
