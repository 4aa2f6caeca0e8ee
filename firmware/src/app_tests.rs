use super::*;
use crate::estimate::EstimateError;
use crate::frame::rotation_from_rpy;
use crate::frontend::FrontendConfig;
use crate::frontend::FrontendError;

/// `t` s since boot as a time stamp.
fn at(t: f32) -> Instant {
    Instant::from_secs_f64(f64::from(t)).unwrap()
}

fn config() -> AppConfig {
    AppConfig::new(Vec3::new(21.0, 0.0, -42.0), Some(0.56))
}

fn level_imu(rx: &mut Receiver, t0: f32, n: usize) -> f32 {
    let earth = Vec3::new(21.0, 0.0, -42.0);
    let mut t = t0;
    for _ in 0..n {
        t += 0.01;
        rx.on_imu(
            at(t),
            &Vec3::new(0.0, 0.0, 9.80665),
            &Vec3::zeros(),
            Some(&earth),
        )
        .unwrap();
    }
    t
}

#[test]
fn fits_in_sram_beside_the_stack_with_four_victims() {
    // 128 KB SRAM minus a 36 KB stack (high-water ≈ 25 KB in the QEMU soak).
    let bytes = core::mem::size_of::<Receiver>();
    assert!(bytes <= 92 * 1024, "Receiver is {bytes} bytes");
}

#[test]
fn bad_inputs_are_refused_and_leave_the_state_intact() {
    let mut rx = Receiver::new(config()).unwrap();
    let t = level_imu(&mut rx, 10.0, 50);
    // A dipole 20 m north, 1 m down, moment along north.
    let h = crate::dipole::field(&Vec3::new(-20.0, 0.0, 2.0), &Vec3::new(0.02, 0.0, 0.0)).unwrap();
    let d0 = rx.on_pulse(at(t), &h, None).unwrap();
    assert_eq!(d0.pulses, 1);
    assert_ne!(d0.status, Status::NoSignal);
    let snapshot = format!("{:?}", rx);
    let nan = Vec3::new(f32::NAN, 0.0, 0.0);
    assert_eq!(
        rx.on_pulse(at(t + 1.0), &nan, None),
        Err(AppError::NonFinite)
    );
    assert_eq!(Instant::from_secs_f64(f64::INFINITY), None);
    assert_eq!(
        rx.on_pulse(at(t - 1.0), &h, None),
        Err(AppError::Estimate(EstimateError::TimeWentBackwards))
    );
    assert_eq!(
        rx.on_pulse(at(t + 1.0), &Vec3::zeros(), None),
        Err(AppError::Estimate(EstimateError::ZeroField))
    );
    assert!(matches!(
        rx.on_imu(at(t + 0.01), &nan, &Vec3::zeros(), None),
        Err(AppError::Motion(MotionError::NonFinite))
    ));
    assert!(matches!(
        rx.on_imu(at(t - 0.5), &Vec3::z(), &Vec3::zeros(), None),
        Err(AppError::Motion(MotionError::TimeNotIncreasing))
    ));
    // Everything but the refusal counters is unchanged.
    let mut after = format!("{:?}", rx);
    let stats = *rx.stats();
    assert_eq!((stats.pulses_refused, stats.imu_refused), (3, 2));
    after = after.replace(
        &format!("{:?}", stats),
        &format!("{:?}", AppStats::default()),
    );
    assert_eq!(snapshot, after);
    assert_eq!(rx.display_model(), d0);
}

#[test]
fn classic_mode_guides_along_the_flux_line_without_the_estimator() {
    let cfg = AppConfig {
        mode: SearchMode::Classic,
        ..config()
    };
    let mut rx = Receiver::new(cfg).unwrap();
    let t = level_imu(&mut rx, 10.0, 50);
    // Beacon 30 m to the west, moment along west: the flux line points ±west, so the
    // arrow of a receiver facing north is ±90°, and the distance reading is finite.
    let h = crate::dipole::field(&Vec3::new(0.0, -30.0, 2.0), &Vec3::new(0.0, 0.02, 0.0)).unwrap();
    let d = rx.on_pulse(at(t), &h, Some(0)).unwrap();
    assert_eq!(d.status, Status::FluxLine);
    assert_eq!(d.pulses, 1);
    let a = d.arrow_deg.unwrap();
    assert!((a.abs() - 90.0).abs() < 5.0, "arrow {a}");
    assert!(d.distance_m.is_some_and(|r| r.is_finite() && r > 0.0));
    // The SOGs bank is not used in this mode.
    assert!(rx.victims().is_empty());
    // Refusals leave the state intact and come back as the classic mode's errors.
    let before = format!("{:?}", rx);
    assert_eq!(
        rx.on_pulse(at(t + 1.0), &Vec3::zeros(), None),
        Err(AppError::Classic(ClassicError::ZeroField))
    );
    assert_eq!(
        rx.on_pulse(at(t - 1.0), &h, None),
        Err(AppError::Classic(ClassicError::TimeNotIncreasing))
    );
    let mut after = format!("{:?}", rx);
    after = after.replace(
        &format!("{:?}", rx.stats()),
        &format!("{:?}", AppStats::default()),
    );
    assert_eq!(before, after);
    // No pulse for longer than the timeout: no signal, no arrow.
    let t2 = level_imu(&mut rx, t, 400);
    assert!(t2 - t > cfg.signal_timeout_s);
    let quiet = rx.display_model();
    assert_eq!((quiet.status, quiet.arrow_deg), (Status::NoSignal, None));
}

#[test]
fn flux_line_then_display_turns_with_the_device() {
    let mut rx = Receiver::new(config()).unwrap();
    let t = level_imu(&mut rx, 0.0, 50);
    assert_eq!(rx.display_model().status, Status::NoSignal);
    // Beacon 30 m to the west, moment along west: field along ±west at the receiver.
    let h = crate::dipole::field(&Vec3::new(0.0, -30.0, 2.0), &Vec3::new(0.0, 0.02, 0.0)).unwrap();
    let d = rx.on_pulse(at(t), &h, None).unwrap();
    assert_eq!(d.status, Status::FluxLine);
    assert_eq!(d.victims, 1);
    let a = d.arrow_deg.unwrap();
    assert!((a.abs() - 90.0).abs() < 5.0, "arrow {a}");
    assert!(d.uncertainty_m.is_some());
    // Turn the device 90° to the left (toward west) at rest: the arrow turns with it.
    let earth = Vec3::new(21.0, 0.0, -42.0);
    let r = rotation_from_rpy(&Vec3::new(0.0, 0.0, core::f32::consts::FRAC_PI_2));
    let mut tt = t;
    for _ in 0..300 {
        tt += 0.01;
        let _ = rx.on_imu(
            at(tt),
            &Vec3::new(0.0, 0.0, 9.80665),
            &Vec3::zeros(),
            Some(&(r.transpose() * earth)),
        );
    }
    let turned = rx.display_model().arrow_deg.unwrap();
    assert!((turned - (a - 90.0)).abs() < 15.0, "{a} → {turned}");
    // No pulse for long: no signal.
    let _ = level_imu(&mut rx, tt, 400);
    assert_eq!(rx.display_model().status, Status::NoSignal);
}

/// A pulse of the dipole `m` at `p` (W, relative to the level receiver facing north).
fn pulse_from(p: [f32; 3], m: [f32; 3]) -> Vec3 {
    crate::dipole::field(&(-Vec3::from(p)), &Vec3::from(m)).unwrap()
}

#[test]
fn each_victim_has_its_own_mixture_and_marking_moves_on() {
    let mut rx = Receiver::new(config()).unwrap();
    let mut t = level_imu(&mut rx, 0.0, 20);
    let near = pulse_from([8.0, 3.0, -2.0], [0.02, 0.0, 0.0]);
    let far = pulse_from([-25.0, 10.0, -2.0], [0.0, 0.02, 0.0]);
    let d = rx.on_pulse(at(t), &far, Some(3)).unwrap();
    assert_eq!((d.victims, d.target), (1, Some(1)));
    for _ in 0..6 {
        t = level_imu(&mut rx, t, 45);
        let before = format!("{:?}", rx.victims().filter(0));
        rx.on_pulse(at(t), &near, Some(1)).unwrap();
        // A pulse of victim 2 leaves victim 1's mixture alone.
        assert_eq!(before, format!("{:?}", rx.victims().filter(0)));
        t = level_imu(&mut rx, t, 50);
        rx.on_pulse(at(t), &far, Some(3)).unwrap();
    }
    let d = rx.display_model();
    assert_eq!((d.victims, d.found, d.pulses), (2, 0, 13));
    assert_eq!(rx.victims().get(0).unwrap().pulses(), 7);
    assert_eq!(rx.victims().get(1).unwrap().pulses(), 6);
    let rows: Vec<VictimRow> = d.list.iter().flatten().copied().collect();
    assert_eq!(rows.len(), 2);
    assert!(rows.iter().all(|r| r.distance_m.is_some() && !r.marked));
    // Standing still neither is localized nearer than SWITCH_MIN_M: the first victim
    // heard (list number 1) stays the target.
    assert_eq!(d.target, Some(1));
    assert!(rows[0].target && !rows[1].target);
    // Mark: victim 1 found, the guidance moves on to victim 2; marked stays listed.
    assert_eq!(rx.mark(), Ok(1));
    let d = rx.display_model();
    assert_eq!((d.target, d.found, d.victims), (Some(2), 1, 2));
    assert!(d.list[0].unwrap().marked);
    // Its pulses still update its own mixture, but the guidance stays on victim 2.
    t = level_imu(&mut rx, t, 50);
    let d = rx.on_pulse(at(t), &far, Some(3)).unwrap();
    assert_eq!(d.target, Some(2));
    assert_eq!(rx.mark(), Ok(2));
    assert_eq!(rx.mark(), Err(AppError::NoTarget));
    assert_eq!(rx.display_model().found, 2);
}
#[test]
fn a_silent_target_is_shown_at_its_estimate_then_gives_way_to_a_heard_victim() {
    let mut rx = Receiver::new(config()).unwrap();
    let mut t = level_imu(&mut rx, 0.0, 20);
    let a = pulse_from([8.0, 3.0, -2.0], [0.02, 0.0, 0.0]);
    let b = pulse_from([-25.0, 10.0, -2.0], [0.0, 0.02, 0.0]);
    rx.on_pulse(at(t), &a, Some(3)).unwrap();
    for _ in 0..6 {
        t = level_imu(&mut rx, t, 45);
        rx.on_pulse(at(t), &b, Some(1)).unwrap();
        t = level_imu(&mut rx, t, 50);
        rx.on_pulse(at(t), &a, Some(3)).unwrap();
    }
    assert_eq!(rx.display_model().target, Some(1));
    // Victim 1 falls silent (its pulses withheld, say) beyond the signal timeout:
    // still the target, shown where its mixture puts it (its list row).
    t = level_imu(&mut rx, t, 500);
    let d = rx.on_pulse(at(t), &b, Some(1)).unwrap();
    let row = d.list[0].unwrap();
    assert_eq!(d.target, Some(1));
    assert_eq!(d.status, Status::Localized);
    assert_eq!((d.arrow_deg, d.walk_m), (row.arrow_deg, row.distance_m));
    // Silent for TARGET_SILENT_S while victim 2 is heard: the guidance moves on.
    while rx.display_model().target == Some(1) {
        t = level_imu(&mut rx, t, 100);
        rx.on_pulse(at(t), &b, Some(1)).unwrap();
        assert!(t < 200.0);
    }
    assert_eq!(rx.display_model().target, Some(2));
    assert!(t - rx.victims().get(0).unwrap().last_t() > TARGET_SILENT_S);
}

#[test]
fn full_list_counts_other_sources_and_lost_victims_are_dropped() {
    let mut rx = Receiver::new(config()).unwrap();
    let mut t = level_imu(&mut rx, 0.0, 20);
    let h = pulse_from([10.0, 0.0, -1.0], [0.02, 0.0, 0.0]);
    for src in 0..MAX_VICTIMS as u8 {
        rx.on_pulse(at(t), &h, Some(src)).unwrap();
        t = level_imu(&mut rx, t, 20);
    }
    let d = rx.on_pulse(at(t), &h, Some(9)).unwrap();
    assert_eq!((d.victims, rx.stats().other_source), (MAX_VICTIMS as u8, 1));
    // Sources 1..3 fall silent: after LOST_S they make room for a new one.
    let n = ((crate::victims::LOST_S + 1.0) / 0.01) as usize;
    let later = level_imu(&mut rx, t, n);
    rx.on_pulse(at(later), &h, Some(0)).unwrap();
    let later = level_imu(&mut rx, later, 50);
    rx.on_pulse(at(later), &h, Some(9)).unwrap();
    let d = rx.display_model();
    assert_eq!(d.victims, 2);
    assert_eq!(rx.stats().other_source, 1);
}

#[test]
fn adc_samples_drive_the_front_end() {
    let mut rx = Receiver::new(config()).unwrap();
    let mut fe = Frontend::new(FrontendConfig::default()).unwrap();
    assert!(matches!(
        rx.on_adc_sample(&mut fe, [f32::NAN, 0.0, 0.0], false),
        Err(AppError::Frontend(FrontendError::NonFiniteSample))
    ));
    // Noise only: no pulse.
    let mut seed = 1u32;
    for _ in 0..2000 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let v = (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
        assert_eq!(
            rx.on_adc_sample(&mut fe, [v * 1e-6, v * 1e-6, -v * 1e-6], false),
            Ok(None)
        );
    }
}

#[test]
fn emplace_builds_in_a_slot() {
    let mut slot = Box::new(MaybeUninit::<Receiver>::uninit());
    let rx = Receiver::emplace(&mut slot, config()).unwrap();
    assert_eq!(rx.display_model().pulses, 0);
    let mut bad = config();
    bad.sog.m_min = -1.0;
    assert!(matches!(
        Receiver::new(bad),
        Err(AppError::Estimate(EstimateError::InvalidConfig))
    ));
}
