//! cargo-fuzz target `session_log_reader`: see `e2e::fuzz::session_log_reader`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::session_log_reader(data));
