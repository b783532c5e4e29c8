use super::*;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};

/// A log written into reserved space larger than what it ends up holding, with its disk
/// writes started on the way: the file is cut to its records, which read back unchanged with
/// the mcap crate's reader (chunk, data-section and summary CRCs checked).
#[test]
fn reserved_space_and_early_writeback_leave_an_exact_log() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.mcap");
    let mut log = OutputLog::create(&target, false, "x").unwrap();
    let reserved = 4 * WRITEBACK_STEP;
    log.reserve(reserved).unwrap();
    if cfg!(all(target_os = "linux", target_env = "gnu")) {
        // tmpfs and ext4 both preallocate; the cut at the end is then exercised.
        let file = log.w().get_ref().get_ref().metadata().unwrap();
        assert_eq!(file.len(), reserved);
    }
    let ch = log
        .add_channel("/blob", "", "", &[], "application/octet-stream")
        .unwrap();
    // Incompressible payloads (xorshift), so that the file passes several writeback steps.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut payloads = Vec::new();
    for k in 0..24u64 {
        let data: Vec<u8> = (0..1 << 20)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state as u8
            })
            .collect();
        log.write(ch, k, k, &data).unwrap();
        log.write_behind().unwrap();
        payloads.push(data);
    }
    let requested = log.writeback.as_ref().map_or(0, |w| w.requested);
    assert!(
        requested >= 2 * WRITEBACK_STEP,
        "handed on {requested} bytes"
    );
    log.start_writeback().unwrap();
    log.write_behind().unwrap(); // after the data sync was requested: nothing more to do
    log.finish().unwrap();

    let bytes = std::fs::read(&target).unwrap();
    assert!((bytes.len() as u64) < reserved);
    assert!(bytes.ends_with(mcap::MAGIC));
    let summary = mcap::Summary::read(&bytes).unwrap().expect("summary");
    assert_eq!(summary.stats.as_ref().unwrap().message_count, 24);
    let read: Vec<Vec<u8>> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap().data.into_owned())
        .collect();
    assert!(read == payloads, "payloads differ");
    let mut reader = LinearReader::new_with_options(
        mcap::sans_io::LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true),
    );
    let mut rest = &bytes[..];
    while let Some(e) = reader.next_event() {
        if let LinearReadEvent::ReadRequest(need) = e.unwrap() {
            let n = need.min(rest.len());
            reader.insert(n).copy_from_slice(&rest[..n]);
            reader.notify_read(n);
            rest = &rest[n..];
        }
    }
}
