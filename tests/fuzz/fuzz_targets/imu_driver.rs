//! cargo-fuzz target `imu_driver`: see `e2e::fuzz::imu_driver`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| e2e::fuzz::imu_driver(data));
