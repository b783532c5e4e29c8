//! Parsing one MCAP record body safely: every length-prefixed string inside it is checked
//! against the bytes left in the body before the mcap crate's parser sees it.
//!
//! The mcap crate reads a string by reserving its declared length first (binrw's `count`), so a
//! 60-byte attachment record whose name claims 4 GiB allocates 4 GiB (found by the `mcap_records`
//! fuzz target). [`parse_record`] walks the record's layout (MCAP specification, "Records")
//! and refuses such a record with a plain description; the caller adds file and offset.

use mcap::records::{Record, op};

/// The fields of a record layout, in order.
#[derive(Clone, Copy)]
enum Field {
    /// A fixed number of bytes.
    Fixed(usize),
    /// A `uint32` length and that many bytes (a string or a byte array).
    Str,
    /// A `uint32` byte length and key/value string pairs filling it.
    StrMap,
    /// A `uint32` byte length and fixed-size entries filling it.
    Entries,
    /// A `uint64` length and that many bytes.
    Data64,
    /// Everything left (message data, schema data after its own length check).
    Rest,
}

use Field::{Data64, Entries, Fixed, Rest, Str, StrMap};

/// The layout of the records whose strings the mcap crate reads; `None` for records without
/// strings (messages, message indexes, footers, …) or of unknown opcodes.
fn layout(opcode: u8) -> Option<&'static [Field]> {
    Some(match opcode {
        op::HEADER => &[Str, Str],
        op::SCHEMA => &[Fixed(2), Str, Str, Rest],
        op::CHANNEL => &[Fixed(4), Str, Str, StrMap],
        op::CHUNK => &[Fixed(28), Str, Rest],
        op::CHUNK_INDEX => &[Fixed(32), Entries, Fixed(8), Str, Fixed(16)],
        op::ATTACHMENT => &[Fixed(16), Str, Str, Data64, Fixed(4)],
        op::ATTACHMENT_INDEX => &[Fixed(40), Str, Str],
        op::STATISTICS => &[Fixed(42), Entries],
        op::METADATA => &[Str, StrMap],
        op::METADATA_INDEX => &[Fixed(16), Str],
        _ => return None,
    })
}

fn u32_at(body: &[u8], at: usize) -> Option<usize> {
    let b = body.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes(b.try_into().expect("4 bytes")) as usize)
}

/// Fails when a length inside the record body runs past its end.
pub fn check_lengths(opcode: u8, body: &[u8]) -> Result<(), String> {
    let Some(fields) = layout(opcode) else {
        return Ok(());
    };
    let short = |what: &str, at: usize| {
        Err(format!(
            "record (opcode 0x{opcode:02x}) of {} bytes: {what} at byte {at} runs past its end",
            body.len()
        ))
    };
    let mut at = 0usize;
    for f in fields {
        match *f {
            Fixed(n) => {
                if body.len() - at.min(body.len()) < n {
                    return short("a fixed field", at);
                }
                at += n;
            }
            Str | Entries => {
                let Some(n) = u32_at(body, at) else {
                    return short("a length", at);
                };
                if body.len() - at - 4 < n {
                    return short(
                        if matches!(f, Str) {
                            "a string"
                        } else {
                            "a table"
                        },
                        at,
                    );
                }
                at += 4 + n;
            }
            StrMap => {
                let Some(n) = u32_at(body, at) else {
                    return short("a map length", at);
                };
                let end = at + 4;
                if body.len() - end < n {
                    return short("a map", at);
                }
                // Key and value strings, in pairs: the parser reads a value after every key,
                // even one that ends the map.
                let (mut k, stop, mut strings) = (end, end + n, 0usize);
                while k < stop {
                    match u32_at(body, k) {
                        Some(len) if stop - (k + 4).min(stop) >= len => k += 4 + len,
                        _ => return short("a map string", k),
                    }
                    strings += 1;
                }
                if strings % 2 == 1 {
                    return short("a map key without a value", k);
                }
                at = stop;
            }
            Data64 => {
                let Some(b) = body.get(at..at + 8) else {
                    return short("a length", at);
                };
                let n = u64::from_le_bytes(b.try_into().expect("8 bytes"));
                if ((body.len() - at - 8) as u64) < n {
                    return short("a byte array", at);
                }
                at += 8 + n as usize;
            }
            Rest => return Ok(()),
        }
    }
    Ok(())
}

/// [`mcap::parse_record`] after [`check_lengths`]; errors are plain descriptions.
pub fn parse_record(opcode: u8, body: &[u8]) -> Result<Record<'_>, String> {
    check_lengths(opcode, body)?;
    mcap::parse_record(opcode, body).map_err(|e| format!("bad record (opcode 0x{opcode:02x}): {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &[u8]) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend(s);
        v
    }

    fn metadata(name: &[u8], pairs: &[(&[u8], &[u8])]) -> Vec<u8> {
        let mut map = Vec::new();
        for (k, v) in pairs {
            map.extend(string(k));
            map.extend(string(v));
        }
        let mut b = string(name);
        b.extend((map.len() as u32).to_le_bytes());
        b.extend(map);
        b
    }

    #[test]
    fn valid_records_parse_and_lying_lengths_are_refused_before_parsing() {
        let good = metadata(b"robot", &[(b"id", b"r2"), (b"k", b"")]);
        match parse_record(op::METADATA, &good).unwrap() {
            Record::Metadata(m) => assert_eq!(m.metadata["id"], "r2"),
            r => panic!("{r:?}"),
        }
        // Every length field set to 4 GiB − 1 in turn: refused, never parsed.
        for at in [0usize, 9, 13, 19, 24] {
            let mut bad = good.clone();
            bad[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
            let e = parse_record(op::METADATA, &bad).unwrap_err();
            assert!(e.contains("runs past its end"), "{at}: {e}");
        }
        // An attachment whose name claims 4 GiB (the fuzzer's finding).
        let mut att = vec![0u8; 16];
        att.extend(u32::MAX.to_le_bytes());
        att.extend([0u8; 40]);
        assert!(check_lengths(op::ATTACHMENT, &att).is_err());
        // A map whose last key has no value inside the map (the parser would read the value's
        // length from the bytes after it: the fuzzer's second out-of-memory).
        let mut odd = string(b"robot");
        odd.extend(6u32.to_le_bytes());
        odd.extend(string(b"id"));
        odd.extend(u32::MAX.to_le_bytes());
        assert!(check_lengths(op::METADATA, &odd).is_err());
        // An attachment whose data leaves no room for its CRC (the mcap crate's parser panicked
        // on it: the mcap_records fuzz target).
        let mut att = vec![0u8; 16];
        att.extend(0u32.to_le_bytes());
        att.extend(0u32.to_le_bytes());
        att.extend(2u64.to_le_bytes());
        att.extend([7, 7]);
        assert!(check_lengths(op::ATTACHMENT, &att).is_err());
        att.extend(0u32.to_le_bytes());
        assert!(matches!(
            parse_record(op::ATTACHMENT, &att),
            Ok(Record::Attachment { .. })
        ));
        // Truncated fixed parts.
        assert!(check_lengths(op::STATISTICS, &[0u8; 10]).is_err());
        assert!(check_lengths(op::CHANNEL, &[0u8; 3]).is_err());
        // Records without strings and unknown opcodes are left to the parser.
        assert!(check_lengths(op::MESSAGE, &[]).is_ok());
        assert!(check_lengths(0x80, &[1, 2, 3]).is_ok());
    }
}
