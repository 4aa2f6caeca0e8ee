//! Rotations of the per-component step, built from one set of sines and cosines.
//!
//! `libm::sinf`/`cosf` evaluate their kernels in `f64`, which the Cortex-M4F's
//! single-precision FPU emulates in software (≈ 1 200 instructions per call), and the
//! generic `frame` helpers call them again for every rotation, partial derivative and
//! composition (≈ 100 calls per component and pulse). Here each angle's sine and cosine
//! is computed once in `f32` ([`crate::frame::sin_cos`], ≤ 2 ulp on the angles the filter sees), and
//! the rotation `R = Rz(φ) Ry(θ) Rx(ψ)` (IROS 2006 eq. 2), its partial derivatives and
//! the Jacobians of the composition `Ψ ⊕ ΔΨ` (IROS eq. 5–6) are written out from them.

use crate::frame::{Rpy, rpy_from_rotation, sin_cos};
use crate::{Mat3, Vec3};

/// A rotation `R(Ψ)` with its partial derivatives `∂R/∂ψ`, `∂R/∂θ`, `∂R/∂φ`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rot {
    /// `R = Rz(φ) Ry(θ) Rx(ψ)`.
    pub r: Mat3,
    /// `[∂R/∂roll, ∂R/∂pitch, ∂R/∂yaw]`.
    pub d: [Mat3; 3],
}

impl Rot {
    /// `R(Ψ)` and its partials from three `sin_cos` calls (IROS eq. 2 written out).
    pub fn new(rpy: &Rpy) -> Self {
        let (sr, cr) = sin_cos(rpy.x);
        let (sp, cp) = sin_cos(rpy.y);
        let (sy, cy) = sin_cos(rpy.z);
        let r = Mat3::new(
            cy * cp,
            cy * sp * sr - sy * cr,
            cy * sp * cr + sy * sr,
            sy * cp,
            sy * sp * sr + cy * cr,
            sy * sp * cr - cy * sr,
            -sp,
            cp * sr,
            cp * cr,
        );
        // ∂R/∂roll = R [x]×: columns (0, R₂, −R₁).
        let d_roll = Mat3::new(
            0.0,
            r[(0, 2)],
            -r[(0, 1)],
            0.0,
            r[(1, 2)],
            -r[(1, 1)],
            0.0,
            r[(2, 2)],
            -r[(2, 1)],
        );
        // ∂R/∂pitch = Rz [y]× Ry Rx.
        let d_pitch = Mat3::new(
            -cy * sp,
            cy * cp * sr,
            cy * cp * cr,
            -sy * sp,
            sy * cp * sr,
            sy * cp * cr,
            -cp,
            -sp * sr,
            -sp * cr,
        );
        // ∂R/∂yaw = [z]× R: rows (−R¹, R⁰, 0).
        let d_yaw = Mat3::new(
            -r[(1, 0)],
            -r[(1, 1)],
            -r[(1, 2)],
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            0.0,
            0.0,
            0.0,
        );
        Self {
            r,
            d: [d_roll, d_pitch, d_yaw],
        }
    }
}

/// Element `(i, j)` of the product `a · b`.
fn prod_at(a: &Mat3, b: &Mat3, i: usize, j: usize) -> f32 {
    a[(i, 0)] * b[(0, j)] + a[(i, 1)] * b[(1, j)] + a[(i, 2)] * b[(2, j)]
}

/// The composed orientation `Ψ ⊕ ΔΨ = rpy(R(Ψ)·R(ΔΨ))` (IROS eq. 5–6) with its
/// Jacobians: `(rpy, R(Ψ)·R(ΔΨ), ∂rpy/∂Ψ, ∂rpy/∂ΔΨ)`. Same formulas as
/// [`crate::frame::compose_rpy`], with the rotations shared and only the five entries of
/// each `dR` that the differential of `rpy(R)` reads.
pub(crate) fn compose_rpy(a: &Rot, b: &Rot) -> (Rpy, Mat3, Mat3, Mat3) {
    let r = a.r * b.r;
    let (r21, r22, r20, r10, r00) = (r[(2, 1)], r[(2, 2)], r[(2, 0)], r[(1, 0)], r[(0, 0)]);
    let roll_den = 1.0 / (r21 * r21 + r22 * r22).max(1e-12);
    let yaw_den = 1.0 / (r10 * r10 + r00 * r00).max(1e-12);
    let pitch_den = 1.0 / libm::sqrtf((1.0 - r20 * r20).max(1e-12));
    // Differential of `rpy_from_rotation` at `r` along `dR = x · y`.
    let diff = |x: &Mat3, y: &Mat3| {
        Vec3::new(
            (r22 * prod_at(x, y, 2, 1) - r21 * prod_at(x, y, 2, 2)) * roll_den,
            -prod_at(x, y, 2, 0) * pitch_den,
            (r00 * prod_at(x, y, 1, 0) - r10 * prod_at(x, y, 0, 0)) * yaw_den,
        )
    };
    let mut ja = Mat3::zeros();
    let mut jb = Mat3::zeros();
    for i in 0..3 {
        ja.set_column(i, &diff(&a.d[i], &b.r));
        jb.set_column(i, &diff(&a.r, &b.d[i]));
    }
    (rpy_from_rotation(&r), r, ja, jb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{rotation_from_rpy, rotation_partials};
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    #[test]
    fn sin_cos_is_within_two_ulp_of_f64() {
        let mut worst = 0.0f64;
        for i in -200_000..=200_000 {
            let a = i as f32 * 1e-4;
            let (s, c) = sin_cos(a);
            let (s64, c64) = (a as f64).sin_cos();
            // Error in units of f32 epsilon at magnitude max(|value|, 2^-4).
            worst = worst.max((s as f64 - s64).abs() / (s64.abs().max(0.0625) * 1.19e-7));
            worst = worst.max((c as f64 - c64).abs() / (c64.abs().max(0.0625) * 1.19e-7));
        }
        assert!(worst < 2.0, "worst error {worst} ulp");
        assert!(sin_cos(f32::NAN).0.is_nan());
        let (s, c) = sin_cos(1e6);
        assert!((s - libm::sinf(1e6)).abs() < 1e-6 && (c - libm::cosf(1e6)).abs() < 1e-6);
    }

    #[test]
    fn rotation_and_composition_match_frame() {
        let mut rng = SmallRng::seed_from_u64(41);
        for _ in 0..500 {
            let a = Rpy::new(
                rng.random_range(-3.2..3.2),
                rng.random_range(-1.5..1.5),
                rng.random_range(-3.2..3.2),
            );
            let b = Rpy::new(
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
                rng.random_range(-1.0..1.0),
            );
            let ra = Rot::new(&a);
            assert!((ra.r - rotation_from_rpy(&a)).abs().max() < 1e-6);
            for (d, e) in ra.d.iter().zip(rotation_partials(&a).iter()) {
                assert!((d - e).abs().max() < 1e-6);
            }
            let (psi, r, ja, jb) = compose_rpy(&ra, &Rot::new(&b));
            let (psi_f, ja_f, jb_f) = crate::frame::compose_rpy(&a, &b);
            let d = psi - psi_f;
            let d = Vec3::from_fn(|i, _| crate::frame::wrap_pi(d[i]));
            assert!(d.abs().max() < 1e-5, "{d}");
            assert!(
                (r - rotation_from_rpy(&a) * rotation_from_rpy(&b))
                    .abs()
                    .max()
                    < 1e-6
            );
            let tol = 1e-4 * (1.0 + ja_f.abs().max() + jb_f.abs().max());
            assert!((ja - ja_f).abs().max() < tol && (jb - jb_f).abs().max() < tol);
        }
    }
}
