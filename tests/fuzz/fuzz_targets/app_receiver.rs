//! cargo-fuzz target `app_receiver`: see `e2e::fuzz::app_receiver`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::app_receiver(data));
