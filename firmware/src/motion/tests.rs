use super::*;
use crate::frame::rotation_from_rpy;

fn earth() -> Vec3 {
    Vec3::new(21.792, 0.0, -42.768)
}

fn level_sample(yaw: f32) -> (Vec3, Vec3) {
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, yaw));
    (
        r.transpose() * Vec3::new(0.0, 0.0, GRAVITY),
        r.transpose() * earth(),
    )
}

fn running() -> Motion {
    let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let (acc, mag) = level_sample(0.3);
    for k in 0..50 {
        m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
            .unwrap();
    }
    m
}

#[test]
fn tilt_heading_variance_is_tan_dip_squared_times_tilt() {
    let cov = Mat3::from_diagonal(&Vec3::new(1e-4, 4e-4, 1e-6));
    let tan_dip = 42.768 / 21.792;
    let v = tilt_heading_var(&earth(), &cov);
    assert!((v - tan_dip * tan_dip * 4e-4).abs() < 1e-7, "{v}");
    // A vertical field has no heading: nothing to add (and no division by zero).
    assert_eq!(tilt_heading_var(&Vec3::new(0.0, 0.0, -50.0), &cov), 0.0);
    let off = MotionConfig {
        tilt_heading: false,
        ..MotionConfig::new(earth(), Some(0.6))
    };
    let mut m = Motion::new(off);
    let mut on = running();
    let (acc, mag) = level_sample(0.3);
    for k in 0..50 {
        m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
            .unwrap();
    }
    let (a, b) = (m.attitude().1, on.attitude().1);
    let extra = tilt_heading_var(&earth(), &a);
    assert!(extra > 0.0);
    assert!((b[(2, 2)] - a[(2, 2)] - extra).abs() < 1e-9);
    let _ = on.take_displacement(0.5);
}

/// A sustained horizontal acceleration (a walker's surge lasting seconds, which the
/// attitude filter takes for white noise) tilts the estimate, and the tilt turns the
/// magnetometer heading by ≈ tan(dip) · tilt: the reported yaw σ covers that error.
#[test]
fn yaw_sigma_covers_the_heading_error_of_a_tilt_error() {
    let mut m = running();
    let (acc, mag) = level_sample(0.3);
    let surge = acc + Vec3::new(0.5, 0.0, 0.0);
    let mut worst: f32 = 0.0;
    for k in 50..550 {
        m.on_imu(k as f32 * 0.01, &surge, &Vec3::zeros(), &mag)
            .unwrap();
        let (rpy, cov) = m.attitude();
        let err = wrap_pi(rpy.z - 0.3);
        worst = worst.max(err.abs() / cov[(2, 2)].sqrt());
    }
    assert!(worst < 3.0, "yaw error {worst} σ");
    let (rpy, cov) = m.attitude();
    // The test does exercise a heading error beyond the filter's own yaw σ.
    let own = m
        .attitude_filter()
        .map(|f| f.rpy_cov()[(2, 2)])
        .unwrap_or(0.0);
    assert!(
        wrap_pi(rpy.z - 0.3).abs() > 3.0 * own.sqrt(),
        "{rpy:?} {cov:?}"
    );
}

#[test]
fn a_saturated_magnetometer_drops_the_heading_aid_only() {
    let (acc, mag) = level_sample(0.3);
    let gyr = Vec3::new(0.0, 0.0, 0.2);
    for axis in 0..3 {
        let mut with = running();
        let mut without = running();
        let mut sat = mag;
        sat[axis] = if axis == 1 { -4900.0 } else { 6000.0 };
        for k in 1..=20 {
            let t = 0.5 + 0.01 * k as f32;
            with.on_imu_sample(t, &acc, &gyr, Some(&sat)).unwrap();
            without.on_imu_sample(t, &acc, &gyr, None).unwrap();
        }
        // Fed as a sample without magnetometer: acc and gyro still move the state.
        assert_eq!(with, without, "axis {axis}");
        assert_ne!(with, running());
    }
    // A non-finite magnetometer reading is still refused.
    let mut m = running();
    let nan = Vec3::new(0.0, f32::NAN, 0.0);
    assert_eq!(
        m.on_imu_sample(0.51, &acc, &gyr, Some(&nan)),
        Err(MotionError::NonFinite)
    );
}

#[test]
fn bad_input_leaves_state_unchanged() {
    let mut m = running();
    let before = m.clone();
    let (acc, mag) = level_sample(0.3);
    let z = Vec3::zeros();
    let nan = Vec3::new(f32::NAN, 0.0, 0.0);
    let inf = Vec3::new(0.0, f32::INFINITY, 0.0);
    let t = 0.5;
    assert_eq!(m.on_imu(t, &nan, &z, &mag), Err(MotionError::NonFinite));
    assert_eq!(m.on_imu(t, &acc, &inf, &mag), Err(MotionError::NonFinite));
    assert_eq!(m.on_imu(t, &acc, &z, &nan), Err(MotionError::NonFinite));
    assert_eq!(
        m.on_imu(f32::NAN, &acc, &z, &mag),
        Err(MotionError::NonFinite)
    );
    let sat = Vec3::new(0.0, 0.0, 160.0);
    assert_eq!(m.on_imu(t, &sat, &z, &mag), Err(MotionError::Saturated));
    let spin = Vec3::new(35.0, 0.0, 0.0);
    assert_eq!(m.on_imu(t, &acc, &spin, &mag), Err(MotionError::Saturated));
    assert_eq!(
        m.on_imu(49.0 * 0.01, &acc, &z, &mag),
        Err(MotionError::TimeNotIncreasing)
    );
    assert_eq!(
        m.on_imu(0.2, &acc, &z, &mag),
        Err(MotionError::TimeNotIncreasing)
    );
    assert!(matches!(
        m.on_imu(1.0, &acc, &z, &mag),
        Err(MotionError::Gap { .. })
    ));
    assert_eq!(m, before);
    // After a gap, resync lets the samples flow again.
    m.resync(1.0).unwrap();
    m.on_imu(1.01, &acc, &z, &mag).unwrap();
    // A calibration without a start, and with too few steps.
    assert_eq!(m.finish_calibration(20.0), Err(MotionError::NoCalibration));
    m.start_calibration();
    assert_eq!(
        m.finish_calibration(20.0),
        Err(MotionError::TooFewSteps { steps: 0 })
    );
}

#[test]
fn standing_still_gives_a_still_displacement() {
    let mut m = running();
    let d0 = m.take_displacement(0.495);
    let (acc, mag) = level_sample(0.3);
    for k in 50..150 {
        m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
            .unwrap();
    }
    let d = m.take_displacement(1.495);
    assert!(d0.translation.norm() < 1e-6 && d.translation.norm() < 1e-6);
    assert!(d.rotation.norm() < 1e-3);
    assert_eq!(d.steps, 0);
    let (rpy, cov) = m.attitude();
    assert!((rpy - Rpy::new(0.0, 0.05, 0.3)).norm() < 1e-3);
    assert!(cov[(2, 2)] > 0.0);
    assert!((m.scale_sigma() - 0.02).abs() < 1e-7);
}

#[test]
fn lowering_and_raising_in_lift_mode_track_the_height() {
    // Standing, device pitched 0.05 rad: lowered 0.8 m over 1 s from t = 2 s
    // (minimum jerk), pulses during and after; then raised again from t = 6 s.
    let mut m = running();
    m.set_lift_mode(true);
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, 0.3));
    let mag = r.transpose() * earth();
    let jerk = |t: f32, t0: f32, dz: f32| {
        let u = t - t0;
        if (0.0..=1.0).contains(&u) {
            dz * (60.0 * u - 180.0 * u * u + 120.0 * u * u * u)
        } else {
            0.0
        }
    };
    let mut after_lowering = f32::NAN;
    for k in 50..900 {
        let t = k as f32 * 0.01;
        let a = jerk(t, 2.0, -0.8) + jerk(t, 6.0, 0.8);
        let acc = r.transpose() * Vec3::new(0.0, 0.0, a + GRAVITY);
        m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        if k % 90 == 0 {
            let _ = m.take_displacement(t);
        }
        if k == 500 {
            after_lowering = m.vertical_m();
        }
    }
    let _ = m.take_displacement(9.0);
    assert!((after_lowering + 0.8).abs() < 0.02, "{after_lowering}");
    assert!(m.vertical_m().abs() < 0.02, "raised: {}", m.vertical_m());
    assert_eq!(m.total_steps(), 0, "the moves are not taken for steps");
    // A rescuer who ignores the prompt: nothing measured, nothing changes.
    let mut still = running();
    still.set_lift_mode(true);
    let acc = r.transpose() * Vec3::new(0.0, 0.0, GRAVITY);
    for k in 50..400 {
        let t = k as f32 * 0.01;
        still.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        if k % 90 == 0 {
            let _ = still.take_displacement(t);
        }
    }
    assert_eq!(still.vertical_m(), 0.0);
}

#[test]
fn a_lift_in_lift_mode_gives_the_absolute_vertical_part() {
    // Standing, device pitched 0.05 rad, yaw 0.3: a 0.4 m raised-cosine lift over
    // 2 s from t = 2 s; pulses before, at the top and after.
    let mut m = running();
    m.set_lift_mode(true);
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, 0.3));
    let mag = r.transpose() * earth();
    let w = 2.0 * core::f32::consts::PI / 2.0;
    let mut got = [Displacement::still(0.0, 0.0); 3];
    let pulses = [1.5f32, 3.0, 5.0];
    let mut next = 0;
    for k in 50..600 {
        let t = k as f32 * 0.01;
        let a = if (2.0..=4.0).contains(&t) {
            0.2 * w * w * libm::cosf(w * (t - 2.0))
        } else {
            0.0
        };
        let acc = r.transpose() * Vec3::new(0.0, 0.0, a + GRAVITY);
        m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        if next < 3 && t >= pulses[next] - 1e-4 {
            got[next] = m.take_displacement(t);
            next += 1;
        }
    }
    assert_eq!(got[0].absolute, Vec3::zeros());
    assert_eq!(m.total_steps(), 0, "the lift is not taken for steps");
    // In R_{k-1} axes; back in W it is vertical.
    let up = r * got[1].absolute;
    assert!((up - Vec3::new(0.0, 0.0, 0.4)).norm() < 0.02, "{up:?}");
    let down = r * got[2].absolute;
    assert!((down + Vec3::new(0.0, 0.0, 0.4)).norm() < 0.02, "{down:?}");
    let var_w = r * got[1].absolute_cov * r.transpose();
    assert!(var_w[(2, 2)] > 0.0 && var_w[(2, 2)].sqrt() < 0.05);
    assert!(var_w[(0, 0)] < 1e-5);
    assert!(got.iter().all(|d| d.translation.norm() < 1e-6));
}

#[test]
fn synthetic_walk_counts_steps_and_moves_forward() {
    // Walk north-west (yaw 0.8) at 1.8 steps/s with a 2.5 m/s² vertical bob.
    let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let yaw = 0.8f32;
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, yaw));
    let mag = r.transpose() * earth();
    let f = 1.8f32;
    let mut total = Vec3::zeros();
    let mut steps = 0u32;
    for k in 0..1000 {
        let t = k as f32 * 0.01;
        let a_w = Vec3::new(0.0, 0.0, 2.5 * (2.0 * core::f32::consts::PI * f * t).sin());
        let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
        m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        if k % 100 == 99 {
            let d = m.take_displacement(t);
            total += r * d.translation;
            steps += d.steps as u32;
        }
    }
    // 10 s × 1.8 = 18 peaks (the first needs the filter to settle).
    assert!((17..=18).contains(&m.total_steps()), "{}", m.total_steps());
    assert_eq!(steps, m.total_steps());
    let dir = Vec3::new(yaw.cos(), yaw.sin(), 0.0);
    let along = total.dot(&dir);
    assert!((along - 0.6 * steps as f32).abs() < 0.61, "{along}");
    assert!((total - dir * along).norm() < 0.05);
}

/// Feeds 100 Hz samples of a level device from `t0` for `secs` s: yaw `yaw(t)` (its
/// rate on the gyro), and the bob of a walk (the sim's gait: one upward acceleration
/// peak in the middle of each step) while `phase(t)` advances, none when it stands.
fn feed(
    m: &mut Motion,
    t0: f32,
    secs: f32,
    yaw: impl Fn(f32) -> f32,
    phase: impl Fn(f32) -> Option<f32>,
) -> f32 {
    let n = (secs * 100.0).round() as usize;
    let mut t = t0;
    for k in 1..=n {
        t = t0 + k as f32 * 0.01;
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, yaw(t)));
        let rate = (yaw(t + 0.005) - yaw(t - 0.005)) / 0.01;
        // z = B (cos 2πφ − 1) at 1.8 steps/s, B = 2 cm: z'' = −B (2π·1.8)² cos 2πφ.
        let w = core::f32::consts::TAU * 1.8;
        let az = phase(t).map_or(0.0, |ph| {
            -0.02 * w * w * libm::cosf(core::f32::consts::TAU * ph)
        });
        let acc = r.transpose() * Vec3::new(0.0, 0.0, GRAVITY + az);
        m.on_imu(
            t,
            &acc,
            &Vec3::new(0.0, 0.0, rate),
            &(r.transpose() * earth()),
        )
        .unwrap();
    }
    t
}

/// Two steps from rest, at 1.8 steps/s from `t0` (phase 0 → 2).
fn two_steps(t0: f32) -> impl Fn(f32) -> Option<f32> {
    move |t| {
        let ph = (t - t0) * 1.8;
        (0.0..2.0).contains(&ph).then_some(ph)
    }
}

#[test]
fn a_pulse_during_a_short_walk_and_one_after_it_split_the_two_steps_right() {
    // Stand 1 s, walk two steps (t 1.0 – 2.11 s), a pulse at 2.0 s (φ = 1.8: 1.8 steps
    // walked), stand, a pulse at 3.5 s (2 steps walked, 0.2 of them since the pulse).
    let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let yaw = |_: f32| 0.3f32;
    let t = feed(&mut m, 0.0, 1.0, yaw, |_| None);
    let d0 = m.take_displacement(t);
    let t = feed(&mut m, t, 1.0, yaw, two_steps(1.0));
    let d1 = m.take_displacement(t);
    let t = feed(&mut m, t, 1.5, yaw, two_steps(1.0));
    let d2 = m.take_displacement(t);
    assert!(d0.translation.norm() < 1e-6);
    assert_eq!(d1.steps + d2.steps, 2, "{d1:?} {d2:?}");
    // The device frame is the walking frame (level, facing the walk): forward is x.
    assert!(
        (d1.translation.x - 1.8 * 0.6).abs() < 0.1,
        "{:?}",
        d1.translation
    );
    // After the stop the remaining 0.2 step, not the half step the count ran ahead
    // taken back (the walker standing would seem to move 0.2–0.3 m backwards).
    assert!(
        (d2.translation.x - 0.2 * 0.6).abs() < 0.1,
        "{:?}",
        d2.translation
    );
    assert!((d1.translation.x + d2.translation.x - 1.2).abs() < 0.02);
    // Each within its own σ (consistent, not merely unbiased).
    let sd = |d: &Displacement| libm::sqrtf(d.cov[(0, 0)]);
    assert!((d1.translation.x - 1.08).abs() < 3.0 * sd(&d1), "{d1:?}");
    assert!(
        (d2.translation.x - 0.12).abs() < 3.0 * sd(&d2) + 0.03,
        "{d2:?}"
    );
}

#[test]
fn a_turn_on_the_spot_does_not_bend_the_next_step() {
    // Stand facing yaw 0.3, turn around on the spot (π in 1.5 s), stand 0.5 s, walk
    // two steps: they go along the new yaw. The mean yaw since the last step (the
    // stand before the turn included) pointed them up to 90° sideways.
    let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let yaw = |t: f32| 0.3 + core::f32::consts::PI * ((t - 1.0) / 1.5).clamp(0.0, 1.0);
    let t = feed(&mut m, 0.0, 1.0, yaw, |_| None);
    let _ = m.take_displacement(t);
    let t = feed(&mut m, t, 3.0, yaw, |_| None);
    let r0 = rotation_from_rpy(&Rpy::new(0.0, 0.0, yaw(t)));
    let _ = m.take_displacement(t);
    let t = feed(&mut m, t, 2.0, yaw, two_steps(4.0));
    let d = m.take_displacement(t);
    assert_eq!(d.steps, 2);
    let along = r0 * d.translation;
    let dir = Vec3::new(libm::cosf(yaw(t)), libm::sinf(yaw(t)), 0.0);
    assert!((along.dot(&dir) - 1.2).abs() < 0.05, "{along:?}");
    assert!((along - dir * along.dot(&dir)).norm() < 0.05, "{along:?}");
}

#[test]
fn split_cuts_compose_to_the_single_interval_without_inflating_q() {
    // One victim's pulses every 1.1 s, other victims' pulses at 0.37 s between them.
    // Victim A through take_split (composing every cut, its own pulse adding the
    // partial step and restarting from `back`) must match a receiver hearing A alone
    // (take_displacement at A's pulses); composing whole take_displacement cuts
    // instead adds the partial step's variance twice at every other pulse.
    use crate::estimate::Displacement as E;
    use crate::victims::compose;
    let e = |d: &Displacement| E {
        translation: d.translation,
        rotation: d.rotation,
        cov: d.cov,
        absolute: d.absolute,
        absolute_cov: d.absolute_cov,
    };
    let mut split = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let (mut alone, mut naive) = (split.clone(), split.clone());
    let yaw = 0.8f32;
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, yaw));
    let mag = r.transpose() * earth();
    let (mut pend_split, mut pend_naive) = (E::zero(), E::zero());
    let (mut worst, mut infl_split, mut infl_naive) = (0.0f32, 0.0f32, 0.0f32);
    let (mut split_steps, mut split_standing) = (0u32, true);
    for k in 0..1200 {
        let t = k as f32 * 0.01;
        let a_w = Vec3::new(
            0.0,
            0.0,
            2.5 * (2.0 * core::f32::consts::PI * 1.8 * t).sin(),
        );
        let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
        for m in [&mut split, &mut alone, &mut naive] {
            m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        }
        let own = k % 110 == 109;
        if !(own || k % 37 == 36) {
            continue;
        }
        let s = split.take_split(t);
        pend_split = compose(&pend_split, &e(&s.cut)).unwrap();
        split_steps += u32::from(s.cut.steps);
        split_standing &= s.standing;
        pend_naive = compose(&pend_naive, &e(&naive.take_displacement(t))).unwrap();
        if own {
            let mut full = compose(&pend_split, &e(&s.partial)).unwrap();
            full.cov += split
                .config()
                .noise
                .interval_floors(split_steps, split_standing);
            let d = e(&alone.take_displacement(t));
            if k > 300 {
                worst = worst.max((full.translation - d.translation).norm());
                let tr = |c: &crate::estimate::Mat6| c[(0, 0)] + c[(1, 1)];
                infl_split = infl_split.max(tr(&full.cov) / tr(&d.cov));
                infl_naive = infl_naive.max(tr(&pend_naive.cov) / tr(&d.cov));
            }
            pend_split = e(&s.back);
            (split_steps, split_standing) = (0, true);
            pend_naive = E::zero();
        }
    }
    assert!(worst < 0.02, "{worst}");
    // Neither the partial step nor the per-interval floors come with every cut: the
    // victim's Q_k stays that of a receiver hearing it alone.
    assert!(
        infl_naive > infl_split * 1.05 && infl_split < 1.2,
        "{infl_naive} vs {infl_split}"
    );
}

#[test]
fn a_lone_victim_gets_the_same_displacement_from_take_split() {
    use crate::estimate::Displacement as E;
    let e = |d: &Displacement| E {
        translation: d.translation,
        rotation: d.rotation,
        cov: d.cov,
        absolute: d.absolute,
        absolute_cov: d.absolute_cov,
    };
    let mut split = Motion::new(MotionConfig::new(earth(), Some(0.6)));
    let mut alone = split.clone();
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, -0.4));
    let mag = r.transpose() * earth();
    let mut back = E::zero();
    for k in 0..900 {
        let t = k as f32 * 0.01;
        let a_w = Vec3::new(
            0.0,
            0.0,
            2.5 * (2.0 * core::f32::consts::PI * 1.7 * t).sin(),
        );
        let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
        split.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        alone.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        if k % 93 == 92 {
            let s = split.take_split(t);
            let own = crate::victims::compose(&back, &e(&s.cut)).unwrap();
            let mut own = crate::victims::compose(&own, &e(&s.partial)).unwrap();
            // The floors come once per victim interval (here: one cut per interval).
            own.cov += split
                .config()
                .noise
                .interval_floors(u32::from(s.cut.steps), s.standing);
            let d = alone.take_displacement(t);
            assert!((own.translation - d.translation).norm() < 1e-3, "{k}");
            let (a, b) = (
                own.cov[(0, 0)] + own.cov[(1, 1)],
                d.cov[(0, 0)] + d.cov[(1, 1)],
            );
            // Equal but for the heading errors of the partial step, applied to it
            // apart instead of to the whole interval (measured ≤ 11 %).
            assert!((a - b).abs() <= 0.15 * b, "{k}: {a} vs {b}");
            back = e(&s.back);
        }
    }
}

#[test]
fn calibration_walk_sets_the_step_length() {
    let mut m = Motion::new(MotionConfig::new(earth(), None));
    let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, 0.0));
    let mag = r.transpose() * earth();
    for k in 0..2500 {
        let t = k as f32 * 0.01;
        if k == 100 {
            m.start_calibration();
        }
        let az = if k >= 100 {
            2.5 * (2.0 * core::f32::consts::PI * 1.8 * t).sin()
        } else {
            0.0
        };
        let acc = Vec3::new(0.0, 0.0, GRAVITY + az);
        m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
    }
    let n = m.total_steps();
    let res = m.finish_calibration(20.0).unwrap();
    assert_eq!(res.steps, n);
    assert!((res.step_length_m - 20.0 / n as f32).abs() < 1e-5);
    assert!((m.scale_sigma() - 0.02).abs() < 1e-7);
}
