#![no_main]
//! `mireg::fuzzing::ros1_bag` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::ros1_bag(data));
