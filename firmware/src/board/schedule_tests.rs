use super::*;

/// Cycles of one millisecond.
const MS: u64 = SYSCLK_HZ / 1000;

fn board(scale: Scale) -> Outcome {
    simulate(
        &BOARD_COSTS,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        scale,
    )
}

/// Pulses of `load` that end within its duration.
fn expected_pulses(load: &Load) -> u64 {
    (0..load.beacons)
        .map(|b| {
            let first = load.first_pulse_ms + b * load.pulse_spacing_ms;
            if first >= load.duration_ms {
                0
            } else {
                (load.duration_ms - 1 - first) / load.pulse_period_ms + 1
            }
        })
        .sum()
}

#[test]
fn board_schedule_loses_nothing_at_the_worst_measured_costs() {
    let o = board(Scale::ONE);
    let busy = |k: usize| o.busy_cycles[k] as f64 / o.cycles as f64 * 100.0;
    println!(
        "schedule: samples {}/{} (max depth/capacity), IMU {}/{}, log {}/{} records; \
         worst DRDY {:.1} µs, IMU tick {:.2} ms, frame {:.1} ms; busy DRDY {:.1} % IMU {:.1} % \
         process {:.1} % display {:.1} % log {:.1} %; {} pulses, {} IMU records, {} frames",
        o.max_samples,
        SAMPLE_QUEUE,
        o.max_imu,
        IMU_QUEUE,
        o.max_log_items,
        LOG_QUEUE,
        o.worst_drdy_cycles as f64 / MS as f64 * 1000.0,
        o.worst_imu_cycles as f64 / MS as f64,
        o.worst_frame_cycles as f64 / MS as f64,
        busy(0),
        busy(1),
        busy(2),
        busy(3),
        busy(4),
        o.pulses,
        o.imu_records,
        o.frames,
    );
    assert!(o.lossless(), "{o:?}");
    assert!(o.max_samples < SAMPLE_QUEUE && o.max_imu < IMU_QUEUE && o.max_log_items < LOG_QUEUE);
    // The model did the work: every pulse, every IMU tick, a frame per pulse or second.
    assert_eq!(o.pulses, expected_pulses(&WORST_LOAD));
    assert!(
        o.imu_records + u64::from(o.max_imu) >= 999,
        "{}",
        o.imu_records
    );
    assert!(o.frames >= 10, "{}", o.frames);
    // Queued samples = the backlog of a pulse burst: four worst steps (≈ 45 ms each)
    // come in 150 ms, so the queue must have held several hundred samples.
    assert!(o.max_samples > 400, "{}", o.max_samples);
}

#[test]
fn margin_of_the_board_schedule() {
    let cpu = margin(
        &BOARD_COSTS,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        |k| Scale { cpu: k, bus: 1.0 },
        Outcome::lossless,
    );
    let sensors = margin(
        &BOARD_COSTS,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        |k| Scale { cpu: k, bus: 1.0 },
        Outcome::sensors_lossless,
    );
    let all = margin(
        &BOARD_COSTS,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        |k| Scale { cpu: k, bus: k },
        Outcome::lossless,
    );
    println!(
        "schedule margin: instructions ×{cpu:.2?} (samples and IMU alone ×{sensors:.2?}), \
         every cost (bus and card too) ×{all:.2?}"
    );
    let (Some(cpu), Some(all), Some(sensors)) = (cpu, all, sensors) else {
        panic!("the board's schedule loses data at its measured costs");
    };
    assert!(sensors >= cpu && cpu >= all && all >= 1.0);
    // The bisection's answer is an edge: 5 % more loses something.
    let past = board(Scale {
        cpu: cpu * 1.05,
        bus: 1.0,
    });
    println!(
        "schedule past the margin (×{:.2}): samples {}/{SAMPLE_QUEUE} dropped {}, IMU {}/{IMU_QUEUE} \
         missed {} overrun {}, log {}/{LOG_QUEUE} records overruns {}",
        cpu * 1.05,
        past.max_samples,
        past.dropped_samples,
        past.max_imu,
        past.missed_ticks,
        past.imu_overruns,
        past.max_log_items,
        past.log_overruns
    );
    assert!(!past.lossless());
    assert!(board(Scale { cpu, bus: 1.0 }).lossless());
}

#[test]
fn uart_stream_without_a_card_loses_nothing() {
    let o = simulate(
        &UART_ONLY,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale::ONE,
    );
    let m = margin(
        &UART_ONLY,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        |k| Scale { cpu: k, bus: 1.0 },
        Outcome::lossless,
    );
    println!(
        "schedule, UART only: log {}/{LOG_QUEUE} records, margin ×{m:.2?}",
        o.max_log_items
    );
    assert!(o.lossless() && m.is_some(), "{o:?}");
    // Both writers at once with the card's worst busy times: the log cannot keep up
    // (why the stream is off while the card logs).
    let both = Costs {
        uart_byte_ns: UART_ONLY.uart_byte_ns,
        ..BOARD_COSTS
    };
    let o = simulate(
        &both,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale::ONE,
    );
    assert!(
        o.log_overruns > 0 && o.dropped_samples == 0 && o.missed_ticks == 0,
        "{o:?}"
    );
}

#[test]
fn imu_at_the_processing_level_misses_ticks() {
    // The old structure: everything but DRDY in one loop (the IMU read waits for an
    // estimator step). The model must see the loss the priorities remove.
    let one_loop = Priorities {
        drdy: 4,
        imu: 1,
        process: 1,
        display: 1,
        log: 1,
    };
    let o = simulate(
        &BOARD_COSTS,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &one_loop,
        Scale::ONE,
    );
    assert!(o.missed_ticks > 0, "{o:?}");
    assert!(board(Scale::ONE).missed_ticks == 0);
}

/// Costs that are all zero.
fn nothing() -> Costs {
    Costs {
        drdy_instr: 0,
        drdy_bus_ns: 0,
        imu_instr: 0,
        imu_bus_ns: 0,
        sample_instr: 0,
        pulse_instr: 0,
        imu_step_instr: 0,
        imu_record_instr: 0,
        pulse_record_instr: 0,
        render_instr: 0,
        flush_chunks: 0,
        chunk_bus_ns: 0,
        imu_record_bytes: 0,
        pulse_record_bytes: 0,
        uart_byte_ns: 0,
        sd_block_ns: 0,
        sd_stall_ns: 0,
        sd_stall_every_ms: 500,
        flush_extra_blocks: 0,
        flush_every_ms: 500,
    }
}

#[test]
fn backlog_of_one_step_matches_the_hand_count() {
    // DRDY takes 10 % of the core (12.5 µs of every 125 µs), one pulse step 100 ms of CPU:
    // the step ends after 100 / 0.9 = 111.1 ms, with 889 samples waiting.
    let costs = Costs {
        drdy_bus_ns: 12_500,
        pulse_instr: 100 * MS,
        ..nothing()
    };
    let load = Load {
        duration_ms: 1_000,
        beacons: 1,
        pulse_period_ms: 10_000,
        ..WORST_LOAD
    };
    let o = simulate(
        &costs,
        &load,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale::ONE,
    );
    assert!(o.lossless() && o.pulses == 1, "{o:?}");
    assert!((887..=891).contains(&o.max_samples), "{}", o.max_samples);
    // Half the step: about half the backlog.
    let o = simulate(
        &costs,
        &load,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale { cpu: 0.5, bus: 1.0 },
    );
    assert!((443..=447).contains(&o.max_samples), "{}", o.max_samples);
    // A step longer than the queue (300 ms of CPU ≈ 2 667 samples) drops the excess.
    let o = simulate(
        &costs,
        &load,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale { cpu: 3.0, bus: 1.0 },
    );
    assert_eq!(o.max_samples, SAMPLE_QUEUE);
    assert!(
        (600..=640).contains(&o.dropped_samples),
        "{}",
        o.dropped_samples
    );
}

#[test]
fn flush_in_short_transactions_bounds_the_imu_wait() {
    let o = board(Scale::ONE);
    let imu = ns_cycles(BOARD_COSTS.imu_bus_ns, 1.0) + BOARD_COSTS.imu_instr;
    let chunk = ns_cycles(BOARD_COSTS.chunk_bus_ns, 1.0);
    let drdy = ns_cycles(BOARD_COSTS.drdy_bus_ns, 1.0) + BOARD_COSTS.drdy_instr;
    // At most one transaction ahead of it and the DRDY interrupts meanwhile (≤ 9 in 1 ms).
    assert!(
        o.worst_imu_cycles <= imu + chunk + 10 * drdy,
        "{}",
        o.worst_imu_cycles
    );
    assert!(
        o.worst_imu_cycles > imu,
        "the flush never blocked the IMU: {o:?}"
    );
    // The whole screen in one locked transfer (≈ 27 ms) holds the IMU tick past its period.
    let one_piece = Costs {
        flush_chunks: 1,
        chunk_bus_ns: 66 * BOARD_COSTS.chunk_bus_ns,
        ..BOARD_COSTS
    };
    let o = simulate(
        &one_piece,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale::ONE,
    );
    assert!(o.missed_ticks > 0, "{o:?}");
}

#[test]
fn a_slow_card_fills_only_the_log_queue() {
    // A card busy 250 ms on every block cannot take 17 kB/s: log records are lost (and
    // counted), samples and IMU ticks are not.
    let slow = Costs {
        sd_stall_every_ms: 1,
        ..BOARD_COSTS
    };
    let o = simulate(
        &slow,
        &WORST_LOAD,
        &BOARD_CAPACITIES,
        &Priorities::BOARD,
        Scale::ONE,
    );
    assert!(o.log_overruns > 0, "{o:?}");
    assert_eq!(
        (o.dropped_samples, o.missed_ticks, o.imu_overruns),
        (0, 0, 0)
    );
    // The queue was full when records were refused.
    assert_eq!(o.max_log_items, LOG_QUEUE);
}

#[test]
fn an_imu_record_waits_for_the_samples_queued_before_it() {
    // Read after 80 samples were queued: due once 80 are taken.
    assert!(!imu_record_due(79, 80, true));
    assert!(imu_record_due(80, 80, true));
    assert!(imu_record_due(81, 80, true));
    // No sample waits (the ADC stalled): due at once.
    assert!(imu_record_due(10, 80, false));
    // Across the counts' wrap.
    assert!(!imu_record_due(u32::MAX - 2, 5, true));
    assert!(imu_record_due(6, u32::MAX - 2, true));
}
