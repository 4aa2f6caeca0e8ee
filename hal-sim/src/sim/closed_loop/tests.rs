use super::*;

#[test]
fn imu_at_rest_reads_gravity_and_earth_field() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let quiet = ImuNoise {
        gyr_noise_rad_s: 0.0,
        acc_noise_m_s2: 0.0,
        mag_noise_ut: 0.0,
        ..ImuNoise::default()
    };
    let pose = |t| Pose {
        t,
        p: V3::new(1.0, 2.0, 1.0),
        rpy: V3::new(0.0, 0.0, 0.5),
    };
    let earth = V3::new(21.0, 0.0, -42.0);
    let (a, g, m) = imu_sample(
        &mut rng,
        &quiet,
        &V3::zeros(),
        &earth,
        [&pose(0.0), &pose(0.01), &pose(0.02)],
    );
    assert!((a - Vec3::new(0.0, 0.0, 9.80665)).norm() < 1e-4);
    assert!(g.norm() < 1e-9);
    assert!((m.norm() - earth.norm() as f32).abs() < 1e-3 && m.z < -41.0);
}

#[test]
fn a_rescuer_lowers_the_receiver_and_its_height_is_tracked() {
    // Seed 35: a victim 1.5 m deep, deep enough for the lowering.
    let o = run(&ClosedLoopConfig::new(35), &mut |_, _| {}).expect("run");
    assert!(o.probe_t.is_some(), "reached probe here");
    assert!(o.height_moves >= 1, "the receiver was lowered");
    let last = o.rows.last().expect("pulses");
    // The true receiver is near the snow (within the 4 cm step bounce of 0.2 m), and
    // the tracked height agrees with it.
    assert!(last.rx[2] < LOW_HOLD_M + 0.05, "true height {}", last.rx[2]);
    let tracked = f64::from(last.display.height_m);
    assert!((tracked - last.rx[2]).abs() < 0.06, "tracked {tracked}");
    // The depth shown is below the snow, not below the receiver.
    let depth = o.depth_shown_m.expect("depth shown");
    assert!(
        (depth + o.victim[2]).abs() < 0.3,
        "depth {depth} vs {}",
        -o.victim[2]
    );
    // Without the prompt the whole fine search stays at the walking height.
    let mut cfg = ClosedLoopConfig::new(35);
    cfg.lower = false;
    let o = run(&cfg, &mut |_, _| {}).expect("run");
    assert_eq!(o.height_moves, 0);
    let last = o.rows.last().expect("pulses");
    assert!(last.rx[2] > HOLD_HEIGHT_M - 0.05);
    assert!((f64::from(last.display.height_m) - HOLD_HEIGHT_M).abs() < 0.02);
}
