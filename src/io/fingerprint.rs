//! The content fingerprint of an input log: what `register` records of the log it read
//! (`input_fingerprint` in its `mireg` metadata) and `stitch` compares with the log it is given,
//! so that a segment registered from another log — even one with the same name, size, topic and
//! stamps — is refused.
//!
//! The fingerprint is the CRC-32 of the log's size and of [`BLOCKS`] blocks of [`BLOCK_BYTES`]
//! spread evenly over it, first and last included (the whole file when it is smaller than
//! that): a few MiB read whatever the log's size, so that each of many segment runs of one long
//! log pays little for it. For a ROS 2 bag directory, its `metadata.yaml` and storage files
//! (`.mcap`, `.db3`, compressed `.zstd`) by name, each with its name and size.

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use super::io_err;
use crate::Result;

/// Blocks read from each file (default and only value: 64).
pub const BLOCKS: u64 = 64;

/// Bytes per block (default and only value: 64 KiB).
pub const BLOCK_BYTES: u64 = 64 << 10;

/// The fingerprint of the log at `path` (a file, or a ROS 2 bag directory), as
/// `SIZE-CRC32` in hex: the total bytes of the files read, and their sampled CRC.
///
/// # Errors
/// [`crate::Error::Io`] naming the file that cannot be read.
pub fn content_fingerprint(path: &Path) -> Result<String> {
    let mut crc = crc32fast::Hasher::new();
    let mut total = 0u64;
    if path.is_dir() {
        let mut files: Vec<_> = std::fs::read_dir(path)
            .map_err(|e| io_err(path, e))?
            .filter_map(|e| e.ok())
            .map(|e| e.path())
            .filter(|p| {
                let name = p.file_name().map(|n| n.to_string_lossy().into_owned());
                name.is_some_and(|n| {
                    n == "metadata.yaml"
                        || [".mcap", ".db3", ".zstd"].iter().any(|x| n.ends_with(x))
                }) && p.is_file()
            })
            .collect();
        files.sort();
        for f in files {
            let name = f.file_name().expect("listed by name");
            crc.update(name.as_encoded_bytes());
            total += sample_file(&f, &mut crc)?;
        }
    } else {
        total = sample_file(path, &mut crc)?;
    }
    Ok(format!("{total}-{:08x}", crc.finalize()))
}

/// Feeds the size of the file at `path` and its sampled blocks into `crc`; returns the size.
fn sample_file(path: &Path, crc: &mut crc32fast::Hasher) -> Result<u64> {
    let (mut file, meta) = super::input_file::open_regular(path)?;
    let size = meta.len();
    crc.update(&size.to_le_bytes());
    let mut buf = vec![0u8; BLOCK_BYTES as usize];
    let starts: Vec<u64> = if size <= BLOCKS * BLOCK_BYTES {
        (0..size.div_ceil(BLOCK_BYTES))
            .map(|k| k * BLOCK_BYTES)
            .collect()
    } else {
        let last = u128::from(size - BLOCK_BYTES);
        (0..BLOCKS)
            .map(|k| (last * u128::from(k) / u128::from(BLOCKS - 1)) as u64)
            .collect()
    };
    for start in starts {
        let n = BLOCK_BYTES.min(size - start) as usize;
        file.seek(SeekFrom::Start(start))
            .and_then(|_| file.read_exact(&mut buf[..n]))
            .map_err(|e| io_err(path, e))?;
        crc.update(&buf[..n]);
    }
    Ok(size)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One changed byte anywhere in a small file, or in a sampled block of a large one, changes
    /// the fingerprint; the same bytes under another name do not.
    #[test]
    fn a_changed_byte_changes_the_fingerprint() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
        for size in [1000usize, (BLOCKS * BLOCK_BYTES) as usize * 3] {
            let bytes: Vec<u8> = (0..size).map(|i| (i * 7 % 251) as u8).collect();
            std::fs::write(&a, &bytes).unwrap();
            std::fs::write(&b, &bytes).unwrap();
            let fa = content_fingerprint(&a).unwrap();
            assert_eq!(fa, content_fingerprint(&b).unwrap());
            assert!(fa.starts_with(&format!("{size}-")), "{fa}");
            for at in [0, size / 2, size - 1] {
                let mut changed = bytes.clone();
                changed[at] ^= 1;
                // In a large file: the first byte, the last, and one inside the middle block.
                let at = if size > 1000 && at == size / 2 {
                    let block = (size as u64 - BLOCK_BYTES) * (BLOCKS / 2) / (BLOCKS - 1);
                    changed[at] ^= 1;
                    changed[block as usize + 5] ^= 1;
                    block as usize + 5
                } else {
                    at
                };
                std::fs::write(&b, &changed).unwrap();
                assert_ne!(fa, content_fingerprint(&b).unwrap(), "byte {at} of {size}");
            }
        }
    }
}
