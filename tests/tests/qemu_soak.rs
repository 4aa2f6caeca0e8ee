//! Soak of the application on the emulated STM32F405: a short version (10 simulated
//! minutes, two report windows) of the hour-long run whose output is in
//! `hal-sim/reports/reliability.md` (`SOAK_MINUTES=60 cargo qemu --bin qemu_soak`).
//!
//! Checks, from the binary's own report: no input refused and nothing non-finite, the
//! mixture within its capacity, the stack high-water mark not growing after the first
//! window beyond a few frames' worth (a deeper but bounded path seen later is allowed; a
//! leak per pulse is not), and the final estimate within the 1 m of the truth.
// Test code: a failed unwrap or a panic is a failed test, the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use e2e::{build_firmware_bin_with_env, keyed_values, run_in_qemu};
use std::collections::HashMap;
use std::time::Duration;

#[test]
fn ten_minutes_of_search_on_cortex_m4f_without_growth_or_drift() {
    let elf = build_firmware_bin_with_env("qemu_soak", "qemu", &[("SOAK_MINUTES", "10")]);
    let run = run_in_qemu(&elf, Duration::from_secs(600));
    println!("{}", run.stdout);
    assert!(
        run.success,
        "qemu_soak failed:\n{}\n{}",
        run.stdout, run.stderr
    );
    let soak: HashMap<&str, f64> = keyed_values(&run.stdout, "soak ");
    assert_eq!(soak["minutes"], 10.0);
    assert_eq!(soak["pulses"], 600.0, "one pulse a second");
    assert_eq!(soak["pulses_in_display"], 600.0);
    for k in [
        "imu_refused",
        "pulses_refused",
        "non_finite",
        "reinitializations",
    ] {
        assert_eq!(soak[k], 0.0, "{k}");
    }
    assert!(soak["components_max"] <= soak["capacity"]);
    let windows: Vec<Vec<f64>> = run
        .stdout
        .lines()
        .filter_map(|l| l.strip_prefix("window "))
        .map(|l| l.split(' ').filter_map(|x| x.parse().ok()).collect())
        .collect();
    assert_eq!(windows.len(), 2);
    // Stack: at most 256 B deeper than after the first window, and far from the limit.
    let (first, end) = (
        soak["stack_high_water_first_window"],
        soak["stack_high_water"],
    );
    assert!(end <= first + 256.0, "stack grew from {first} to {end} B");
    assert!(end < 0.5 * soak["stack_size"], "stack {end} B");
    // Drift: the final estimate within 1 m of the truth.
    assert!(
        soak["final_error_mm"] < 1000.0,
        "final error {} mm",
        soak["final_error_mm"]
    );
}
