//! Logs as damaged recordings leave them, whatever the container: cut off by a power loss or a
//! crash (no end record, index or summary; a last record or chunk that stops short), or with
//! corrupt chunks (a CRC mismatch, a compressed stream that does not decode).
//!
//! [`ReadPolicy`] says how such damage is treated and [`Damage`] reports what was found. The
//! containers salvage in their own way: MCAP in [`super::mcap::salvage`] and
//! [`super::mcap::read`], ROS 1 bags in [`super::bag::ros1`].

use std::io::Read;

/// Appends to `out` what `r`, a decompressor over the first bytes of a chunk the file cuts
/// short, yields before its stream stops or stops making sense, up to `limit` bytes in all: the
/// whole records among them are what a cut chunk gives back.
pub(crate) fn read_prefix(mut r: impl Read, limit: u64, out: &mut Vec<u8>) {
    let mut buf = vec![0u8; 1 << 16];
    while (out.len() as u64) < limit {
        match r.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
        }
    }
    out.truncate(limit as usize);
}

/// How damaged input is treated. The default salvages a cut-off log and fails on a corrupt
/// chunk.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadPolicy {
    /// A log that stops short is an error (`--strict`), as it was before salvage existed.
    pub strict: bool,
    /// A chunk whose CRC does not match or that does not decompress is skipped, and named in
    /// the damage report, instead of being an error (`--skip-corrupt`).
    pub skip_corrupt: bool,
}

impl ReadPolicy {
    /// Every damage is an error: for reading our own outputs, which are never cut.
    pub const STRICT: ReadPolicy = ReadPolicy {
        strict: true,
        skip_corrupt: false,
    };
}

/// What was wrong with an input that was read anyway.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct Damage {
    /// Size of the input in bytes.
    pub file_size: u64,
    /// Offset in bytes where the log was cut: the start of the first record that is not whole
    /// (or the end of the file when it stops between records); `None` when it was not cut.
    pub cut_at: Option<u64>,
    /// How the log stops, e.g. "the chunk at offset 4242 claims 2429226 bytes, 1000 remain".
    pub cut_reason: Option<String>,
    /// Messages recovered from the chunk that was cut (not checked by its CRC).
    pub partial_messages: u64,
    /// Corrupt chunks skipped (`--skip-corrupt`): their offsets and what was wrong.
    pub skipped_chunks: Vec<(u64, String)>,
}

impl Damage {
    /// No damage yet, for a file of `file_size` bytes.
    pub fn new(file_size: u64) -> Self {
        Self {
            file_size,
            ..Self::default()
        }
    }

    /// Whether anything was wrong.
    pub fn any(&self) -> bool {
        self.cut_at.is_some() || !self.skipped_chunks.is_empty()
    }

    /// Records that the log stops at `offset` for `reason`.
    pub fn cut(&mut self, offset: u64, reason: String) {
        self.cut_at = Some(offset);
        self.cut_reason = Some(reason);
    }

    /// One line for the summary, e.g. "the log stops at byte 1217846: the chunk at offset 1380
    /// claims 2429270 bytes, the file holds 1216457 of them; 70 messages recovered from that
    /// chunk".
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(reason) = &self.cut_reason {
            // The readers' reasons end in a guess for `--strict`'s error; here it is known.
            let reason = reason
                .trim_end_matches(" (truncated bag?)")
                .trim_end_matches(" (truncated MCAP?)");
            let mut s = format!("the log stops at byte {}: {reason}", self.file_size);
            match self.partial_messages {
                0 => {}
                1 => s += "; 1 message recovered from that chunk",
                n => s += &format!("; {n} messages recovered from that chunk"),
            }
            parts.push(s);
        }
        for (offset, what) in &self.skipped_chunks {
            parts.push(format!("corrupt chunk at offset {offset} skipped: {what}"));
        }
        parts.join("; ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn describe_says_where_and_how_many() {
        let mut d = Damage::new(1000);
        assert!(!d.any());
        d.cut(
            600,
            "record data claims 900 bytes, 300 remain (truncated bag?)".into(),
        );
        d.partial_messages = 1;
        assert_eq!(
            d.describe(),
            "the log stops at byte 1000: record data claims 900 bytes, 300 remain; \
             1 message recovered from that chunk"
        );
        d.partial_messages = 3;
        d.skipped_chunks.push((40, "CRC mismatch".into()));
        assert!(d.describe().ends_with(
            "3 messages recovered from that chunk; corrupt chunk at offset 40 skipped: CRC mismatch"
        ));
        assert!(d.any());
    }
}
