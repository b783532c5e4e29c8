#![no_main]
//! `mireg::fuzzing::rosbag2_metadata` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::rosbag2_metadata(data));
