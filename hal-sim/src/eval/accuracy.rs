//! Monte Carlo accuracy of the SOGs estimator (`hal-sim accuracy`): the papers' protocol
//! over seeded scenarios, in the layout of IROS 2006 Table I / ICRA 2006 Table II.
//!
//! Until pedestrian dead reckoning feeds the estimator, each run gives it the *true*
//! displacement between pulses (from the simulated world) with realistic errors: a
//! walk-long scale error (the calibrated step length's actual error, or a drawn one when
//! uncalibrated), independent per-interval translation noise and per-interval rotation
//! noise. The same noise is declared to the filter in `Q_k`.
use crate::sensors::SensorConfig;
use crate::world::physics::{M3, V3, rotation_from_rpy, to_f32};
use crate::world::scenario::{Preset, ScenarioConfig, simulate};
use crate::world::transmitter::{Transmitter, TransmitterSpec};
use firmware::estimate::{
    Attitude, DefaultSog, Displacement, Estimator, Pulse, SogConfig, VictimEstimate,
};
use firmware::frame::rpy_from_rotation;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;
use std::time::Instant;

mod budget;
mod render;
mod tracker;
mod walker;
pub use budget::*;
pub use render::*;
use tracker::*;
pub use walker::*;

/// The evaluated cases.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Case {
    /// Known trajectory (ICRA 2006): exact displacements and attitude, low pulse noise.
    Known,
    /// Robocentric, open-loop `paper` path, calibrated step length.
    Calibrated,
    /// Robocentric, open-loop `paper` path, no step-length calibration.
    Uncalibrated,
    /// Robocentric, open-loop `line`/`arc` paths (passing beside the victim), calibrated.
    Paths,
    /// Robocentric, closed loop: flux line until the mixture is trusted, then straight to
    /// its mean; stops at "probe" (IROS III-C).
    ClosedLoop,
    /// Robocentric, open-loop `paper` path, calibrated, with the motion from the
    /// firmware's own attitude filter and dead reckoning on the simulated IMU samples —
    /// the application pipeline, exactly as `replay` runs a session log.
    Imu,
}

/// Noise of the displacement fed to the estimator (and declared in `Q_k`).
///
/// Translation follows the pedestrian-dead-reckoning model of Kleiner et al. (eq. 3,
/// `σ_d² = (0.05 m/√m)² · d`): the error variance grows with the distance walked in the
/// interval, so a receiver standing still (no step detected) gets no walking error,
/// only the hand's wobble around the body (`sigma_hand_m`).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MotionNoise {
    /// Translation noise per horizontal axis per √(metre walked), m/√m.
    pub sigma_t_m_per_sqrt_m: f64,
    /// Vertical translation noise per √(metre walked), m/√m.
    pub sigma_z_m_per_sqrt_m: f64,
    /// Per-interval hand wobble per axis, independent of walking, m.
    pub sigma_hand_m: f64,
    /// Per-interval rotation noise per angle, rad.
    pub sigma_r_rad: f64,
    /// Standard deviation of the walk-long scale error when uncalibrated.
    pub scale_sigma_uncalibrated: f64,
    /// Absolute attitude error on every pulse (roll/pitch from gravity, yaw from the
    /// tilt-compensated magnetometer): tilt and yaw standard deviations, rad.
    pub attitude_sigma_rad: [f64; 2],
    /// Multiplier of the walk-long scale error (the true one and the filter's prior
    /// `SogConfig::scale_sigma`), for the error budget; 1 normally.
    #[serde(skip)]
    pub scale_multiplier: f64,
    /// Multiplier of the pulse noise (ICRA eq. 10: background and sensor terms, simulated
    /// and declared), for the error budget; 1 normally.
    #[serde(skip)]
    pub pulse_multiplier: f64,
}

impl Default for MotionNoise {
    fn default() -> Self {
        Self {
            sigma_t_m_per_sqrt_m: 0.05,
            sigma_z_m_per_sqrt_m: 0.02,
            sigma_hand_m: 0.01,
            sigma_r_rad: 0.01,
            scale_sigma_uncalibrated: 0.08,
            attitude_sigma_rad: [0.02, 0.05],
            scale_multiplier: 1.0,
            pulse_multiplier: 1.0,
        }
    }
}

impl MotionNoise {
    /// Per-axis translation standard deviations (horizontal, vertical) for an interval
    /// in which the receiver moved `walked` metres horizontally.
    pub fn translation_sigmas(&self, walked: f64) -> (f64, f64) {
        let h2 = self.sigma_hand_m * self.sigma_hand_m;
        (
            (self.sigma_t_m_per_sqrt_m.powi(2) * walked + h2).sqrt(),
            (self.sigma_z_m_per_sqrt_m.powi(2) * walked + h2).sqrt(),
        )
    }
}

/// One run's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    /// Scenario seed.
    pub seed: u64,
    /// Initial horizontal distance to the victim, m.
    pub start_distance_m: f64,
    /// True 3-D distance at the last pulse, m.
    pub final_distance_m: f64,
    /// Final 3-D position error, m (`None`: never initialized).
    pub final_error_m: Option<f64>,
    /// Final horizontal position error, m.
    pub final_error_h_m: Option<f64>,
    /// Final depth (vertical) error, m.
    pub final_error_z_m: Option<f64>,
    /// 3-D error at the first pulse with the true distance below 20 m.
    pub error_at_20m: Option<f64>,
    /// 3-D error at the first pulse with the true distance below 10 m.
    pub error_at_10m: Option<f64>,
    /// Steps (pulses after initialization) with the truth inside the reported 3σ
    /// ellipsoid (Mahalanobis distance ≤ 3).
    pub inside_3sigma: usize,
    /// Steps evaluated for `inside_3sigma`.
    pub evaluated_steps: usize,
    /// Steps with the position NEES `eᵀP⁻¹e` inside the 95 % χ²(3) bound (slides 002:
    /// a consistent filter keeps ≈ 95 % of its steps there).
    pub nees_inside_95: usize,
    /// Sum of the position NEES over the evaluated steps (mean NEES ≈ 3 when consistent).
    pub nees_sum: f64,
    /// Updated steps with the innovation test `min_i νᵢᵀSᵢ⁻¹νᵢ` (the estimator's
    /// `best_d2`, the component closest to the pulse) inside the 95 % χ²(3) bound.
    pub nis_inside_95: usize,
    /// Updated steps evaluated for `nis_inside_95`.
    pub nis_evaluated: usize,
    /// Pulses processed.
    pub pulses: usize,
    /// Closed loop: pulses until "probe here" (`None`: never reached).
    pub steps_to_probe: Option<usize>,
    /// Closed loop: pulses until the receiver first stood within the probe radius of the
    /// mean (the walk, without the stop rule's pulses over the mean). Not in the
    /// sidecars' run records.
    #[serde(skip)]
    pub steps_to_mean: Option<usize>,
    /// Closed loop: the ideal straight path's length in pulse periods.
    pub ideal_steps: Option<usize>,
    /// Times the mixture was re-initialized after divergence.
    pub reinitializations: usize,
    /// Mean host time per estimator step, µs.
    pub host_us_per_step: f64,
    /// Largest component count seen.
    pub max_components: usize,
    /// 3-D error at every pulse (NaN before initialization), for error-vs-time plots.
    #[serde(skip)]
    pub error_trace: Vec<f64>,
    /// Final position error vector (estimate − truth, W axes), m.
    #[serde(skip)]
    pub final_error_vec: Option<V3>,
    /// Open-loop robocentric runs: the Cramér–Rao bound on the final position's
    /// covariance (W axes, m², [`crate::eval::accuracy_bound`]).
    #[serde(skip)]
    pub final_bound: Option<M3>,
}

fn gauss(rng: &mut impl Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// The mixture components `(weight, mean, covariance)` of a filter, for the trace
/// (`SOG_TRACE`); estimators without components give none.
type Components<E> = fn(&E) -> Vec<(f32, firmware::Vec3, firmware::Mat3)>;

fn sog_components(filter: &DefaultSog) -> Vec<(f32, firmware::Vec3, firmware::Mat3)> {
    filter.components().collect()
}
/// 95 % quantile of χ² with 3 degrees of freedom: the bound of the NEES of a 3-D position
/// and of the normalized innovation of a 3-axis pulse (slides 002, consistency tests).
pub const CHI2_3DOF_95: f64 = 7.815;

/// `--iekf-iterations` of the running report (`u8::MAX`: the firmware's default), for
/// the ablation of the iterated update; read by [`filter_config`].
static IEKF_ITERATIONS: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(u8::MAX);

/// `--iekf-min-weight` of the running report (bits of an `f32`; NaN: the default).
static IEKF_MIN_WEIGHT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(u32::MAX);

/// `--scale-tau-s` of the running report (bits of an `f32`; NaN: the default).
static SCALE_TAU_S: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(u32::MAX);

/// The filter configuration a receiver with `receiver` settings uses for `case`.
fn filter_config(
    case: Case,
    sensors: &SensorConfig,
    depth: [f64; 2],
    m: [f64; 2],
    noise: &MotionNoise,
) -> SogConfig {
    let base = match case {
        Case::Known => SogConfig::known_trajectory(),
        Case::Uncalibrated => SogConfig::default().with_calibrated_step(false),
        _ => SogConfig::default().with_calibrated_step(true),
    };
    let iekf = IEKF_ITERATIONS.load(std::sync::atomic::Ordering::Relaxed);
    SogConfig {
        iekf_iterations: if iekf == u8::MAX {
            base.iekf_iterations
        } else {
            iekf
        },
        iekf_min_weight: match f32::from_bits(
            IEKF_MIN_WEIGHT.load(std::sync::atomic::Ordering::Relaxed),
        ) {
            w if w.is_nan() => base.iekf_min_weight,
            w => w,
        },
        m_min: m[0] as f32,
        m_max: m[1] as f32,
        depth_min: depth[0] as f32,
        depth_max: depth[1] as f32,
        sigma_bkg: sensors.pulse.sigma_bkg_a_per_m as f32,
        k_sen: sensors.pulse.k_sen as f32,
        scale_sigma: base.scale_sigma * noise.scale_multiplier as f32,
        scale_tau_s: match f32::from_bits(SCALE_TAU_S.load(std::sync::atomic::Ordering::Relaxed)) {
            t if t.is_nan() => base.scale_tau_s,
            t => t,
        },
        ..base
    }
}

/// Pulse noise of the known-trajectory case: the ICRA paper gives no values, so this is
/// a low setting (an order of magnitude below the default background, 1 % sensor error).
fn low_noise(sensors: &mut SensorConfig) {
    sensors.pulse.sigma_bkg_a_per_m = 2.59e-10;
    sensors.pulse.k_sen = 0.01;
}

/// A noisy displacement from the true poses `(p0, r0)` → `(p1, r1)` (W frame).
fn noisy_displacement(
    rng: &mut ChaCha8Rng,
    noise: &MotionNoise,
    scale: f64,
    exact: bool,
    (p0, r0): (&V3, &M3),
    (p1, r1): (&V3, &M3),
) -> Displacement {
    let t_true = r0.transpose() * (p1 - p0);
    let rel = r0.transpose() * r1;
    let rot = rpy_from_rotation(&rel.map(|x| x as f32));
    if exact {
        return Displacement::with_sigmas(to_f32(&t_true), rot, 0.0, 0.0);
    }
    // The dead reckoning's distance walked (what its error model can see).
    let (sigma_t, sigma_z) = noise.translation_sigmas(t_true.xy().norm() * scale);
    let t = t_true * scale
        + V3::new(
            sigma_t * gauss(rng),
            sigma_t * gauss(rng),
            sigma_z * gauss(rng),
        );
    let r = rot
        + firmware::Vec3::new(
            (noise.sigma_r_rad * gauss(rng)) as f32,
            (noise.sigma_r_rad * gauss(rng)) as f32,
            (noise.sigma_r_rad * gauss(rng)) as f32,
        );
    let mut d = Displacement::with_sigmas(to_f32(&t), r, sigma_t as f32, noise.sigma_r_rad as f32);
    d.cov[(2, 2)] = (sigma_z * sigma_z) as f32;
    d
}

fn noisy_attitude(rng: &mut ChaCha8Rng, noise: &MotionNoise, rpy: &V3, exact: bool) -> Attitude {
    let [tilt, yaw] = noise.attitude_sigma_rad;
    if exact {
        return Attitude::with_sigmas(to_f32(rpy), 1e-4, 1e-4);
    }
    let noisy = rpy + V3::new(tilt * gauss(rng), tilt * gauss(rng), yaw * gauss(rng));
    Attitude::with_sigmas(to_f32(&noisy), tilt as f32, yaw as f32)
}

/// One open-loop run: a `hal-sim` scenario, its pulses fed to the filter in order.
pub fn run_open_loop(case: Case, seed: u64, noise: &MotionNoise) -> RunResult {
    open_loop(
        case,
        seed,
        noise,
        |c| DefaultSog::new(c).ok().map(Box::new),
        sog_components,
        None,
    )
}

/// As [`run_open_loop`] (same scenario and noise draws), but as soon as the mixture is
/// initialized it is replaced by a single Gaussian near the truth ("oracle start"): an
/// EKF without mixture approximation whose prior is `N(x̂₀, P₀)` with `x̂₀` drawn from
/// `N(truth, P₀)` (so the prior is consistent, not the truth itself). `P₀` is diagonal:
/// the attitude's variances for Ψ, `(rel_sigma · range)²` per position axis,
/// `(3 rel_sigma · |m|)²` per moment axis (`|m| ∝ r³` under the scale invariance) and
/// the filter's scale prior `N(1, scale_sigma²)` (the scale is not told). The final
/// error of this filter is the error budget's reference for what the pulses and the
/// dead reckoning allow without the mixture's approximations.
pub fn run_open_loop_oracle(
    case: Case,
    seed: u64,
    noise: &MotionNoise,
    rel_sigma: f64,
) -> RunResult {
    open_loop(
        case,
        seed,
        noise,
        |c| DefaultSog::new(c).ok().map(Box::new),
        sog_components,
        Some((rel_sigma, reseed_sog)),
    )
}

fn reseed_sog(
    f: &mut DefaultSog,
    x: &nalgebra::SVector<f32, 10>,
    p: &nalgebra::SMatrix<f32, 10, 10>,
) -> bool {
    f.reset_to_single(x, p).is_ok()
}

/// Replaces an estimator's belief by one Gaussian (mean, covariance; see
/// [`run_open_loop_oracle`]); `false` if it refused.
type Reseed<E> = fn(&mut E, &nalgebra::SVector<f32, 10>, &nalgebra::SMatrix<f32, 10, 10>) -> bool;

/// The oracle start's prior `(mean, covariance)` around the true state: attitude `rpy`
/// (W), transmitter offset `p` (W axes, m), moment `m` (A·m²).
fn oracle_prior(
    rng: &mut ChaCha8Rng,
    noise: &MotionNoise,
    rel_sigma: f64,
    scale_sigma: f64,
    (rpy, p, m): (&V3, &V3, &V3),
) -> (nalgebra::SVector<f32, 10>, nalgebra::SMatrix<f32, 10, 10>) {
    let [tilt, yaw] = noise.attitude_sigma_rad;
    let sp = rel_sigma * p.norm();
    let sm = 3.0 * rel_sigma * m.norm();
    let sig = [tilt, tilt, yaw, sp, sp, sp, sm, sm, sm, scale_sigma];
    let truth = [rpy.x, rpy.y, rpy.z, p.x, p.y, p.z, m.x, m.y, m.z, 1.0];
    let mut mean = nalgebra::SVector::<f32, 10>::zeros();
    let mut cov = nalgebra::SMatrix::<f32, 10, 10>::zeros();
    for i in 0..10 {
        // The scale's prior mean is the calibration (1), never the truth.
        let draw = if i == 9 { 0.0 } else { sig[i] * gauss(rng) };
        mean[i] = (truth[i] + draw) as f32;
        cov[(i, i)] = (sig[i] * sig[i]) as f32;
    }
    (mean, cov)
}

/// As [`run_open_loop`] (same scenario, same motion noise), with any estimator: `make`
/// builds it from the SOGs filter's configuration for the case (moment and depth ranges,
/// pulse noise, scale prior); `None` counts as a run that never initialized.
pub fn run_open_loop_with(
    case: Case,
    seed: u64,
    noise: &MotionNoise,
    make: impl FnOnce(&SogConfig) -> Option<Box<dyn Estimator>>,
) -> RunResult {
    open_loop(case, seed, noise, |c| make(&c), |_| Vec::new(), None)
}

fn open_loop<E: Estimator + ?Sized, B: std::ops::DerefMut<Target = E>>(
    case: Case,
    seed: u64,
    noise: &MotionNoise,
    make: impl FnOnce(SogConfig) -> Option<B>,
    components: Components<E>,
    mut oracle: Option<(f64, Reseed<E>)>,
) -> RunResult {
    let preset = match case {
        Case::Paths => {
            if seed.is_multiple_of(2) {
                Preset::Line
            } else {
                Preset::Arc
            }
        }
        _ => Preset::Paper,
    };
    let mut cfg = ScenarioConfig::new(preset, seed);
    cfg.calibrated = case != Case::Uncalibrated;
    if case == Case::Known {
        low_noise(&mut cfg.sensors);
    }
    cfg.sensors.pulse.sigma_bkg_a_per_m *= noise.pulse_multiplier;
    cfg.sensors.pulse.k_sen *= noise.pulse_multiplier;
    let sim = simulate(&cfg);
    let Some(tx) = sim.world.transmitters.first() else {
        return Tracker::new(seed, f64::NAN).finish();
    };
    let exact = case == Case::Known;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_0fac);
    // The scale the dead reckoning gets wrong, walk-long: calibrated step length / true.
    let scale = match (&sim.receiver.pdr, exact) {
        (_, true) => 1.0,
        (Some(pdr), false) => pdr.step_length_m / sim.draw.gait.step_length_m,
        (None, false) => 1.0 + noise.scale_sigma_uncalibrated * gauss(&mut rng),
    };
    let scale = 1.0 + (scale - 1.0) * noise.scale_multiplier;
    let fcfg = filter_config(
        case,
        &cfg.sensors,
        cfg.depth_m,
        cfg.transmitter.moment_range,
        noise,
    );
    let scale_sigma = f64::from(fcfg.scale_sigma);
    // The bound's scale prior is the one the scale is drawn from (the filter may
    // declare a looser one).
    let true_scale_sigma = noise.scale_multiplier
        * if cfg.calibrated {
            cfg.step_calibration_rel_sigma
        } else {
            noise.scale_sigma_uncalibrated
        };
    let Some(mut filter) = make(fcfg) else {
        return Tracker::new(seed, f64::NAN).finish();
    };
    let mut oracle_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0a5c_1e00);
    let start = sim.world.rescuer_state(0.0).p;
    let tx_p = V3::from(tx.position);
    let mut tracker = Tracker::new(seed, (tx_p - start).xy().norm());
    if tracker.trace {
        eprintln!(
            "scale {scale:.4} moment {:?} |m| {:.4}",
            tx.moment,
            V3::from(tx.moment).norm()
        );
    }
    let mut previous: Option<(V3, M3)> = None;
    let mut bound_in = crate::eval::accuracy_bound::BoundInput {
        sigma_r: noise.sigma_r_rad,
        attitude_sigma: noise.attitude_sigma_rad,
        scale,
        scale_sigma: true_scale_sigma,
        transmitter: (tx_p, V3::from(tx.moment)),
        pulse_noise: (cfg.sensors.pulse.sigma_bkg_a_per_m, cfg.sensors.pulse.k_sen),
        ..Default::default()
    };
    for pulse in sim.session.pulses() {
        let s = sim.world.rescuer_state(pulse.t);
        let motion = match &previous {
            Some((p0, r0)) => {
                noisy_displacement(&mut rng, noise, scale, exact, (p0, r0), (&s.p, &s.rot))
            }
            None => Displacement::zero(),
        };
        let attitude = noisy_attitude(&mut rng, noise, &s.rpy, exact);
        let h = firmware::Vec3::new(pulse.h[0] as f32, pulse.h[1] as f32, pulse.h[2] as f32);
        tracker.truth_next = tx_p - s.p;
        tracker.step(
            &mut *filter,
            components,
            &motion,
            &attitude,
            &Pulse {
                h,
                t: pulse.t as f32,
            },
        );
        if let Some((rel, reseed)) = oracle
            && filter.is_initialized()
        {
            let (x, p) = oracle_prior(
                &mut oracle_rng,
                noise,
                rel,
                scale_sigma,
                (&s.rpy, &(tx_p - s.p), &V3::from(tx.moment)),
            );
            if reseed(&mut *filter, &x, &p) {
                oracle = None;
            }
        }
        tracker.record(filter.estimate(), &(tx_p - s.p));
        if filter.is_initialized() {
            if !exact {
                if let Some((p0, r0)) = &previous {
                    let walked = (r0.transpose() * (s.p - p0)).xy().norm();
                    bound_in
                        .translation_sigmas
                        .push(noise.translation_sigmas(walked * scale));
                }
                bound_in.poses.push((s.p, s.rpy));
            }
            previous = Some((s.p, s.rot));
        }
    }
    tracker.result.final_bound = crate::eval::accuracy_bound::final_position_bound(&bound_in);
    tracker.finish()
}

/// One open-loop `paper` run through the application pipeline: the simulated session
/// log's IMU samples and pulses go to [`crate::io::sog_replay::SogReplay`] (attitude, PDR,
/// SOGs, as on the board), and every pulse's estimate is scored against the truth.
pub fn run_imu(seed: u64) -> RunResult {
    use crate::io::replay::Estimator as _;
    use crate::io::session::Record;
    let sim = simulate(&ScenarioConfig::new(Preset::Paper, seed));
    let Some(tx) = sim.world.transmitters.first() else {
        return Tracker::new(seed, f64::NAN).finish();
    };
    let tx_p = V3::from(tx.position);
    let start = sim.world.rescuer_state(0.0).p;
    let mut tracker = Tracker::new(seed, (tx_p - start).xy().norm());
    let Ok(mut app) = crate::io::sog_replay::SogReplay::new(&sim.session.header, &sim.receiver)
    else {
        return tracker.finish();
    };
    for record in &sim.session.records {
        match record {
            Record::Imu(imu) => app.on_imu(imu),
            Record::Pulse(pulse) => {
                let t0 = Instant::now();
                app.on_pulse(pulse);
                tracker.step_time_s += t0.elapsed().as_secs_f64();
                tracker.steps += 1;
                let truth = tx_p - sim.world.rescuer_state(pulse.t).p;
                tracker.record(app.receiver().estimate(), &truth);
            }
            _ => {}
        }
    }
    tracker.result.reinitializations = app.receiver().stats().reinitializations as usize;
    tracker.finish()
}

/// Runs `tries` seeded runs of `case` in parallel (seeds `first_seed..`).
pub fn run_case(case: Case, first_seed: u64, tries: u64, noise: &MotionNoise) -> Vec<RunResult> {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    (first_seed..first_seed + tries)
        .into_par_iter()
        .progress_with(crate::cli::progress::bar(tries, &format!("{case:?} runs")))
        .map(|seed| match case {
            Case::ClosedLoop => run_closed_loop(seed, noise),
            Case::Imu => run_imu(seed),
            _ => run_open_loop(case, seed, noise),
        })
        .collect()
}

/// Max, mean and median of the present values.
pub fn stats(values: impl Iterator<Item = Option<f64>>) -> Option<[f64; 3]> {
    let mut v: Vec<f64> = values.flatten().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    Some([v[n - 1], v.iter().sum::<f64>() / n as f64, median])
}

/// Options of `hal-sim accuracy`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeded tries per case (seeds `first_seed..first_seed + tries`), at least 1.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
    pub tries: u64,
    /// First seed (1 for the checked-in report; another range validates it).
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Override of the SOGs filter's iterated-update re-linearizations
    /// (`SogConfig::iekf_iterations`; 0 = plain EKF update), for the ablation.
    #[arg(long)]
    pub iekf_iterations: Option<u8>,
    /// Override of `SogConfig::iekf_min_weight` (the weight share above which a
    /// component's update is iterated), for the ablation.
    #[arg(long)]
    pub iekf_min_weight: Option<f32>,
    /// Also run the error budget of the calibrated case (each noise source alone and
    /// removed, and the single-Gaussian oracle starts): ≈ 20 × the calibrated case's time.
    #[arg(long)]
    pub budget: bool,
    /// Override of `SogConfig::scale_tau_s` (the scale's correlation time; 0 = a
    /// walk-long constant), for the ablation.
    #[arg(long)]
    pub scale_tau_s: Option<f32>,
    /// Cases to run (default: all).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub cases: Vec<Case>,
    /// Write the markdown report here (default: stdout only).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Write every run's result as JSON Lines here.
    #[arg(long = "jsonl", alias = "runs", value_name = "PATH")]
    pub runs: Option<std::path::PathBuf>,
}

/// Runs the selected cases and writes the report.
pub fn run(args: &Args, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    use std::io::Write as _;
    let cases: Vec<Case> = if args.cases.is_empty() {
        ALL_CASES.to_vec()
    } else {
        args.cases.clone()
    };
    let noise = MotionNoise::default();
    if let Some(n) = args.iekf_iterations {
        IEKF_ITERATIONS.store(n.min(u8::MAX - 1), std::sync::atomic::Ordering::Relaxed);
    }
    if let Some(w) = args.iekf_min_weight {
        IEKF_MIN_WEIGHT.store(w.to_bits(), std::sync::atomic::Ordering::Relaxed);
    }
    let mut flags = String::new();
    flags.push_str(&crate::eval::sidecar::first_seed_flag(args.first_seed));
    if let Some(n) = args.iekf_iterations {
        flags.push_str(&format!(" --iekf-iterations {n}"));
    }
    if let Some(w) = args.iekf_min_weight {
        flags.push_str(&format!(" --iekf-min-weight {w}"));
    }
    if let Some(t) = args.scale_tau_s {
        SCALE_TAU_S.store(t.to_bits(), std::sync::atomic::Ordering::Relaxed);
        flags.push_str(&format!(" --scale-tau-s {t}"));
    }
    if args.budget {
        flags.push_str(" --budget");
    }
    let command = format!("cargo sim accuracy --tries {}{flags}", args.tries);
    let mut report = format!(
        "## SOGs accuracy (`{command}`)\n\nMotion noise fed to the filter in every case but `Imu` (true displacement plus errors, to isolate the estimator; `Imu` runs the firmware's own attitude filter and PDR on the simulated IMU): {}\n\n",
        serde_json::to_string(&noise)?
    );
    let header_len = report.len();
    let mut all_runs = Vec::new();
    let mut summary = Vec::new();
    for case in cases {
        let start = Instant::now();
        eprintln!("accuracy: {case:?}, {} tries …", args.tries);
        let runs = run_case(case, args.first_seed, args.tries, &noise);
        eprintln!(
            "accuracy: {case:?} done in {:.1} s",
            start.elapsed().as_secs_f64()
        );
        report.push_str(&case_report(case, &runs));
        summary.push((case, summary_row(&runs)));
        all_runs.extend(runs.into_iter().map(|r| (case, r)));
    }
    if args.budget {
        let start = Instant::now();
        let table = budget(args.first_seed, args.tries, &noise);
        eprintln!(
            "accuracy: budget done in {:.1} s",
            start.elapsed().as_secs_f64()
        );
        report.push_str(&format!(
            "### Error budget of the calibrated case (final 3-D error, m)\n\n{table}\n{BUDGET_NOTE}"
        ));
    }
    report.insert_str(header_len, &summary_section(&summary));
    if let Some(path) = &args.runs {
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        for (case, r) in &all_runs {
            writeln!(f, "{}", serde_json::json!({"case": case, "run": r}))?;
        }
    }
    if let Some(path) = &args.out {
        let side = sidecar(&command, args, &summary, &all_runs)?;
        crate::eval::sidecar::write(path, &report, side)?;
    }
    out.write_all(report.as_bytes())?;
    Ok(())
}

/// Keys of a run record that depend on the machine, not on the code.
const VOLATILE: &[&str] = &["host_us_per_step"];

/// The report's sidecar: per-case headline numbers and the first seed's run of each case.
fn sidecar(
    command: &str,
    args: &Args,
    summary: &[(Case, Option<SummaryRow>)],
    runs: &[(Case, RunResult)],
) -> anyhow::Result<crate::eval::sidecar::Sidecar> {
    let mut headline = serde_json::Map::new();
    for (case, row) in summary {
        let value = row.map_or(serde_json::Value::Null, |r| {
            serde_json::json!({
                "final_error_m_median": r.median_m,
                "final_error_m_max": r.max_m,
                "inside_3sigma_pct": r.inside_3sigma_pct,
                "bound_median_m": r.bound_median_m,
            })
        });
        headline.insert(format!("{case:?}"), value);
    }
    let check = runs
        .iter()
        .filter(|(_, r)| r.seed == args.first_seed)
        .map(|(case, r)| {
            Ok(serde_json::json!({"case": case, "run": crate::eval::sidecar::record(r, VOLATILE)?}))
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(crate::eval::sidecar::Sidecar::new(
        "accuracy",
        command,
        args.first_seed,
        args.tries,
        serde_json::Value::Object(headline),
        check,
    ))
}

/// Re-runs one sidecar record (its case and seed) with the current code and default noise.
pub fn rerun(record: &serde_json::Value) -> anyhow::Result<serde_json::Value> {
    let case: Case = crate::eval::sidecar::field(record, "/case")?;
    let seed = crate::eval::sidecar::seed_of(record, "/run/seed")?;
    let run = run_case(case, seed, 1, &MotionNoise::default())
        .pop()
        .ok_or_else(|| anyhow::anyhow!("no run"))?;
    Ok(serde_json::json!({"case": case, "run": crate::eval::sidecar::record(&run, VOLATILE)?}))
}

#[cfg(test)]
mod tests;
