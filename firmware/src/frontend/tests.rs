//! DSP tests on synthetic IF buffers: three coils, carrier offsets, noise at the EMI
//! floor, several transmitters.

use super::*;
use crate::Vec3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI as PI64;

const FS: f64 = 8000.0;
const IF: f64 = 2000.0;
/// EMI floor of the receiver spec (`receiver.json`): per-component σ of h, A/m.
const SIGMA_BKG: f64 = 2.59e-9;
/// Per-sample noise (A/m equivalent, per coil) giving SIGMA_BKG on a 70 ms pulse:
/// σ_h = σ_s·√(2/N) with N = 560 samples.
const SIGMA_SAMPLE: f64 = SIGMA_BKG / 0.059_761;
/// Coil gains (A/m per V) of the synthetic analog chain; y is wired reversed.
const GAIN: [f64; 3] = [2.0e-5, -2.5e-5, 1.5e-5];
/// Phase lag of each synthetic analog channel (rad).
const PHASE: [f64; 3] = [0.10, -0.05, 0.20];

#[derive(Clone, Copy, Debug)]
struct PulseSpec {
    start: f64,
    dur: f64,
    h: [f64; 3],
    offset_hz: f64,
    phase: f64,
    tx: usize,
}

fn gauss(rng: &mut SmallRng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI64 * u2).cos()
}

/// IF samples (V) of the three coils for `dur_s` seconds.
fn synth(dur_s: f64, pulses: &[PulseSpec], sigma: f64, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = SmallRng::seed_from_u64(seed);
    let n = (dur_s * FS) as usize;
    (0..n)
        .map(|k| {
            let t = k as f64 / FS;
            let mut v = [0.0f64; 3];
            for p in pulses
                .iter()
                .filter(|p| t >= p.start && t < p.start + p.dur)
            {
                for i in 0..3 {
                    let arg = 2.0 * PI64 * (IF + p.offset_hz) * t + p.phase - PHASE[i];
                    v[i] += p.h[i] * arg.cos();
                }
            }
            [0, 1, 2].map(|i| ((v[i] + sigma * gauss(&mut rng)) / GAIN[i]) as f32)
        })
        .collect()
}

fn frontend() -> Frontend {
    let cfg = FrontendConfig {
        calibration: Calibration {
            gain_a_per_m_per_v: GAIN.map(|g| g as f32),
            offset_v: [0.0; 3],
            phase_rad: PHASE.map(|p| p as f32),
            ..Calibration::default()
        },
        ..FrontendConfig::default()
    };
    Frontend::new(cfg).unwrap()
}

fn run(fe: &mut Frontend, samples: &[[f32; 3]]) -> Vec<Pulse> {
    samples
        .iter()
        .filter_map(|s| fe.push(*s, false).unwrap())
        .collect()
}

fn random_dir(rng: &mut SmallRng) -> [f64; 3] {
    loop {
        let v = [0, 1, 2].map(|_| gauss(rng));
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 0.1 {
            return v.map(|x| x / n);
        }
    }
}

fn vec3(h: [f64; 3]) -> Vec3 {
    Vec3::new(h[0] as f32, h[1] as f32, h[2] as f32)
}

/// `truth` with the sign that best matches `est`.
fn signed_truth(est: &Vec3, truth: [f64; 3]) -> Vec3 {
    let t = vec3(truth);
    if est.dot(&t) >= 0.0 { t } else { -t }
}

/// One pulse per second, random direction/offset/phase/sign/duration.
fn pulse_train(rng: &mut SmallRng, count: usize, amp: f64, offsets: &[f64]) -> Vec<PulseSpec> {
    (0..count)
        .map(|k| {
            let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
            PulseSpec {
                start: 0.3 + k as f64 + 0.05 * rng.random::<f64>(),
                dur: 0.070 + 0.030 * rng.random::<f64>(),
                h: random_dir(rng).map(|x| sign * amp * x),
                offset_hz: offsets[k % offsets.len()],
                phase: 2.0 * PI64 * rng.random::<f64>(),
                tx: 0,
            }
        })
        .collect()
}

/// The reported pulse whose centre is within 30 ms of the spec's centre.
fn find(pulses: &[Pulse], spec: &PulseSpec) -> Option<Pulse> {
    let c = spec.start + spec.dur / 2.0;
    pulses
        .iter()
        .find(|p| (p.t_s as f64 - c).abs() < 0.03)
        .copied()
}

#[test]
fn vector_amplitude_signs_and_timing_at_high_snr() {
    let mut rng = SmallRng::seed_from_u64(1);
    let specs = pulse_train(&mut rng, 12, 1e-6, &[-80.0, 0.0, 80.0, -40.0]);
    let samples = synth(12.5, &specs, SIGMA_SAMPLE, 2);
    let mut fe = frontend();
    let out = run(&mut fe, &samples);
    assert_eq!(out.len(), specs.len(), "{out:#?}");
    let (mut worst_amp, mut worst_vec, mut worst_t, mut worst_f) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for s in &specs {
        let p = find(&out, s).expect("pulse detected");
        let Some(h) = p.field() else {
            panic!("no vector: {p:?} for {s:?}")
        };
        let t = signed_truth(&h, s.h);
        let amp_err = ((h.norm() - t.norm()) / t.norm()).abs() as f64;
        let vec_err = ((h - t).norm() / t.norm()) as f64;
        // Relative signs: every component that stands out of the noise agrees with the
        // truth once the overall sign is fixed.
        for i in 0..3 {
            if t[i].abs() > 0.02 * t.norm() {
                assert_eq!(h[i] > 0.0, t[i] > 0.0, "component {i}: {h:?} vs {t:?}");
            }
        }
        worst_amp = worst_amp.max(amp_err);
        worst_vec = worst_vec.max(vec_err);
        worst_t = worst_t.max((p.t_s as f64 - (s.start + s.dur / 2.0)).abs());
        worst_f = worst_f.max((p.carrier_offset_hz as f64 - s.offset_hz).abs());
        assert!(p.residual_fraction < 0.05, "{p:?}");
        assert!(p.quadrature_fraction < 0.01, "{p:?}");
    }
    println!(
        "high SNR (|H| = 1e-6 A/m, offsets ±80/0/−40 Hz): worst amplitude error {:.3} %, \
         worst vector error {:.3} %, worst centre-time error {:.2} ms, worst offset error {:.2} Hz",
        100.0 * worst_amp,
        100.0 * worst_vec,
        1e3 * worst_t,
        worst_f
    );
    assert!(worst_amp < 0.01, "amplitude error {worst_amp}");
    assert!(worst_vec < 0.015, "vector error {worst_vec}");
    assert!(worst_t < 0.002, "timing error {worst_t}");
    assert!(worst_f < 2.0, "offset error {worst_f}");
    assert_eq!(fe.stats().overlaps, 0);
}

#[test]
fn accuracy_at_the_emi_floor_matches_the_noise() {
    // |H| = 30 σ_bkg ≈ 7.8e-8 A/m (a 0.05 A·m² beacon at ~55 m).
    let mut rng = SmallRng::seed_from_u64(3);
    let specs: Vec<PulseSpec> =
        pulse_train(&mut rng, 40, 30.0 * SIGMA_BKG, &[-80.0, 80.0, 0.0, 25.0])
            .into_iter()
            .map(|mut s| {
                s.dur = 0.070;
                s
            })
            .collect();
    let samples = synth(40.5, &specs, SIGMA_SAMPLE, 4);
    let mut fe = frontend();
    let out = run(&mut fe, &samples);
    let (mut sq, mut n, mut amp, mut sig) = (0.0f64, 0usize, 0.0f64, 0.0f64);
    let mut found = 0;
    for s in &specs {
        let Some(p) = find(&out, s) else { continue };
        found += 1;
        let Some(h) = p.field() else { continue };
        let t = signed_truth(&h, s.h);
        sq += (h - t).norm_squared() as f64;
        n += 3;
        amp += ((h.norm() - t.norm()) / t.norm()) as f64;
        sig += p.sigma_a_per_m as f64;
    }
    let fields = n / 3;
    let rms = (sq / n as f64).sqrt();
    println!(
        "EMI floor (|H| = 30 σ_bkg, 70 ms, ±80 Hz): detected {found}/{}, vectors {fields}, \
         per-component RMS error {:.2} σ_bkg, mean amplitude bias {:+.2} %, reported σ {:.2} σ_bkg",
        specs.len(),
        rms / SIGMA_BKG,
        100.0 * amp / fields as f64,
        sig / fields as f64 / SIGMA_BKG
    );
    assert!(found >= 39, "detected {found}");
    assert!(fields >= 37, "vectors {fields}");
    assert!(rms < 1.6 * SIGMA_BKG, "rms {:.3e}", rms);
    let sig_ratio = sig / fields as f64 / SIGMA_BKG;
    assert!(
        (0.7..1.4).contains(&sig_ratio),
        "reported sigma ratio {sig_ratio}"
    );
}

#[test]
fn detection_down_to_the_floor_without_false_alarms() {
    let mut rng = SmallRng::seed_from_u64(5);
    for (k, min_rate) in [(20.0, 0.95), (15.0, 0.8)] {
        let specs = pulse_train(&mut rng, 30, k * SIGMA_BKG, &[-80.0, 80.0, 10.0]);
        let samples = synth(30.5, &specs, SIGMA_SAMPLE, 6 + k as u64);
        let mut fe = frontend();
        let out = run(&mut fe, &samples);
        let found = specs.iter().filter(|s| find(&out, s).is_some()).count();
        let false_alarms = out
            .iter()
            .filter(|p| {
                !specs
                    .iter()
                    .any(|s| (p.t_s as f64 - s.start - s.dur / 2.0).abs() < 0.03)
            })
            .count();
        println!(
            "|H| = {k} σ_bkg: detected {found}/{}, false {false_alarms}",
            specs.len()
        );
        assert!(
            found as f64 >= min_rate * specs.len() as f64,
            "{k}: {found}"
        );
        assert_eq!(false_alarms, 0);
    }
    // Noise only, 30 s.
    let samples = synth(30.0, &[], SIGMA_SAMPLE, 9);
    let mut fe = frontend();
    let out = run(&mut fe, &samples);
    assert!(out.is_empty(), "{out:?}");
    // The floor matches the injected noise: E = 3 coils × 4σ_s²/L per block.
    let expect = 3.0 * 4.0 * SIGMA_SAMPLE * SIGMA_SAMPLE / 16.0;
    let ratio = fe.noise_floor() as f64 / expect;
    assert!((0.85..1.15).contains(&ratio), "floor ratio {ratio}");
    assert!((fe.sigma_for_pulse(0.07) as f64 / SIGMA_BKG - 1.0).abs() < 0.1);
}

#[test]
fn overlapping_transmitters_are_flagged() {
    let h1 = [0.8e-6, -0.3e-6, 0.4e-6];
    let h2 = [-0.2e-6, 0.6e-6, 0.5e-6];
    let cases = [
        // Different carriers, partial overlap.
        (-40.0, 50.0, 0.040),
        // Different carriers, full overlap.
        (-60.0, 30.0, 0.0),
        // Nearly the same carrier, partial overlap.
        (10.0, 12.0, 0.030),
        // Nearly the same carrier, full overlap (only the phases differ).
        (5.0, 5.0, 0.0),
    ];
    for (i, (f1, f2, lag)) in cases.into_iter().enumerate() {
        let specs = [
            PulseSpec {
                start: 0.3,
                dur: 0.08,
                h: h1,
                offset_hz: f1,
                phase: 0.3,
                tx: 0,
            },
            PulseSpec {
                start: 0.3 + lag,
                dur: 0.08,
                h: h2,
                offset_hz: f2,
                phase: 2.0,
                tx: 1,
            },
        ];
        let samples = synth(1.0, &specs, SIGMA_SAMPLE, 10 + i as u64);
        let mut fe = frontend();
        let out = run(&mut fe, &samples);
        println!("overlap case {i}: {out:?}");
        assert_eq!(out.len(), 1, "case {i}: {out:#?}");
        assert_eq!(out[0].measurement, PulseMeasurement::Overlap, "case {i}");
        assert_eq!(out[0].src, None);
    }
}

#[test]
fn two_transmitters_separated_by_period() {
    let mut rng = SmallRng::seed_from_u64(11);
    let mut specs = Vec::new();
    let ha = [4e-7, 1e-7, -2e-7];
    let hb = [-1e-7, 3e-7, 2e-7];
    for k in 0..12 {
        specs.push(PulseSpec {
            start: 0.2 + 0.93 * k as f64,
            dur: 0.08,
            h: ha,
            offset_hz: -35.0,
            phase: rng.random::<f64>() * 6.0,
            tx: 0,
        });
        specs.push(PulseSpec {
            start: 0.65 + 1.17 * k as f64,
            dur: 0.09,
            h: hb,
            offset_hz: 45.0,
            phase: rng.random::<f64>() * 6.0,
            tx: 1,
        });
    }
    specs.retain(|s| s.start < 11.0);
    let samples = synth(11.5, &specs, SIGMA_SAMPLE, 12);
    let mut fe = frontend();
    let out = run(&mut fe, &samples);
    let overlapping = |s: &PulseSpec| {
        specs
            .iter()
            .any(|o| o.tx != s.tx && o.start < s.start + s.dur && s.start < o.start + o.dur)
    };
    let mut ids: [Option<u8>; 2] = [None, None];
    let (mut good, mut total) = (0, 0);
    for s in specs.iter().filter(|s| !overlapping(s)) {
        total += 1;
        let Some(p) = find(&out, s) else { continue };
        let h = p.field().expect("clean pulse gives a vector");
        let t = signed_truth(&h, s.h);
        assert!((h - t).norm() < 0.02 * t.norm());
        let id = p.src.expect("attributed");
        if *ids[s.tx].get_or_insert(id) == id {
            good += 1;
        }
    }
    for s in specs.iter().filter(|s| overlapping(s)) {
        // Overlapping pulses never yield a vector.
        assert!(
            out.iter()
                .all(|p| (p.t_s as f64 - s.start - s.dur / 2.0).abs() > 0.03
                    || p.field().is_none()
                    || {
                        let h = p.field().unwrap();
                        let t = signed_truth(&h, s.h);
                        (h - t).norm() < 0.05 * t.norm()
                    })
        );
    }
    println!(
        "two transmitters: {good}/{total} clean pulses with consistent src, ids {ids:?}, stats {:?}",
        fe.stats()
    );
    assert_ne!(ids[0], ids[1]);
    assert!(good + 1 >= total, "{good}/{total}");
}

#[test]
fn saturation_short_pulses_and_bad_input() {
    let specs = [PulseSpec {
        start: 0.3,
        dur: 0.08,
        h: [1e-6, 0.0, 0.0],
        offset_hz: 0.0,
        phase: 0.0,
        tx: 0,
    }];
    let samples = synth(1.0, &specs, SIGMA_SAMPLE, 20);
    let mut fe = frontend();
    let out: Vec<Pulse> = samples
        .iter()
        .enumerate()
        .filter_map(|(k, s)| fe.push(*s, k == 2700).unwrap())
        .collect();
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].measurement, PulseMeasurement::Saturated);

    let specs = [PulseSpec {
        start: 0.3,
        dur: 0.03,
        h: [1e-6, 0.0, 0.0],
        offset_hz: 0.0,
        phase: 0.0,
        tx: 0,
    }];
    let samples = synth(1.0, &specs, SIGMA_SAMPLE, 21);
    let mut fe = frontend();
    assert!(run(&mut fe, &samples).is_empty());
    assert_eq!(fe.stats().rejected_short, 1);

    let n = fe.samples();
    assert_eq!(
        fe.push([f32::NAN, 0.0, 0.0], false),
        Err(FrontendError::NonFiniteSample)
    );
    assert_eq!(fe.samples(), n);
    let bad = FrontendConfig {
        block_len: 15,
        ..FrontendConfig::default()
    };
    assert_eq!(Frontend::new(bad).err(), Some(FrontendError::InvalidConfig));
}

#[test]
fn continuous_interferer_is_truncated_and_detection_recovers() {
    let specs = [
        PulseSpec {
            start: 0.2,
            dur: 1.5,
            h: [1e-6, 1e-6, 0.0],
            offset_hz: 0.0,
            phase: 0.0,
            tx: 0,
        },
        PulseSpec {
            start: 5.0,
            dur: 0.08,
            h: [2e-6, 0.0, -1e-6],
            offset_hz: 20.0,
            phase: 1.0,
            tx: 1,
        },
    ];
    let samples = synth(6.0, &specs, SIGMA_SAMPLE, 30);
    let mut fe = frontend();
    let out = run(&mut fe, &samples);
    assert!(
        out.iter()
            .any(|p| p.measurement == PulseMeasurement::Truncated)
    );
    let last = out.last().unwrap();
    let h = last.field().expect("detection recovered");
    assert!((h - signed_truth(&h, specs[1].h)).norm() < 0.02 * h.norm());
}

/// Fuzz regression (`tests/fuzz/regressions/frontend_push/crash-d75ab9bd…`): finite but
/// huge samples made every block's energy `f32::MAX`; the detection window's sum
/// overflowed to +∞, a "truncated" pulse made that the noise floor, and the receiver was
/// deaf for good. Block energies are now capped so the floor stays finite. Also
/// `…/crash-96e6cf79…`: such blocks inside a pulse gave a NaN field vector; an
/// overflowing block is now zeroed and flagged saturated, so the pulse is withheld.
#[test]
fn huge_finite_samples_keep_the_noise_floor_finite() {
    let mut fe = frontend();
    let quiet = |i: usize| 1e-6 * ((i % 4) as f32 - 1.5);
    for i in 0..64 * 16 {
        let v = quiet(i);
        fe.push([v, -v, v], false).unwrap();
    }
    for i in 0..(RING_BLOCKS + 64) * 16 {
        let v = 1e30 * ((i % 4) as f32 - 1.5);
        if let Some(p) = fe.push([v, -v, v], false).unwrap() {
            assert!(
                !matches!(p.measurement, PulseMeasurement::Field(_)),
                "{p:?}"
            );
            assert!(p.residual_fraction.is_finite() && p.quadrature_fraction.is_finite());
        }
        assert!(fe.noise_floor().is_finite(), "floor after sample {i}");
    }
    for i in 0..64 * 16 {
        let v = quiet(i);
        fe.push([v, -v, v], false).unwrap();
    }
    assert!(fe.noise_floor().is_finite());
}

/// One strong pulse (|H| = `amp`) overlapped by a transmitter `db` below it (none for
/// −∞), random carriers, phases, directions, durations; half the cases a partial overlap
/// at the start, half a lag of up to 30 % of the pulse. Returns (kept, flagged, worst
/// relative vector error of the kept pulses).
fn overlap_trials(rng: &mut SmallRng, amp: f64, db: f64, trials: u64) -> (u32, u32, f32) {
    let rho = 10f64.powf(db / 20.0);
    let (mut kept, mut flagged, mut worst) = (0, 0, 0.0f32);
    for k in 0..trials {
        let own = random_dir(rng).map(|x| amp * x);
        let dur = 0.07 + 0.05 * rng.random::<f64>();
        let lag = if k % 2 == 0 {
            0.3 * dur * rng.random::<f64>()
        } else {
            -0.5 * dur
        };
        let mut specs = vec![PulseSpec {
            start: 0.3 + 0.002 * rng.random::<f64>(),
            dur,
            h: own,
            offset_hz: -70.0 + 140.0 * rng.random::<f64>(),
            phase: 6.0 * rng.random::<f64>(),
            tx: 0,
        }];
        let other = random_dir(rng).map(|x| amp * rho * x);
        if rho > 0.0 {
            specs.push(PulseSpec {
                start: specs[0].start + lag,
                dur: 0.07 + 0.05 * rng.random::<f64>(),
                h: other,
                offset_hz: -70.0 + 140.0 * rng.random::<f64>(),
                phase: 6.0 * rng.random::<f64>(),
                tx: 1,
            });
        }
        let samples = synth(0.8, &specs, SIGMA_SAMPLE, 1000 + k);
        for p in run(&mut frontend(), &samples) {
            match p.field() {
                Some(h) => {
                    kept += 1;
                    let t = signed_truth(&h, own);
                    worst = worst.max((h - t).norm() / t.norm());
                }
                None => flagged += 1,
            }
        }
    }
    (kept, flagged, worst)
}

#[test]
fn overlaps_are_flagged_down_to_the_dominance_ratio() {
    // Strong pulses (|H| = 1e-6 and 1e-5 A/m: ≈ 400 and 4000 σ_bkg, a victim within a few
    // metres): the noise alone gives 0.6 % and 0.1 % vector error.
    let mut rng = SmallRng::seed_from_u64(77);
    for amp in [1e-6, 1e-5] {
        for db in [f64::NEG_INFINITY, -60.0, -40.0, -30.0, -20.0, -10.0] {
            let (kept, flagged, worst) = overlap_trials(&mut rng, amp, db, 16);
            println!(
                "|H| {amp:.0e}, interferer {db:>5} dB: kept {kept:2}, flagged {flagged:2}, worst kept error {:.2} %",
                100.0 * worst
            );
            assert_eq!(kept + flagged, 16, "every pulse reported once");
            // A kept pulse carries at most ≈ 2× the dominance ratio of interference
            // (above the residual test's noise allowance) on top of the noise.
            assert!(worst < 0.025, "{amp} {db}: {worst}");
            if db <= -60.0 {
                assert_eq!(
                    flagged, 0,
                    "clean pulses are never overlaps ({amp}, {db} dB)"
                );
            }
            if db >= -20.0 {
                assert!(flagged >= 15, "{amp} {db} dB: only {flagged} flagged");
            }
        }
    }
}

#[test]
fn image_leakage_matches_an_f64_block_sum() {
    // One 16-sample block of cos(2π(IF + δ)t) mixed with the fs/4 oscillator, in f64:
    // the image's share of the block energy against the closed form the DSP subtracts.
    for offset_hz in [-80.0, -35.0, 0.0, 10.0, 70.0] {
        let (mut main, mut image) = (0.0f64, 0.0f64);
        // Main and image parts of the block sum: ½e^{jθ}·Σ e^{j2πδk/fs} and
        // ½e^{−jθ}·Σ e^{−j2π(2·IF+δ)k/fs}; energies of each at unit amplitude.
        let sum = |f: f64| {
            let (mut re, mut im) = (0.0, 0.0);
            for k in 0..16 {
                let a = 2.0 * PI64 * f * k as f64 / FS;
                re += a.cos();
                im += a.sin();
            }
            (re * re + im * im).sqrt() / 16.0
        };
        main += sum(offset_hz);
        image += sum(-(2.0 * IF + offset_hz));
        let want = (image / main).powi(2);
        let nu = (offset_hz * 16.0 / FS) as f32;
        let gain =
            (PI64 * f64::from(nu)).sin().abs() / (16.0 * (PI64 * f64::from(nu) / 16.0).sin().abs());
        let gain = if nu == 0.0 { 1.0 } else { gain as f32 };
        let nu_image = (2.0 * IF * 16.0 / FS) as f32 + nu;
        let got = super::analysis::image_share(nu_image, 16.0, gain);
        println!("offset {offset_hz:+} Hz: image share {got:.3e} (f64 {want:.3e})");
        assert!(
            (f64::from(got) - want).abs() <= 1e-3 * want + 1e-9,
            "{offset_hz}: {got} vs {want}"
        );
    }
}

#[test]
fn a_drifting_amplitude_is_not_an_overlap() {
    // The receiver moves ≈ 0.1 m during a pulse: at 1.5 m from the beacon |H| changes by
    // ≈ 20 % over the pulse. Piecewise-constant 1 ms slices (phase-continuous carrier)
    // ramp the envelope 0.9 → 1.1; the pulse must keep its vector, the mid-pulse one.
    let mut rng = SmallRng::seed_from_u64(5);
    for trial in 0..8 {
        let h = random_dir(&mut rng).map(|x| 1e-5 * x);
        let (start, dur) = (
            0.3 + 0.002 * rng.random::<f64>(),
            0.08 + 0.04 * rng.random::<f64>(),
        );
        let offset_hz = -70.0 + 140.0 * rng.random::<f64>();
        let phase = 6.0 * rng.random::<f64>();
        let slices = (dur / 0.001).round() as usize;
        let specs: Vec<PulseSpec> = (0..slices)
            .map(|i| {
                let u = (i as f64 + 0.5) / slices as f64;
                PulseSpec {
                    start: start + i as f64 * dur / slices as f64,
                    dur: dur / slices as f64,
                    h: h.map(|x| x * (0.9 + 0.2 * u)),
                    offset_hz,
                    phase,
                    tx: 0,
                }
            })
            .collect();
        let out = run(
            &mut frontend(),
            &synth(0.8, &specs, SIGMA_SAMPLE, 50 + trial),
        );
        assert_eq!(out.len(), 1, "{out:?}");
        let got = out[0].field().expect("a drifting pulse keeps its vector");
        let t = signed_truth(&got, h);
        let err = (got - t).norm() / t.norm();
        assert!(
            err < 0.01,
            "trial {trial}: {err}, residual {}",
            out[0].residual_fraction
        );
    }
}
