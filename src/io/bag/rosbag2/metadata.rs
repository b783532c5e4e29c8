//! The few keys of a rosbag2 `metadata.yaml` that reading a bag needs.

/// A YAML scalar without its quotes.
fn unquote(v: &str) -> String {
    let v = v.trim();
    for q in ['\'', '"'] {
        if v.len() >= 2 && v.starts_with(q) && v.ends_with(q) {
            return v[1..v.len() - 1].to_string();
        }
    }
    v.to_string()
}

/// The keys of a rosbag2 `metadata.yaml` we need: `storage_identifier`, the list
/// `relative_file_paths` (block or flow style), `compression_mode` and `compression_format`. A
/// small reader for the layout rosbag2 (and rosbags) write, not a YAML parser.
#[derive(Debug, Default, PartialEq, Eq)]
pub(crate) struct Metadata {
    pub(super) storage_identifier: Option<String>,
    pub(super) relative_file_paths: Vec<String>,
    pub(super) compression_mode: String,
    pub(super) compression_format: String,
}

pub(crate) fn parse_metadata(text: &str) -> Metadata {
    let mut m = Metadata::default();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        let indent = line.len() - t.len();
        if let Some(v) = t.strip_prefix("storage_identifier:") {
            m.storage_identifier = Some(unquote(v));
        } else if let Some(v) = t.strip_prefix("compression_mode:") {
            m.compression_mode = unquote(v);
        } else if let Some(v) = t.strip_prefix("compression_format:") {
            m.compression_format = unquote(v);
        } else if let Some(v) = t.strip_prefix("relative_file_paths:") {
            let v = v.trim();
            if let Some(inner) = v.strip_prefix('[').and_then(|v| v.strip_suffix(']')) {
                m.relative_file_paths = inner
                    .split(',')
                    .map(unquote)
                    .filter(|s| !s.is_empty())
                    .collect();
                continue;
            }
            while let Some(next) = lines.peek() {
                let nt = next.trim_start();
                let nindent = next.len() - nt.len();
                match nt.strip_prefix("- ") {
                    Some(item) if nindent >= indent => {
                        m.relative_file_paths.push(unquote(item));
                        lines.next();
                    }
                    _ => break,
                }
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_block_and_flow_lists_and_quotes() {
        let m = parse_metadata(
            "rosbag2_bagfile_information:\n  compression_format: ''\n  compression_mode: ''\n  relative_file_paths:\n  - a_0.db3\n  - 'a_1.db3'\n  storage_identifier: sqlite3\n  topics_with_message_count:\n  - message_count: 8\n",
        );
        assert_eq!(m.storage_identifier.as_deref(), Some("sqlite3"));
        assert_eq!(m.relative_file_paths, ["a_0.db3", "a_1.db3"]);
        assert_eq!(m.compression_mode, "");
        let m = parse_metadata("x:\n  relative_file_paths: [\"b.mcap\", c.mcap]\n");
        assert_eq!(m.relative_file_paths, ["b.mcap", "c.mcap"]);
        assert_eq!(m.storage_identifier, None);
    }
}
