#![no_main]
//! `mireg::fuzzing::ros1_messages` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::ros1_messages(data));
