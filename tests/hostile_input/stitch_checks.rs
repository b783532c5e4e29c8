//! Finding 7 of the third round: `stitch` trusted its segments. Given out of order it kept 10
//! of 71 frames with exit 0; segments registered from another log were stitched without a word;
//! `map` failed on any stitch output (no `voxel_m` in its metadata). Now segments are sorted
//! into log order, every stitched frame must be a cloud of the given log on the segments' topic,
//! and the output records the segments' voxel.

use super::*;
use mireg::register::{WindowBound, stitch};

/// `log` registered over frames `start..end` (without loops) into `dir/name`.
fn segment(dir: &Path, log: &Path, name: &str, start: u64, end: u64) -> PathBuf {
    let out = dir.join(name);
    let mut opts = options(log, &out);
    opts.start = Some(WindowBound::Frame(start));
    opts.end = Some(WindowBound::Frame(end));
    opts.loops = false;
    register_log(&opts).unwrap();
    out
}

#[test]
fn stitch_sorts_its_segments_refuses_another_logs_and_records_the_voxel() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let log = d.join("log.mcap");
    std::fs::write(&log, small(10)).unwrap();
    let a = segment(d, &log, "a.mcap", 0, 6);
    let b = segment(d, &log, "b.mcap", 4, 10);

    // Out of order: sorted, all ten frames kept.
    let out = d.join("stitched.mcap");
    let s = stitch(&log, &[b.clone(), a.clone()], &out, false, "test", false).unwrap();
    assert_eq!((s.frames, s.segments), (10, 2));

    // `map` works on the output: the voxel is in its metadata.
    let map = d.join("map.ply");
    let run = mireg(&["map", out.to_str().unwrap(), "-o", map.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    assert!(map.exists());

    // Segments of another log (the same scene, 4 frames, other log times) are refused.
    let other = d.join("other.mcap");
    std::fs::write(
        &other,
        small_log(
            4,
            mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
        ),
    )
    .unwrap();
    let m = messages(&other);
    let shifted: Vec<(u16, u64, Vec<u8>)> = m
        .messages
        .iter()
        .map(|(c, t, data)| (*c, t + 7, data.clone()))
        .collect();
    let moved = Messages {
        channels: m.channels.clone(),
        messages: shifted,
    };
    let order: Vec<usize> = (0..moved.messages.len()).collect();
    std::fs::write(&other, rewrite(&moved, &order, mcap::WriteOptions::new())).unwrap();
    let out2 = d.join("wrong.mcap");
    let e = stitch(&other, &[a.clone(), b.clone()], &out2, false, "test", false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("a.mcap") && e.contains("another log"), "{e}");
    assert!(!out2.exists());
}

/// Segments of another log with the same clouds on the same topic at the same log times (the
/// same recording, re-exported with one other message changed) passed every check of topic and
/// stamps; they are now refused by the log's content fingerprint, which `register` records.
#[test]
fn stitch_refuses_segments_of_a_log_with_the_same_stamps_but_other_content() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let log = d.join("log.mcap");
    std::fs::write(&log, small(8)).unwrap();
    let a = segment(d, &log, "a.mcap", 0, 5);
    let b = segment(d, &log, "b.mcap", 3, 8);
    // The same log stitches.
    let ok = d.join("ok.mcap");
    stitch(&log, &[a.clone(), b.clone()], &ok, false, "test", false).unwrap();
    // Its twin: every message and stamp the same but one note's text.
    let mut m = messages(&log);
    let note = m
        .messages
        .iter()
        .position(|(c, _, _)| m.channels[c].0 == "/notes")
        .unwrap();
    m.messages[note].2 = br#"{"k":9}"#.to_vec();
    let order: Vec<usize> = (0..m.messages.len()).collect();
    let twin = d.join("twin.mcap");
    std::fs::write(
        &twin,
        rewrite(
            &m,
            &order,
            mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
        ),
    )
    .unwrap();
    let out = d.join("wrong.mcap");
    let e = stitch(&twin, &[a, b], &out, false, "test", false)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a.mcap") && e.contains("twin.mcap") && e.contains("another log"),
        "{e}"
    );
    assert!(!out.exists());
}
