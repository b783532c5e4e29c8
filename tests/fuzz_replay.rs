//! Replays every committed fuzz input — the seed corpora (`fuzz/corpus/TARGET/`) and the inputs
//! that once crashed a target (`fuzz/regressions/TARGET/`) — through the same functions the fuzz
//! targets call ([`mireg::fuzzing::TARGETS`]), so that CI guards them on a stable toolchain.

use std::path::Path;

fn inputs(folder: &str, target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(folder)
        .join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut v: Vec<(String, Vec<u8>)> = entries
        .map(|e| {
            let p = e.unwrap().path();
            (p.display().to_string(), std::fs::read(&p).unwrap())
        })
        .collect();
    v.sort();
    v
}

#[test]
fn every_committed_fuzz_input_replays_without_a_crash() {
    let mut seeds = 0;
    // Every regression input goes through every target: an input that broke one reader is a
    // good test of the others.
    let regressions: Vec<(String, Vec<u8>)> = mireg::fuzzing::TARGETS
        .iter()
        .flat_map(|(t, _)| inputs("regressions", t))
        .collect();
    assert!(!regressions.is_empty());
    for &(target, run) in mireg::fuzzing::TARGETS {
        let corpus = inputs("corpus", target);
        assert!(!corpus.is_empty(), "no seed corpus for {target}");
        seeds += corpus.len();
        for (name, data) in corpus.iter().chain(&regressions) {
            // A panic names the input that caused it.
            let r = std::panic::catch_unwind(|| run(data));
            assert!(r.is_ok(), "{target} crashed on {name}");
        }
    }
    assert!(seeds >= mireg::fuzzing::TARGETS.len());
}

/// The MCAP seeds but the bombs are valid logs that register (a corpus of broken seeds would
/// start the fuzzer far from the code that handles valid input), those with far points and
/// glitched point times included.
#[test]
fn mcap_seeds_are_valid_logs() {
    let dir = tempfile::tempdir().unwrap();
    let corpus = inputs("corpus", "register_input");
    assert!(corpus.iter().any(|(n, _)| n.ends_with("far_points.mcap")));
    assert!(
        corpus
            .iter()
            .any(|(n, _)| n.ends_with("time_glitches.mcap"))
    );
    for (name, data) in corpus.into_iter().filter(|(n, _)| !is_bomb(n)) {
        let input = dir.path().join("in.mcap");
        std::fs::write(&input, &data).unwrap();
        let out = dir.path().join("out.mcap");
        let _ = std::fs::remove_file(&out);
        let config = mireg::odometry::OdometryConfig {
            pair: mireg::pipeline::PairConfig {
                voxel_size_m: 0.05,
                ..Default::default()
            },
            ..Default::default()
        };
        let opts = mireg::register::RegisterOptions::new(&input, &out, config);
        let s = mireg::register::register_log(&opts).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((s.frames, s.failed_frames), (2, 0), "{name}");
    }
}

fn is_bomb(name: &str) -> bool {
    Path::new(name)
        .file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with("bomb_"))
}

/// The decompression bomb seeds (`bomb_*`: MCAP chunks, ROS 1 chunks, rosbag2 `file` and
/// `message` modes) are each refused by `register` with an error naming the input and what its
/// decompression claims or produces (a chunk decompressing past its claim stops there); no
/// output is left.
#[test]
fn bomb_seeds_are_refused_naming_the_input() {
    let dir = tempfile::tempdir().unwrap();
    let mut bombs = 0;
    for target in ["register_input", "ros1_bag", "rosbag2_compressed"] {
        for (name, data) in inputs("corpus", target)
            .into_iter()
            .filter(|(n, _)| is_bomb(n))
        {
            let input = match target {
                "register_input" => dir.path().join("in.mcap"),
                "ros1_bag" => dir.path().join("in.bag"),
                _ => {
                    let bag = dir.path().join("bag");
                    let _ = std::fs::remove_dir_all(&bag);
                    std::fs::create_dir(&bag).unwrap();
                    let (meta, file) = mireg::fuzzing::compressed_bag_metadata(data[0] % 2 == 0);
                    std::fs::write(bag.join("metadata.yaml"), meta).unwrap();
                    std::fs::write(bag.join(file), &data[1..]).unwrap();
                    bag.join(file)
                }
            };
            let log = if target == "rosbag2_compressed" {
                input.parent().unwrap().to_path_buf()
            } else {
                std::fs::write(&input, &data).unwrap();
                input.clone()
            };
            let out = dir.path().join("out.mcap");
            let config = mireg::odometry::OdometryConfig {
                pair: mireg::pipeline::PairConfig {
                    voxel_size_m: 0.05,
                    ..Default::default()
                },
                ..Default::default()
            };
            let opts = mireg::register::RegisterOptions {
                read_policy: mireg::io::damage::ReadPolicy::STRICT,
                ..mireg::register::RegisterOptions::new(&log, &out, config)
            };
            let e = match mireg::register::register_log(&opts) {
                Ok(_) => panic!("{name}: registered"),
                Err(e) => e.to_string(),
            };
            assert!(e.contains(input.to_str().unwrap()), "{name}: {e}");
            // Claims past the expansion limit, or data past the claim.
            assert!(
                e.contains("decompression bomb")
                    || e.contains("decompresses to more than")
                    || e.contains("Destination buffer is too small"),
                "{name}: {e}"
            );
            assert!(!out.exists(), "{name}");
            bombs += 1;
        }
    }
    assert_eq!(bombs, 7);
}
