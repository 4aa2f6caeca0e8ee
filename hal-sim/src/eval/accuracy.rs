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

/// Error bookkeeping shared by the open- and closed-loop runs.
struct Tracker {
    result: RunResult,
    step_time_s: f64,
    steps: usize,
    trace: bool,
    near: (f64, f64),
    truth_next: V3,
    last: Option<firmware::estimate::StepReport>,
}

impl Tracker {
    fn new(seed: u64, start_distance_m: f64) -> Self {
        Self {
            result: RunResult {
                seed,
                start_distance_m,
                final_distance_m: f64::NAN,
                final_error_m: None,
                final_error_h_m: None,
                final_error_z_m: None,
                error_at_20m: None,
                error_at_10m: None,
                inside_3sigma: 0,
                evaluated_steps: 0,
                nees_inside_95: 0,
                nees_sum: 0.0,
                nis_inside_95: 0,
                nis_evaluated: 0,
                pulses: 0,
                steps_to_probe: None,
                ideal_steps: None,
                reinitializations: 0,
                host_us_per_step: 0.0,
                max_components: 0,
                error_trace: Vec::new(),
                final_error_vec: None,
                final_bound: None,
            },
            step_time_s: 0.0,
            steps: 0,
            trace: std::env::var("SOG_TRACE").is_ok_and(|v| v == seed.to_string()),
            last: None,
            near: (0.0, 0.0),
            truth_next: V3::zeros(),
        }
    }

    /// Records the estimate against the true victim offset `truth` (in G_k = W axes).
    fn record(&mut self, est: Option<VictimEstimate>, truth: &V3) {
        let r = &mut self.result;
        r.pulses += 1;
        r.final_distance_m = truth.norm();
        let Some(est) = est else {
            r.error_trace.push(f64::NAN);
            return;
        };
        r.max_components = r.max_components.max(est.n_components);
        let p = V3::new(est.p.x as f64, est.p.y as f64, est.p.z as f64);
        let e = p - truth;
        let err = e.norm();
        r.error_trace.push(err);
        r.final_error_m = Some(err);
        r.final_error_vec = Some(e);
        r.final_error_h_m = Some(e.x.hypot(e.y));
        r.final_error_z_m = Some(e.z.abs());
        if truth.norm() < 20.0 && r.error_at_20m.is_none() {
            r.error_at_20m = Some(err);
        }
        if truth.norm() < 10.0 && r.error_at_10m.is_none() {
            r.error_at_10m = Some(err);
        }
        let cov = M3::from_fn(|i, j| est.cov[(i, j)] as f64);
        if self.trace {
            let d2 = cov
                .try_inverse()
                .map(|inv| (e.transpose() * inv * e)[(0, 0)]);
            let l = self.last;
            eprintln!(
                "k {:3} dist {:6.2} truth [{:7.2} {:7.2} {:6.2}] err {:6.3} [{:6.3} {:6.3} {:6.3}] sd [{:.3} {:.3} {:.3}] md2 {:7.2} n {:3} wmax {:.3} s {:.4}±{:.4} |m| {:.4} d2best {:7.2} pr {} mg {} sp {} near d2 {:7.2} w {:.2e}",
                r.pulses,
                truth.norm(),
                truth.x,
                truth.y,
                truth.z,
                err,
                e.x,
                e.y,
                e.z,
                cov[(0, 0)].sqrt(),
                cov[(1, 1)].sqrt(),
                cov[(2, 2)].sqrt(),
                d2.unwrap_or(f64::NAN),
                est.n_components,
                est.max_weight,
                est.scale,
                est.scale_sigma,
                est.moment.norm(),
                l.map_or(0.0, |l| l.best_d2),
                l.map_or(0, |l| l.pruned),
                l.map_or(0, |l| l.merged),
                l.map_or(0, |l| l.split),
                self.near.0,
                self.near.1,
            );
        }
        if let Some(inv) = cov.try_inverse() {
            r.evaluated_steps += 1;
            let nees = (e.transpose() * inv * e)[(0, 0)];
            if nees <= 9.0 {
                r.inside_3sigma += 1;
            }
            if nees <= CHI2_3DOF_95 {
                r.nees_inside_95 += 1;
            }
            r.nees_sum += nees;
        }
    }

    fn step<E: Estimator + ?Sized>(
        &mut self,
        filter: &mut E,
        components: Components<E>,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) {
        let start = Instant::now();
        let out = filter.step(motion, attitude, pulse);
        self.step_time_s += start.elapsed().as_secs_f64();
        if self.trace && std::env::var("SOG_NEAR").is_ok() {
            let mut v: Vec<(f64, f32, firmware::Vec3, firmware::Vec3)> = components(filter)
                .into_iter()
                .map(|(w, p, c)| {
                    let cd = M3::from_fn(|i, j| c[(i, j)] as f64);
                    let e = V3::new(p.x as f64, p.y as f64, p.z as f64) - self.truth_next;
                    let d2 = cd
                        .try_inverse()
                        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[(0, 0)]);
                    (
                        d2,
                        w,
                        p,
                        firmware::Vec3::new(c[(0, 0)].sqrt(), c[(1, 1)].sqrt(), c[(2, 2)].sqrt()),
                    )
                })
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (d2, w, p, sd) in v.iter().take(4) {
                eprintln!(
                    "   near d2 {d2:8.2} w {w:.2e} p [{:.2} {:.2} {:.2}] sd [{:.2} {:.2} {:.2}] truth [{:.2} {:.2} {:.2}]",
                    p.x,
                    p.y,
                    p.z,
                    sd.x,
                    sd.y,
                    sd.z,
                    self.truth_next.x,
                    self.truth_next.y,
                    self.truth_next.z
                );
            }
        }
        if self.trace {
            self.near = components(filter)
                .into_iter()
                .map(|(w, p, c)| {
                    let c = M3::from_fn(|i, j| c[(i, j)] as f64);
                    let e = V3::new(p.x as f64, p.y as f64, p.z as f64) - self.truth_next;
                    let d2 = c
                        .try_inverse()
                        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[(0, 0)]);
                    (d2, w as f64)
                })
                .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
        }
        self.steps += 1;
        self.last = out.ok();
        if let Ok(report) = out
            && report.outcome == firmware::estimate::StepOutcome::Updated
        {
            self.result.nis_evaluated += 1;
            if f64::from(report.best_d2) <= CHI2_3DOF_95 {
                self.result.nis_inside_95 += 1;
            }
        }
        if let Ok(report) = out
            && report.outcome == firmware::estimate::StepOutcome::Reinitialized
        {
            self.result.reinitializations += 1;
        }
    }

    fn finish(mut self) -> RunResult {
        self.result.host_us_per_step = 1e6 * self.step_time_s / self.steps.max(1) as f64;
        self.result
    }
}

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

/// The closed-loop rescuer: position on the snow, walking heading, hand-held attitude.
struct Walker {
    p: V3,
    heading: f64,
    flux_sign: f64,
    best_h: f64,
    best_h_at: V3,
}

impl Walker {
    fn rotation(&self, rng: &mut ChaCha8Rng) -> (V3, M3) {
        // Hand wobble: a few degrees of roll/pitch/yaw about the walking heading.
        let rpy = V3::new(
            0.03 * gauss(rng),
            0.1 + 0.03 * gauss(rng),
            self.heading + 0.05 * gauss(rng),
        );
        (rpy, rotation_from_rpy(&rpy))
    }
}

/// Horizontal direction (unit, W) the flux line points to, sign chosen by `sign`.
fn flux_direction(h_w: &V3, sign: f64) -> Option<V3> {
    let d = V3::new(h_w.x, h_w.y, 0.0) * sign;
    (d.norm() > 0.0).then(|| d.normalize())
}

/// Squared Mahalanobis distance of the receiver (the origin of `G_k`) from the mixture
/// mean, horizontally (IROS III-C: the rescuer is sent to the mean once the receiver is
/// far from it in Mahalanobis distance, i.e. once the whole belief lies to one side).
fn horizontal_mahalanobis2(est: &VictimEstimate) -> f64 {
    let c = est.cov;
    let (a, b, d) = (c[(0, 0)] as f64, c[(0, 1)] as f64, c[(1, 1)] as f64);
    let det = a * d - b * b;
    if det <= 0.0 {
        return 0.0;
    }
    let (x, y) = (est.p.x as f64, est.p.y as f64);
    (d * x * x - 2.0 * b * x * y + a * y * y) / det
}

/// Unit principal axis (W, horizontal) and largest standard deviation of the horizontal
/// position covariance.
fn horizontal_axis(est: &VictimEstimate) -> (V3, f64) {
    let c = est.cov;
    let (a, b, cc) = (c[(0, 0)] as f64, c[(0, 1)] as f64, c[(1, 1)] as f64);
    let lmax = 0.5 * (a + cc) + ((0.5 * (a - cc)).powi(2) + b * b).sqrt();
    // Eigenvector of [[a, b], [b, cc]] for lmax.
    let v = if b.abs() > 1e-12 {
        V3::new(lmax - cc, b, 0.0)
    } else if a >= cc {
        V3::x()
    } else {
        V3::y()
    };
    let n = v.norm();
    let axis = if n > 0.0 { v / n } else { V3::x() };
    (axis, lmax.max(0.0).sqrt())
}

/// Guidance thresholds of the closed loop.
const GO_TO_MEAN_D2: f64 = 9.0; // 3σ: the receiver is outside the belief's 3σ ellipse
const PROBE_RADIUS_M: f64 = 0.3; // "probe here" when the mean is this close, horizontally
const PROBE_STILL_PULSES: usize = 4; // pulses taken standing still before probing

/// One closed-loop rescue (the papers' protocol): start 40–70 m away, 1 m/s, a pulse
/// per transmitter period, stop at "probe here".
pub fn run_closed_loop(seed: u64, noise: &MotionNoise) -> RunResult {
    closed_loop(
        seed,
        noise,
        40.0..=70.0,
        |c| DefaultSog::new(c).ok().map(Box::new),
        sog_components,
        &mut |_, _| {},
    )
}

/// As [`run_closed_loop`] (same scenario draw, walker and IROS III-C guidance), with the
/// start distance drawn in `start_m` and any estimator guiding: `make` builds it from
/// the SOGs filter's configuration (`None`: a run that never initialized); `observe`
/// sees the estimator and the true victim offset (W axes) after every pulse.
pub fn run_closed_loop_with<E: Estimator + ?Sized, B: std::ops::DerefMut<Target = E>>(
    seed: u64,
    noise: &MotionNoise,
    start_m: std::ops::RangeInclusive<f64>,
    make: impl FnOnce(SogConfig) -> Option<B>,
    observe: &mut dyn FnMut(&E, &V3),
) -> RunResult {
    closed_loop(seed, noise, start_m, make, |_| Vec::new(), observe)
}

fn closed_loop<E: Estimator + ?Sized, B: std::ops::DerefMut<Target = E>>(
    seed: u64,
    noise: &MotionNoise,
    start_m: std::ops::RangeInclusive<f64>,
    make: impl FnOnce(SogConfig) -> Option<B>,
    components: Components<E>,
    observe: &mut dyn FnMut(&E, &V3),
) -> RunResult {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d0 = rng.random_range(start_m);
    let bearing: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    let depth = rng.random_range(0.3..=3.0);
    let tx = Transmitter::random(
        &mut rng,
        &TransmitterSpec::default(),
        [d0 * bearing.cos(), d0 * bearing.sin(), -depth],
    );
    let mut sensors = SensorConfig::default();
    // The pulse noise simulated and declared (×1 normally: the values are unchanged).
    sensors.pulse.sigma_bkg_a_per_m *= noise.pulse_multiplier;
    sensors.pulse.k_sen *= noise.pulse_multiplier;
    let tx_p = V3::from(tx.position);
    let scale = 1.0 + 0.02 * noise.scale_multiplier * gauss(&mut rng);
    let fcfg = filter_config(
        Case::ClosedLoop,
        &sensors,
        [0.3, 3.0],
        TransmitterSpec::default().moment_range,
        noise,
    );
    let Some(mut filter) = make(fcfg) else {
        return Tracker::new(seed, d0).finish();
    };
    let mut tracker = Tracker::new(seed, d0);
    if tracker.trace {
        eprintln!(
            "scale {scale:.4} moment {:?} |m| {:.4}",
            tx.moment,
            V3::from(tx.moment).norm()
        );
    }
    let ideal = (d0 / tx.period_s).ceil() as usize;
    tracker.result.ideal_steps = Some(ideal);
    let mut walker = Walker {
        p: V3::new(0.0, 0.0, 1.0),
        heading: rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
        flux_sign: 1.0,
        best_h: 0.0,
        best_h_at: V3::zeros(),
    };
    let mut previous: Option<(V3, M3)> = None;
    let mut bound_in = crate::eval::accuracy_bound::BoundInput {
        sigma_r: noise.sigma_r_rad,
        attitude_sigma: noise.attitude_sigma_rad,
        scale,
        scale_sigma: 0.02 * noise.scale_multiplier,
        transmitter: (tx_p, V3::from(tx.moment)),
        pulse_noise: (sensors.pulse.sigma_bkg_a_per_m, sensors.pulse.k_sen),
        ..Default::default()
    };
    let mut probe_hold = 0;
    let mut going_to_mean = false;
    let mut sure_hold = 0;
    let mut sweep = 1.0;
    for k in 0..3 * ideal + 10 {
        let t = tx.phase_s + k as f64 * tx.period_s;
        let (rpy, rot) = walker.rotation(&mut rng);
        let Some(h_w) = tx.field_at(&walker.p) else {
            break;
        };
        let sigma = sensors
            .pulse
            .sigma_bkg_a_per_m
            .hypot(sensors.pulse.k_sen * h_w.norm());
        let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
        let h_b = (rot.transpose() * h_w
            + V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * sigma)
            * sign;
        let motion = match &previous {
            Some((p0, r0)) => {
                noisy_displacement(&mut rng, noise, scale, false, (p0, r0), (&walker.p, &rot))
            }
            None => Displacement::zero(),
        };
        let attitude = noisy_attitude(&mut rng, noise, &rpy, false);
        tracker.truth_next = tx_p - walker.p;
        tracker.step(
            &mut *filter,
            components,
            &motion,
            &attitude,
            &Pulse {
                h: to_f32(&h_b),
                t: t as f32,
            },
        );
        let est = filter.estimate();
        tracker.record(est, &(tx_p - walker.p));
        observe(&*filter, &(tx_p - walker.p));
        if filter.is_initialized() {
            if let Some((p0, r0)) = &previous {
                let walked = (r0.transpose() * (walker.p - p0)).xy().norm();
                bound_in
                    .translation_sigmas
                    .push(noise.translation_sigmas(walked * scale));
            }
            bound_in.poses.push((walker.p, rpy));
            previous = Some((walker.p, rot));
        }
        // Guidance for the next period (IROS III-C): follow the flux line until the
        // receiver is far from the mixture mean in Mahalanobis distance, then walk to
        // the mean; once over it, stand still for a few pulses (no walking error, the
        // strongest field) and probe.
        let step = tx.period_s; // 1 m/s
        if let Some(e) = est
            && horizontal_mahalanobis2(&e) >= GO_TO_MEAN_D2
        {
            going_to_mean = true;
        }
        let target = match est {
            Some(e) if going_to_mean => {
                let to_mean = V3::new(e.p.x as f64, e.p.y as f64, 0.0);
                if to_mean.norm() < PROBE_RADIUS_M {
                    // Over the mean. A single spot cannot separate the transmitter's
                    // position from its moment, so while the 3σ circle is wider than
                    // the probe radius, sweep across the mean along the most uncertain
                    // horizontal axis (±0.5 m, the classical fine search's bracketing);
                    // once sure, stand still for the last pulses and probe.
                    let (axis, sigma) = horizontal_axis(&e);
                    probe_hold += 1;
                    if 3.0 * sigma <= PROBE_RADIUS_M {
                        sure_hold += 1;
                        if sure_hold >= PROBE_STILL_PULSES {
                            tracker.result.steps_to_probe = Some(k + 1);
                            break;
                        }
                        None
                    } else if probe_hold >= 4 * PROBE_STILL_PULSES {
                        tracker.result.steps_to_probe = Some(k + 1);
                        break;
                    } else {
                        sure_hold = 0;
                        sweep = -sweep;
                        Some(to_mean + axis * (0.5 * sweep))
                    }
                } else if probe_hold > 0 && to_mean.norm() < 1.0 {
                    // Still sweeping across the mean.
                    sweep = -sweep;
                    Some(to_mean + horizontal_axis(&e).0 * (0.5 * sweep))
                } else {
                    probe_hold = 0;
                    sure_hold = 0;
                    Some(to_mean)
                }
            }
            _ => {
                let hn = h_w.norm();
                // Classical rule: if the signal fell over the last 5 m, turn around.
                if hn > walker.best_h {
                    walker.best_h = hn;
                    walker.best_h_at = walker.p;
                } else if (walker.p - walker.best_h_at).xy().norm() > 5.0 {
                    walker.flux_sign = -walker.flux_sign;
                    walker.best_h_at = walker.p;
                    walker.best_h = hn;
                }
                flux_direction(&h_w, walker.flux_sign).map(|d| d * 10.0)
            }
        };
        if let Some(dir) = target {
            let len = dir.norm().min(step);
            let heading = dir.y.atan2(dir.x) + 0.05 * gauss(&mut rng);
            walker.heading = heading;
            walker.p += V3::new(heading.cos(), heading.sin(), 0.0) * len;
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

/// The error sources of the calibrated case, for the error budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// Horizontal dead-reckoning noise `σ_t` (m/√m).
    Translation,
    /// Vertical dead-reckoning noise `σ_z` (m/√m).
    Vertical,
    /// Hand wobble per interval (m).
    Hand,
    /// Per-interval rotation noise `σ_r` (rad).
    Rotation,
    /// Walk-long step-length scale error (and the filter's prior on it).
    Scale,
    /// Absolute roll/pitch error.
    Tilt,
    /// Absolute yaw error.
    Yaw,
    /// Pulse noise (ICRA eq. 10).
    Pulse,
}

/// Every source, in the budget's order.
pub const SOURCES: [Source; 8] = [
    Source::Translation,
    Source::Vertical,
    Source::Hand,
    Source::Rotation,
    Source::Scale,
    Source::Tilt,
    Source::Yaw,
    Source::Pulse,
];

/// Multiplier standing for a removed source: 10 % of its level (1 % of its variance),
/// not 0, so every declared covariance stays positive definite and the pulses keep a
/// noise floor (the error's variance adds up over the sources, so 1 % of a source's
/// variance leaves ≈ nothing of its share).
pub const REMOVED: f64 = 0.1;

/// `noise` with source `source` multiplied by `k` (the true error and the filter's
/// declared variance alike).
pub fn scaled(noise: &MotionNoise, source: Source, k: f64) -> MotionNoise {
    let mut n = *noise;
    match source {
        Source::Translation => n.sigma_t_m_per_sqrt_m *= k,
        Source::Vertical => n.sigma_z_m_per_sqrt_m *= k,
        Source::Hand => n.sigma_hand_m *= k,
        Source::Rotation => n.sigma_r_rad *= k,
        Source::Scale => n.scale_multiplier *= k,
        Source::Tilt => n.attitude_sigma_rad[0] *= k,
        Source::Yaw => n.attitude_sigma_rad[1] *= k,
        Source::Pulse => n.pulse_multiplier *= k,
    }
    n
}

/// `noise` with every motion source but `keep` removed ([`REMOVED`]), the pulse noise
/// kept (it is the measurement: without it the updates are only as good as their
/// linearization); `None` keeps the pulse noise alone.
pub fn only(noise: &MotionNoise, keep: Option<Source>) -> MotionNoise {
    SOURCES
        .iter()
        .filter(|&&s| Some(s) != keep && s != Source::Pulse)
        .fold(*noise, |n, &s| scaled(&n, s, REMOVED))
}

/// Draws per run of the bound-efficient estimator's error (see [`bound_stats`]).
const BOUND_DRAWS: usize = 200;

/// The final 3-D error an efficient unbiased estimator would have on `runs`, from
/// their Cramér–Rao bounds ([`crate::eval::accuracy_bound`]): errors drawn from
/// `N(0, C_bound)`, [`BOUND_DRAWS`] per run (seeded), pooled; `[99th percentile, mean,
/// median]` (the 99th percentile stands for the largest of 100 runs), each divided by
/// the run's final distance when `relative`; horizontal errors when `horizontal`.
pub fn bound_stats(runs: &[RunResult], relative: bool, horizontal: bool) -> Option<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(0xb0_0d);
    let mut draws: Vec<f64> = Vec::new();
    for r in runs {
        let Some(l) = r.final_bound.and_then(|c| c.cholesky()) else {
            continue;
        };
        let d = if relative { r.final_distance_m } else { 1.0 };
        for _ in 0..BOUND_DRAWS {
            let n = V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng));
            let e = l.l() * n;
            let e = if horizontal { e.xy().norm() } else { e.norm() };
            draws.push(e / d);
        }
    }
    let [_, mean, median] = stats(draws.iter().map(|&x| Some(x)))?;
    draws.sort_by(f64::total_cmp);
    let p99 = draws
        .get(((draws.len() - 1) as f64 * 0.99) as usize)
        .copied()?;
    Some([p99, mean, median])
}

/// Mean over `runs` of the final error normalized by the bound, `eᵀ C_bound⁻¹ e`: 3 for
/// an efficient estimator, more when the estimator loses information.
pub fn bound_normalized_mean(runs: &[RunResult]) -> Option<f64> {
    let v: Vec<f64> = runs
        .iter()
        .filter_map(|r| {
            let inv = r.final_bound?.try_inverse()?;
            let e = r.final_error_vec?;
            Some((e.transpose() * inv * e)[(0, 0)])
        })
        .collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// One row of the error budget: final 3-D error max/mean/median, truth inside 3σ, mean
/// NEES, the bound's efficient error and the error normalized by the bound.
fn budget_row(label: &str, runs: &[RunResult]) -> String {
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let nees: f64 = runs.iter().map(|r| r.nees_sum).sum();
    format!(
        "| {label} | {} | {:.1} | {:.2} | {} | {:.2} |\n",
        fmt3(stats(runs.iter().map(|r| r.final_error_m))),
        100.0 * inside as f64 / evaluated.max(1) as f64,
        nees / evaluated.max(1) as f64,
        fmt3(bound_stats(runs, false, false)),
        bound_normalized_mean(runs).unwrap_or(f64::NAN),
    )
}

/// The error budget of the calibrated case (seeds `first_seed..`): the pulse noise with
/// each motion source, every source removed, and the oracle starts (an EKF without
/// mixture near the truth). Every variant sees the same scenarios and the same noise
/// draws (only their amplitudes change), so the rows compare run by run.
pub fn budget(first_seed: u64, tries: u64, noise: &MotionNoise) -> String {
    use rayon::prelude::*;
    let case = Case::Calibrated;
    let seeds = first_seed..first_seed + tries;
    let run = |n: MotionNoise| -> Vec<RunResult> {
        seeds
            .clone()
            .into_par_iter()
            .map(|seed| run_open_loop(case, seed, &n))
            .collect()
    };
    let mut s = String::from(
        "| variant | max | mean | median | inside 3σ (%) | mean NEES | bound: p99 | bound: mean | bound: median | eᵀC⁻¹e mean |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let base = run(*noise);
    s.push_str(&budget_row("SOG, all sources (default)", &base));
    s.push_str(&budget_row(
        "SOG, pulse noise only (motion sources removed)",
        &run(only(noise, None)),
    ));
    for src in SOURCES {
        eprintln!("accuracy budget: {src:?} …");
        if src != Source::Pulse {
            s.push_str(&budget_row(
                &format!("SOG, pulse noise + {src:?} only"),
                &run(only(noise, Some(src))),
            ));
        }
        s.push_str(&budget_row(
            &format!("SOG, all but {src:?}"),
            &run(scaled(noise, src, REMOVED)),
        ));
    }
    for rel in ORACLE_REL_SIGMAS {
        let o: Vec<RunResult> = seeds
            .clone()
            .into_par_iter()
            .map(|seed| run_open_loop_oracle(case, seed, noise, rel))
            .collect();
        let name = format!("EKF, oracle start (σ_p {:.0} % of range)", 100.0 * rel);
        s.push_str(&budget_row(&name, &o));
        s.push_str(&paired_line(&base, &o));
    }
    s
}

/// Relative position σ of the oracle starts in the budget.
pub const ORACLE_REL_SIGMAS: [f64; 2] = [0.05, 0.15];

/// A table row comparing the SOG's final error with the oracle's, run by run.
fn paired_line(sog: &[RunResult], oracle: &[RunResult]) -> String {
    let d: Vec<Option<f64>> = sog
        .iter()
        .zip(oracle)
        .map(|(a, b)| Some(a.final_error_m? - b.final_error_m?))
        .collect();
    let worse = d.iter().flatten().filter(|&&x| x > 0.0).count();
    format!(
        "| ↳ SOG − oracle, per run (SOG worse in {worse} of {}) | {} | | | | | | |\n",
        d.iter().flatten().count(),
        fmt3(stats(d.into_iter())),
    )
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

const ALL_CASES: [Case; 6] = [
    Case::Known,
    Case::Calibrated,
    Case::Uncalibrated,
    Case::Paths,
    Case::ClosedLoop,
    Case::Imu,
];

fn fmt3(s: Option<[f64; 3]>) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.3} | {b:.3} | {c:.3}"),
        None => "– | – | –".into(),
    }
}

/// Markdown section for one case's runs.
pub fn case_report(case: Case, runs: &[RunResult]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let n = runs.len();
    let init = runs.iter().filter(|r| r.final_error_m.is_some()).count();
    let _ = writeln!(s, "### {case:?} ({n} tries, {init} initialized)\n");
    let _ = writeln!(s, "| metric | max | mean | median |\n|---|---|---|---|");
    let rows: [(&str, Option<[f64; 3]>); 7] = [
        (
            "final error 3-D (m)",
            stats(runs.iter().map(|r| r.final_error_m)),
        ),
        (
            "final error horizontal (m)",
            stats(runs.iter().map(|r| r.final_error_h_m)),
        ),
        (
            "final depth error (m)",
            stats(runs.iter().map(|r| r.final_error_z_m)),
        ),
        (
            "error at 20 m (m)",
            stats(runs.iter().map(|r| r.error_at_20m)),
        ),
        (
            "error at 10 m (m)",
            stats(runs.iter().map(|r| r.error_at_10m)),
        ),
        (
            "initial distance (m)",
            stats(runs.iter().map(|r| Some(r.start_distance_m))),
        ),
        (
            "final true distance (m)",
            stats(runs.iter().map(|r| Some(r.final_distance_m))),
        ),
    ];
    for (name, st) in rows {
        let _ = writeln!(s, "| {name} | {} |", fmt3(st));
    }
    if case == Case::ClosedLoop {
        let _ = writeln!(
            s,
            "| steps to probe | {} |",
            fmt3(stats(
                runs.iter().map(|r| r.steps_to_probe.map(|x| x as f64))
            ))
        );
        let _ = writeln!(
            s,
            "| ideal steps | {} |",
            fmt3(stats(runs.iter().map(|r| r.ideal_steps.map(|x| x as f64))))
        );
        let ratio = stats(
            runs.iter()
                .map(|r| match (r.steps_to_probe, r.ideal_steps) {
                    (Some(a), Some(b)) => Some(a as f64 / b.max(1) as f64),
                    _ => None,
                }),
        );
        let _ = writeln!(s, "| steps / ideal | {} |", fmt3(ratio));
    }
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let over_1m = runs
        .iter()
        .filter(|r| r.final_error_m.is_none_or(|e| e > 1.0))
        .count();
    let reinit: usize = runs.iter().map(|r| r.reinitializations).sum();
    let comps = stats(runs.iter().map(|r| Some(r.max_components as f64)));
    let _ = writeln!(
        s,
        "\nTruth inside the reported 3σ ellipsoid on {:.1} % of {evaluated} steps; final error > 1 m (or never initialized) in {over_1m} of {n} runs; {reinit} re-initializations; components max/mean/median {} (step cost on the target: `budget.md`).",
        100.0 * inside as f64 / evaluated.max(1) as f64,
        fmt3(comps),
    );
    let _ = writeln!(s, "{}", consistency_line(runs));
    if let (Some(b), Some(rel), Some(h), Some(norm)) = (
        bound_stats(runs, false, false),
        bound_stats(runs, true, false),
        bound_stats(runs, false, true),
        bound_normalized_mean(runs),
    ) {
        let _ = writeln!(
            s,
            "Cramér–Rao bound of the final 3-D error (`accuracy_bound`: an efficient unbiased estimator given the same pulses, dead reckoning and attitude) p99 / mean / median {} m, {:.1} / {:.1} / {:.1} % of the final distance, horizontal {} m; this filter's final error normalized by the bound, eᵀC⁻¹e, mean {norm:.2} (3 if efficient).",
            fmt3(Some(b)),
            100.0 * rel[0],
            100.0 * rel[1],
            100.0 * rel[2],
            fmt3(Some(h)),
        );
    }
    let mut worst: Vec<&RunResult> = runs.iter().collect();
    worst.sort_by(|a, b| {
        b.final_error_m
            .unwrap_or(f64::INFINITY)
            .total_cmp(&a.final_error_m.unwrap_or(f64::INFINITY))
    });
    let list: Vec<String> = worst
        .iter()
        .take(5)
        .map(|r| {
            let sigmas = bound_normalized_mean(std::slice::from_ref(*r))
                .map(|d2| format!(", {:.1} bound σ", d2.sqrt()))
                .unwrap_or_default();
            format!(
                "seed {} ({:.3} m{sigmas})",
                r.seed,
                r.final_error_m.unwrap_or(f64::NAN)
            )
        })
        .collect();
    let _ = writeln!(s, "Worst runs: {}.\n", list.join(", "));
    s
}

/// The NEES and innovation consistency figures of `runs` (slides 002), one sentence.
pub fn consistency_line(runs: &[RunResult]) -> String {
    let nees_in: usize = runs.iter().map(|r| r.nees_inside_95).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let nees_sum: f64 = runs.iter().map(|r| r.nees_sum).sum();
    let nis_in: usize = runs.iter().map(|r| r.nis_inside_95).sum();
    let nis_n: usize = runs.iter().map(|r| r.nis_evaluated).sum();
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    // The application pipeline (`Case::Imu`) does not expose its innovations.
    let innovation = if nis_n == 0 {
        String::new()
    } else {
        format!(
            "; innovation (best component) inside on {:.1} % of {nis_n} updates",
            pct(nis_in, nis_n)
        )
    };
    format!(
        "Consistency (95 % χ²(3) bound {CHI2_3DOF_95}, target ≥ 90 % inside): position NEES inside on {:.1} % of {evaluated} steps (mean NEES {:.2}, 3 when consistent){innovation}.",
        pct(nees_in, evaluated),
        nees_sum / evaluated.max(1) as f64,
    )
}

/// One case's headline: final 3-D error median and max, share inside 3σ, and the bound's
/// median where the case computes it.
#[derive(Debug, Clone, Copy)]
struct SummaryRow {
    median_m: f64,
    max_m: f64,
    inside_3sigma_pct: f64,
    bound_median_m: Option<f64>,
}

fn summary_row(runs: &[RunResult]) -> Option<SummaryRow> {
    let [max_m, _, median_m] = stats(runs.iter().map(|r| r.final_error_m))?;
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    Some(SummaryRow {
        median_m,
        max_m,
        inside_3sigma_pct: 100.0 * inside as f64 / evaluated.max(1) as f64,
        bound_median_m: bound_stats(runs, false, false).map(|b| b[2]),
    })
}

/// The report's opening summary, generated from this run's cases.
fn summary_section(rows: &[(Case, Option<SummaryRow>)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from(
        "**Summary** (final 3-D error median / max; share of steps with the truth inside the \
         reported 3σ; the Cramér–Rao bound's median where computed):\n\n",
    );
    for (case, row) in rows {
        let Some(r) = row else {
            let _ = writeln!(s, "- {case:?}: no run initialized.");
            continue;
        };
        let bound = r
            .bound_median_m
            .map_or(String::new(), |b| format!(", bound {b:.3} m"));
        let _ = writeln!(
            s,
            "- {case:?}: {:.3} / {:.3} m, {:.1} % inside 3σ{bound}.",
            r.median_m, r.max_m, r.inside_3sigma_pct
        );
    }
    let median = |c: Case| {
        rows.iter()
            .find(|(k, _)| *k == c)
            .and_then(|(_, r)| r.map(|r| r.median_m))
    };
    if let (Some(imu), Some(exact)) = (median(Case::Imu), median(Case::Calibrated)) {
        let _ = writeln!(
            s,
            "\nThe application pipeline (`Imu`: the firmware's attitude filter and PDR on the \
             simulated IMU) ends {:+.0} % from the calibrated case's synthetic motion in the \
             median (issue target: within 10 %).",
            100.0 * (imu / exact - 1.0)
        );
    }
    s.push('\n');
    s
}

/// How to read the budget table (written under it).
const BUDGET_NOTE: &str = "Every row is the calibrated case on the same scenarios with the \
same noise draws, only their amplitudes changed (`budget` in `hal-sim/src/eval/accuracy.rs`); a \
\"removed\" source is kept at 10 % of its σ (1 % of its variance) so every declared covariance \
stays positive definite. \"bound\" columns: the Cramér–Rao bound of each run \
(`hal-sim/src/eval/accuracy_bound.rs`) as the error of an efficient unbiased estimator (p99 of 100 \
pooled draws per run standing for the largest run); `eᵀC⁻¹e`: the filter's final error \
normalized by its run's bound (mean 3 for an efficient estimator, larger when information \
is lost). \"mean NEES\" is the filter's own consistency against its reported covariance. \
What the budget has shown, and the estimator's gates and their measurements: \
`docs/decisions/estimator.md`.\n";

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
    if args.first_seed != 1 {
        flags.push_str(&format!(" --first-seed {}", args.first_seed));
    }
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
    let command = format!(
        "cargo run -p hal-sim --release -- accuracy --tries {}{flags}",
        args.tries
    );
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
    let case: Case = serde_json::from_value(record["case"].clone())?;
    let seed = crate::eval::sidecar::seed_of(record, "/run/seed")?;
    let run = run_case(case, seed, 1, &MotionNoise::default())
        .pop()
        .ok_or_else(|| anyhow::anyhow!("no run"))?;
    Ok(serde_json::json!({"case": case, "run": crate::eval::sidecar::record(&run, VOLATILE)?}))
}

#[cfg(test)]
mod tests {
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
}
