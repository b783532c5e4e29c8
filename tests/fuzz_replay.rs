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

/// The MCAP seeds are valid logs that register (a corpus of broken seeds would start the fuzzer
/// far from the code that handles valid input).
#[test]
fn mcap_seeds_are_valid_logs() {
    let dir = tempfile::tempdir().unwrap();
    for (name, data) in inputs("corpus", "register_input") {
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
