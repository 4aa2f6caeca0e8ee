//! cargo-fuzz target `estimator_step`: see `e2e::fuzz::estimator_step`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::estimator_step(data));
