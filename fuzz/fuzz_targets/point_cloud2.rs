#![no_main]
//! `mireg::fuzzing::point_cloud2` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::point_cloud2(data));
