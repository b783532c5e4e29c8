//! The input of the commands that read what `mireg register` wrote (`evaluate`, `export`,
//! `map`): anything else is refused with what the command reads and what to run first.

use std::path::Path;

use crate::io::input_log::{FileKind, file_kind, not_a_log};
use crate::io::mcap::log::{ChannelInfo, list_channels};
use crate::register::default_output;
use crate::trajectory::{self, newest_mireg_namespace};
use crate::{Error, Result};

/// Most `.mcap` files of a directory named in the message that refuses it: 3.
const FILES_NAMED: usize = 3;

/// What `mireg COMMAND` reads, for messages.
fn reads(command: &str) -> String {
    format!("mireg {command} reads the MCAP file that `mireg register` writes")
}

/// "run `mireg register PATH` first (it writes NAME.mireg.mcap), then `mireg COMMAND` on that".
fn register_first(path: &Path, command: &str) -> String {
    format!(
        "run `mireg register {}` first (it writes {}), then `mireg {command}` on that",
        path.display(),
        default_output(path).display()
    )
}

/// The channels of `path` when it is an MCAP file; else an error naming `path`, what it is,
/// what `mireg COMMAND` reads and what to run first.
fn mcap_channels(path: &Path, command: &str) -> Result<Vec<ChannelInfo>> {
    let invalid = |what: String| Err(Error::InvalidInput(format!("{}: {what}", path.display())));
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return invalid(format!("no such file; {}", reads(command)));
        }
        Err(source) => {
            return Err(Error::Io {
                path: path.to_path_buf(),
                source,
            });
        }
    };
    if meta.is_dir() {
        if path.join("metadata.yaml").is_file() {
            return invalid(format!(
                "is a ROS 2 bag directory, not a register output; {}",
                register_first(path, command)
            ));
        }
        return invalid(format!(
            "is a directory, not a regular file; {} (NAME.mireg.mcap){}",
            reads(command),
            mcap_files_in(path)
        ));
    }
    let kind = file_kind(path)?;
    let bag = match kind {
        FileKind::Mcap => return list_channels(path),
        FileKind::Ros1Bag => "a ROS 1 bag",
        FileKind::Db3 => "a ROS 2 bag's SQLite storage",
        FileKind::Zstd => "a zstd-compressed file",
        FileKind::Other(head) => {
            return invalid(format!(
                "{}; {}, from a log (MCAP, ROS 1 bag or ROS 2 bag directory)",
                not_a_log(path, &head),
                reads(command)
            ));
        }
    };
    invalid(format!(
        "is {bag}, not a register output; {}",
        register_first(path, command)
    ))
}

/// "; in it: a.mcap, b.mcap" for the first [`FILES_NAMED`] `.mcap` files of `dir`, by name;
/// empty when it has none (or cannot be listed).
fn mcap_files_in(dir: &Path) -> String {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return String::new();
    };
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".mcap"))
        .collect();
    if names.is_empty() {
        return String::new();
    }
    names.sort();
    let more = names.len().saturating_sub(FILES_NAMED);
    names.truncate(FILES_NAMED);
    let more = if more > 0 {
        format!(" and {more} more")
    } else {
        String::new()
    };
    format!("; in it: {}{more}", names.join(", "))
}

/// The channels of `path`, a `mireg register` output that `mireg COMMAND` reads; `topic_given`:
/// the user named the pose topic to read (then any MCAP with it will do).
///
/// # Errors
/// [`Error::InvalidInput`] naming `path` when it is not an MCAP file (a bag, a directory, a text
/// file), or, without `topic_given`, an MCAP that was never registered (no mireg pose topic):
/// each says what to run first.
pub fn registered_log(path: &Path, command: &str, topic_given: bool) -> Result<Vec<ChannelInfo>> {
    let channels = mcap_channels(path, command)?;
    if topic_given || newest_mireg_namespace(&channels).is_some() {
        return Ok(channels);
    }
    let poses = crate::io::poses::pose_stamped_topics(&channels);
    let choose = match (command, poses.is_empty()) {
        ("map", _) | (_, true) => String::new(),
        (_, false) => format!(
            " (or choose a PoseStamped topic with {}: {})",
            if command == "export" {
                "--topic"
            } else {
                "--est-topic"
            },
            poses.join(", ")
        ),
    };
    Err(Error::InvalidInput(format!(
        "{}: has no {}/pose topic, so `mireg register` has not registered it; {}{choose}",
        path.display(),
        trajectory::MIREG_NAMESPACE,
        register_first(path, command)
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_directory_names_its_mcap_files() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(mcap_files_in(dir.path()), "");
        for n in ["a.mireg.mcap", "b.mcap", "c.mcap", "d.mcap", "notes.txt"] {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        assert_eq!(
            mcap_files_in(dir.path()),
            "; in it: a.mireg.mcap, b.mcap, c.mcap and 1 more"
        );
    }
}
