//! Rotations between the receiver's body frame R and the geographic frame G/W.
//!
//! Conventions (session-log spec, IROS 2006 eq. 2): body x forward, y left, z up;
//! geographic x north, y west, z up; orientation as roll ψ, pitch θ, yaw φ with
//! `R_WR = Rot(z, φ) · Rot(y, θ) · Rot(x, ψ)`. A vector in R maps to W as `v_W = R_WR v_R`.
//!
//! Trigonometry goes through [`sin_cos`] (f32, ≤ 2 ulp) and `libm` explicitly, never the
//! `f32` methods (std on the host), so the host tests and the Cortex-M4F run the very same
//! functions.

use crate::{Mat3, Vec3};

/// Roll, pitch and yaw (ψ, θ, φ) in radians, in that order.
pub type Rpy = Vec3;

/// Rotation about the x axis by `a` radians.
pub fn rot_x(a: f32) -> Mat3 {
    let (s, c) = sin_cos(a);
    Mat3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// Rotation about the y axis by `a` radians.
pub fn rot_y(a: f32) -> Mat3 {
    let (s, c) = sin_cos(a);
    Mat3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// Rotation about the z axis by `a` radians.
pub fn rot_z(a: f32) -> Mat3 {
    let (s, c) = sin_cos(a);
    Mat3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// `R = Rz(yaw) Ry(pitch) Rx(roll)` (IROS 2006 eq. 2).
pub fn rotation_from_rpy(rpy: &Rpy) -> Mat3 {
    rot_z(rpy.z) * rot_y(rpy.y) * rot_x(rpy.x)
}

/// The partial derivatives `[∂R/∂roll, ∂R/∂pitch, ∂R/∂yaw]` of [`rotation_from_rpy`].
pub fn rotation_partials(rpy: &Rpy) -> [Mat3; 3] {
    let (rx, ry, rz) = (rot_x(rpy.x), rot_y(rpy.y), rot_z(rpy.z));
    // d/da Rot(axis, a) = [axis]× Rot(axis, a): a skew matrix times the rotation.
    let (dx, dy, dz) = (skew_x() * rx, skew_y() * ry, skew_z() * rz);
    [rz * ry * dx, rz * dy * rx, dz * ry * rx]
}

/// Roll, pitch and yaw of a rotation matrix (inverse of [`rotation_from_rpy`]).
///
/// Pitch lies in [-π/2, π/2], roll and yaw in (-π, π]. At pitch ±90° (gimbal lock) the
/// split between roll and yaw is arbitrary; roll is then reported as 0.
pub fn rpy_from_rotation(r: &Mat3) -> Rpy {
    let sin_pitch = (-r[(2, 0)]).clamp(-1.0, 1.0);
    let pitch = libm::asinf(sin_pitch);
    let cos_pitch_sq = r[(2, 1)] * r[(2, 1)] + r[(2, 2)] * r[(2, 2)];
    if cos_pitch_sq < 1e-12 {
        // Gimbal lock: only yaw - roll (or yaw + roll) is defined.
        let yaw = libm::atan2f(-r[(0, 1)], r[(1, 1)]);
        return Rpy::new(0.0, pitch, yaw);
    }
    let roll = libm::atan2f(r[(2, 1)], r[(2, 2)]);
    let yaw = libm::atan2f(r[(1, 0)], r[(0, 0)]);
    Rpy::new(roll, pitch, yaw)
}

/// Composition of orientations (IROS 2006 eq. 5–6): the roll/pitch/yaw of `R(a) · R(b)`,
/// with the Jacobians of the result with respect to `a` and to `b`.
///
/// Used when the displacement's rotation `b = Ψ_{R_{k-1} R_k}` is composed onto the
/// orientation `a = Ψ_{G_{k-1} R_{k-1}}`. Returns `(rpy, ∂rpy/∂a, ∂rpy/∂b)`.
pub fn compose_rpy(a: &Rpy, b: &Rpy) -> (Rpy, Mat3, Mat3) {
    let (ra, rb) = (rotation_from_rpy(a), rotation_from_rpy(b));
    let r = ra * rb;
    let (pa, pb) = (rotation_partials(a), rotation_partials(b));
    let mut ja = Mat3::zeros();
    let mut jb = Mat3::zeros();
    for (i, (dpa, dpb)) in pa.iter().zip(pb.iter()).enumerate() {
        ja.set_column(i, &rpy_differential(&r, &(dpa * rb)));
        jb.set_column(i, &rpy_differential(&r, &(ra * dpb)));
    }
    (rpy_from_rotation(&r), ja, jb)
}

/// Wraps an angle to (-π, π].
pub fn wrap_pi(a: f32) -> f32 {
    use core::f32::consts::PI;
    let w = a - 2.0 * PI * libm::floorf((a + PI) / (2.0 * PI));
    if w <= -PI { w + 2.0 * PI } else { w }
}

/// Differential of [`rpy_from_rotation`] at `r` along the matrix direction `dr`.
fn rpy_differential(r: &Mat3, dr: &Mat3) -> Vec3 {
    let (r21, r22, r20, r10, r00) = (r[(2, 1)], r[(2, 2)], r[(2, 0)], r[(1, 0)], r[(0, 0)]);
    let roll_den = (r21 * r21 + r22 * r22).max(1e-12);
    let yaw_den = (r10 * r10 + r00 * r00).max(1e-12);
    let pitch_den = libm::sqrtf((1.0 - r20 * r20).max(1e-12));
    Vec3::new(
        (r22 * dr[(2, 1)] - r21 * dr[(2, 2)]) / roll_den,
        -dr[(2, 0)] / pitch_den,
        (r00 * dr[(1, 0)] - r10 * dr[(0, 0)]) / yaw_den,
    )
}

// `libm::sinf`/`cosf` evaluate their kernels in f64, which the Cortex-M4F emulates in
// software (≈ 1 200 instructions per call): rotations use this f32 version instead.
/// `π/2` split in three parts for the Cody–Waite reduction; `HI` and `MID` have few
/// enough significant bits that `k·HI` and `k·MID` are exact for `|k| < 2¹²`.
const PIO2_HI: f32 = 1.570_312_5;
const PIO2_MID: f32 = 4.838_705e-4;
const PIO2_LO: f32 = -4.371_139e-8;
/// Beyond this magnitude the reduction above loses accuracy; `libm` takes over (angles
/// are wrapped to (−π, π] here, so this never happens in practice).
const FAST_LIMIT: f32 = 4096.0;

/// `(sin a, cos a)` in `f32` (≤ 2 ulp for |a| < 4096, `libm` beyond): reduction to `[−π/4, π/4]` by a multiple of `π/2`, then
/// the minimax polynomials of musl's `__sindf`/`__cosdf` evaluated in `f32`.
pub fn sin_cos(a: f32) -> (f32, f32) {
    // NaN goes to `libm`, which propagates it.
    if a.is_nan() || a.abs() >= FAST_LIMIT {
        return (libm::sinf(a), libm::cosf(a));
    }
    let k = (a * core::f32::consts::FRAC_2_PI + 0.5f32.copysign(a)) as i32;
    let kf = k as f32;
    let r = ((a - kf * PIO2_HI) - kf * PIO2_MID) - kf * PIO2_LO;
    let r2 = r * r;
    let s = r + r
        * r2
        * (-0.166_666_67 + r2 * (8.333_329e-3 + r2 * (-1.983_933_5e-4 + r2 * 2.718_311_4e-6)));
    let c = 1.0 + r2 * (-0.5 + r2 * (4.166_662_3e-2 + r2 * (-1.388_676_4e-3 + r2 * 2.439_045e-5)));
    match k & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

fn skew_x() -> Mat3 {
    Mat3::new(0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0)
}

fn skew_y() -> Mat3 {
    Mat3::new(0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0)
}

fn skew_z() -> Mat3 {
    Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// f64 reference of `Rz(yaw) Ry(pitch) Rx(roll)`, written out element by element.
    fn rotation_f64(roll: f64, pitch: f64, yaw: f64) -> [[f64; 3]; 3] {
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let (sy, cy) = yaw.sin_cos();
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    }

    fn random_rpy(rng: &mut SmallRng) -> Rpy {
        Rpy::new(
            rng.random_range(-3.1..3.1),
            rng.random_range(-1.5..1.5),
            rng.random_range(-3.1..3.1),
        )
    }

    #[test]
    fn rotation_matches_f64_closed_form() {
        let mut rng = SmallRng::seed_from_u64(1);
        let mut worst = 0.0f64;
        for _ in 0..2000 {
            let a = random_rpy(&mut rng);
            let r = rotation_from_rpy(&a);
            let e = rotation_f64(a.x as f64, a.y as f64, a.z as f64);
            for i in 0..3 {
                for j in 0..3 {
                    worst = worst.max((r[(i, j)] as f64 - e[i][j]).abs());
                }
            }
        }
        assert!(worst < 2e-6, "worst abs error {worst}");
    }

    #[test]
    fn yaw_turns_north_toward_west() {
        // Positive yaw is counter-clockwise seen from above: body x (forward) at yaw 90°
        // points west, which is +y of the geographic frame.
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, core::f32::consts::FRAC_PI_2));
        let fwd = r * Vec3::x();
        assert!((fwd - Vec3::y()).norm() < 1e-6);
        // Positive pitch turns the nose down (right-handed about the y axis = left).
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.3, 0.0));
        assert!((r * Vec3::x()).z < 0.0);
    }

    #[test]
    fn rpy_round_trip() {
        let mut rng = SmallRng::seed_from_u64(2);
        for _ in 0..2000 {
            let a = random_rpy(&mut rng);
            let b = rpy_from_rotation(&rotation_from_rpy(&a));
            let d = (b - a).map(|x| wrap_pi(x).abs());
            assert!(d.max() < 1e-4, "{a:?} -> {b:?}");
        }
    }

    #[test]
    fn gimbal_lock_gives_an_equivalent_rotation() {
        let a = Rpy::new(0.4, core::f32::consts::FRAC_PI_2, -1.0);
        let r = rotation_from_rpy(&a);
        let back = rotation_from_rpy(&rpy_from_rotation(&r));
        assert!((back - r).abs().max() < 1e-3);
    }

    #[test]
    fn partials_match_central_differences() {
        let mut rng = SmallRng::seed_from_u64(3);
        for _ in 0..500 {
            let a = random_rpy(&mut rng);
            let p = rotation_partials(&a);
            for (k, pk) in p.iter().enumerate() {
                let h = 1e-3;
                let (mut ap, mut am) = (a, a);
                ap[k] += h;
                am[k] -= h;
                let fd = (rotation_from_rpy(&ap) - rotation_from_rpy(&am)) / (2.0 * h);
                assert!((fd - pk).abs().max() < 2e-3, "k={k}");
            }
        }
    }

    #[test]
    fn compose_matches_matrix_product_and_differences() {
        let mut rng = SmallRng::seed_from_u64(4);
        for _ in 0..500 {
            let a = Rpy::new(
                rng.random_range(-0.6..0.6),
                rng.random_range(-0.6..0.6),
                rng.random_range(-3.0..3.0),
            );
            let b = Rpy::new(
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.5..0.5),
            );
            let (c, ja, jb) = compose_rpy(&a, &b);
            let prod = rotation_from_rpy(&a) * rotation_from_rpy(&b);
            assert!((rotation_from_rpy(&c) - prod).abs().max() < 1e-5);
            let h = 1e-3;
            for k in 0..3 {
                let (mut ap, mut am, mut bp, mut bm) = (a, a, b, b);
                ap[k] += h;
                am[k] -= h;
                bp[k] += h;
                bm[k] -= h;
                let fa = (compose_rpy(&ap, &b).0 - compose_rpy(&am, &b).0).map(wrap_pi) / (2.0 * h);
                let fb = (compose_rpy(&a, &bp).0 - compose_rpy(&a, &bm).0).map(wrap_pi) / (2.0 * h);
                assert!((fa - ja.column(k)).abs().max() < 5e-3, "∂/∂a{k}");
                assert!((fb - jb.column(k)).abs().max() < 5e-3, "∂/∂b{k}");
            }
        }
    }

    #[test]
    fn wrap_pi_range() {
        for i in -100..100 {
            let a = i as f32 * 0.37;
            let w = wrap_pi(a);
            assert!(w > -core::f32::consts::PI - 1e-6 && w <= core::f32::consts::PI + 1e-6);
            assert!(
                ((a - w) as f64 / (2.0 * PI)).fract().abs() < 1e-3
                    || ((a - w) as f64 / (2.0 * PI)).fract().abs() > 1.0 - 1e-3
            );
        }
    }
}
