//! Findings 6–12: re-registration, decompression bombs, message indexes, clouds, order, sizes,
//! messages.

use super::*;

// ---------------------------------------------------------------------------------------------
// Findings 6–8: re-registration, decompression bombs, message indexes
// ---------------------------------------------------------------------------------------------

/// Registering a mireg output again added a second set of messages to `/mireg/pose` and
/// `/mireg/stats`; `export` then wrote two lines per frame.
#[test]
fn registering_an_output_again_keeps_the_runs_apart() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.mcap");
    std::fs::write(&log, small(3)).unwrap();
    let (a, b) = (dir.path().join("a1.mcap"), dir.path().join("a2.mcap"));
    register_log(&options(&log, &a)).unwrap();
    let s = register_log(&options(&a, &b)).unwrap();
    assert_eq!(s.pose_topic, "/mireg_2/pose");
    let m = messages(&b);
    let count = |topic: &str| {
        m.messages
            .iter()
            .filter(|(c, _, _)| m.channels[c].0 == topic)
            .count()
    };
    for t in [
        "/mireg/pose",
        "/mireg/stats",
        "/mireg_2/pose",
        "/mireg_2/stats",
    ] {
        assert_eq!(count(t), 3, "{t}");
    }
    let run = mireg(&["export", b.to_str().unwrap(), "--format", "tum"]);
    assert_eq!(String::from_utf8_lossy(&run.stdout).lines().count(), 3);
    let run = mireg(&["evaluate", b.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["frames"], 3, "{v}");
}

/// A 68 KB log (one chunk of 2 GiB of zeros) took 2.1 GB of memory. A chunk claiming more than
/// the limit is refused before anything is allocated; one that lies about its size (claims
/// 1 MiB, holds 64 MiB of zeros) never decompresses past its claim.
#[test]
fn decompression_bomb_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let base = small_log(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
    );
    let bomb = dir.path().join("bomb.mcap");
    let out = dir.path().join("out.mcap");
    let claim = mireg::io::MAX_CHUNK_BYTES + 1;
    std::fs::write(
        &bomb,
        mireg::fuzzing::with_first_chunk(&base, &mireg::fuzzing::zstd_zero_chunk(1 << 20, claim)),
    )
    .unwrap();
    let e = register_log(&options(&bomb, &out)).unwrap_err().to_string();
    assert!(
        e.contains("bomb.mcap") && e.contains("more than the limit"),
        "{e}"
    );
    let e = for_each_record(&bomb, |_| Ok(())).unwrap_err().to_string();
    assert!(e.contains("more than the limit"), "{e}");
    std::fs::write(
        &bomb,
        mireg::fuzzing::with_first_chunk(
            &base,
            &mireg::fuzzing::zstd_zero_chunk(64 << 20, 1 << 20),
        ),
    )
    .unwrap();
    let (r, largest) = largest_allocation(|| for_each_record(&bomb, |_| Ok(())));
    assert!(
        largest <= 2 << 20,
        "allocated {largest} bytes at once for a 1 MiB claim"
    );
    let e = r.unwrap_err().to_string();
    assert!(e.contains("zstd decompression failed"), "{e}");
    assert!(register_log(&options(&bomb, &out)).is_err());
    assert!(!out.exists());
}

/// Message index records were copied unchecked: one flipped byte gave an output whose index
/// pointed 68 GB past its chunk.
#[test]
fn corrupt_message_index_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let base = small(3);
    let out = dir.path().join("out.mcap");
    let input = dir.path().join("bad_index.mcap");
    let (at, _, _) = top_level_records(&base)
        .into_iter()
        .find(|r| r.1 == mcap::records::op::MESSAGE_INDEX)
        .unwrap();
    // channel id (2), byte length of the entries (4), first entry: log time (8), offset (8)
    for (field, at) in [("offset", at + 9 + 6 + 8 + 4), ("log time", at + 9 + 6 + 3)] {
        let mut b = base.clone();
        b[at] ^= 0x10;
        std::fs::write(&input, &b).unwrap();
        let e = register_log(&options(&input, &out))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad_index.mcap") && e.contains("message index"),
            "{field}: {e}"
        );
        assert!(!out.exists());
    }
}

// ---------------------------------------------------------------------------------------------
// Findings 9–12: clouds, order, sizes, messages
// ---------------------------------------------------------------------------------------------

/// One undecodable cloud (no `y` field) ended the run with exit code 2; now it is one flagged
/// frame and the others are registered.
#[test]
fn an_undecodable_cloud_is_one_flagged_frame() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    std::fs::write(&good, small(5)).unwrap();
    let mut m = messages(&good);
    let clouds: Vec<usize> = (0..m.messages.len())
        .filter(|&i| m.channels[&m.messages[i].0].0 == "/points")
        .collect();
    // Rename the field "y" (CDR string: length 2, "y\0") of the third cloud.
    let payload = &mut m.messages[clouds[2]].2;
    let at = payload
        .windows(6)
        .position(|w| w == [2, 0, 0, 0, b'y', 0])
        .unwrap();
    payload[at + 4] = b'q';
    let bad = dir.path().join("bad.mcap");
    std::fs::write(
        &bad,
        rewrite(
            &m,
            &(0..m.messages.len()).collect::<Vec<_>>(),
            mcap::WriteOptions::new(),
        ),
    )
    .unwrap();
    let out = dir.path().join("out.mcap");
    let s = register_log(&options(&bad, &out)).unwrap();
    assert_eq!((s.frames, s.failed_frames), (5, 1));
    let st = stats(&out);
    assert_eq!(st[2]["failure_reason"], "invalid_cloud");
    let detail = st[2]["failure_detail"].as_str().unwrap();
    assert!(
        detail.contains("/points") && detail.contains("y"),
        "{detail}"
    );
    assert!(
        st.iter()
            .enumerate()
            .all(|(k, v)| (k == 2) != v["success"].as_bool().unwrap())
    );
}

/// 40 clouds in reverse log-time order, with no summary to prove the order, were registered in
/// file order without a word. Now: an error naming both log times; a window as large as the
/// disorder registers them in log-time order.
#[test]
fn clouds_out_of_order_beyond_the_window_are_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    std::fs::write(&good, small(20)).unwrap();
    let m = messages(&good);
    let order: Vec<usize> = (0..m.messages.len()).rev().collect();
    let reversed = dir.path().join("reversed.mcap");
    std::fs::write(
        &reversed,
        rewrite(
            &m,
            &order,
            mcap::WriteOptions::new()
                .emit_summary_records(false)
                .emit_summary_offsets(false),
        ),
    )
    .unwrap();
    let out = dir.path().join("out.mcap");
    let e = register_log(&options(&reversed, &out))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("reversed.mcap") && e.contains("out of log-time order"),
        "{e}"
    );
    assert!(e.contains("--reorder-window"), "{e}");
    assert!(!out.exists());
    let mut opts = options(&reversed, &out);
    opts.reorder_window = 20;
    let s = register_log(&opts).unwrap();
    assert_eq!(s.frames, 20);
    let stamps: Vec<i64> = stats(&out)
        .iter()
        .map(|v| v["stamp_ns"].as_i64().unwrap())
        .collect();
    assert!(stamps.windows(2).all(|w| w[0] < w[1]), "{stamps:?}");
}

/// Two clouds of 5 M points took 6.2 GB and over 400 s. A cloud over the bound is flagged
/// `too_many_points` without being prepared.
#[test]
fn a_cloud_over_the_point_bound_is_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.mcap");
    std::fs::write(&log, small(3)).unwrap();
    let out = dir.path().join("out.mcap");
    let mut opts = options(&log, &out);
    opts.max_points_per_cloud = 1000;
    let s = register_log(&opts).unwrap();
    assert_eq!(s.failed_frames, 3);
    for v in stats(&out) {
        assert_eq!(v["failure_reason"], "too_many_points", "{v}");
        assert!(
            v["failure_detail"]
                .as_str()
                .unwrap()
                .contains("--max-points")
        );
    }
}

/// The unclear messages of finding 12, one by one.
#[test]
fn errors_say_what_is_wrong_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    // Shorter than an MCAP header: said "Invalid argument (os error 22)" twice.
    let short = dir.path().join("short.mcap");
    std::fs::write(&short, b"\x89MCAP0\r\n").unwrap();
    let run = mireg(&["register", short.to_str().unwrap()]);
    let e = stderr(&run);
    assert!(
        e.contains("not an MCAP file") && !e.contains("os error"),
        "{e}"
    );
    // A directory: said "input MCAP not found" twice.
    let run = mireg(&["register", d]);
    let e = stderr(&run);
    assert!(
        e.contains("is a directory") && e.matches("directory").count() == 2,
        "{e}"
    );
    // A missing file: says so once, and what is accepted.
    let run = mireg(&["register", &format!("{d}/missing.mcap")]);
    let e = stderr(&run);
    assert_eq!(e.matches("no such file").count(), 1, "{e}");
    assert!(e.contains(".mcap"), "{e}");
    // --min-fitness nan disabled the check.
    let log = dir.path().join("a.mcap");
    std::fs::write(&log, small(2)).unwrap();
    let run = mireg(&["register", log.to_str().unwrap(), "--min-fitness", "nan"]);
    assert_eq!(run.status.code(), Some(2));
    assert!(stderr(&run).contains("fraction"), "{}", stderr(&run));
    // Two channels on one topic listed it twice ("/points, /points") and refused the log.
    let mut m = messages(&log);
    let (&id, ch) = m.channels.iter().find(|(_, c)| c.0 == "/points").unwrap();
    let twin = m.channels.keys().max().unwrap() + 1;
    let ch = ch.clone();
    m.channels.insert(twin, ch);
    let second = m.messages.iter().position(|x| x.0 == id).unwrap();
    let last = m.messages.iter().rposition(|x| x.0 == id).unwrap();
    assert_ne!(second, last);
    m.messages[last].0 = twin;
    let two = dir.path().join("two.mcap");
    std::fs::write(
        &two,
        rewrite(
            &m,
            &(0..m.messages.len()).collect::<Vec<_>>(),
            mcap::WriteOptions::new(),
        ),
    )
    .unwrap();
    let s = register_log(&options(&two, &dir.path().join("two_out.mcap"))).unwrap();
    assert_eq!((s.topic.as_str(), s.frames), ("/points", 2));
    // A chunk inside a chunk was accepted.
    let base = small_log(2, mcap::WriteOptions::new().compression(None));
    let (at, _, len) = top_level_records(&base)
        .into_iter()
        .find(|r| r.1 == mcap::records::op::CHUNK)
        .unwrap();
    let chunk = &base[at..at + 9 + len];
    let mut outer_records = chunk.to_vec();
    outer_records.extend(mcap_message_record());
    let nested = dir.path().join("nested.mcap");
    let mut body = Vec::new();
    body.extend([0u8; 16]);
    body.extend((outer_records.len() as u64).to_le_bytes());
    body.extend(0u32.to_le_bytes());
    body.extend(0u32.to_le_bytes());
    body.extend((outer_records.len() as u64).to_le_bytes());
    body.extend(&outer_records);
    let mut rec = vec![mcap::records::op::CHUNK];
    rec.extend((body.len() as u64).to_le_bytes());
    rec.extend(body);
    std::fs::write(&nested, mireg::fuzzing::with_first_chunk(&base, &rec)).unwrap();
    let e = for_each_record(&nested, |_| Ok(()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("may not appear inside a chunk"), "{e}");
    let e = register_log(&options(&nested, &dir.path().join("n.mcap")))
        .unwrap_err()
        .to_string();
    assert!(e.contains("may not appear inside a chunk"), "{e}");
}

/// A message record on channel 1 (any payload), for hand-made chunks.
fn mcap_message_record() -> Vec<u8> {
    let mut r = vec![mcap::records::op::MESSAGE];
    r.extend(22u64.to_le_bytes());
    r.extend(1u16.to_le_bytes());
    r.extend([0u8; 20]);
    r
}

/// `mireg pair` exited 0 after "registration FAILED": now 1, with the result still printed.
#[test]
fn a_failed_pair_registration_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = dir.path().join("two.bin");
    // Two points: too few to register.
    let pts: Vec<u8> = [0.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(&cloud, pts).unwrap();
    let c = cloud.to_str().unwrap();
    let run = mireg(&["pair", c, c, "--voxel", "0.1"]);
    assert_eq!(run.status.code(), Some(1), "{}", stderr(&run));
    assert!(String::from_utf8_lossy(&run.stdout).contains("registration FAILED"));
    assert!(stderr(&run).contains("registration failed"));
}
