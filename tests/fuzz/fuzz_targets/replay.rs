//! cargo-fuzz target `replay`: see `e2e::fuzz::replay`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::replay(data));
