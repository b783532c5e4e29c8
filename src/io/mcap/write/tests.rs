use super::*;

fn channel(id: u16, schema_id: u16, topic: &str) -> Channel {
    Channel {
        id,
        schema_id,
        topic: topic.into(),
        message_encoding: "json".into(),
        metadata: BTreeMap::from([("k".to_string(), "v".to_string())]),
    }
}

/// The definition checks that both the writer and the input readers use.
#[test]
fn schema_and_channel_checks() {
    let mut w = McapWriter::new(Vec::new(), Path::new("t.mcap"), "x", "test", 1, 64).unwrap();
    let schema = |name: &str| SchemaRecord {
        name: name.into(),
        encoding: "jsonschema".into(),
        data: b"{}".to_vec(),
    };
    assert!(w.check_schema(0, &schema("S")).is_err());
    assert_eq!(w.check_schema(7, &schema("S")), Ok(false));
    assert!(
        w.check_channel(&channel(1, 7, "/a")).is_err(),
        "schema 7 undefined"
    );
    w.define_schema(7, schema("S"), false).unwrap();
    assert_eq!(w.check_schema(7, &schema("S")), Ok(true));
    assert!(w.check_schema(7, &schema("T")).is_err());
    assert_eq!(w.check_channel(&channel(1, 7, "/a")), Ok(false));
    assert_eq!(w.check_channel(&channel(2, 0, "/schemaless")), Ok(false));
    w.define_channel(channel(1, 7, "/a"), false).unwrap();
    assert_eq!(w.check_channel(&channel(1, 7, "/a")), Ok(true));
    assert!(w.check_channel(&channel(1, 7, "/b")).is_err());
}

/// A file from every kind of record, read back by the `mcap` crate's own readers.
#[test]
fn written_files_read_back_with_the_mcap_crate() {
    let mut w = McapWriter::new(Vec::new(), Path::new("t.mcap"), "x", "test", 1, 64).unwrap();
    let schema = SchemaRecord {
        name: "S".into(),
        encoding: "jsonschema".into(),
        data: b"{}".to_vec(),
    };
    w.define_schema(7, schema.clone(), true).unwrap();
    w.define_schema(7, schema, true).unwrap(); // same again: fine
    assert!(
        w.define_schema(
            7,
            SchemaRecord {
                name: "T".into(),
                encoding: "jsonschema".into(),
                data: vec![],
            },
            true
        )
        .is_err()
    );
    assert!(w.define_channel(channel(1, 9, "/bad"), true).is_err());
    w.define_channel(channel(3, 7, "/a"), true).unwrap();
    w.define_channel(channel(9, 0, "/b"), true).unwrap();
    for k in 0..20u64 {
        let header = MessageHeader {
            channel_id: if k % 3 == 0 { 9 } else { 3 },
            sequence: k as u32,
            log_time: 100 - k,
            publish_time: k,
        };
        w.message(&header, format!("{{\"k\":{k}}}").as_bytes())
            .unwrap();
    }
    w.metadata(&Metadata {
        name: "m".into(),
        metadata: BTreeMap::from([("a".to_string(), "b".to_string())]),
    })
    .unwrap();
    w.attachment(
        &AttachmentHeader {
            log_time: 1,
            create_time: 2,
            name: "att".into(),
            media_type: "text/plain".into(),
        },
        b"hello",
    )
    .unwrap();
    let bytes = w.finish().unwrap();

    let summary = mcap::Summary::read(&bytes).unwrap().expect("summary");
    let stats = summary.stats.as_ref().unwrap();
    assert_eq!(stats.message_count, 20);
    assert_eq!(stats.channel_message_counts[&9], 7);
    assert_eq!(stats.channel_message_counts[&3], 13);
    assert_eq!(
        (stats.message_start_time, stats.message_end_time),
        (81, 100)
    );
    assert_eq!((stats.metadata_count, stats.attachment_count), (1, 1));
    assert!(
        summary.chunk_indexes.len() > 1,
        "small chunk size: several chunks"
    );
    assert_eq!(stats.chunk_count as usize, summary.chunk_indexes.len());
    assert_eq!(summary.channels[&3].topic, "/a");
    assert_eq!(summary.channels[&3].schema.as_ref().unwrap().id, 7);
    // Through the chunk indexes and message indexes.
    let mut indexed = 0;
    for ci in &summary.chunk_indexes {
        let idx = summary.read_message_indexes(&bytes, ci).unwrap();
        indexed += idx.values().map(|v| v.len()).sum::<usize>();
        for (ch, entries) in &idx {
            for e in entries {
                let m = summary.seek_message(&bytes, ci, e).unwrap();
                assert_eq!(m.channel.id, ch.id);
                assert_eq!(m.log_time, e.log_time);
            }
        }
    }
    assert_eq!(indexed, 20);
    // Linearly, with every CRC checked.
    let mut n = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        m.unwrap();
        n += 1;
    }
    assert_eq!(n, 20);
    let mut reader = mcap::sans_io::LinearReader::new_with_options(
        mcap::sans_io::LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true),
    );
    let mut rest = &bytes[..];
    let mut records = 0;
    while let Some(e) = reader.next_event() {
        match e.unwrap() {
            mcap::sans_io::LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            mcap::sans_io::LinearReadEvent::Record { .. } => records += 1,
        }
    }
    assert!(records > 20);
    let m = mcap::read::metadata(&bytes, &summary.metadata_indexes[0]).unwrap();
    assert_eq!(m.metadata["a"], "b");
    let a = mcap::read::attachment(&bytes, &summary.attachment_indexes[0]).unwrap();
    assert_eq!(&a.data[..], b"hello");
}
