//! Gain ranging through the whole DSP: a synthetic analog chain whose IF range and PGA
//! follow the front end's [`RangeChange`]s, clipping at the setting's full scale.

use super::*;
use crate::Vec3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI as PI64;

const FS: f64 = 8000.0;
const IF: f64 = 2000.0;
/// High-range coil gains (A/m per V), the reference board's 4 mA/m per V.
const GAIN: [f64; 3] = [4.0e-3, -4.1e-3, 3.9e-3];
const PHASE: [f64; 3] = [0.05, -0.03, 0.02];
const LOW_RATIO: [f64; 3] = [64.0, 63.0, 65.0];
const LOW_PHASE: [f64; 3] = [0.01, -0.02, 0.015];
/// EMI per sample (A/m per coil): σ_bkg = 2.59e-9 A/m on a 70 ms pulse.
const SIGMA_SAMPLE: f64 = 2.59e-9 / 0.059_761;

fn gauss(rng: &mut SmallRng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI64 * u2).cos()
}

fn config() -> FrontendConfig {
    FrontendConfig {
        calibration: Calibration {
            gain_a_per_m_per_v: GAIN.map(|g| g as f32),
            offset_v: [0.0; 3],
            phase_rad: PHASE.map(|p| p as f32),
            low_range_ratio: LOW_RATIO.map(|r| r as f32),
            low_range_phase_rad: LOW_PHASE.map(|p| p as f32),
        },
        range: Range::MOST_SENSITIVE,
        ranging: Some(RangingConfig::default()),
        ..FrontendConfig::default()
    }
}

/// One pulse: start (s), duration (s), field (A/m), carrier offset (Hz).
#[derive(Clone, Copy, Debug)]
struct Spec {
    start: f64,
    dur: f64,
    h: [f64; 3],
    offset_hz: f64,
}

/// What a run saw: pulses, range changes (with the sample index they took effect at).
struct Outcome {
    pulses: Vec<Pulse>,
    changes: Vec<(u64, RangeChange)>,
}

/// Feeds `dur_s` of the chain to `fe`, applying every range change from the next sample.
fn run(fe: &mut Frontend, specs: &[Spec], dur_s: f64, seed: u64) -> Outcome {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut hw = fe.range();
    let (mut pulses, mut changes) = (Vec::new(), Vec::new());
    for k in 0..(dur_s * FS) as u64 {
        let t = k as f64 / FS;
        let mut v = [0.0f32; 3];
        let mut clipped = false;
        for (i, out) in v.iter_mut().enumerate() {
            let (ratio, lag) = match hw.if_range {
                IfRange::High => (1.0, PHASE[i]),
                IfRange::Low => (LOW_RATIO[i], PHASE[i] + LOW_PHASE[i]),
            };
            let field: f64 = specs
                .iter()
                .filter(|p| t >= p.start && t < p.start + p.dur)
                .map(|p| p.h[i] * (2.0 * PI64 * (IF + p.offset_hz) * t - lag).cos())
                .sum();
            let volts = (field + SIGMA_SAMPLE * gauss(&mut rng)) / (GAIN[i] * ratio);
            let fs = f64::from(hw.full_scale_v());
            clipped |= volts.abs() >= fs;
            *out = volts.clamp(-fs, fs) as f32;
        }
        if let Some(p) = fe.push(v, clipped).unwrap() {
            pulses.push(p);
        }
        if let Some(c) = fe.take_range_change() {
            assert_eq!(c.from, hw, "a change starts from the hardware's setting");
            hw = c.to;
            changes.push((k + 1, c));
        }
    }
    Outcome { pulses, changes }
}

fn train(t0: f64, count: usize, h: [f64; 3], offset_hz: f64) -> Vec<Spec> {
    (0..count)
        .map(|k| Spec {
            start: t0 + k as f64 * 0.95,
            dur: 0.08,
            h,
            offset_hz,
        })
        .collect()
}

fn rel_err(got: &Vec3, want: [f64; 3]) -> f64 {
    let w = Vec3::new(want[0] as f32, want[1] as f32, want[2] as f32);
    let w = if got.dot(&w) >= 0.0 { w } else { -w };
    f64::from((got - w).norm() / w.norm())
}

#[test]
fn a_shallow_strong_beacon_is_measured_after_ranging_down_and_a_weak_one_after_ranging_up() {
    // 0.4 m over the strongest transmitter: ≈ 0.076 A/m, 2000× the most sensitive full
    // scale (3.75e-5 A/m), a quarter of the least sensitive one.
    let strong = [0.035, -0.06, 0.03];
    // Then the receiver is far away: 3e-7 A/m (≈ 120 σ_bkg).
    let weak = [1.5e-7, 2.0e-7, -1.5e-7];
    let mut specs = train(0.4, 10, strong, 30.0);
    specs.extend(train(10.4, 8, weak, -50.0));
    let mut fe = Frontend::new(config()).unwrap();
    let out = run(&mut fe, &specs, 18.0, 1);

    // No change of setting inside a pulse (with its detection margin).
    for (k, c) in &out.changes {
        let t = *k as f64 / FS;
        for s in &specs {
            assert!(
                t < s.start - 0.005 || t > s.start + s.dur + 0.005,
                "change at {t:.3} s inside the pulse at {:.3} s: {c:?}",
                s.start
            );
        }
    }
    let strong_out: Vec<&Pulse> = out.pulses.iter().filter(|p| p.t_s < 10.0).collect();
    let saturated = strong_out
        .iter()
        .filter(|p| p.measurement == PulseMeasurement::Saturated)
        .count();
    assert!(
        saturated <= 4,
        "{saturated} saturated pulses before ranging settled"
    );
    // Every strong pulse after the ranging settled is a field vector, accurate to the
    // calibration (exact here) and the noise.
    let fields: Vec<f64> = strong_out
        .iter()
        .filter_map(|p| p.field())
        .map(|h| rel_err(&h, strong))
        .collect();
    assert_eq!(
        fields.len() + saturated,
        specs.iter().filter(|s| s.start < 10.0).count()
    );
    for e in &fields {
        assert!(*e < 2e-3, "strong pulse error {e}");
    }
    // Settled in the low range, the pulse within the band.
    let settled = out.changes.iter().rfind(|(k, _)| (*k as f64) < 10.0 * FS);
    assert!(
        settled.is_some_and(|(_, c)| c.to.if_range == IfRange::Low),
        "settles in the low range: {:?}",
        out.changes
    );
    // Far away the gain comes back up and the weak pulses are measured.
    let weak_out: Vec<Vec3> = out
        .pulses
        .iter()
        .filter(|p| p.t_s > 10.0)
        .filter_map(|p| p.field())
        .collect();
    assert!(
        weak_out.len() >= 6,
        "{} weak pulses measured",
        weak_out.len()
    );
    for h in weak_out.iter().skip(1) {
        assert!(rel_err(h, weak) < 0.1, "weak pulse {h:?}");
    }
    assert_eq!(fe.range().if_range, IfRange::High);
    assert!(fe.range().index().unwrap() <= 2, "{:?}", fe.range());
    assert_eq!(fe.stats().range_changes as usize, out.changes.len());
}

#[test]
fn without_ranging_the_setting_stays_and_set_range_is_checked() {
    let cfg = FrontendConfig {
        ranging: None,
        range: Range::HIGH_G1,
        ..config()
    };
    let mut fe = Frontend::new(cfg).unwrap();
    let specs = train(0.4, 3, [0.01, 0.0, 0.0], 0.0);
    let out = run(&mut fe, &specs, 3.0, 2);
    assert!(out.changes.is_empty());
    assert!(
        out.pulses
            .iter()
            .all(|p| p.measurement == PulseMeasurement::Saturated)
    );
    // Off-ladder settings are refused while ranging, accepted without.
    let off = Range {
        if_range: IfRange::Low,
        gain: crate::drivers::ads131m04::Gain::G128,
    };
    assert_eq!(fe.set_range(off), Ok(()));
    let mut fe = Frontend::new(config()).unwrap();
    assert_eq!(fe.set_range(off), Err(FrontendError::InvalidConfig));
    assert_eq!(fe.range(), Range::MOST_SENSITIVE);
    let bad = FrontendConfig {
        range: off,
        ..config()
    };
    assert_eq!(Frontend::new(bad).err(), Some(FrontendError::InvalidConfig));
}
