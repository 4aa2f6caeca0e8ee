//! The near-field magnetic dipole model of an avalanche beacon.
//!
//! `H = A m / (4π r⁵)` (ICRA 2006 eq. 5–7, IROS 2006 eq. 12–13) where `r = p_R − p_T` goes
//! from the transmitter to the receiver, `m` is the transmitter's magnetic moment (A·m²)
//! and `H` the field strength (A/m). Equivalently `H = (3 (m·u) u − m) / (4π r³)` with the
//! unit vector `u = r / |r|`: this crate evaluates that form, which keeps every
//! intermediate term of order `|m|` and scales by a single power of the range, so `f32`
//! keeps its relative precision (≈1e-7) over the whole search range, where |H| spans
//! about 1e-9 … 1e-3 A/m.
//!
//! Because `H` is linear in `m`, `H = G(r) m` with `G(r) = (3 u uᵀ − I) / (4π r³)`, whose
//! inverse is closed-form: `G⁻¹ = 4π r³ (3/2 u uᵀ − I)`.

use crate::{Mat3, Vec3};
use core::f32::consts::PI;

/// Ranges below this (m) are rejected: the point-dipole model is meaningless inside the
/// transmitter's own antenna and the field diverges at r = 0.
pub const MIN_RANGE_M: f32 = 0.05;

/// Why a dipole computation was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DipoleError {
    /// The range is below [`MIN_RANGE_M`].
    #[error("range below the dipole model's minimum")]
    TooClose,
    /// An input was NaN or infinite.
    #[error("an input was NaN or infinite")]
    NonFinite,
    /// A magnitude that must be positive (field, moment bound) was zero or negative.
    #[error("a magnitude that must be positive was zero or negative")]
    NonPositive,
}

/// The field at one point together with its Jacobians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldJacobians {
    /// Field strength `H` (A/m).
    pub h: Vec3,
    /// `∂H/∂r` (A/m per m); symmetric. With respect to the transmitter position it is `−∂H/∂r`.
    pub d_r: Mat3,
    /// `∂H/∂m = G(r)` (A/m per A·m²); symmetric.
    pub d_m: Mat3,
}

/// Unit direction and range of `r`, after checking it.
fn direction_and_range(r: &Vec3) -> Result<(Vec3, f32), DipoleError> {
    if !r.iter().all(|x| x.is_finite()) {
        return Err(DipoleError::NonFinite);
    }
    let range = r.norm();
    if range < MIN_RANGE_M {
        return Err(DipoleError::TooClose);
    }
    Ok((r / range, range))
}

fn check_finite(v: &Vec3) -> Result<(), DipoleError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(DipoleError::NonFinite)
    }
}

/// Field `H` (A/m) at offset `r` (m, from transmitter to receiver) of a dipole with moment
/// `m` (A·m²): ICRA 2006 eq. 5.
pub fn field(r: &Vec3, m: &Vec3) -> Result<Vec3, DipoleError> {
    check_finite(m)?;
    let (u, range) = direction_and_range(r)?;
    let k = 1.0 / (4.0 * PI * range * range * range);
    Ok((u * (3.0 * m.dot(&u)) - m) * k)
}

/// `G(r) = ∂H/∂m = A / (4π r⁵)` (ICRA 2006 eq. 6–7): the linear map from moment to field.
pub fn field_matrix(r: &Vec3) -> Result<Mat3, DipoleError> {
    let (u, range) = direction_and_range(r)?;
    Ok(g_matrix(&u, range))
}

fn g_matrix(u: &Vec3, range: f32) -> Mat3 {
    let k = 1.0 / (4.0 * PI * range * range * range);
    (u * u.transpose() * 3.0 - Mat3::identity()) * k
}

/// The field and its analytic Jacobians with respect to `r` and `m`, sharing all terms.
///
/// `∂H/∂r = 3 / (4π r⁴) · (u mᵀ + m uᵀ + (m·u) I − 5 (m·u) u uᵀ)`.
pub fn field_with_jacobians(r: &Vec3, m: &Vec3) -> Result<FieldJacobians, DipoleError> {
    check_finite(m)?;
    let (u, range) = direction_and_range(r)?;
    let k3 = 1.0 / (4.0 * PI * range * range * range);
    let mu = m.dot(&u);
    let uut = u * u.transpose();
    let h = (u * (3.0 * mu) - m) * k3;
    let sym = u * m.transpose() + m * u.transpose();
    let d_r = (sym + Mat3::identity() * mu - uut * (5.0 * mu)) * (3.0 * k3 / range);
    let d_m = (uut * 3.0 - Mat3::identity()) * k3;
    Ok(FieldJacobians { h, d_r, d_m })
}

/// The moment that produces field `h` (A/m) at offset `r` (m): `m = G(r)⁻¹ h`, with
/// `G⁻¹ = 4π r³ (3/2 u uᵀ − I)` (the inverse of ICRA 2006 eq. 6, used to initialize each
/// Gaussian's moment, ICRA V-C).
pub fn moment_from_field(r: &Vec3, h: &Vec3) -> Result<Vec3, DipoleError> {
    check_finite(h)?;
    let (u, range) = direction_and_range(r)?;
    let k = 4.0 * PI * range * range * range;
    Ok((u * (1.5 * h.dot(&u)) - h) * k)
}

/// Range bounds `(r_min, r_max)` in m at which a transmitter with moment magnitude in
/// `[m_min, m_max]` produces a field of magnitude `h_norm` (ICRA 2006 eq. 16).
///
/// The field magnitude lies between `m/(4π r³)` (equator) and `2m/(4π r³)` (axis), so
/// `r_min = (m_min / (4π|H|))^⅓` and `r_max = (2 m_max / (4π|H|))^⅓`.
pub fn range_bounds(h_norm: f32, m_min: f32, m_max: f32) -> Result<(f32, f32), DipoleError> {
    if !(h_norm.is_finite() && m_min.is_finite() && m_max.is_finite()) {
        return Err(DipoleError::NonFinite);
    }
    if h_norm <= 0.0 || m_min <= 0.0 || m_max < m_min {
        return Err(DipoleError::NonPositive);
    }
    let r_min = libm::cbrtf(m_min / (4.0 * PI * h_norm));
    let r_max = libm::cbrtf(2.0 * m_max / (4.0 * PI * h_norm));
    Ok((r_min, r_max))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    type V64 = [f64; 3];

    fn dot(a: V64, b: V64) -> f64 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }

    /// f64 reference, written from the matrix form of ICRA eq. 6–7 (not the u-form above).
    fn field_f64(r: V64, m: V64) -> V64 {
        let [x, y, z] = r;
        let r2 = dot(r, r);
        let a = [
            [2.0 * x * x - y * y - z * z, 3.0 * x * y, 3.0 * x * z],
            [3.0 * x * y, 2.0 * y * y - x * x - z * z, 3.0 * y * z],
            [3.0 * x * z, 3.0 * y * z, 2.0 * z * z - x * x - y * y],
        ];
        let k = 1.0 / (4.0 * std::f64::consts::PI * r2 * r2 * r2.sqrt());
        [dot(a[0], m) * k, dot(a[1], m) * k, dot(a[2], m) * k]
    }

    fn v64(v: &Vec3) -> V64 {
        [v.x as f64, v.y as f64, v.z as f64]
    }

    fn norm64(v: V64) -> f64 {
        dot(v, v).sqrt()
    }

    /// A random offset with log-uniform range in [lo, hi] m and a random direction.
    fn random_offset(rng: &mut SmallRng, lo: f32, hi: f32) -> Vec3 {
        let range = lo * (hi / lo).powf(rng.random::<f32>());
        loop {
            let d = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            if d.norm() > 0.1 && d.norm() <= 1.0 {
                return d.normalize() * range;
            }
        }
    }

    fn random_moment(rng: &mut SmallRng) -> Vec3 {
        random_offset(rng, 3e-3, 3e-2)
    }

    #[test]
    fn field_matches_f64_over_the_search_range() {
        let mut rng = SmallRng::seed_from_u64(10);
        let mut worst = 0.0f64;
        for _ in 0..20_000 {
            let (r, m) = (random_offset(&mut rng, 0.1, 200.0), random_moment(&mut rng));
            let h = field(&r, &m).unwrap();
            let e = field_f64(v64(&r), v64(&m));
            let err = norm64([h.x as f64 - e[0], h.y as f64 - e[1], h.z as f64 - e[2]]) / norm64(e);
            worst = worst.max(err);
        }
        // f32 has a 6e-8 unit roundoff; a few dozen operations stay well below 1e-5.
        println!("field vs f64: worst relative error {worst:e}");
        assert!(worst < 1e-5, "worst relative error {worst:e}");
    }

    #[test]
    fn closed_form_axis_and_equator() {
        let m = 0.02f32;
        for &range in &[0.3f32, 1.0, 10.0, 80.0] {
            let k = m / (4.0 * PI * range.powi(3));
            let on_axis = field(&Vec3::new(0.0, 0.0, range), &Vec3::new(0.0, 0.0, m)).unwrap();
            assert!((on_axis - Vec3::new(0.0, 0.0, 2.0 * k)).norm() <= 1e-6 * 2.0 * k);
            let equator = field(&Vec3::new(range, 0.0, 0.0), &Vec3::new(0.0, 0.0, m)).unwrap();
            assert!((equator - Vec3::new(0.0, 0.0, -k)).norm() <= 1e-6 * k);
        }
    }

    #[test]
    fn dynamic_range_1e9_to_1e3_stays_accurate() {
        // Choose ranges so that |H| sweeps 1e-9 … 1e-3 A/m for a mid-power beacon.
        let mut rng = SmallRng::seed_from_u64(11);
        let m = Vec3::new(0.006, -0.004, 0.009);
        let mut decade = -9.0f64;
        while decade <= -3.0 {
            let target = 10f64.powf(decade);
            let range = (m.norm() as f64 / (4.0 * std::f64::consts::PI * target)).cbrt() as f32;
            let r = random_offset(&mut rng, range, range * 1.0001);
            let h = field(&r, &m).unwrap();
            let e = field_f64(v64(&r), v64(&m));
            let rel = norm64([h.x as f64 - e[0], h.y as f64 - e[1], h.z as f64 - e[2]]) / norm64(e);
            assert!(rel < 1e-5, "|H|≈{target:e}: rel {rel:e}");
            decade += 0.25;
        }
    }

    #[test]
    fn jacobians_match_central_differences_of_f64_model() {
        let mut rng = SmallRng::seed_from_u64(12);
        let mut worst_r = 0.0f64;
        let mut worst_m = 0.0f64;
        for _ in 0..5_000 {
            let (r, m) = (random_offset(&mut rng, 0.3, 150.0), random_moment(&mut rng));
            let fj = field_with_jacobians(&r, &m).unwrap();
            let (r64, m64) = (v64(&r), v64(&m));
            let hr = 1e-6 * norm64(r64);
            let hm = 1e-6 * norm64(m64);
            let scale_r = 3.0 * norm64(m64) / (4.0 * std::f64::consts::PI * norm64(r64).powi(4));
            let scale_m = 1.0 / (4.0 * std::f64::consts::PI * norm64(r64).powi(3));
            for k in 0..3 {
                let (mut rp, mut rm, mut mp, mut mm) = (r64, r64, m64, m64);
                rp[k] += hr;
                rm[k] -= hr;
                mp[k] += hm;
                mm[k] -= hm;
                let (fp, fm) = (field_f64(rp, m64), field_f64(rm, m64));
                let (gp, gm) = (field_f64(r64, mp), field_f64(r64, mm));
                for i in 0..3 {
                    let fd_r = (fp[i] - fm[i]) / (2.0 * hr);
                    let fd_m = (gp[i] - gm[i]) / (2.0 * hm);
                    worst_r = worst_r.max((fj.d_r[(i, k)] as f64 - fd_r).abs() / scale_r);
                    worst_m = worst_m.max((fj.d_m[(i, k)] as f64 - fd_m).abs() / scale_m);
                }
            }
            let h = field(&r, &m).unwrap();
            assert_eq!(h, fj.h);
            assert_eq!(field_matrix(&r).unwrap(), fj.d_m);
        }
        // Relative to the Jacobian's natural scale: f32 roundoff plus O(h²) truncation.
        println!("Jacobians vs f64 central differences: ∂H/∂r {worst_r:e}, ∂H/∂m {worst_m:e}");
        assert!(worst_r < 1e-5, "∂H/∂r worst relative error {worst_r:e}");
        assert!(worst_m < 1e-5, "∂H/∂m worst relative error {worst_m:e}");
    }

    #[test]
    fn jacobian_is_symmetric_and_linear_in_m() {
        let mut rng = SmallRng::seed_from_u64(13);
        for _ in 0..1000 {
            let (r, m) = (random_offset(&mut rng, 0.3, 100.0), random_moment(&mut rng));
            let fj = field_with_jacobians(&r, &m).unwrap();
            let tol = 1e-6 * fj.d_r.abs().max();
            assert!((fj.d_r - fj.d_r.transpose()).abs().max() <= tol);
            assert!((fj.d_m * m - fj.h).norm() <= 1e-6 * fj.h.norm());
        }
    }

    #[test]
    fn inverse_round_trips() {
        let mut rng = SmallRng::seed_from_u64(14);
        let mut worst = 0.0f32;
        for _ in 0..10_000 {
            let (r, m) = (random_offset(&mut rng, 0.1, 200.0), random_moment(&mut rng));
            let h = field(&r, &m).unwrap();
            let back = moment_from_field(&r, &h).unwrap();
            worst = worst.max((back - m).norm() / m.norm());
        }
        println!("inverse round trip: worst relative error {worst:e}");
        assert!(worst < 1e-5, "worst relative error {worst:e}");
    }

    #[test]
    fn range_bounds_bracket_every_orientation() {
        let mut rng = SmallRng::seed_from_u64(15);
        let (m_min, m_max) = (3e-3f32, 3e-2f32);
        for _ in 0..10_000 {
            let r = random_offset(&mut rng, 0.5, 100.0);
            let m = random_offset(&mut rng, m_min * 1.0001, m_max * 0.9999);
            let h = field(&r, &m).unwrap();
            let (lo, hi) = range_bounds(h.norm(), m_min, m_max).unwrap();
            let d = r.norm();
            assert!(lo <= d * 1.0001 && d <= hi * 1.0001, "{lo} <= {d} <= {hi}");
        }
        // Tight at the extremes: weakest beacon broadside, strongest beacon on its axis.
        let d = 20.0f32;
        let weakest = field(&Vec3::new(d, 0.0, 0.0), &Vec3::new(0.0, 0.0, m_min)).unwrap();
        assert!((range_bounds(weakest.norm(), m_min, m_max).unwrap().0 - d).abs() < 1e-3);
        let strongest = field(&Vec3::new(0.0, 0.0, d), &Vec3::new(0.0, 0.0, m_max)).unwrap();
        assert!((range_bounds(strongest.norm(), m_min, m_max).unwrap().1 - d).abs() < 1e-3);
    }

    #[test]
    fn bad_input_is_an_error_not_a_nan() {
        let m = Vec3::new(0.0, 0.0, 0.01);
        assert_eq!(field(&Vec3::zeros(), &m), Err(DipoleError::TooClose));
        assert_eq!(
            field(&Vec3::new(f32::NAN, 1.0, 1.0), &m),
            Err(DipoleError::NonFinite)
        );
        assert_eq!(
            field(
                &Vec3::new(1.0, 1.0, 1.0),
                &Vec3::new(0.0, f32::INFINITY, 0.0)
            ),
            Err(DipoleError::NonFinite)
        );
        assert_eq!(
            moment_from_field(&Vec3::new(0.0, 0.0, 0.01), &m),
            Err(DipoleError::TooClose)
        );
        assert_eq!(range_bounds(0.0, 1e-3, 1e-2), Err(DipoleError::NonPositive));
        assert_eq!(
            range_bounds(f32::NAN, 1e-3, 1e-2),
            Err(DipoleError::NonFinite)
        );
        assert_eq!(
            range_bounds(1e-6, 1e-2, 1e-3),
            Err(DipoleError::NonPositive)
        );
    }
}
