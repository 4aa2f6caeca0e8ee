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

use super::super::SogConfig;
use super::super::model::K_H;
use super::particles::{ParticleModel, particle_filter};
use super::{Prng, gauss3, sign_ambiguous_log_lik};
use crate::dipole::{field, moment_from_field};
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};

/// The vanilla filter's model: each particle is a point hypothesis of the whole state,
/// moment included (44 bytes: no extra state).
/// One particle of the vanilla filter: the state `[Ψ; p_T; m; s]` and its log-weight
/// (44 bytes).
pub(crate) type Particle = super::particles::Particle<()>;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Vanilla;

/// Initialization constants: the pulse's relative noise and the uniform log-weight.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prior {
    rel: f32,
    log_w: f32,
}

impl ParticleModel for Vanilla {
    const RESAMPLE_AT_INIT: bool = false;
    type Extra = ();
    type Prior = Prior;

    fn prior(_config: &SogConfig, z: &Vec3, r_var: f32, n: usize) -> Prior {
        Prior {
            rel: libm::sqrtf(r_var) / z.norm(),
            log_w: -libm::logf(n as f32),
        }
    }

    /// The moment is the dipole inverse of the first pulse at the particle's position
    /// (so the particle explains it), perturbed by the pulse's relative noise.
    fn draw(prior: &Prior, pose: (Rpy, Vec3, f32), z: &Vec3, rng: &mut Prng) -> Option<Particle> {
        let (psi, p, s) = pose;
        let z_g = rotation_from_rpy(&psi) * z;
        let m = moment_from_field(&(-p), &z_g).ok()? / K_H;
        let m = m + gauss3(rng) * (prior.rel * m.norm());
        Some(Particle {
            psi,
            p,
            m,
            s,
            log_w: prior.log_w,
            extra: (),
        })
    }

    fn weigh(q: &mut Particle, rot: &Mat3, z: &Vec3, r_var: f32) -> Option<(f32, f32)> {
        pulse_log_lik(rot, &q.p, &q.m, z, r_var)
    }

    /// Roughens both the position and the moment.
    fn roughen(q: &mut Particle, rng: &mut Prng, k: f32) {
        let jp = gauss3(rng) * (k * q.p.norm());
        let jm = gauss3(rng) * (k * q.m.norm());
        q.p += jp;
        q.m += jm;
    }
}

particle_filter!(
    /// Vanilla particle filter with room for `N` particles (no heap).
    ParticleFilter,
    Vanilla
);

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
