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

use super::super::SogConfig;
use super::super::gaussian::{cholesky3, lower_inverse3};
use super::super::model::{K_H, MOMENT_SCALE};
use super::particles::{ParticleModel, particle_filter};
use super::{Prng, gauss3, sign_ambiguous_log_lik};
use crate::dipole::field_matrix;
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};

/// The Rao-Blackwellized model: each particle carries a Kalman filter of the moment,
/// whose mean is the particle's `m` and whose covariance is the extra state, packed as
/// the upper triangle xx, xy, xz, yy, yz, zz (68 bytes per particle).
/// One particle of the RBPF: pose, the moment's Kalman filter and the log-weight
/// (68 bytes).
pub(crate) type Particle = super::particles::Particle<[f32; 6]>;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RaoBlackwell;

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

/// Initialization constants: the moment's prior covariance `σ_m² I` and the pulse's
/// noise variance.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prior {
    pm: Mat3,
    r_var: f32,
}

impl ParticleModel for RaoBlackwell {
    const RESAMPLE_AT_INIT: bool = true;
    type Extra = [f32; 6];
    type Prior = Prior;

    /// `σ_m = m_max/√3`, so `E|m|² = m_max²`.
    fn prior(config: &SogConfig, _z: &Vec3, r_var: f32, _n: usize) -> Prior {
        let sigma_m = config.m_max * MOMENT_SCALE / libm::sqrtf(3.0);
        Prior {
            pm: Mat3::identity() * (sigma_m * sigma_m),
            r_var,
        }
    }

    /// The first pulse is the first Kalman update of the moment's prior `N(0, σ_m² I)`;
    /// its marginal likelihood is the particle's initial weight.
    fn draw(prior: &Prior, pose: (Rpy, Vec3, f32), z: &Vec3, _rng: &mut Prng) -> Option<Particle> {
        let (psi, p, s) = pose;
        let h = moment_jacobian(&rotation_from_rpy(&psi), &p)?;
        let u = moment_update(&Vec3::zeros(), &prior.pm, &h, z, prior.r_var)?;
        Some(Particle {
            psi,
            p,
            m: u.m,
            s,
            log_w: u.log_lik,
            extra: pack3(&u.pm),
        })
    }

    /// The moment's Kalman update with the pulse; the weight is its marginal likelihood.
    fn weigh(q: &mut Particle, rot: &Mat3, z: &Vec3, r_var: f32) -> Option<(f32, f32)> {
        let u = moment_jacobian(rot, &q.p)
            .and_then(|h| moment_update(&q.m, &unpack3(&q.extra), &h, z, r_var))?;
        q.m = u.m;
        q.extra = pack3(&u.pm);
        Some((u.d2, u.log_lik))
    }

    /// Roughens the position only (the moments keep their Kalman filters).
    fn roughen(q: &mut Particle, rng: &mut Prng, k: f32) {
        let jp = gauss3(rng) * (k * q.p.norm());
        q.p += jp;
    }
}

particle_filter!(
    /// Rao-Blackwellized particle filter with room for `N` particles (no heap).
    Rbpf,
    RaoBlackwell
);
