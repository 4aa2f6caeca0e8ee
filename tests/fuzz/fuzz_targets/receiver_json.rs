//! cargo-fuzz target `receiver_json`: see `e2e::fuzz::receiver_json`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::receiver_json(data));
