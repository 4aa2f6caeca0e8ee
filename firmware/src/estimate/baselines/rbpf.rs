//! The Rao-Blackwellized particle filter (IROS 2006 Algorithm 3).
//!
//! Particles sample the orientation `Ψ`, the transmitter position `p_T` and the scale
//! `s`; given those, the pulse is linear in the moment, `h = K_H R(Ψ)ᵀ G(−p_T) m`
//! (IROS eq. 12–14 with `G` of ICRA eq. 6), so each particle carries a Kalman filter for
//! `m`: mean (3) and packed covariance (6). With `Ψ`, `p_T`, `s` (7) and the log-weight,
//! **68 bytes per particle** (17 `f32`).
//!
//! Per pulse: each particle draws its displacement from `N(u, Q)` and is composed into
//! `G_k` (IROS eq. 5–9; the moment is expressed in `G_k`, whose axes do not turn, so its
//! Kalman filter has no prediction step); the moment's Kalman update uses the pulse with
//! the sign closer to the particle's prediction, and the particle's weight is multiplied
//! by the marginal likelihood of the pulse over both signs, `½N(±z; H m̂, H P Hᵀ + R)`
//! (and, in robocentric mode, by the IMU attitude likelihood). When `N_eff` (IROS eq. 20)
//! falls below a fraction of `N` the particles are resampled systematically and their
//! positions roughened.
//!
//! Initialization: positions from the SOGs filter's initial region of the first pulse
//! (IROS III-B), orientations from the IMU attitude, the scale from its prior; the
//! moment's prior is `N(0, σ_m² I)` with `σ_m = m_max/√3` (so `E|m|² = m_max²`), and the
//! first pulse is its first Kalman update.

use super::super::gaussian::{cholesky3, lower_inverse3};
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
use crate::dipole::field_matrix;
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};
use heapless::Vec;

/// One particle: a pose hypothesis and the Kalman filter of the moment (68 bytes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Particle {
    /// Orientation of `R_k` in `G_k` (rad).
    psi: Rpy,
    /// Transmitter position in `G_k` (m).
    p: Vec3,
    /// Scale factor of the dead-reckoned translation.
    s: f32,
    /// Mean of the moment in `G_k` (mA·m²).
    m: Vec3,
    /// Upper triangle of the moment's covariance: xx, xy, xz, yy, yz, zz.
    pm: [f32; 6],
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

/// Packs a symmetric 3×3 matrix.
fn pack3(p: &Mat3) -> [f32; 6] {
    [
        p[(0, 0)],
        p[(0, 1)],
        p[(0, 2)],
        p[(1, 1)],
        p[(1, 2)],
        p[(2, 2)],
    ]
}

/// Unpacks [`pack3`].
fn unpack3(v: &[f32; 6]) -> Mat3 {
    Mat3::new(v[0], v[1], v[2], v[1], v[3], v[4], v[2], v[4], v[5])
}

/// Result of one moment Kalman update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct MomentUpdate {
    /// Posterior mean.
    pub m: Vec3,
    /// Posterior covariance.
    pub pm: Mat3,
    /// Squared Mahalanobis distance of the innovation with the chosen sign.
    pub d2: f32,
    /// Log marginal likelihood of the pulse over both signs, up to a constant common to
    /// all particles (`−½ d² − ½ ln det S`, mixed over the signs).
    pub log_lik: f32,
}

/// Kalman update of the moment `N(m, P)` with the pulse `±z = H m + v`, `v ~ N(0, r I)`:
/// `S = H P Hᵀ + r I = L Lᵀ`, innovation `ν` of the sign with the smaller `|L⁻¹ν|²`,
/// `K = P Hᵀ S⁻¹`, `m' = m + K ν`, Joseph form `P' = (I − K H) P (I − K H)ᵀ + r K Kᵀ`.
/// `None` when `S` is not positive definite or the result is not finite.
pub(crate) fn moment_update(
    m: &Vec3,
    pm: &Mat3,
    h: &Mat3,
    z: &Vec3,
    r_var: f32,
) -> Option<MomentUpdate> {
    let w = pm * h.transpose();
    let mut s = h * w;
    s = (s + s.transpose()) * 0.5 + Mat3::identity() * r_var;
    let l = cholesky3(&s).ok()?;
    let l_inv = lower_inverse3(&l);
    let pred = h * m;
    let d2_pos = (l_inv * (z - pred)).norm_squared();
    let d2_neg = (l_inv * (-z - pred)).norm_squared();
    let (nu, d2) = if d2_neg < d2_pos {
        (-z - pred, d2_neg)
    } else {
        (z - pred, d2_pos)
    };
    let half_log_det = libm::logf(l[(0, 0)] * l[(1, 1)] * l[(2, 2)]);
    let log_lik = sign_ambiguous_log_lik(d2_pos, d2_neg) - half_log_det;
    let k = w * (l_inv.transpose() * l_inv);
    let a = Mat3::identity() - k * h;
    let mut p2 = a * pm * a.transpose() + k * k.transpose() * r_var;
    p2 = (p2 + p2.transpose()) * 0.5;
    let m2 = m + k * nu;
    let finite = m2.iter().chain(p2.iter()).all(|v| v.is_finite()) && log_lik.is_finite();
    finite.then_some(MomentUpdate {
        m: m2,
        pm: p2,
        d2,
        log_lik,
    })
}

/// `H = K_H R(Ψ)ᵀ G(−p_T)` from `rot = R(Ψ)`: the pulse as a linear function of the moment (mA·m² → µA/m).
fn moment_jacobian(rot: &Mat3, p: &Vec3) -> Option<Mat3> {
    let g = field_matrix(&(-p)).ok()?;
    Some(rot.tr_mul(&g) * K_H)
}

/// Rao-Blackwellized particle filter with room for `N` particles (no heap).
#[derive(Debug, Clone, PartialEq)]
pub struct Rbpf<const N: usize> {
    config: SogConfig,
    params: ParticleConfig,
    particles: Vec<Particle, N>,
    rng: Prng,
    inconsistent_pulses: u8,
    last_t: Option<f32>,
    resamples: u32,
}

impl<const N: usize> Rbpf<N> {
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

    /// Draws the particles and applies pulse `z` (µA/m in `R_1`) to their moment priors.
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
        let r_var = noise_var(&self.config, z);
        let sigma_m = self.config.m_max * MOMENT_SCALE / libm::sqrtf(3.0);
        let prior = Mat3::identity() * (sigma_m * sigma_m);
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
            let Some(h) = moment_jacobian(&rotation_from_rpy(&psi), &p) else {
                continue;
            };
            let Some(u) = moment_update(&Vec3::zeros(), &prior, &h, z, r_var) else {
                continue;
            };
            let _ = self.particles.push(Particle {
                psi,
                p,
                s,
                m: u.m,
                pm: pack3(&u.pm),
                log_w: u.log_lik,
            });
        }
        if normalize(&mut self.particles).is_none() {
            self.particles.clear();
        }
        let n = self.particles.len();
        if n > 0 && self.n_eff() < self.params.resample_fraction * n as f32 {
            self.resample();
        }
        let outcome = if n > 0 { outcome } else { StepOutcome::Waiting };
        report(outcome, n, 0.0)
    }

    /// Systematic resampling, then roughening of the positions (the moments keep their
    /// Kalman filters).
    fn resample(&mut self) {
        let u0 = self.rng.uniform();
        systematic_resample(&mut self.particles, u0);
        let k = self.params.roughen;
        if k > 0.0 {
            for q in self.particles.iter_mut() {
                let jp = gauss3(&mut self.rng) * (k * q.p.norm());
                q.p += jp;
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

impl<const N: usize> Estimator for Rbpf<N> {
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
            let updated = moment_jacobian(&rot, &p)
                .and_then(|h| moment_update(&q.m, &unpack3(&q.pm), &h, &z, r_var));
            match updated {
                Some(u) => {
                    best_d2 = best_d2.min(u.d2);
                    let la = att.map_or(0.0, |l| attitude_log_lik(&psi, &attitude.rpy, &l));
                    q.m = u.m;
                    q.pm = pack3(&u.pm);
                    q.log_w += u.log_lik + la;
                }
                None => {
                    q.log_w = LOG_ZERO;
                    dropped += 1;
                }
            }
        }
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
