#![no_main]
//! `mireg::fuzzing::cloud_files` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::cloud_files(data));
