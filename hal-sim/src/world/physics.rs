//! `f64` truth physics of the simulator: the dipole field, the rotation convention and
//! the Euler-rate to body-rate map. Each is the firmware's `f32` function written in
//! `f64` (the tests compare them), so truth stays exact while the firmware stays `f32`.
use firmware::nalgebra::{Matrix3, Vector3};

/// A 3-vector of `f64`.
pub type V3 = Vector3<f64>;
/// A 3×3 matrix of `f64`.
pub type M3 = Matrix3<f64>;

/// Gravity in the world frame W (x north, y west, z up), m/s².
pub const GRAVITY_W: [f64; 3] = [0.0, 0.0, -9.80665];

/// Field `H` (A/m) at offset `r = p_receiver − p_transmitter` (m) of a dipole with moment
/// `m` (A·m²): `H = (3 (m·u) u − m) / (4π |r|³)`, as `firmware::dipole::field`.
pub fn dipole_field(r: &V3, m: &V3) -> V3 {
    let range = r.norm();
    let u = r / range;
    (u * (3.0 * m.dot(&u)) - m) / (4.0 * std::f64::consts::PI * range.powi(3))
}

/// `R_WR = Rz(yaw) Ry(pitch) Rx(roll)` for `rpy = [roll, pitch, yaw]`, as
/// `firmware::frame::rotation_from_rpy`.
pub fn rotation_from_rpy(rpy: &V3) -> M3 {
    let (sr, cr) = rpy.x.sin_cos();
    let (sp, cp) = rpy.y.sin_cos();
    let (sy, cy) = rpy.z.sin_cos();
    M3::new(
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )
}

/// Angular rate of R relative to W expressed in R (rad/s), from the roll/pitch/yaw
/// angles and their rates (ZYX convention).
pub fn body_rate_from_rpy_rates(rpy: &V3, rates: &V3) -> V3 {
    let (sr, cr) = rpy.x.sin_cos();
    let (sp, cp) = rpy.y.sin_cos();
    V3::new(
        rates.x - rates.z * sp,
        rates.y * cr + rates.z * sr * cp,
        -rates.y * sr + rates.z * cr * cp,
    )
}

/// The rotation `exp([w]×)` of a rotation vector `w` (rad), by Rodrigues' formula.
pub fn exp_so3(w: &V3) -> M3 {
    let theta = w.norm();
    let k = w.cross_matrix();
    if theta < 1e-12 {
        return M3::identity() + k;
    }
    M3::identity() + k * (theta.sin() / theta) + k * k * ((1.0 - theta.cos()) / (theta * theta))
}

/// Converts an `f64` vector to the firmware's `f32` vector.
pub fn to_f32(v: &V3) -> firmware::Vec3 {
    firmware::Vec3::new(v.x as f32, v.y as f32, v.z as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn field_matches_firmware() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..2000 {
            let r = V3::new(
                rng.random_range(-60.0..60.0),
                rng.random_range(-60.0..60.0),
                rng.random_range(-5.0..5.0),
            );
            let m = V3::new(
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
            );
            if r.norm() < 0.5 {
                continue;
            }
            let h = dipole_field(&r, &m);
            let hf = firmware::dipole::field(&to_f32(&r), &to_f32(&m)).unwrap();
            let err = (h - hf.cast::<f64>()).norm() / h.norm();
            assert!(err < 1e-5, "relative error {err:e}");
        }
    }

    #[test]
    fn rotation_matches_firmware() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..1000 {
            let a = V3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(-3.0..3.0),
            );
            let r = rotation_from_rpy(&a);
            let rf = firmware::frame::rotation_from_rpy(&to_f32(&a));
            assert!((r - rf.cast::<f64>()).abs().max() < 1e-6);
        }
    }

    #[test]
    fn body_rate_matches_differentiated_rotation() {
        // [w]× = R^T dR/dt.
        let rpy = V3::new(0.3, -0.4, 1.1);
        let rates = V3::new(0.5, -0.2, 0.8);
        let h = 1e-6;
        let dr = (rotation_from_rpy(&(rpy + rates * h)) - rotation_from_rpy(&(rpy - rates * h)))
            / (2.0 * h);
        let w = rotation_from_rpy(&rpy).transpose() * dr;
        let expect = V3::new(w[(2, 1)], w[(0, 2)], w[(1, 0)]);
        assert!((body_rate_from_rpy_rates(&rpy, &rates) - expect).norm() < 1e-6);
    }
}
