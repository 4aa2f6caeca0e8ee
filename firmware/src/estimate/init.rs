//! Initialization of the mixture from the first usable pulse (IROS III-B, ICRA V-C).
//!
//! The transmitter lies in a cylinder ring around the receiver: depth from the burial
//! range, 3-D range from the dipole bounds (ICRA eq. 16). We cover it more tightly than
//! the papers do by using the pulse's direction as well as its magnitude: for a
//! transmitter in direction `u` (from transmitter to receiver) the moment that explains
//! the pulse `z` is `m = 4π r³ (3/2 (z·u) u − z)` (the dipole inverse), so
//! `m_min ≤ |m| ≤ m_max` bounds the range along each direction to an interval whose
//! ends have the fixed ratio `(m_max/m_min)^⅓`. The cells are laid out in azimuth ×
//! log-range × depth; equal weights then mean a prior uniform in azimuth and in
//! `log |m|`.
//!
//! Each Gaussian's position covariance is a box's inscribed ellipsoid scaled so that
//! every point of its cell (the corner being the farthest) passes the `init_chi2` test
//! (3 dof). Its moment is the dipole inverse at the cell centre, and the moment's
//! covariance and cross-covariances are the linearized propagation of the position, the
//! attitude and the pulse noise through that inverse, so each Gaussian starts on the
//! manifold of states that explain the first pulse.

use super::gaussian::Component;
use super::model::{I_M, I_P, I_RPY, I_S, K_H, MOMENT_SCALE, StateMat, StateVec};
use super::{Attitude, SogConfig};
use crate::dipole::{field_with_jacobians, moment_from_field};
use crate::frame::{rotation_from_rpy, rotation_partials};
use crate::{Mat3, Vec3};
use core::f32::consts::PI;
use heapless::Vec;

/// The layout of the initial grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Grid {
    /// Number of azimuth sectors.
    pub n_az: usize,
    /// Number of log-range cells per azimuth and depth.
    pub n_r: usize,
    /// Number of depth layers.
    pub n_z: usize,
}

/// The grid with the finest cells (relative half-size ε, equal in azimuth and log
/// range) that has at most `target` cells.
pub(crate) fn choose_grid(target: usize, log_ratio: f32, r_min: f32, depth_span: f32) -> Grid {
    let mut eps = 0.01f32;
    loop {
        let n_az = (libm::ceilf(PI / eps) as usize).max(8);
        let n_r = (libm::ceilf(log_ratio / (2.0 * eps)) as usize).max(1);
        let n_z = (libm::ceilf(depth_span / (2.0 * eps * r_min.max(0.1))) as usize).clamp(1, 4);
        if n_az * n_r * n_z <= target || eps > 1.0 {
            return Grid { n_az, n_r, n_z };
        }
        eps *= 1.05;
    }
}

/// Fills `out` with the initial mixture for pulse `z_body` (µA/m, in `R_1`). Returns
/// the number of components; 0 when the pulse cannot be inverted.
pub(crate) fn initialize<const N: usize>(
    out: &mut Vec<Component, N>,
    config: &SogConfig,
    attitude: &Attitude,
    z_body: &Vec3,
    r_var: f32,
    exact_motion: bool,
) -> usize {
    out.clear();
    let att_cov = if exact_motion {
        Mat3::zeros()
    } else {
        attitude.cov
    };
    let scale_var = if exact_motion {
        0.0
    } else {
        config.scale_sigma * config.scale_sigma
    };
    let rot = rotation_from_rpy(&attitude.rpy);
    let z = rot * z_body;
    let z_norm = z.norm();
    if z_norm.is_nan() || z_norm <= 0.0 {
        return 0;
    }
    // Moments in internal units (mA·m²), the interval widened by the pulse's own noise
    // (see `noise_widening`): the grid must cover every transmitter whose true moment
    // lies in [m_min, m_max], not only those the noisy pulse would imply exactly.
    let widen = noise_widening(r_var, z_norm);
    let (m_min, m_max) = (
        config.m_min * MOMENT_SCALE / widen,
        config.m_max * MOMENT_SCALE * widen,
    );
    // ICRA eq. 16 (internal units: |H| = K_H m / (4π r³) on the equator).
    let r_min = libm::cbrtf(K_H * m_min / (4.0 * PI * z_norm));
    let log_ratio = libm::logf(m_max / m_min) / 3.0;
    let z_hi = -(config.receiver_height + config.depth_min);
    let z_lo = -(config.receiver_height + config.depth_max);
    let target = ((N as f32 * config.init_fill) as usize).clamp(1, N);
    let grid = choose_grid(target, log_ratio, r_min, z_hi - z_lo);

    // ∂z_G/∂Ψ and the attitude's contribution, shared by all components.
    let parts = rotation_partials(&attitude.rpy);
    let dz_dpsi = Mat3::from_columns(&[parts[0] * z_body, parts[1] * z_body, parts[2] * z_body]);

    let n_total = grid.n_az * grid.n_r * grid.n_z;
    let log_w = -libm::logf(n_total as f32);
    // σ_i = a_i·sqrt(3/χ²) puts the cell's corner, its farthest point, exactly on the
    // χ² bound: (a_r/σ_r)² + (a_t/σ_t)² + (a_z/σ_z)² = χ².
    let corner = libm::sqrtf(config.init_chi2 / 3.0);

    let dz = (z_hi - z_lo) / grid.n_z as f32;
    let q = libm::expf(log_ratio / grid.n_r as f32);
    for iz in 0..grid.n_z {
        let zc = z_lo + dz * (iz as f32 + 0.5);
        for ia in 0..grid.n_az {
            let az = 2.0 * PI * (ia as f32 + 0.5) / grid.n_az as f32;
            let (sa, ca) = (libm::sinf(az), libm::cosf(az));
            let Some((r_lo, _)) = range_interval(&z, zc, ca, sa, m_min, m_max) else {
                continue;
            };
            for ir in 0..grid.n_r {
                let rc = r_lo * libm::powf(q, ir as f32 + 0.5);
                let rho = libm::sqrtf((rc * rc - zc * zc).max(0.0));
                let p = Vec3::new(rho * ca, rho * sa, zc);
                // Cell half-sizes: range (along the 3-D ray), azimuth arc, depth.
                let a_r = rc * 0.5 * (libm::sqrtf(q) - 1.0 / libm::sqrtf(q));
                let a_t = rho.max(rc * 0.1) * PI / grid.n_az as f32;
                let a_z = 0.5 * dz;
                let sig = Vec3::new(a_r, a_t, a_z) / corner;
                let Some(c) = component_at(
                    &p, &sig, &z, &dz_dpsi, attitude, &att_cov, scale_var, r_var, log_w,
                ) else {
                    continue;
                };
                if out.push(c).is_err() {
                    return out.len();
                }
            }
        }
    }
    out.len()
}

/// Factor by which the moment interval of the initial grid is widened at each end to
/// account for the noise of the initializing pulse.
///
/// The moment the dipole inverse infers from a pulse is proportional to the pulse,
/// `m = 4π r³ (3/2 (z·u) u − z)`, so a relative error `ε` of `z` is the same relative
/// error of the inferred `|m|` and, through `r ∝ |m|^⅓`, shifts the range interval of
/// ICRA eq. 16. With per-axis noise variance `R` (ICRA eq. 10) the relative error of a
/// pulse of norm `|z|` is at most `ε = √(3R) / |z|`; widening by `1 + 2ε` (2σ) keeps a
/// transmitter near `m_max` (or `m_min`) inside the grid when the first pulse happens
/// to be read high (or low). At the lowest initialization SNR (10) this is ≈ 1.35; for
/// strong pulses it tends to `1 + 2√3 k_sen` ≈ 1.1.
pub(crate) fn noise_widening(r_var: f32, z_norm: f32) -> f32 {
    let eps = libm::sqrtf(3.0 * r_var.max(0.0)) / z_norm;
    // A zero pulse (ε = ∞) widens by the cap; NaN inputs leave the interval as it is.
    if eps.is_nan() {
        1.0
    } else {
        1.0 + 2.0 * eps.min(1.0)
    }
}

/// The 3-D range interval along azimuth (cos, sin) at height `zc` where the dipole
/// inverse of `z` has a moment within `[m_min, m_max]`. Two fixed-point passes resolve
/// the dependence of the direction on the range.
fn range_interval(
    z: &Vec3,
    zc: f32,
    ca: f32,
    sa: f32,
    m_min: f32,
    m_max: f32,
) -> Option<(f32, f32)> {
    let mut rho = 10.0f32;
    let mut out = None;
    for _ in 0..3 {
        let p = Vec3::new(rho * ca, rho * sa, zc);
        let u = -p / p.norm();
        let g = (u * (1.5 * z.dot(&u)) - z).norm();
        if g.is_nan() || g <= 0.0 {
            return None;
        }
        let r_lo = libm::cbrtf(K_H * m_min / (4.0 * PI * g));
        let r_hi = libm::cbrtf(K_H * m_max / (4.0 * PI * g));
        let r_mid = libm::sqrtf(r_lo * r_hi);
        rho = libm::sqrtf((r_mid * r_mid - zc * zc).max(0.01));
        out = Some((r_lo, r_hi));
    }
    out
}

/// One initial Gaussian centred at transmitter position `p` with standard deviations
/// `sig` along (range, azimuth, depth).
#[allow(clippy::too_many_arguments)]
fn component_at(
    p: &Vec3,
    sig: &Vec3,
    z: &Vec3,
    dz_dpsi: &Mat3,
    attitude: &Attitude,
    att_cov: &Mat3,
    scale_var: f32,
    r_var: f32,
    log_w: f32,
) -> Option<Component> {
    let r = -p;
    let range = r.norm();
    let e_r = -r / range; // from the receiver toward the transmitter
    let horiz = Vec3::new(e_r.x, e_r.y, 0.0);
    let e_t = if horiz.norm() > 1e-6 {
        Vec3::z().cross(&horiz).normalize()
    } else {
        Vec3::y()
    };
    let e_z = e_r.cross(&e_t);
    let basis = Mat3::from_columns(&[e_r, e_t, e_z]);
    let p_pp = basis * Mat3::from_diagonal(&sig.component_mul(sig)) * basis.transpose();

    // Dipole inverse in internal units: K_H G m = z  ⇒  m = G⁻¹ z / K_H.
    let m = moment_from_field(&r, z).ok()? / K_H;
    let fj = field_with_jacobians(&r, &m).ok()?;
    // G⁻¹ column by column.
    let g_inv = Mat3::from_columns(&[
        moment_from_field(&r, &Vec3::x()).ok()?,
        moment_from_field(&r, &Vec3::y()).ok()?,
        moment_from_field(&r, &Vec3::z()).ok()?,
    ]);
    // Implicit function theorem on K_H G(r) m(r) = z: ∂m/∂r = −G⁻¹ ∂H/∂r, r = −p.
    let dm_dp = g_inv * fj.d_r;
    let dm_dz = g_inv / K_H;
    let dm_dpsi = dm_dz * dz_dpsi;

    let mut x = StateVec::zeros();
    x.fixed_rows_mut::<3>(I_RPY).copy_from(&attitude.rpy);
    x.fixed_rows_mut::<3>(I_P).copy_from(p);
    x.fixed_rows_mut::<3>(I_M).copy_from(&m);
    x[I_S] = 1.0;

    let mut cov = StateMat::zeros();
    cov.fixed_view_mut::<3, 3>(I_RPY, I_RPY).copy_from(att_cov);
    cov.fixed_view_mut::<3, 3>(I_P, I_P).copy_from(&p_pp);
    let p_mp = dm_dp * p_pp;
    let p_mpsi = dm_dpsi * att_cov;
    let p_mm =
        p_mp * dm_dp.transpose() + p_mpsi * dm_dpsi.transpose() + dm_dz * dm_dz.transpose() * r_var;
    cov.fixed_view_mut::<3, 3>(I_M, I_M).copy_from(&p_mm);
    cov.fixed_view_mut::<3, 3>(I_M, I_P).copy_from(&p_mp);
    cov.fixed_view_mut::<3, 3>(I_P, I_M)
        .copy_from(&p_mp.transpose());
    cov.fixed_view_mut::<3, 3>(I_M, I_RPY).copy_from(&p_mpsi);
    cov.fixed_view_mut::<3, 3>(I_RPY, I_M)
        .copy_from(&p_mpsi.transpose());
    cov[(I_S, I_S)] = scale_var;
    if !(x.iter().all(|v| v.is_finite()) && cov.iter().all(|v| v.is_finite())) {
        return None;
    }
    Some(Component::new(x, &cov, log_w))
}

#[cfg(test)]
mod tests {
    use super::super::model::{MOMENT_SCALE, measure, p_of};
    use super::*;
    use crate::dipole::field;
    use crate::frame::Rpy;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    fn setup(seed: u64) -> (SogConfig, Attitude, Vec3, Vec3, Vec3) {
        let mut rng = SmallRng::seed_from_u64(seed);
        let config = SogConfig::default();
        let att = Attitude::with_sigmas(
            Rpy::new(
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(-3.0..3.0),
            ),
            0.01,
            0.05,
        );
        let d = rng.random_range(40.0f32..70.0);
        let az = rng.random_range(-3.1f32..3.1);
        let p_t = Vec3::new(
            d * libm::cosf(az),
            d * libm::sinf(az),
            -(1.0 + rng.random_range(0.3..3.0)),
        );
        let dir = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .normalize();
        let m = dir * rng.random_range(3e-3f32..3e-2);
        let h_g = field(&(-p_t), &m).unwrap();
        let z_body = rotation_from_rpy(&att.rpy).transpose() * h_g * 1e6;
        (config, att, z_body, p_t, m)
    }

    #[test]
    fn every_component_explains_the_first_pulse() {
        for seed in 0..5 {
            let (config, att, z_body, _, _) = setup(seed);
            let mut v: Vec<Component, 240> = Vec::new();
            let n = initialize(&mut v, &config, &att, &z_body, 1e-6, false);
            assert!(n > 50 && n <= 144, "n = {n}");
            let w: f32 = v.iter().map(|c| libm::expf(c.log_w)).sum();
            assert!((w - 1.0).abs() < 1e-3, "weights sum {w}");
            let widen = noise_widening(1e-6, z_body.norm());
            for c in v.iter() {
                let h = measure(&c.x).unwrap().h;
                assert!((h - z_body).norm() < 1e-4 * z_body.norm());
                let mnorm = Vec3::new(c.x[I_M], c.x[I_M + 1], c.x[I_M + 2]).norm() / MOMENT_SCALE;
                assert!(
                    mnorm > config.m_min / widen * 0.99 && mnorm < config.m_max * widen * 1.01,
                    "{mnorm}"
                );
                assert!(nalgebra::Cholesky::new(c.p().cast::<f64>()).is_some());
            }
        }
    }

    #[test]
    fn a_known_sign_seeds_only_that_sign() {
        // Each cell's moment is the dipole inverse of the signed pulse, so every
        // component predicts `+z`, none `−z`: with `sign_ambiguous` false (the sign
        // known) the initial mixture holds the known sign only.
        for seed in 0..5 {
            let (mut config, att, z_body, _, _) = setup(seed);
            config.sign_ambiguous = false;
            let mut v: Vec<Component, 240> = Vec::new();
            assert!(initialize(&mut v, &config, &att, &z_body, 1e-6, false) > 50);
            for c in v.iter() {
                let h = measure(&c.x).unwrap().h;
                assert!(
                    h.dot(&z_body) > 0.99 * z_body.norm_squared(),
                    "{h} vs {z_body}"
                );
            }
        }
    }

    #[test]
    fn noisy_first_pulse_still_covers_the_moment_range() {
        // A transmitter at m_max whose first pulse reads 1.5σ high (SNR 10): without the
        // widening the inferred moment interval would end below the true moment.
        let z_norm = 10.0f32;
        let r_var = 1.0 + (0.03 * z_norm) * (0.03 * z_norm);
        let eps = libm::sqrtf(3.0 * r_var) / z_norm;
        let w = noise_widening(r_var, z_norm);
        assert!(w >= 1.0 + 1.5 * eps && w < 1.5, "{w}");
        // Strong pulses: only the 3 % sensor error remains.
        let w = noise_widening((0.03f32 * 1e3).powi(2), 1e3);
        assert!(
            (w - (1.0 + 2.0 * libm::sqrtf(3.0) * 0.03)).abs() < 1e-4,
            "{w}"
        );
        assert_eq!(noise_widening(1.0, 0.0), 1.0 + 2.0);
        assert_eq!(noise_widening(f32::NAN, 1.0), 1.0);
    }

    #[test]
    fn truth_passes_the_chi2_test_for_some_component() {
        for seed in 0..40 {
            let (config, att, z_body, p_t, _) = setup(seed);
            let mut v: Vec<Component, 240> = Vec::new();
            initialize(&mut v, &config, &att, &z_body, 1e-6, false);
            let best = v
                .iter()
                .map(|c| {
                    let d = p_t - p_of(&c.x);
                    let l = c.block3(I_P).cast::<f64>().cholesky().unwrap();
                    l.solve(&d.cast::<f64>()).dot(&d.cast::<f64>())
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                best <= config.init_chi2 as f64 * 1.02,
                "seed {seed}: best d² {best}"
            );
        }
    }

    #[test]
    fn grid_respects_target() {
        for target in [10usize, 50, 144, 400, 1000] {
            let g = choose_grid(target, libm::logf(10.0) / 3.0, 30.0, 5.0);
            assert!(g.n_az * g.n_r * g.n_z <= target.max(8), "{target}: {g:?}");
        }
    }
}
