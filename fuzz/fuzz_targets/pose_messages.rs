#![no_main]
//! `mireg::fuzzing::pose_messages` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::pose_messages(data));
