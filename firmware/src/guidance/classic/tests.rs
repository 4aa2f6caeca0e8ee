use super::*;
use crate::frame::Rpy;

/// Dipole field in f64 (ICRA eq. 1): `(3 (m·r̂) r̂ − m) / (4π r³)`, `r` from the
/// transmitter to the receiver.
fn dipole(r: [f64; 3], m: [f64; 3]) -> [f64; 3] {
    let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let u = [r[0] / n, r[1] / n, r[2] / n];
    let mu = m[0] * u[0] + m[1] * u[1] + m[2] * u[2];
    let k = 1.0 / (4.0 * std::f64::consts::PI * n * n * n);
    [
        k * (3.0 * mu * u[0] - m[0]),
        k * (3.0 * mu * u[1] - m[1]),
        k * (3.0 * mu * u[2] - m[2]),
    ]
}

fn att(rpy: Rpy) -> Attitude {
    Attitude::with_sigmas(rpy, 0.01, 0.05)
}

/// The body-frame pulse of a field `h_g` (A/m in G) seen with attitude `rpy`.
fn pulse(h_g: [f64; 3], rpy: &Rpy, t: f32, sign: f32) -> Pulse {
    let h = Vec3::new(h_g[0] as f32, h_g[1] as f32, h_g[2] as f32);
    Pulse {
        h: rotation_from_rpy(rpy).transpose() * h * sign,
        t,
    }
}

fn search() -> ClassicSearch {
    ClassicSearch::new(ClassicConfig::default()).unwrap()
}

#[test]
fn arrow_is_the_horizontal_flux_line_with_the_walking_sign() {
    // Tilted, turned device; a field with a known horizontal direction.
    let rpy = Rpy::new(0.1, -0.2, 0.7);
    let m = [0.004, -0.006, 0.005];
    let h = dipole([-12.0, 7.0, 2.0], m);
    let expected = (h[1]).atan2(h[0]) as f32;
    for sign in [1.0, -1.0] {
        let mut s = search();
        let out = s
            .on_pulse(&pulse(h, &rpy, 1.0, sign), &att(rpy), 0.0)
            .unwrap();
        let b = out.bearing.unwrap();
        // Along ±(h_x, h_y), the sign that agrees with the device's yaw.
        let d = wrap_pi(b - expected).abs();
        assert!(
            d < 1e-3 || (d - core::f32::consts::PI).abs() < 1e-3,
            "{b} {expected}"
        );
        assert!(libm::cosf(b - rpy.z) >= 0.0);
        let arrow = s.display(1.0, rpy.z).arrow_deg.unwrap();
        let want = wrap_pi(b - rpy.z).to_degrees();
        assert!((arrow - want).abs() < 1e-2, "{arrow} {want}");
        assert_eq!(out.instruction, Instruction::FollowFlux);
    }
}

#[test]
fn distance_reading_is_the_nominal_on_axis_range() {
    let cfg = ClassicConfig::default();
    let m = f64::from(cfg.nominal_moment);
    for r in [2.0, 10.0, 40.0] {
        let h = dipole([r, 0.0, 0.0], [m, 0.0, 0.0]);
        let d = cfg.distance_reading(h[0].abs() as f32);
        assert!((f64::from(d) - r).abs() < 1e-3 * r, "{d} vs {r}");
        // On the equator (half the on-axis field) the same beacon reads 2^{1/3} long.
        let he = dipole([0.0, r, 0.0], [m, 0.0, 0.0]);
        let de = cfg.distance_reading(he[0].abs() as f32);
        assert!((f64::from(de) / 2f64.cbrt() - r).abs() < 1e-3 * r);
    }
}

/// Walk `n` pulses of 1 m along +x from `x0`, the beacon at the origin (on its axis).
fn walk_away(s: &mut ClassicSearch, x0: f64, n: usize) -> Vec<ClassicOutput> {
    let rpy = Rpy::zeros();
    (0..n)
        .map(|i| {
            let x = x0 + i as f64;
            let h = dipole([x, 0.0, 0.0], [0.01, 0.0, 0.0]);
            let walked = if i == 0 { 0.0 } else { 1.0 };
            s.on_pulse(&pulse(h, &rpy, i as f32, 1.0), &att(rpy), walked)
                .unwrap()
        })
        .collect()
}

#[test]
fn turns_around_when_the_signal_falls_over_five_metres() {
    let mut s = search();
    let outs = walk_away(&mut s, 20.0, 10);
    // Pulse 0 sets the best; 1 m walked per pulse: past 5 m at pulse 6.
    for o in outs.iter().take(6) {
        assert_eq!(o.instruction, Instruction::FollowFlux);
        assert!(o.bearing.unwrap().abs() < 1e-3);
    }
    assert_eq!(outs[6].instruction, Instruction::TurnAround);
    assert!((outs[6].bearing.unwrap().abs() - core::f32::consts::PI).abs() < 1e-3);
    // And it keeps the new direction although the field's sign says nothing.
    assert!((outs[7].bearing.unwrap().abs() - core::f32::consts::PI).abs() < 1e-3);
    assert_eq!(outs[7].instruction, Instruction::FollowFlux);
}

#[test]
fn falling_after_a_near_peak_returns_to_it_then_lowers() {
    let mut s = search();
    // Start 4 m out: the best reading (≈ 4.9 m for a 0.01 A·m² beacon) is within 8 m.
    let outs = walk_away(&mut s, 4.0, 8);
    assert_eq!(outs[6].instruction, Instruction::ReturnToPeak);
    assert!((outs[6].walk_m.unwrap() - 6.0).abs() < 1e-4);
    assert!(outs[7].instruction == Instruction::ReturnToPeak);
    // Walking back 6 m reaches the peak: the fine search starts.
    let rpy = Rpy::zeros();
    let h = dipole([5.0, 0.0, 0.0], [0.01, 0.0, 0.0]);
    let o = s
        .on_pulse(&pulse(h, &rpy, 9.0, 1.0), &att(rpy), 6.0)
        .unwrap();
    assert_eq!(o.instruction, Instruction::LowerToSnow);
    assert_eq!(s.display(9.0, 0.0).status, Status::Localized);
}

/// Run the fine search with the hand following every request exactly, one pulse per
/// second, over a victim `m` buried at `depth` below the plane of the receiver at
/// `(x0, y0)`; returns the probe point and the pulses taken.
fn bracket(m: [f64; 3], depth: f64, x0: f64, y0: f64, yaw: f32) -> ([f64; 2], u32) {
    let mut s = search();
    let rpy = Rpy::new(0.0, 0.0, yaw);
    let (mut x, mut y) = (x0, y0);
    for k in 0..200 {
        let h = dipole([x, y, depth], m);
        let before = s.phase;
        let o = s
            .on_pulse(&pulse(h, &rpy, k as f32, 1.0), &att(rpy), 0.0)
            .unwrap();
        // A new request (the phase moved on): the hand goes there before the reading.
        let moving = matches!(o.instruction, Instruction::Move | Instruction::Probe);
        if s.phase != before && moving {
            let (b, w) = (f64::from(o.bearing.unwrap()), f64::from(o.walk_m.unwrap()));
            (x, y) = (x + w * b.cos(), y + w * b.sin());
        }
        if o.instruction == Instruction::Probe {
            return ([x, y], s.pulses());
        }
    }
    panic!("no probe within 200 pulses");
}

#[test]
fn fine_search_finds_the_maximum_of_the_field() {
    let depth = 1.5;
    for (m, yaw) in [
        ([0.0, 0.0, 0.01], 0.0),
        ([0.01, 0.0, 0.0], 0.6),
        ([0.004, 0.007, 0.003], -2.0),
    ] {
        let (p, pulses) = bracket(m, depth, 1.1, -0.8, yaw);
        // The maximum of |H| on the plane, by brute force.
        let mut best = (0.0, [0.0, 0.0]);
        for i in -60..=60 {
            for j in -60..=60 {
                let (x, y) = (f64::from(i) * 0.05, f64::from(j) * 0.05);
                let h = dipole([x, y, depth], m);
                let n = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
                if n > best.0 {
                    best = (n, [x, y]);
                }
            }
        }
        let err = (p[0] - best.1[0]).hypot(p[1] - best.1[1]);
        assert!(
            err < 0.3,
            "{m:?}: probe {p:?} vs max {:?} ({pulses} pulses)",
            best.1
        );
    }
}

#[test]
fn without_a_heading_the_fine_search_is_not_localized() {
    // The same hand path twice: the yaw known to 3° (a magnetometer), and not at all.
    let rpy = Rpy::new(0.0, 0.0, 0.6);
    let no_heading = Attitude::with_sigmas(rpy, 0.01, core::f32::consts::PI);
    let (mut with, mut without) = (search(), search());
    let m = [0.01, 0.0, 0.0];
    let (mut x, mut y) = (1.1, -0.8);
    let mut fine = 0;
    for k in 0..200 {
        let p = pulse(dipole([x, y, 1.5], m), &rpy, k as f32, 1.0);
        let before = with.phase;
        let o = with.on_pulse(&p, &att(rpy), 0.0).unwrap();
        // The search itself needs no heading: the same requests either way.
        assert_eq!(without.on_pulse(&p, &no_heading, 0.0).unwrap(), o);
        let (a, b) = (with.display(k as f32, 0.6), without.display(k as f32, 0.6));
        assert_eq!((a.arrow_deg, a.walk_m), (b.arrow_deg, b.walk_m));
        if matches!(o.instruction, Instruction::LowerToSnow | Instruction::Move) {
            fine += 1;
            assert_eq!(a.status, Status::Localized, "pulse {k}");
            assert_eq!(b.status, Status::FluxLine, "pulse {k}");
        }
        if with.phase != before && matches!(o.instruction, Instruction::Move | Instruction::Probe) {
            let (b, w) = (f64::from(o.bearing.unwrap()), f64::from(o.walk_m.unwrap()));
            (x, y) = (x + w * b.cos(), y + w * b.sin());
        }
        if o.instruction == Instruction::Probe {
            assert!(fine > 5, "{fine} fine-search pulses");
            return;
        }
    }
    panic!("no probe within 200 pulses");
}

#[test]
fn pulses_during_the_move_are_not_readings() {
    let mut s = search();
    let rpy = Rpy::zeros();
    let h = dipole([0.5, 0.0, 1.0], [0.0, 0.0, 0.01]);
    let o = s
        .on_pulse(&pulse(h, &rpy, 0.0, 1.0), &att(rpy), 0.0)
        .unwrap();
    assert_eq!(o.instruction, Instruction::LowerToSnow);
    // Lowering takes 0.7 s + 0.8 m / 0.5 m/s = 2.3 s: the pulse at 1 s changes nothing.
    let before = s.clone();
    let o1 = s
        .on_pulse(&pulse(h, &rpy, 1.0, 1.0), &att(rpy), 0.0)
        .unwrap();
    assert_eq!(o1.instruction, Instruction::LowerToSnow);
    assert_eq!(s.phase, before.phase);
    let o2 = s
        .on_pulse(&pulse(h, &rpy, 2.5, 1.0), &att(rpy), 0.0)
        .unwrap();
    assert_eq!(o2.instruction, Instruction::Move);
    assert!((o2.walk_m.unwrap() - 0.5).abs() < 1e-6);
}

#[test]
fn bad_input_is_refused_and_leaves_the_state_intact() {
    let mut s = search();
    let rpy = Rpy::zeros();
    let h = dipole([20.0, 3.0, 1.0], [0.01, 0.0, 0.0]);
    s.on_pulse(&pulse(h, &rpy, 5.0, 1.0), &att(rpy), 0.0)
        .unwrap();
    let before = s.clone();
    let mut nan = pulse(h, &rpy, 6.0, 1.0);
    nan.h.x = f32::NAN;
    assert_eq!(
        s.on_pulse(&nan, &att(rpy), 1.0),
        Err(ClassicError::NonFinite)
    );
    let zero = Pulse {
        h: Vec3::zeros(),
        t: 6.0,
    };
    assert_eq!(
        s.on_pulse(&zero, &att(rpy), 1.0),
        Err(ClassicError::ZeroField)
    );
    let early = pulse(h, &rpy, 4.0, 1.0);
    assert_eq!(
        s.on_pulse(&early, &att(rpy), 1.0),
        Err(ClassicError::TimeNotIncreasing)
    );
    let ok = pulse(h, &rpy, 6.0, 1.0);
    assert_eq!(
        s.on_pulse(&ok, &att(rpy), -1.0),
        Err(ClassicError::NegativeWalk)
    );
    assert_eq!(
        s.on_pulse(&ok, &att(rpy), f32::INFINITY),
        Err(ClassicError::NonFinite)
    );
    let bad_att = att(Rpy::new(f32::NAN, 0.0, 0.0));
    assert_eq!(s.on_pulse(&ok, &bad_att, 1.0), Err(ClassicError::NonFinite));
    assert_eq!(s, before);
    let cfg = ClassicConfig {
        flip_after_m: f32::NAN,
        ..ClassicConfig::default()
    };
    assert_eq!(ClassicSearch::new(cfg).err(), Some(ClassicError::BadConfig));
}

#[test]
fn arbitrary_input_never_panics_nor_shows_nan() {
    // A small xorshift over wild magnitudes, attitudes, walks and times, NaN and ∞
    // among them: every accepted pulse gives finite outputs.
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let mut wild = |scale: f32| -> f32 {
        let r = next();
        match r % 23 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => 0.0,
            3 => f32::MAX,
            _ => ((r >> 8) % 20001) as f32 / 10000.0 * scale - scale,
        }
    };
    let mut s = search();
    let mut t = 0.0;
    for _ in 0..5000 {
        let mag = libm::powf(10.0, wild(6.0) - 6.0);
        let h = Vec3::new(wild(1.0), wild(1.0), wild(1.0)) * mag;
        let rpy = Rpy::new(wild(3.2), wild(1.5), wild(3.2));
        t += libm::fabsf(wild(1.5));
        let walked = wild(2.0);
        let before = s.clone();
        match s.on_pulse(&Pulse { h, t }, &att(rpy), walked) {
            Ok(o) => {
                let vals = [o.bearing, o.distance_m, o.walk_m, Some(o.h_norm)];
                assert!(vals.iter().flatten().all(|v| v.is_finite()), "{o:?}");
                let d = s.display(t, rpy.z);
                assert!(d.arrow_deg.is_none_or(|a| a.is_finite()));
            }
            Err(_) => assert_eq!(s, before),
        }
    }
}

#[test]
fn no_signal_after_the_timeout() {
    let mut s = search();
    assert_eq!(s.display(0.0, 0.0).status, Status::NoSignal);
    let rpy = Rpy::zeros();
    let h = dipole([20.0, 3.0, 1.0], [0.01, 0.0, 0.0]);
    s.on_pulse(&pulse(h, &rpy, 5.0, 1.0), &att(rpy), 0.0)
        .unwrap();
    assert_eq!(s.display(6.0, 0.0).status, Status::FluxLine);
    let lost = s.display(9.0, 0.0);
    assert_eq!(lost.status, Status::NoSignal);
    assert_eq!(lost.arrow_deg, None);
}
