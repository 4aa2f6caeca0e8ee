//! The vanilla particle filter (IROS 2006 Algorithm 2) on the robocentric state.
//!
//! Each particle is a point hypothesis of the whole state `[Ψ; p_T; m; s]` with a
//! log-weight: **44 bytes per particle** (11 `f32`), `N` particles in a fixed-capacity
//! vector. Per pulse: every particle draws its displacement from `N(u, Q)` and is
//! composed into `G_k` (IROS eq. 5–9), its weight is multiplied by the sign-ambiguous
//! pulse likelihood `½N(z; h, R) + ½N(−z; h, R)` (IROS eq. 12–14, noise ICRA eq. 10) and,
//! in robocentric mode, by the IMU attitude likelihood (the SOGs filter's attitude
//! measurement); the weights are normalized and, when `N_eff` (IROS eq. 20) falls below
//! a fraction of `N`, the particles are resampled systematically and roughened.
//!
//! Initialization: positions are drawn from the SOGs filter's initial region of the
//! first pulse (IROS III-B), orientations from the IMU attitude, the scale from its
//! calibration prior, and each moment is the dipole inverse of the first pulse at the
//! particle's position (so every particle explains that pulse), perturbed by the pulse's
//! relative noise.

use super::super::model::{FIELD_SCALE, K_H, MOMENT_SCALE};
use super::super::{
    Attitude, Displacement, EstimateError, Estimator, Mode, Pulse, SogConfig, StepOutcome,
    StepReport, VictimEstimate,
};
use super::{
    LOG_ZERO, MotionNoise, ParticleConfig, Prng, Weighted, attitude_log_lik, attitude_whitener,
    check_inputs, compose_pose, gauss3, initial_region, n_eff, noise_var, normalize, sample_region,
    sign_ambiguous_log_lik, strong_enough, systematic_resample, weighted_moments,
};
use crate::dipole::{field, moment_from_field};
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};
use heapless::Vec;

/// One particle: a point hypothesis of the robocentric state (44 bytes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Particle {
    /// Orientation of `R_k` in `G_k` (rad).
    psi: Rpy,
    /// Transmitter position in `G_k` (m).
    p: Vec3,
    /// Transmitter moment in `G_k` (mA·m²).
    m: Vec3,
    /// Scale factor of the dead-reckoned translation.
    s: f32,
    /// Log-weight.
    log_w: f32,
}

impl Weighted for Particle {
    fn log_w(&self) -> f32 {
        self.log_w
    }
    fn set_log_w(&mut self, v: f32) {
        self.log_w = v;
    }
}

/// Vanilla particle filter with room for `N` particles (no heap).
#[derive(Debug, Clone, PartialEq)]
pub struct ParticleFilter<const N: usize> {
    config: SogConfig,
    params: ParticleConfig,
    particles: Vec<Particle, N>,
    rng: Prng,
    inconsistent_pulses: u8,
    last_t: Option<f32>,
    resamples: u32,
}

impl<const N: usize> ParticleFilter<N> {
    /// A filter with the SOGs filter's configuration and the default particle
    /// parameters drawn from `seed`, or `InvalidConfig`.
    pub fn new(config: SogConfig, seed: u64) -> Result<Self, EstimateError> {
        Self::with_params(config, ParticleConfig::seeded(seed))
    }

    /// A filter with explicit particle parameters, or `InvalidConfig`.
    pub fn with_params(config: SogConfig, params: ParticleConfig) -> Result<Self, EstimateError> {
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
    pub fn n_eff(&self) -> f32 {
        n_eff(&self.particles)
    }

    /// Number of resamplings so far.
    pub fn resamples(&self) -> u32 {
        self.resamples
    }

    fn exact(&self) -> bool {
        self.config.mode == Mode::KnownTrajectory
    }

    /// Draws the particles from pulse `z` (µA/m in `R_1`).
    fn try_initialize(
        &mut self,
        attitude: &Attitude,
        z: &Vec3,
        outcome: StepOutcome,
    ) -> StepReport {
        self.particles.clear();
        self.inconsistent_pulses = 0;
        if !strong_enough(&self.config, z) {
            return report(StepOutcome::Waiting, 0, 0.0);
        }
        let region = initial_region(&self.config, attitude, z);
        if region.is_empty() {
            return report(StepOutcome::Waiting, 0, 0.0);
        }
        let exact = self.exact();
        let att_l = super::psd_factor(&((attitude.cov + attitude.cov.transpose()) * 0.5));
        let rel = libm::sqrtf(noise_var(&self.config, z)) / z.norm();
        let log_w = -libm::logf(N as f32);
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
            let z_g = rotation_from_rpy(&psi) * z;
            let Ok(m) = moment_from_field(&(-p), &z_g) else {
                continue;
            };
            let m = m / K_H;
            let m = m + gauss3(&mut self.rng) * (rel * m.norm());
            let _ = self.particles.push(Particle {
                psi,
                p,
                m,
                s,
                log_w,
            });
        }
        normalize(&mut self.particles);
        let n = self.particles.len();
        let outcome = if n > 0 { outcome } else { StepOutcome::Waiting };
        report(outcome, n, 0.0)
    }

    /// Systematic resampling, then roughening of positions and moments.
    fn resample(&mut self) {
        let u0 = self.rng.uniform();
        systematic_resample(&mut self.particles, u0);
        let k = self.params.roughen;
        if k > 0.0 {
            for q in self.particles.iter_mut() {
                let jp = gauss3(&mut self.rng) * (k * q.p.norm());
                let jm = gauss3(&mut self.rng) * (k * q.m.norm());
                q.p += jp;
                q.m += jm;
            }
        }
        self.resamples = self.resamples.saturating_add(1);
    }
}

fn report(outcome: StepOutcome, n: usize, best_d2: f32) -> StepReport {
    StepReport {
        outcome,
        n_components: n,
        best_d2,
        pruned: 0,
        merged: 0,
        split: 0,
        dropped: 0,
    }
}

/// Weight update of one particle moved to `p` with orientation `rot = R(Ψ)`: returns the pulse's squared
/// distance (with the better sign, in units of the noise) and the log-likelihood, or
/// `None` when the model cannot be evaluated there.
fn pulse_log_lik(rot: &Mat3, p: &Vec3, m: &Vec3, z: &Vec3, r_var: f32) -> Option<(f32, f32)> {
    // h = K_H R(Ψ)ᵀ H(−p_T, m) (IROS eq. 14).
    let h = rot.tr_mul(&field(&(-p), m).ok()?) * K_H;
    let d2_pos = (z - h).norm_squared() / r_var;
    let d2_neg = (z + h).norm_squared() / r_var;
    Some((d2_pos.min(d2_neg), sign_ambiguous_log_lik(d2_pos, d2_neg)))
}

impl<const N: usize> Estimator for ParticleFilter<N> {
    fn step(
        &mut self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Result<StepReport, EstimateError> {
        check_inputs(&self.config, self.last_t, motion, attitude, pulse)?;
        self.last_t = Some(pulse.t);
        let z = pulse.h * FIELD_SCALE;
        if self.particles.is_empty() {
            return Ok(self.try_initialize(attitude, &z, StepOutcome::Initialized));
        }
        let exact = self.exact();
        let noise = MotionNoise::new(motion, exact);
        let r_var = noise_var(&self.config, &z);
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
            match pulse_log_lik(&rot, &p, &q.m, &z, r_var) {
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
        // Divergence as in the SOGs filter: no particle consistent for several pulses.
        if best_d2 > self.config.divergence_d2 {
            self.inconsistent_pulses = self.inconsistent_pulses.saturating_add(1);
        } else {
            self.inconsistent_pulses = 0;
        }
        if normalize(&mut self.particles).is_none()
            || self.inconsistent_pulses >= self.config.divergence_pulses
        {
            let mut r = self.try_initialize(attitude, &z, StepOutcome::Reinitialized);
            r.best_d2 = best_d2;
            r.dropped = dropped;
            return Ok(r);
        }
        if self.n_eff() < self.params.resample_fraction * self.particles.len() as f32 {
            self.resample();
        }
        let mut r = report(StepOutcome::Updated, self.particles.len(), best_d2);
        r.dropped = dropped;
        Ok(r)
    }

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

    fn reset(&mut self) {
        self.particles.clear();
        self.inconsistent_pulses = 0;
        self.last_t = None;
    }

    fn is_initialized(&self) -> bool {
        !self.particles.is_empty()
    }
}
