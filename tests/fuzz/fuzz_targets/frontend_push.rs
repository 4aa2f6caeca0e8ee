//! cargo-fuzz target `frontend_push`: see `e2e::fuzz::frontend_push`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::frontend_push(data));
