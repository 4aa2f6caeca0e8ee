//! Runs `qemu_board` (the board tasks' costs that QEMU can count) and checks that the
//! schedule model's costs (`firmware::board::schedule::BOARD_COSTS`) are not below what
//! the code costs now: a slower driver, screen or log record fails here, not on the board.
use e2e::{build_firmware_bin, run_in_qemu};
use firmware::board::schedule::BOARD_COSTS;
use std::time::Duration;

#[test]
fn schedule_costs_cover_the_measured_ones() {
    let elf = build_firmware_bin("qemu_board", "qemu");
    let run = run_in_qemu(&elf, Duration::from_secs(120));
    assert!(
        run.success,
        "qemu_board failed:\n{}\n{}",
        run.stdout, run.stderr
    );
    assert!(run.stdout.contains("done"), "{}", run.stdout);
    let measured = |name: &str| -> (u64, u32) {
        let line = run
            .stdout
            .lines()
            .find(|l| l.starts_with(&format!("board {name} ")))
            .unwrap_or_else(|| panic!("no {name} line in\n{}", run.stdout));
        let mut f = line.split_whitespace().skip(2);
        let mut next = || f.next().and_then(|v| v.parse::<u64>().ok()).expect(line);
        let (n, bytes) = (next(), next());
        (n, u32::try_from(bytes).expect("bytes"))
    };
    let (drdy, _) = measured("drdy_isr");
    let (imu, _) = measured("imu_read");
    let (render, _) = measured("render");
    let (log_imu, imu_bytes) = measured("log_imu");
    let (log_pulse, pulse_bytes) = measured("log_pulse");
    println!(
        "board costs: DRDY {drdy}, IMU read {imu}, render {render}, IMU record {log_imu} \
         ({imu_bytes} B), pulse record {log_pulse} ({pulse_bytes} B) instructions"
    );
    assert!(drdy <= BOARD_COSTS.drdy_instr, "DRDY {drdy}");
    assert!(imu <= BOARD_COSTS.imu_instr, "IMU {imu}");
    assert!(render <= BOARD_COSTS.render_instr, "render {render}");
    assert!(
        log_imu <= BOARD_COSTS.imu_record_instr,
        "IMU record {log_imu}"
    );
    assert!(
        log_pulse <= BOARD_COSTS.pulse_record_instr,
        "pulse record {log_pulse}"
    );
    assert!(imu_bytes <= BOARD_COSTS.imu_record_bytes, "{imu_bytes} B");
    assert!(
        pulse_bytes <= BOARD_COSTS.pulse_record_bytes,
        "{pulse_bytes} B"
    );
}
