#![allow(dead_code)] // shared by several test crates, each using a part
//! What a log holds, read with mireg's bounded record reader, for tests that check that every
//! input record reaches the output unchanged.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::records::Record;
use mireg::io::mcap::log::for_each_record;

/// Everything a log holds, by kind: messages as (topic, log_time, publish_time, data), metadata,
/// attachments.
#[derive(Default)]
pub struct Contents {
    pub messages: Vec<(String, u64, u64, Vec<u8>)>,
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    pub attachments: Vec<(String, String, u64, Vec<u8>)>,
}

pub fn contents(path: &Path) -> Contents {
    let mut topics = BTreeMap::new();
    let mut c = Contents::default();
    for_each_record(path, |r| {
        match r {
            Record::Channel(ch) => {
                topics.insert(ch.id, ch.topic);
            }
            Record::Message { header, data } => c.messages.push((
                topics[&header.channel_id].clone(),
                header.log_time,
                header.publish_time,
                data.to_vec(),
            )),
            Record::Metadata(m) => c.metadata.push((m.name, m.metadata)),
            Record::Attachment { header, data, .. } => c.attachments.push((
                header.name,
                header.media_type,
                header.log_time,
                data.to_vec(),
            )),
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    c.messages.sort();
    c
}

/// The messages of `topic` in `path`, as bytes, in file order. Panics when `path` has no channel
/// of that topic.
pub fn topic_messages(path: &Path, topic: &str) -> Vec<Vec<u8>> {
    let mut id = None;
    let mut out = Vec::new();
    for_each_record(path, |r| {
        match r {
            Record::Channel(c) if c.topic == topic => id = Some(c.id),
            Record::Message { header, data } if Some(header.channel_id) == id => {
                out.push(data.into_owned());
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    assert!(id.is_some(), "{}: no {topic}", path.display());
    out
}

/// Every message, metadata record and attachment of `input` is in `output`, unchanged.
pub fn assert_superset(input: &Contents, output: &Contents) {
    let mut out = output.messages.clone();
    for m in &input.messages {
        let i = out
            .binary_search(m)
            .unwrap_or_else(|_| panic!("input message on {} at {} missing or altered", m.0, m.1));
        out.remove(i);
    }
    for m in &input.metadata {
        assert!(output.metadata.contains(m), "metadata {} lost", m.0);
    }
    for a in &input.attachments {
        assert!(output.attachments.contains(a), "attachment {} lost", a.0);
    }
}
