#![no_main]
//! `mireg::fuzzing::mcap_records` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| mireg::fuzzing::mcap_records(data));
