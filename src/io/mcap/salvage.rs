//! MCAP logs as damaged recordings leave them ([`crate::io::damage`]): cut off by a power loss
//! or a crash (no data-end record, footer or summary; a last record or chunk that stops short), or
//! with corrupt chunks (a CRC mismatch, a compressed stream that does not decode).
//!
//! A cut-off log is read up to its last complete record; the records of a chunk that was being
//! written when the file stops are recovered from the compressed bytes that reached the disk
//! (zstd and lz4 decode block by block; uncompressed chunks are their records) up to the last
//! whole record. Those records cannot be checked against the chunk's CRC, which covers the whole
//! chunk: [`Damage::partial_messages`] counts them. [`ReadPolicy::strict`] makes a cut an error;
//! [`ReadPolicy::skip_corrupt`] skips a corrupt chunk (naming it in [`Damage::skipped_chunks`])
//! instead of failing.
//!
//! [`Damage::partial_messages`]: crate::io::damage::Damage::partial_messages
//! [`Damage::skipped_chunks`]: crate::io::damage::Damage::skipped_chunks
//! [`ReadPolicy::strict`]: crate::io::damage::ReadPolicy::strict
//! [`ReadPolicy::skip_corrupt`]: crate::io::damage::ReadPolicy::skip_corrupt

use mcap::records::ChunkHeader;

use crate::io::damage::read_prefix;

/// The uncompressed bytes that `data`, the first bytes of a chunk's compressed records, decode
/// to, at most `header.uncompressed_size` (and [`crate::io::MAX_CHUNK_BYTES`]): everything up to
/// where the stream stops or stops making sense. Unknown compressions give nothing.
pub fn decompress_prefix(header: &ChunkHeader, data: &[u8]) -> Vec<u8> {
    let limit = header
        .uncompressed_size
        .min(crate::io::MAX_CHUNK_BYTES)
        .min(crate::io::expansion_limit(data.len() as u64));
    let mut out = Vec::new();
    match header.compression.as_str() {
        "" => read_prefix(data, limit, &mut out),
        "zstd" => {
            if let Ok(d) = zstd::stream::read::Decoder::with_buffer(data) {
                read_prefix(d, limit, &mut out);
            }
        }
        "lz4" => {
            if let Ok(d) = lz4::Decoder::new(data) {
                read_prefix(d, limit, &mut out);
            }
        }
        _ => {}
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(compression: &str, size: u64) -> ChunkHeader {
        ChunkHeader {
            message_start_time: 0,
            message_end_time: 0,
            uncompressed_size: size,
            uncompressed_crc: 0,
            compression: compression.into(),
            compressed_size: 0,
        }
    }

    /// Data that compresses but not to nothing: 4 MiB of a slow pattern.
    fn data() -> Vec<u8> {
        (0..4u32 << 20)
            .map(|i| ((i / 3) ^ (i / 1000)) as u8)
            .collect()
    }

    /// `z`, `data` compressed by `compression`, decodes to `data` whole, and its first half to
    /// more than a quarter of `data` but not all of it, a prefix of it.
    fn assert_halves_give_a_prefix(compression: &str, z: &[u8], data: &[u8]) {
        let h = header(compression, data.len() as u64);
        assert_eq!(decompress_prefix(&h, z), data);
        let got = decompress_prefix(&h, &z[..z.len() / 2]);
        assert!(
            got.len() > data.len() / 4,
            "{} of {}",
            got.len(),
            data.len()
        );
        assert!(got.len() < data.len());
        assert_eq!(got[..], data[..got.len()]);
    }

    #[test]
    fn a_cut_zstd_stream_gives_a_prefix_of_its_data() {
        let data = data();
        let z = zstd::bulk::compress(&data, 1).unwrap();
        assert_halves_give_a_prefix("zstd", &z, &data);
    }

    #[test]
    fn a_cut_lz4_frame_gives_a_prefix_of_its_data() {
        let data = data();
        let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
        std::io::Write::write_all(&mut enc, &data).unwrap();
        let (z, r) = enc.finish();
        r.unwrap();
        assert_halves_give_a_prefix("lz4", &z, &data);
    }

    #[test]
    fn uncompressed_prefixes_are_themselves_and_limits_hold() {
        let data = data();
        assert_eq!(
            decompress_prefix(&header("", 100), &data[..1000]),
            data[..100]
        );
        assert_eq!(
            decompress_prefix(&header("", 5000), &data[..1000]),
            data[..1000]
        );
        assert!(decompress_prefix(&header("brotli", 5000), &data[..1000]).is_empty());
    }
}
