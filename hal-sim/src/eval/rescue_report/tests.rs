use super::*;

#[test]
fn the_phases_account_for_every_pulse_to_probe() {
    let r = run_one(Case::SogCalibrated, 2).expect("run");
    let steps = r.steps.expect("reached probe here");
    let total: u32 = r.phases.iter().sum();
    assert_eq!(f64::from(total), steps, "{:?}", r.phases);
    // A rescue goes through the flux line, the walk to the mean and the fine search.
    assert!(r.phases[1] > 0 && r.phases[2] > 0, "{:?}", r.phases);
    assert!(r.phases[3] + r.phases[4] > 0, "{:?}", r.phases);
    let table = phase_table(std::slice::from_ref(&r));
    assert!(table.contains("| flux line |"), "{table}");
    // The bound replaces the fine-search pulses by the walk of its 2 m.
    let [first, start] = fine_search_at_walking_pace(&[&r]).expect("one run");
    let fine = f64::from(r.phases[3] + r.phases[4] + r.phases[5]);
    let ideal = r.ideal_steps.expect("ideal");
    let walk = FINE_WALK_M * ideal / r.first_rx_distance_m.expect("first pulse");
    assert!(
        (first - (steps - fine + walk) / ideal).abs() < 1e-9,
        "{first}"
    );
    let from_start = r.steps_from_start.expect("from start");
    let expected = (from_start - fine + walk) / r.ideal_steps_from_start;
    assert!((start - expected).abs() < 1e-9, "{start}");
    assert!(
        table.contains("any fine-search policy could take"),
        "{table}"
    );
}

#[test]
fn weak_beacons_at_the_edge_of_reception_are_reached() {
    // Seeds 19 and 80: weak transmitters heard from ≈ 37 m, whose pulses come and go
    // on the flux line. Before the receiver reversed the flux line on a lost weak
    // signal, the rescuer walked in and out at the edge of reception for minutes
    // (4.6× and 3.1× the ideal steps, the report's two failures); now 1.3× and 1.6×.
    // Seed 80 still loses the signal on the way (the reversal is exercised); seed 19
    // no longer does since a horizontal field within the noise keeps the rescuer
    // walking straight (`GuidanceConfig::flux_min_snr`).
    for seed in [19, 80] {
        let r = run_one(Case::SogCalibrated, seed).expect("run");
        assert!(
            seed != 80 || r.phases[0] > 0,
            "seed {seed}: the signal was lost on the way"
        );
        let steps = r.steps.expect("reached probe here");
        let ratio = steps / r.ideal_steps.expect("ideal steps");
        assert!(ratio < 2.0, "seed {seed}: {steps} steps, {ratio:.2}× ideal");
        assert!(
            r.error_h_m.is_some_and(|e| e < 0.2),
            "seed {seed}: {:?}",
            r.error_h_m
        );
    }
}

#[test]
fn a_noisy_horizontal_field_does_not_walk_the_rescuer_in_circles() {
    // Seed 3025: a near-vertical moment heard from 43 m near its equator, where the
    // field is nearly vertical and its horizontal part below the noise. Following each
    // pulse's noisy horizontal direction walked the rescuer in circles for 170 pulses
    // (4.4× the ideal steps, a failure); holding the direction until the horizontal
    // field is significant (`GuidanceConfig::flux_min_snr`) reaches it in 1.5×.
    let r = run_one(Case::SogCalibrated, 3025).expect("run");
    let steps = r.steps.expect("reached probe here");
    let ratio = steps / r.ideal_steps.expect("ideal steps");
    assert!(ratio < 2.0, "{steps} steps, {ratio:.2}× ideal");
}

#[test]
fn a_lowering_started_after_the_steps_under_way_is_measured() {
    // Seeds 1012 and 1037: "LOWER TO SNOW" came while the rescuer was finishing
    // steps; the prompt ran out before the lowering, which went unmeasured, and the
    // firmware took the receiver for 0.8 m higher than it was (probe 0.38 / 0.28 m
    // off). The prompt now waits for the rescuer to stand.
    for seed in [1012, 1037] {
        let mut worst: f64 = 0.0;
        let o = closed_loop::run(&Case::SogCalibrated.config(seed), &mut |r, _| {
            worst = worst.max((f64::from(r.display.height_m) - r.rx[2]).abs());
        })
        .expect("run");
        // The hand's bob is a few centimetres; an unmeasured lowering is 0.8 m.
        assert!(worst < 0.15, "seed {seed}: tracked height {worst:.2} m off");
        assert!(
            o.error_h_m.is_some_and(|e| e < 0.25),
            "seed {seed}: {:?}",
            o.error_h_m
        );
    }
}

#[test]
fn median_and_the_probe_tradeoff_table() {
    assert_eq!(median(&[1.0, 2.0, 3.0]), 2.0);
    assert_eq!(median(&[1.0, 2.0, 3.0, 4.0]), 2.5);
    assert!(median(&[]).is_nan());
    let args = Args {
        tries: 1,
        out: None,
        runs: None,
        no_lift: false,
        first_seed: 2,
        calibrated_only: true,
        trace: None,
        trace_case: Case::SogCalibrated,
        probe_tradeoff: vec![0.3, 0.6],
    };
    let table = probe_tradeoff(&args, &args.probe_tradeoff).expect("runs");
    // One row per radius; the default radius reproduces the calibrated case.
    assert_eq!(table.lines().filter(|l| l.starts_with("| 0.")).count(), 2);
    let r = run_one(Case::SogCalibrated, 2).expect("run");
    let row = format!(
        "| 0.30 | {:.3} |",
        Rescue::ratio(r.steps, r.ideal_steps).expect("reached probe here")
    );
    assert!(table.contains(&row), "{table}\n{row}");
}

#[test]
fn the_walk_dead_reckoning_is_consistent_and_the_fine_search_is_counted() {
    let r = run_one(Case::SogCalibrated, 2).expect("run");
    let [walk, steps, no_step] = r.dead_reckoning;
    // Every interval up to the probe is classified (the first received pulse has no
    // displacement before it).
    let counted: u32 = r.dead_reckoning.iter().map(|s| s.n).sum();
    let heard = r.phases.iter().sum::<u32>() - r.phases[0];
    assert!(
        counted + 1 >= heard && counted <= heard,
        "{counted} vs {heard}"
    );
    // Walking, the PDR's covariance covers its error (a frame or sign slip in the
    // comparison would give metre errors against a decimetre σ).
    let n = f64::from(walk.n);
    assert!(walk.n > 20, "{walk:?}");
    assert!(walk.nees_sum / n < 3.0, "{walk:?}");
    assert!((walk.err2_sum_m2 / n).sqrt() < 0.3, "{walk:?}");
    assert!(steps.n + no_step.n > 0, "{steps:?} {no_step:?}");
    let table = dead_reckoning_table(&[r]);
    assert!(
        table.contains("| fine search, no step counted |"),
        "{table}"
    );
}
