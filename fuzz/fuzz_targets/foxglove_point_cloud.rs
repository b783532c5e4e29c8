#![no_main]
//! `mireg::fuzzing::foxglove_point_cloud` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::foxglove_point_cloud(data));
