#![no_main]
//! `mireg::fuzzing::rosbag2_compressed` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::rosbag2_compressed(data));
