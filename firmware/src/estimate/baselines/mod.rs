//! The papers' baseline filters, behind the same [`Estimator`](super::Estimator) trait
//! and fed the same inputs as the SOGs filter, so the comparison of IROS 2006 §IV and the
//! slides can be re-run:
//! - [`ekf::SingleEkf`]: one EKF on the SOGs filter's robocentric state (slides `002_*`);
//! - [`pf::ParticleFilter`]: the vanilla particle filter (IROS 2006 Algorithm 2);
//! - [`rbpf::Rbpf`]: the Rao-Blackwellized particle filter (IROS 2006 Algorithm 3);
//! - [`grid::HistogramFilter`]: a 2-D histogram filter (Markov localization, slides).
//!
//! All reuse the SOGs filter's models rather than re-deriving them: the measurement
//! `h = K_H R(Ψ)ᵀ H(−p_T, m)` (IROS eq. 12–14), the composition `Ψ' = Ψ ⊕ ΔΨ`,
//! `p' = p − R(Ψ)(s·Δp + a)` (IROS eq. 5–9), the initial region of the first pulse
//! (IROS III-B, `estimate::init`), the input checks and the sign-ambiguous pulse
//! likelihood `½N(z; h, S) + ½N(−z; h, S)`. No heap: capacities are const generics; the
//! particle filters draw from a seeded [`Prng`].
//!
//! Each has a one-line constructor from a [`SogConfig`]:
//! `SingleEkf::new(config)`, `ParticleFilter::<N>::new(config, seed)`,
//! `Rbpf::<N>::new(config, seed)`, `HistogramFilter::<NX, NY>::new(config)`.

pub mod ekf;
pub mod grid;
mod particles;
pub mod pf;
pub mod rbpf;
mod rng;
#[cfg(test)]
mod scenario_tests;

pub use ekf::SingleEkf;
pub use grid::HistogramFilter;
pub use pf::ParticleFilter;
pub use rbpf::Rbpf;
pub use rng::Prng;

use super::gaussian::{Component, cholesky3, lower_inverse3};
use super::init::initialize;
use super::model::{FIELD_SCALE, I_P};
use super::sog::{check_inputs, step_input};
use super::{
    Attitude, Displacement, EstimateError, Mode, Pulse, SogConfig, StepOutcome, StepReport,
};
use crate::frame::{Rpy, rotation_from_rpy, rpy_from_rotation, wrap_pi};
use crate::{Mat3, Vec3};
use nalgebra::SMatrix;

/// Cells of the initial region the baselines are initialized from (the SOGs filter's
/// grid of IROS III-B at this size; particles are drawn from it).
pub(crate) const REGION_CELLS: usize = 48;

/// The initial region: Gaussians covering every transmitter that explains the first pulse.
pub(crate) type Region = heapless::Vec<Component, REGION_CELLS>;

/// Parameters of the particle filters beyond the [`SogConfig`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParticleConfig {
    /// Resample when `N_eff` (IROS eq. 20) falls below this fraction of the particles.
    pub resample_fraction: f32,
    /// Roughening after resampling (Gordon, Salmond & Smith 1993): each copy's position
    /// (and, in the vanilla filter, moment) is jittered by this fraction of its
    /// magnitude (1σ). The transmitter is static, so without it the resampled particles
    /// would only ever be copies of the initial draws.
    pub roughen: f32,
    /// Seed of the pseudo-random generator.
    pub seed: u64,
}

impl ParticleConfig {
    /// The default parameters with `seed`.
    pub fn seeded(seed: u64) -> Self {
        Self {
            resample_fraction: 0.5,
            roughen: 0.01,
            seed,
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), EstimateError> {
        let ok = self.resample_fraction.is_finite()
            && (0.0..=1.0).contains(&self.resample_fraction)
            && self.roughen.is_finite()
            && (0.0..1.0).contains(&self.roughen);
        if ok {
            Ok(())
        } else {
            Err(EstimateError::InvalidConfig)
        }
    }
}

/// Checks one step's inputs against the last pulse time (a refused input changes
/// nothing), then records the pulse's time and returns the pulse in µA/m.
pub(crate) fn accept_pulse(
    config: &SogConfig,
    last_t: &mut Option<f32>,
    motion: &Displacement,
    attitude: &Attitude,
    pulse: &Pulse,
) -> Result<Vec3, EstimateError> {
    check_inputs(config, *last_t, motion, attitude, pulse)?;
    *last_t = Some(pulse.t);
    Ok(pulse.h * FIELD_SCALE)
}

/// The [`Estimator::step`](super::Estimator::step) every baseline shares: check and
/// accept the pulse ([`accept_pulse`], on the fields `config` and `last_t`), then build
/// the filter from it (`try_initialize`) until initialized, and `advance` after.
macro_rules! staged_step {
    () => {
        fn step(
            &mut self,
            motion: &$crate::estimate::Displacement,
            attitude: &$crate::estimate::Attitude,
            pulse: &$crate::estimate::Pulse,
        ) -> Result<$crate::estimate::StepReport, $crate::estimate::EstimateError> {
            let z = $crate::estimate::baselines::accept_pulse(
                &self.config,
                &mut self.last_t,
                motion,
                attitude,
                pulse,
            )?;
            let attitude = &attitude.bounded();
            if !$crate::estimate::Estimator::is_initialized(self) {
                let outcome = $crate::estimate::StepOutcome::Initialized;
                return Ok(self.try_initialize(attitude, &z, outcome));
            }
            Ok(self.advance(motion, attitude, &z))
        }
    };
}
pub(crate) use staged_step;

/// A step report with `n` hypotheses, the best squared distance and the number lost
/// (the baselines neither prune, merge nor split).
pub(crate) fn step_report(
    outcome: StepOutcome,
    n: usize,
    best_d2: f32,
    dropped: u16,
) -> StepReport {
    StepReport {
        outcome,
        n_components: n,
        best_d2,
        pruned: 0,
        merged: 0,
        split: 0,
        dropped,
    }
}

/// Measurement noise variance per axis (ICRA eq. 10) for pulse `z` (µA/m), in (µA/m)².
pub(crate) fn noise_var(config: &SogConfig, z: &Vec3) -> f32 {
    let bkg = config.sigma_bkg * FIELD_SCALE;
    let sen = config.k_sen * z.norm();
    bkg * bkg + sen * sen
}

/// Whether the pulse `z` (µA/m) is strong enough to initialize from (`init_snr`).
pub(crate) fn strong_enough(config: &SogConfig, z: &Vec3) -> bool {
    z.norm() / (config.sigma_bkg * FIELD_SCALE) >= config.init_snr
}

/// `log(½e^{−d₊/2} + ½e^{−d₋/2})` up to the constant `log ½`: the likelihood of a pulse
/// whose overall sign is unknown (both signs equally likely), as in the SOGs filter's
/// weights (IROS eq. 17).
pub(crate) fn sign_ambiguous_log_lik(d2_pos: f32, d2_neg: f32) -> f32 {
    let (lo, hi) = if d2_pos < d2_neg {
        (d2_pos, d2_neg)
    } else {
        (d2_neg, d2_pos)
    };
    -0.5 * lo + libm::log1pf(libm::expf(-0.5 * (hi - lo)))
}

/// The initial region for pulse `z_body` (µA/m in `R_1`): the SOGs filter's
/// initialization (IROS III-B) filled to [`REGION_CELLS`] cells.
pub(crate) fn initial_region(config: &SogConfig, attitude: &Attitude, z_body: &Vec3) -> Region {
    let mut region = Region::new();
    let cfg = SogConfig {
        init_fill: 1.0,
        ..*config
    };
    let exact = config.mode == Mode::KnownTrajectory;
    initialize(
        &mut region,
        &cfg,
        attitude,
        z_body,
        noise_var(config, z_body),
        exact,
    );
    region
}

/// A transmitter position drawn from the region: a cell uniformly (they have equal
/// weights), then its position Gaussian.
pub(crate) fn sample_region(region: &Region, rng: &mut Prng) -> Option<Vec3> {
    let c = region.get(rng.below(region.len()))?;
    let l = cholesky3(&c.block3(I_P)).ok()?;
    let mean = Vec3::new(c.x[I_P], c.x[I_P + 1], c.x[I_P + 2]);
    Some(mean + l * gauss3(rng))
}

/// Three independent standard-normal draws.
pub(crate) fn gauss3(rng: &mut Prng) -> Vec3 {
    Vec3::new(rng.gauss(), rng.gauss(), rng.gauss())
}

/// Lower factor `L` with `L Lᵀ = C` of a symmetric positive semi-definite matrix:
/// Cholesky where a pivot is zero (an exactly known coordinate, e.g. a zero variance)
/// leaves that column zero instead of failing.
pub(crate) fn psd_factor<const D: usize>(c: &SMatrix<f32, D, D>) -> SMatrix<f32, D, D> {
    let mut l = SMatrix::<f32, D, D>::zeros();
    for j in 0..D {
        let mut d = c[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        if d.is_nan() || d <= 1e-12 * c[(j, j)].max(f32::MIN_POSITIVE) {
            continue;
        }
        let ljj = libm::sqrtf(d);
        l[(j, j)] = ljj;
        for i in (j + 1)..D {
            let mut v = c[(i, j)];
            for k in 0..j {
                v -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = v / ljj;
        }
    }
    l
}

/// Draws of the displacement `[Δp; ΔΨ]` and the absolute translation `a` from their
/// Gaussians (IROS eq. 4); exact (the means) with a known trajectory.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MotionNoise {
    dp: Vec3,
    drot: Rpy,
    a: Vec3,
    l: SMatrix<f32, 6, 6>,
    la: Mat3,
    exact: bool,
}

/// One draw of the motion.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MotionDraw {
    /// Dead-reckoned translation in `R_{k-1}` (m).
    pub dp: Vec3,
    /// Rotation `R_{k-1} → R_k` (rad).
    pub drot: Rpy,
    /// Absolute translation in `R_{k-1}` (m).
    pub a: Vec3,
}

impl MotionNoise {
    /// The sampler of `motion` (noise-free when `exact`).
    pub fn new(motion: &Displacement, exact: bool) -> Self {
        Self {
            dp: motion.translation,
            drot: motion.rotation,
            a: motion.absolute,
            l: psd_factor(&((motion.cov + motion.cov.transpose()) * 0.5)),
            la: psd_factor(&((motion.absolute_cov + motion.absolute_cov.transpose()) * 0.5)),
            exact,
        }
    }

    /// One draw.
    pub fn sample(&self, rng: &mut Prng) -> MotionDraw {
        if self.exact {
            return MotionDraw {
                dp: self.dp,
                drot: self.drot,
                a: self.a,
            };
        }
        let e = SMatrix::<f32, 6, 1>::from_fn(|_, _| rng.gauss());
        let n = self.l * e;
        MotionDraw {
            dp: self.dp + Vec3::new(n[0], n[1], n[2]),
            drot: self.drot + Vec3::new(n[3], n[4], n[5]),
            // Draw the absolute part only when there is one (rare: lifts).
            a: if self.la == Mat3::zeros() {
                self.a
            } else {
                self.a + self.la * gauss3(rng)
            },
        }
    }
}

/// The composition of one pose hypothesis (IROS eq. 5–7 with the scale state):
/// `Ψ' = Ψ ⊕ ΔΨ`, `p' = p − R(Ψ)(s·Δp + a)`; `m` and `s` carry over. Also returns
/// `R(Ψ') = R(Ψ) R(ΔΨ)`, which the measurement needs next.
pub(crate) fn compose_pose(psi: &Rpy, p: &Vec3, s: f32, d: &MotionDraw) -> (Rpy, Vec3, Mat3) {
    let r = rotation_from_rpy(psi);
    let r2 = r * rotation_from_rpy(&d.drot);
    (rpy_from_rotation(&r2), p - r * (d.dp * s + d.a), r2)
}

/// `L⁻¹` of the attitude noise `R = L Lᵀ` for the attitude likelihood, or `None` when it
/// is not positive definite (no attitude information then).
pub(crate) fn attitude_whitener(attitude: &Attitude) -> Option<Mat3> {
    let r = (attitude.cov + attitude.cov.transpose()) * 0.5;
    cholesky3(&r).ok().map(|l| lower_inverse3(&l))
}

/// Log-likelihood (up to a constant) of the IMU attitude `z` for orientation `psi`:
/// `−½ |L⁻¹ wrap(z − Ψ)|²` (the SOGs filter's attitude measurement `z = Ψ + v`).
pub(crate) fn attitude_log_lik(psi: &Rpy, z: &Rpy, l_inv: &Mat3) -> f32 {
    let nu = Vec3::from_fn(|i, _| wrap_pi(z[i] - psi[i]));
    -0.5 * (l_inv * nu).norm_squared()
}

/// A weighted hypothesis (particle or cell) with a log-weight.
pub(crate) trait Weighted {
    /// Natural log of the (unnormalized) weight.
    fn log_w(&self) -> f32;
    /// Sets it.
    fn set_log_w(&mut self, v: f32);
}

/// Log-weight of a hypothesis that is ruled out (exactly zero weight after
/// normalization, without infinities in the arithmetic).
pub(crate) const LOG_ZERO: f32 = -1.0e30;

/// Normalizes the log-weights so the weights sum to one (log-sum-exp); returns the
/// largest normalized weight, or `None` when every weight is zero or not finite.
pub(crate) fn normalize<P: Weighted>(ps: &mut [P]) -> Option<f32> {
    let max = ps
        .iter()
        .map(|p| p.log_w())
        .fold(f32::NEG_INFINITY, f32::max);
    if !max.is_finite() || max <= LOG_ZERO {
        return None;
    }
    let sum: f32 = ps.iter().map(|p| libm::expf(p.log_w() - max)).sum();
    let shift = max + libm::logf(sum);
    for p in ps.iter_mut() {
        let w = p.log_w();
        p.set_log_w(if w <= LOG_ZERO { LOG_ZERO } else { w - shift });
    }
    Some(libm::expf(max - shift))
}

/// Effective sample size of normalized weights, `N_eff = 1 / Σ w̃²` (IROS eq. 20).
pub(crate) fn n_eff<P: Weighted>(ps: &[P]) -> f32 {
    let s: f32 = ps.iter().map(|p| libm::expf(2.0 * p.log_w())).sum();
    if s > 0.0 { 1.0 / s } else { 0.0 }
}

/// Systematic resampling in place (Kitagawa 1996; IROS Algorithms 2–3): one uniform
/// `u0 ∈ (0, 1)`, pointers `(u0 + k)/N`; particle `i` gets as many copies as pointers
/// fall in its slice of the weights' CDF, so `E[copies] = N w̃_i` and the count differs
/// from it by less than one. No scratch buffer: the copy counts are kept in the
/// log-weight slots, then the surplus copies fill the slots of the dropped particles.
/// Afterwards every weight is `1/N`. The weights must be normalized.
pub(crate) fn systematic_resample<P: Weighted + Copy>(ps: &mut [P], u0: f32) {
    let n = ps.len();
    if n == 0 {
        return;
    }
    // Pointers scaled by the weights' actual sum (≈ 1), summed in the same order as the
    // CDF below, so rounding cannot push the last pointer past the end.
    let total: f32 = ps.iter().map(|p| libm::expf(p.log_w())).sum();
    let step = total / n as f32;
    let mut pointer = u0.clamp(0.0, 1.0) * step;
    let mut cdf = 0.0f32;
    let mut assigned = 0usize;
    for (i, p) in ps.iter_mut().enumerate() {
        cdf += libm::expf(p.log_w());
        // The last particle takes whatever rounding left over.
        let mut copies = 0usize;
        while assigned < n && (pointer < cdf || i + 1 == n) {
            copies += 1;
            assigned += 1;
            pointer += step;
        }
        p.set_log_w(copies as f32);
    }
    // Fill the empty slots (count 0) with the surplus copies.
    let mut free = 0usize;
    for i in 0..n {
        let copies = ps[i].log_w() as usize;
        for _ in 1..copies {
            while free < n && ps[free].log_w() != 0.0 {
                free += 1;
            }
            if free >= n {
                break;
            }
            ps[free] = ps[i];
            // Mark as a placed copy (not free, not a source with surplus).
            ps[free].set_log_w(1.0);
        }
        if copies > 0 {
            // Done with this source; a dropped particle (0) stays a free slot.
            ps[i].set_log_w(1.0);
        }
    }
    let log_w = -libm::logf(n as f32);
    for p in ps.iter_mut() {
        p.set_log_w(log_w);
    }
}

/// Weighted mean and covariance of positions `(w, p)` (weights summing to one).
pub(crate) fn weighted_moments(items: impl Iterator<Item = (f32, Vec3)> + Clone) -> (Vec3, Mat3) {
    let mean = items.clone().fold(Vec3::zeros(), |acc, (w, p)| acc + p * w);
    let cov = items.fold(Mat3::zeros(), |acc, (w, p)| {
        let d = p - mean;
        acc + d * d.transpose() * w
    });
    (mean, cov)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq)]
    struct W(f32, usize);
    impl Weighted for W {
        fn log_w(&self) -> f32 {
            self.0
        }
        fn set_log_w(&mut self, v: f32) {
            self.0 = v;
        }
    }

    fn weights(ws: &[f32]) -> std::vec::Vec<W> {
        ws.iter()
            .enumerate()
            .map(|(i, w)| W(libm::logf(*w), i))
            .collect()
    }

    #[test]
    fn n_eff_matches_eq_20() {
        // Uniform weights: N_eff = N; one particle with all the weight: 1.
        let mut ps = weights(&[1.0; 8]);
        normalize(&mut ps).unwrap();
        assert!((n_eff(&ps) - 8.0).abs() < 1e-4);
        let mut ps = weights(&[1.0, 0.0, 0.0, 0.0]);
        normalize(&mut ps).unwrap();
        assert!((n_eff(&ps) - 1.0).abs() < 1e-6);
        // General case against the f64 formula.
        let raw = [0.1f64, 0.4, 0.2, 0.05, 0.25, 0.7];
        let mut ps = weights(&raw.map(|w| w as f32));
        normalize(&mut ps).unwrap();
        let total: f64 = raw.iter().sum();
        let expect = 1.0 / raw.iter().map(|w| (w / total).powi(2)).sum::<f64>();
        assert!((f64::from(n_eff(&ps)) - expect).abs() < 1e-4 * expect);
    }

    #[test]
    fn systematic_resampling_keeps_counts_within_one_of_n_w() {
        let mut rng = Prng::new(3);
        for trial in 0..200 {
            let n = 1 + trial % 37;
            let raw: std::vec::Vec<f32> = (0..n)
                .map(|_| {
                    let u = rng.uniform();
                    // Some exactly-zero weights, some tiny.
                    if u < 0.2 { 0.0 } else { u * u * u }
                })
                .collect();
            let mut ps = weights(&raw);
            if normalize(&mut ps).is_none() {
                continue;
            }
            let w: std::vec::Vec<f32> = ps.iter().map(|p| libm::expf(p.0)).collect();
            systematic_resample(&mut ps, rng.uniform());
            assert_eq!(ps.len(), n);
            for (i, wi) in w.iter().enumerate() {
                let copies = ps.iter().filter(|p| p.1 == i).count() as f32;
                assert!(
                    (copies - n as f32 * wi).abs() < 1.0 + 1e-3,
                    "trial {trial}: particle {i} w {wi} copies {copies}"
                );
                if *wi == 0.0 {
                    assert_eq!(copies, 0.0);
                }
            }
            let lw = -libm::logf(n as f32);
            assert!(ps.iter().all(|p| (p.0 - lw).abs() < 1e-6));
        }
    }

    #[test]
    fn resampling_is_unbiased_on_average() {
        // E[copies_i] = N w_i over many draws of u0.
        let raw = [0.05f32, 0.3, 0.15, 0.5];
        let mut rng = Prng::new(4);
        let mut counts = [0f64; 4];
        let trials = 4000;
        for _ in 0..trials {
            let mut ps = weights(&raw);
            normalize(&mut ps).unwrap();
            systematic_resample(&mut ps, rng.uniform());
            for p in &ps {
                counts[p.1] += 1.0;
            }
        }
        for (c, w) in counts.iter().zip(raw) {
            let mean = c / f64::from(trials);
            assert!(
                (mean - 4.0 * f64::from(w)).abs() < 0.03,
                "{mean} vs {}",
                4.0 * w
            );
        }
    }

    #[test]
    fn psd_factor_reproduces_the_matrix_and_tolerates_zero_variances() {
        let a = SMatrix::<f32, 3, 3>::new(4.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0);
        let l = psd_factor(&a);
        assert!((l * l.transpose() - a).abs().max() < 1e-6);
        assert_eq!(psd_factor(&Mat3::zeros()), Mat3::zeros());
    }

    #[test]
    fn sign_ambiguous_likelihood_is_the_two_sign_mixture() {
        for (dp, dn) in [(0.0f32, 0.0f32), (1.0, 30.0), (12.0, 3.0), (400.0, 900.0)] {
            let expect = (0.5 * (-0.5 * f64::from(dp)).exp() + 0.5 * (-0.5 * f64::from(dn)).exp())
                .ln()
                - 0.5f64.ln();
            let got = f64::from(sign_ambiguous_log_lik(dp, dn));
            assert!(
                (got - expect).abs() < 1e-4 * (1.0 + expect.abs()),
                "{got} {expect}"
            );
        }
    }
}
