//! What the vanilla particle filter (IROS 2006 Algorithm 2) and the Rao-Blackwellized
//! one (Algorithm 3) share: the particle set, its initialization from the first pulse's
//! region (IROS III-B), the motion draw and composition (IROS eq. 5–9), the weight
//! normalization, the divergence check, `N_eff` (IROS eq. 20) with systematic resampling
//! and roughening, and the weighted estimate. A [`ParticleModel`] supplies what differs:
//! how a particle's moment is drawn, weighted by a pulse and roughened.

use super::super::model::MOMENT_SCALE;
use super::super::{
    Attitude, Displacement, EstimateError, Estimator, Mode, SogConfig, StepOutcome, StepReport,
    VictimEstimate,
};
use super::{
    LOG_ZERO, MotionNoise, ParticleConfig, Prng, Weighted, attitude_log_lik, attitude_whitener,
    compose_pose, gauss3, initial_region, n_eff, noise_var, normalize, psd_factor, sample_region,
    step_report, strong_enough, systematic_resample, weighted_moments,
};
use crate::frame::Rpy;
use crate::{Mat3, Vec3};
use heapless::Vec;

/// One particle: a point hypothesis of the pose `(Ψ, p_T, s)` with the moment's mean,
/// a log-weight and the model's extra state `E` (11 `f32` plus `E`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Particle<E> {
    /// Orientation of `R_k` in `G_k` (rad).
    pub(crate) psi: Rpy,
    /// Transmitter position in `G_k` (m).
    pub(crate) p: Vec3,
    /// Transmitter moment (mean) in `G_k` (mA·m²).
    pub(crate) m: Vec3,
    /// Scale factor of the dead-reckoned translation.
    pub(crate) s: f32,
    /// Log-weight.
    pub(crate) log_w: f32,
    /// What the model keeps beyond the mean moment.
    pub(crate) extra: E,
}

impl<E> Weighted for Particle<E> {
    fn log_w(&self) -> f32 {
        self.log_w
    }
    fn set_log_w(&mut self, v: f32) {
        self.log_w = v;
    }
}

/// What differs between the particle filters: how a particle's moment is drawn,
/// weighed by a pulse and roughened.
pub(crate) trait ParticleModel {
    /// Whether the particles are resampled right after initialization (when their
    /// initial weights already differ).
    const RESAMPLE_AT_INIT: bool;
    /// The particle's state beyond the mean moment.
    type Extra: Copy + core::fmt::Debug + PartialEq;
    /// What the initialization computes once per pulse for every draw.
    type Prior;
    /// The per-pulse constants of an initialization from pulse `z` (µA/m in `R_1`)
    /// with noise variance `r_var`, for `n` particles.
    fn prior(config: &SogConfig, z: &Vec3, r_var: f32, n: usize) -> Self::Prior;
    /// A particle at pose `(psi, p, s)` explaining pulse `z`, or `None` to redraw.
    fn draw(
        prior: &Self::Prior,
        pose: (Rpy, Vec3, f32),
        z: &Vec3,
        rng: &mut Prng,
    ) -> Option<Particle<Self::Extra>>;
    /// Weighs particle `q`, already moved to orientation `rot = R(Ψ)`, by pulse `z`:
    /// the squared distance (best sign, in noise units) and the log-likelihood, or
    /// `None` when the model cannot be evaluated there.
    fn weigh(q: &mut Particle<Self::Extra>, rot: &Mat3, z: &Vec3, r_var: f32)
    -> Option<(f32, f32)>;
    /// Jitters a resampled copy by the fraction `k` of its magnitudes (1σ).
    fn roughen(q: &mut Particle<Self::Extra>, rng: &mut Prng, k: f32);
}

/// A particle filter with room for `N` particles of type `P` (no heap).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ParticleSet<M: ParticleModel, const N: usize> {
    config: SogConfig,
    params: ParticleConfig,
    particles: Vec<Particle<M::Extra>, N>,
    rng: Prng,
    inconsistent_pulses: u8,
    last_t: Option<f32>,
    resamples: u32,
}

impl<M: ParticleModel, const N: usize> ParticleSet<M, N> {
    /// An empty filter, or `InvalidConfig` (bad parameters, fewer than 2 particles).
    pub(crate) fn new(config: SogConfig, params: ParticleConfig) -> Result<Self, EstimateError> {
        config.validate()?;
        params.validate()?;
        if N < 2 {
            return Err(EstimateError::InvalidConfig);
        }
        Ok(Self {
            config,
            params,
            particles: Vec::new(),
            rng: Prng::new(params.seed),
            inconsistent_pulses: 0,
            last_t: None,
            resamples: 0,
        })
    }

    /// Effective sample size of the current weights (IROS eq. 20).
    pub(crate) fn n_eff(&self) -> f32 {
        n_eff(&self.particles)
    }

    /// Number of resamplings so far.
    pub(crate) fn resamples(&self) -> u32 {
        self.resamples
    }

    fn exact(&self) -> bool {
        self.config.mode == Mode::KnownTrajectory
    }

    /// One step of the drawn particles with pulse `z` (µA/m in `R_k`): weighing,
    /// divergence check, resampling when `N_eff` (IROS eq. 20) is low.
    fn advance(&mut self, motion: &Displacement, attitude: &Attitude, z: &Vec3) -> StepReport {
        let (best_d2, dropped) = self.weigh(motion, attitude, z);
        // Divergence as in the SOGs filter: no particle consistent for several pulses.
        if best_d2 > self.config.divergence_d2 {
            self.inconsistent_pulses = self.inconsistent_pulses.saturating_add(1);
        } else {
            self.inconsistent_pulses = 0;
        }
        if normalize(&mut self.particles).is_none()
            || self.inconsistent_pulses >= self.config.divergence_pulses
        {
            let mut r = self.try_initialize(attitude, z, StepOutcome::Reinitialized);
            r.best_d2 = best_d2;
            r.dropped = dropped;
            return r;
        }
        if self.n_eff() < self.params.resample_fraction * self.particles.len() as f32 {
            self.resample();
        }
        let n = self.particles.len();
        step_report(StepOutcome::Updated, n, best_d2, dropped)
    }

    /// Moves every particle by its own draw of the motion (IROS eq. 5–9) and multiplies
    /// its weight by the pulse likelihood and, in robocentric mode, the IMU attitude
    /// likelihood. Returns the best squared distance and the number of particles lost.
    fn weigh(&mut self, motion: &Displacement, attitude: &Attitude, z: &Vec3) -> (f32, u16) {
        let exact = self.exact();
        let noise = MotionNoise::new(motion, exact);
        let r_var = noise_var(&self.config, z);
        let att = if exact {
            None
        } else {
            attitude_whitener(attitude)
        };
        let mut best_d2 = f32::INFINITY;
        let mut dropped = 0u16;
        for q in self.particles.iter_mut() {
            let d = noise.sample(&mut self.rng);
            let (psi, p, rot) = compose_pose(&q.psi, &q.p, q.s, &d);
            q.psi = psi;
            q.p = p;
            match M::weigh(q, &rot, z, r_var) {
                Some((d2, ll)) => {
                    best_d2 = best_d2.min(d2);
                    let la = att.map_or(0.0, |l| attitude_log_lik(&psi, &attitude.rpy, &l));
                    q.log_w += ll + la;
                }
                None => {
                    q.log_w = LOG_ZERO;
                    dropped += 1;
                }
            }
        }
        (best_d2, dropped)
    }

    /// Draws the particles from pulse `z` (µA/m in `R_1`): positions from the initial
    /// region (IROS III-B), orientations from the IMU attitude, the scale from its prior
    /// and the moment from the model.
    fn try_initialize(&mut self, attitude: &Attitude, z: &Vec3, kind: StepOutcome) -> StepReport {
        self.particles.clear();
        self.inconsistent_pulses = 0;
        if !strong_enough(&self.config, z) {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        let region = initial_region(&self.config, attitude, z);
        if region.is_empty() {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        let exact = self.exact();
        let att_l = psd_factor(&((attitude.cov + attitude.cov.transpose()) * 0.5));
        let prior = M::prior(&self.config, z, noise_var(&self.config, z), N);
        let mut tries = 0;
        while !self.particles.is_full() && tries < 4 * N {
            tries += 1;
            let Some(p) = sample_region(&region, &mut self.rng) else {
                continue;
            };
            let psi = if exact {
                attitude.rpy
            } else {
                attitude.rpy + att_l * gauss3(&mut self.rng)
            };
            let s = if exact {
                1.0
            } else {
                1.0 + self.config.scale_sigma * self.rng.gauss()
            };
            if let Some(q) = M::draw(&prior, (psi, p, s), z, &mut self.rng) {
                let _ = self.particles.push(q);
            }
        }
        self.settle_initial();
        let n = self.particles.len();
        let kind = if n > 0 { kind } else { StepOutcome::Waiting };
        step_report(kind, n, 0.0, 0)
    }

    /// Normalizes freshly drawn weights (dropping the set if none is usable) and, for
    /// models whose initial weights differ, resamples when `N_eff` is low.
    fn settle_initial(&mut self) {
        if normalize(&mut self.particles).is_none() {
            self.particles.clear();
        }
        let n = self.particles.len();
        if M::RESAMPLE_AT_INIT && n > 0 && self.n_eff() < self.params.resample_fraction * n as f32 {
            self.resample();
        }
    }

    /// Systematic resampling, then roughening of the copies (Gordon, Salmond & Smith
    /// 1993; the transmitter is static, so copies would otherwise never move).
    fn resample(&mut self) {
        let u0 = self.rng.uniform();
        systematic_resample(&mut self.particles, u0);
        let k = self.params.roughen;
        if k > 0.0 {
            for q in self.particles.iter_mut() {
                M::roughen(q, &mut self.rng, k);
            }
        }
        self.resamples = self.resamples.saturating_add(1);
    }
}

impl<M: ParticleModel, const N: usize> Estimator for ParticleSet<M, N> {
    super::staged_step!();

    /// The weighted mean and covariance of the positions, the moment with the sign of
    /// the heaviest particle (the sign is not observable) and the scale's moments.
    fn estimate(&self) -> Option<VictimEstimate> {
        let best = self
            .particles
            .iter()
            .max_by(|a, b| a.log_w.total_cmp(&b.log_w))?;
        let items = self.particles.iter().map(|q| (libm::expf(q.log_w), q.p));
        let (p, cov) = weighted_moments(items);
        // Moment with the sign of the heaviest particle (the sign is not observable).
        let mut moment = Vec3::zeros();
        let (mut scale, mut scale2) = (0.0f32, 0.0f32);
        for q in self.particles.iter() {
            let w = libm::expf(q.log_w);
            let sign = if q.m.dot(&best.m) < 0.0 { -1.0 } else { 1.0 };
            moment += q.m * (w * sign);
            scale += w * q.s;
            scale2 += w * q.s * q.s;
        }
        Some(VictimEstimate {
            p,
            cov,
            moment: moment / MOMENT_SCALE,
            scale,
            scale_sigma: libm::sqrtf((scale2 - scale * scale).max(0.0)),
            rpy: best.psi,
            n_components: self.particles.len(),
            max_weight: libm::expf(best.log_w),
        })
    }

    /// Forgets the particles and the last pulse time (the generator runs on).
    fn reset(&mut self) {
        self.particles.clear();
        self.inconsistent_pulses = 0;
        self.last_t = None;
    }

    /// Whether the particles have been drawn.
    fn is_initialized(&self) -> bool {
        !self.particles.is_empty()
    }
}

/// The public face of a particle filter wrapping a [`ParticleSet`] of `$model`:
/// its constructors, diagnostics and the [`Estimator`](super::super::Estimator) impl.
macro_rules! particle_filter {
    ($(#[$doc:meta])* $name:ident, $model:ty) => {
        $(#[$doc])*
        #[derive(Debug, Clone, PartialEq)]
        pub struct $name<const N: usize>(
            $crate::estimate::baselines::particles::ParticleSet<$model, N>,
        );

        impl<const N: usize> $name<N> {
            /// A filter with the SOGs filter's configuration and the default particle
            /// parameters drawn from `seed`, or `InvalidConfig`.
            pub fn new(
                config: $crate::estimate::SogConfig,
                seed: u64,
            ) -> Result<Self, $crate::estimate::EstimateError> {
                Self::with_params(
                    config,
                    $crate::estimate::baselines::ParticleConfig::seeded(seed),
                )
            }

            /// A filter with explicit particle parameters, or `InvalidConfig`.
            pub fn with_params(
                config: $crate::estimate::SogConfig,
                params: $crate::estimate::baselines::ParticleConfig,
            ) -> Result<Self, $crate::estimate::EstimateError> {
                $crate::estimate::baselines::particles::ParticleSet::new(config, params).map(Self)
            }

            /// Effective sample size of the current weights (IROS eq. 20).
            pub fn n_eff(&self) -> f32 {
                self.0.n_eff()
            }

            /// Number of resamplings so far.
            pub fn resamples(&self) -> u32 {
                self.0.resamples()
            }
        }

        impl<const N: usize> $crate::estimate::Estimator for $name<N> {
            fn step(
                &mut self,
                motion: &$crate::estimate::Displacement,
                attitude: &$crate::estimate::Attitude,
                pulse: &$crate::estimate::Pulse,
            ) -> Result<$crate::estimate::StepReport, $crate::estimate::EstimateError> {
                $crate::estimate::Estimator::step(&mut self.0, motion, attitude, pulse)
            }

            fn estimate(&self) -> Option<$crate::estimate::VictimEstimate> {
                $crate::estimate::Estimator::estimate(&self.0)
            }

            fn reset(&mut self) {
                $crate::estimate::Estimator::reset(&mut self.0);
            }

            fn is_initialized(&self) -> bool {
                $crate::estimate::Estimator::is_initialized(&self.0)
            }
        }
    };
}
pub(crate) use particle_filter;
