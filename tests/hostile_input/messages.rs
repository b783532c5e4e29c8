//! Finding 8 of the third round: messages that did not say what was wrong. (A `metadata.yaml`
//! that is a FIFO or a directory is in `special_files.rs`.)

use super::*;
use mireg::fuzzing::{ChunkCompression, small_bag};

fn fixture_bag(dir: &Path, name: &str) -> PathBuf {
    let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/bags/icl4_db3");
    let bag = dir.join(name);
    std::fs::create_dir(&bag).unwrap();
    for e in std::fs::read_dir(&from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), bag.join(e.file_name())).unwrap();
    }
    bag
}

/// An unparseable `metadata.yaml` said "lists no files"; a `.db3` listed twice duplicated every
/// message.
#[test]
fn bag_metadata_errors_say_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let garbage = fixture_bag(dir.path(), "garbage");
    std::fs::write(garbage.join("metadata.yaml"), "\u{1}\u{2}{{[ not yaml").unwrap();
    let run = mireg(&["info", garbage.to_str().unwrap()]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(
        e.contains("metadata.yaml: is not a rosbag2 metadata.yaml"),
        "{e}"
    );

    let twice = fixture_bag(dir.path(), "twice");
    let meta = std::fs::read_to_string(twice.join("metadata.yaml")).unwrap();
    let listed = meta.replace("  - icl4_db3.db3\n", "  - icl4_db3.db3\n  - icl4_db3.db3\n");
    assert_ne!(listed, meta, "the fixture lists its file in block style");
    std::fs::write(twice.join("metadata.yaml"), listed).unwrap();
    let run = mireg(&["info", twice.to_str().unwrap()]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(e.contains("lists icl4_db3.db3 twice"), "{e}");
}

/// A ROS 1 bag cut inside its index warned "the index the file ends inside the record".
#[test]
fn a_cut_ros1_index_is_reported_in_words() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("cut.bag");
    let bytes = small_bag(3, ChunkCompression::None, None);
    std::fs::write(&bag, &bytes[..bytes.len() - 20]).unwrap();
    let out = dir.path().join("out.mcap");
    let run = mireg(&[
        "register",
        bag.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--voxel",
        "0.05",
        "--no-loops",
    ]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(0), "{e}");
    assert!(e.contains("the index is cut short: "), "{e}");
    assert!(!e.contains("the index the "), "{e}");
}

/// `map --voxel 1e-12` said "no cloud has a pose"; it now says the voxel is too small.
#[test]
fn a_map_voxel_too_small_for_the_grid_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("in.mcap"), dir.path().join("out.mcap"));
    std::fs::write(&input, small(3)).unwrap();
    let mut opts = options(&input, &output);
    opts.loops = false;
    register_log(&opts).unwrap();
    let map = dir.path().join("map.ply");
    let run = mireg(&[
        "map",
        output.to_str().unwrap(),
        "-o",
        map.to_str().unwrap(),
        "--voxel",
        "1e-12",
    ]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(e.contains("choose a larger --voxel"), "{e}");
    assert!(!map.exists());
}
