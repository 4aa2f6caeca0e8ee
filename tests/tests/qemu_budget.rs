//! The estimator's per-step instruction count and memory on the emulated STM32F405.
//!
//! Instruction counts under `-icount shift=0` are deterministic, so they could be
//! asserted; the 8.4 M-instruction step budget is not met yet at full capacity (issue 7),
//! so this test checks that the run completes without a refused step, that the memory
//! fits the MCU, and prints the figures.
use e2e::{build_firmware_bin, run_in_qemu, section_sizes};
use std::collections::HashMap;
use std::time::Duration;

#[test]
fn estimator_budget_on_cortex_m4f() {
    let elf = build_firmware_bin("qemu_budget", "qemu");
    let run = run_in_qemu(&elf, Duration::from_secs(600));
    assert!(
        run.success,
        "qemu_budget failed:\n{}\n{}",
        run.stdout, run.stderr
    );
    let budget: HashMap<&str, u64> = run
        .stdout
        .lines()
        .filter_map(|l| l.strip_prefix("budget "))
        .filter_map(|l| {
            let (k, v) = l.split_once(' ')?;
            Some((k, v.trim().parse().ok()?))
        })
        .collect();
    for (k, v) in &budget {
        println!("{k}: {v}");
    }
    assert_eq!(budget["failures"], 0);
    assert!(budget["steps"] >= 20, "too few recorded steps ran");
    let sizes = section_sizes(&elf);
    let in_ram = |name: &str| sizes.iter().find(|s| s.0 == name).map_or(0, |s| s.1);
    let static_ram = in_ram(".data") + in_ram(".bss") + in_ram(".uninit");
    let ram = static_ram + budget["stack_high_water"];
    println!(
        "static RAM {static_ram} B + stack {} B = {ram} B",
        budget["stack_high_water"]
    );
    assert!(ram <= 192 * 1024, "RAM {ram} B exceeds 192 KB");
}
