//! cargo-fuzz target `ads131m04_frames`: see `e2e::fuzz::ads131m04_frames`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::ads131m04_frames(data));
