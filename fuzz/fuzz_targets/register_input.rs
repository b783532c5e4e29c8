#![no_main]
//! `mireg::fuzzing::register_input` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::register_input(data));
