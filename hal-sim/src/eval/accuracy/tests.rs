use super::*;

fn result(evaluated: usize, nees_in: usize, nees_sum: f64, nis: (usize, usize)) -> RunResult {
    let mut t = Tracker::new(1, 50.0);
    t.result.evaluated_steps = evaluated;
    t.result.nees_inside_95 = nees_in;
    t.result.nees_sum = nees_sum;
    t.result.nis_inside_95 = nis.0;
    t.result.nis_evaluated = nis.1;
    t.finish()
}

#[test]
fn the_imu_case_runs_the_application_pipeline_and_finds_the_victim() {
    // The firmware's own attitude and dead reckoning from the simulated IMU: a broken
    // motion pipeline (axes, units, step detection) ends metres off.
    let r = run_imu(3);
    let err = r.final_error_m.expect("initialized");
    assert!(
        err < 0.2 * r.final_distance_m,
        "{err:.3} m at {:.2} m",
        r.final_distance_m
    );
    assert!(r.evaluated_steps > 10 && r.nis_evaluated == 0);
    assert!(consistency_line(&[r]).ends_with("3 when consistent)."));
}

#[test]
fn consistency_line_pools_the_runs() {
    let runs = [result(10, 9, 30.0, (8, 10)), result(30, 27, 90.0, (20, 30))];
    let line = consistency_line(&runs);
    assert!(line.contains("inside on 90.0 % of 40 steps"), "{line}");
    assert!(line.contains("mean NEES 3.00"), "{line}");
    assert!(line.contains("inside on 70.0 % of 40 updates"), "{line}");
}

#[test]
fn ablation_scales_one_source_and_keeps_the_pulse_noise() {
    let n = MotionNoise::default();
    let s = scaled(&n, Source::Yaw, 0.5);
    assert_eq!(s.attitude_sigma_rad, [0.02, 0.025]);
    assert_eq!(s.sigma_t_m_per_sqrt_m, n.sigma_t_m_per_sqrt_m);
    let o = only(&n, Some(Source::Scale));
    assert_eq!(o.scale_multiplier, 1.0);
    assert_eq!(o.pulse_multiplier, 1.0);
    assert!((o.sigma_hand_m - REMOVED * n.sigma_hand_m).abs() < 1e-15);
    assert!((o.attitude_sigma_rad[1] - REMOVED * n.attitude_sigma_rad[1]).abs() < 1e-15);
}

#[test]
fn the_bound_of_a_seeded_run_shrinks_when_the_motion_noise_is_removed() {
    // Same scenario and pulses: with the dead-reckoning and attitude noise at 10 %,
    // the information about the final position can only grow.
    let noise = MotionNoise::default();
    let full = run_open_loop(Case::Calibrated, 3, &noise);
    let quiet = run_open_loop(Case::Calibrated, 3, &only(&noise, None));
    let (b_full, b_quiet) = (full.final_bound.unwrap(), quiet.final_bound.unwrap());
    assert!(b_full.cholesky().is_some());
    assert!(
        b_quiet.trace() < 0.5 * b_full.trace(),
        "{} vs {}",
        b_quiet.trace(),
        b_full.trace()
    );
    let norm = bound_normalized_mean(std::slice::from_ref(&full)).unwrap();
    assert!(norm.is_finite() && norm >= 0.0);
    let [p99, mean, median] = bound_stats(std::slice::from_ref(&full), false, false).unwrap();
    assert!(median < p99 && mean > 0.0);
    // The oracle start runs the same scenario and ends initialized.
    let o = run_open_loop_oracle(Case::Calibrated, 3, &noise, 0.05);
    assert!(o.final_error_m.is_some_and(f64::is_finite));
}

#[test]
fn the_nees_of_a_seeded_known_trajectory_run_is_counted() {
    // The truth is compared with the filter's own covariance: a NEES above the bound
    // on every step would be a broken filter or a broken count.
    let r = run_open_loop(Case::Known, 3, &MotionNoise::default());
    assert!(r.evaluated_steps > 20);
    // NEES ≤ 7.815 implies NEES ≤ 9 (the 3σ count).
    assert!(r.nees_inside_95 <= r.inside_3sigma);
    assert!(r.nees_inside_95 <= r.evaluated_steps);
    assert!(r.nis_evaluated > 20 && r.nis_inside_95 <= r.nis_evaluated);
    let frac = r.nees_inside_95 as f64 / r.evaluated_steps as f64;
    assert!(
        frac > 0.5,
        "NEES inside the 95 % bound on only {frac:.2} of the steps"
    );
    assert!((r.nees_sum / r.evaluated_steps as f64).is_finite());
}
