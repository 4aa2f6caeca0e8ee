//! Attitude of the receiver (roll, pitch, yaw of body R in the geographic frame W) from
//! the accelerometer, gyro and magnetometer: a small error-state Kalman filter.
//!
//! - Nominal state: the rotation `R_WR` (unit quaternion) and the gyro bias `b` (rad/s).
//! - Error state `[δθ; δb]` (6), with `δθ` a small rotation in W:
//!   `R_true = exp([δθ]×) R_est`, `b_true = b_est + δb`; covariance `P` (6×6).
//! - Propagation with the bias-corrected gyro (`δθ' = −R δb`, white rate noise plus a
//!   random-walk floor for unmodelled effects; the bias is a random walk).
//! - Tilt correction from the accelerometer (the specific force at rest is `Rᵀ [0,0,g]`),
//!   gated when `|acc|` is far from g and with a large noise σ because walking adds a
//!   few m/s² of step accelerations. It never corrects yaw (its gain row for yaw is zeroed).
//! - Yaw correction from the tilt-compensated magnetometer against the known earth field
//!   (declination folded in), after hard/soft-iron calibration; rejected when `|mag|` or its
//!   inclination deviates from the earth field (magnetic disturbance) or when the innovation
//!   is an outlier. It never corrects tilt (gain rows for roll and pitch are zeroed).
//! - Zero-rate update of the gyro bias while the device is still.
//!
//! Gains with zeroed rows are not Kalman-optimal, so the covariance is updated in Joseph
//! form, which stays valid (and symmetric positive semi-definite) for any gain.

use super::Mat6;
use crate::frame::{Rpy, compose_rpy, rotation_from_rpy, rpy_from_rotation, wrap_pi};
use crate::{Mat3, Vec3};
use nalgebra::{Quaternion, SMatrix, UnitQuaternion};

/// Standard gravity, m/s² (the spec's `[0, 0, -9.80665]` in W).
pub const GRAVITY: f32 = 9.80665;

/// Magnetometer calibration: `m = soft_iron · (m_raw − hard_iron)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagCalibration {
    /// Hard-iron offset in the body frame, µT (subtracted first).
    pub hard_iron: Vec3,
    /// Soft-iron correction matrix (applied after the offset).
    pub soft_iron: Mat3,
}

impl MagCalibration {
    /// No correction.
    pub fn identity() -> Self {
        Self {
            hard_iron: Vec3::zeros(),
            soft_iron: Mat3::identity(),
        }
    }

    /// Applies the calibration to a raw reading (µT).
    pub fn apply(&self, raw: &Vec3) -> Vec3 {
        self.soft_iron * (raw - self.hard_iron)
    }
}

impl Default for MagCalibration {
    fn default() -> Self {
        Self::identity()
    }
}

/// Tuning of the attitude filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeConfig {
    /// Gyro white noise per sample, rad/s (the session log's `gyr_noise_rad_s`).
    pub gyr_noise_rad_s: f32,
    /// Extra attitude random walk for unmodelled gyro errors (scale factor, vibration), rad/√s.
    pub attitude_walk_rad_sqrt_s: f32,
    /// Gyro bias random walk, rad/s/√s.
    pub bias_walk_rad_s_sqrt_s: f32,
    /// Initial gyro bias standard deviation per axis, rad/s.
    pub bias_sigma0_rad_s: f32,
    /// Accelerometer noise σ used for tilt, m/s²; large because step accelerations of a
    /// walking person (a few m/s² at ≈ 1.8 Hz) are treated as noise.
    pub acc_sigma_m_s2: f32,
    /// Tilt updates are skipped when `| |acc| − g |` exceeds this, m/s².
    pub acc_gate_m_s2: f32,
    /// Magnetometer noise σ per axis, µT (sensor noise plus small local disturbances).
    pub mag_sigma_ut: f32,
    /// Mag updates are rejected when `|mag|` differs from the earth field's magnitude by
    /// more than this fraction.
    pub mag_norm_gate: f32,
    /// Mag updates are rejected when the measured inclination differs from the earth
    /// field's by more than this, rad.
    pub mag_dip_gate_rad: f32,
    /// Normalised-innovation gate of the yaw update (squared, 1 degree of freedom).
    pub mag_nis_gate: f32,
    /// After this many consecutive innovation-gate rejections (with norm and dip fine)
    /// the yaw update is accepted anyway: the filter, not the field, is then wrong.
    pub mag_reacquire_after: u16,
    /// Gyro magnitude below which (smoothed) the device may be still, rad/s.
    pub still_gyr_rad_s: f32,
    /// `| |acc| − g |` below which (smoothed) the device may be still, m/s².
    pub still_acc_m_s2: f32,
    /// Time the still conditions must hold before zero-rate bias updates, s.
    pub still_time_s: f32,
}

impl Default for AttitudeConfig {
    fn default() -> Self {
        Self {
            gyr_noise_rad_s: 0.005,
            attitude_walk_rad_sqrt_s: 0.002,
            bias_walk_rad_s_sqrt_s: 2e-4,
            bias_sigma0_rad_s: 0.02,
            acc_sigma_m_s2: 2.5,
            acc_gate_m_s2: 3.0,
            mag_sigma_ut: 1.0,
            mag_norm_gate: 0.1,
            mag_dip_gate_rad: 0.0873,
            mag_nis_gate: 16.0,
            mag_reacquire_after: 100,
            still_gyr_rad_s: 0.02,
            still_acc_m_s2: 0.3,
            still_time_s: 0.5,
        }
    }
}

/// Counters of what the filter did with the measurements (for diagnostics and tests).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AttitudeStats {
    /// Accelerometer tilt updates applied.
    pub acc_used: u32,
    /// Accelerometer samples skipped by the `|acc|` gate.
    pub acc_gated: u32,
    /// Magnetometer yaw updates applied.
    pub mag_used: u32,
    /// Magnetometer samples rejected as disturbed (norm, inclination or innovation).
    pub mag_rejected: u32,
    /// Zero-rate bias updates applied.
    pub still_updates: u32,
}

/// Roll and pitch (rad) of a level-referenced body from its specific force at rest.
///
/// `acc = Rᵀ [0, 0, g]` is the third row of `R` times g: `[−sin θ, cos θ sin ψ, cos θ cos ψ]`.
pub fn tilt_from_acc(acc: &Vec3) -> (f32, f32) {
    let roll = libm::atan2f(acc.y, acc.z);
    let pitch = libm::atan2f(-acc.x, libm::sqrtf(acc.y * acc.y + acc.z * acc.z));
    (roll, pitch)
}

/// Yaw (rad) from a calibrated magnetometer reading given roll and pitch: the angle of the
/// tilt-compensated horizontal field against the earth field's horizontal direction.
pub fn yaw_from_mag(mag: &Vec3, roll: f32, pitch: f32, earth_field: &Vec3) -> f32 {
    // m_h = Ry(θ) Rx(ψ) m = Rz(φ)ᵀ B_W, so angle(m_h) = angle(B_W) − φ.
    let m_h = rotation_from_rpy(&Rpy::new(roll, pitch, 0.0)) * mag;
    wrap_pi(libm::atan2f(earth_field.y, earth_field.x) - libm::atan2f(m_h.y, m_h.x))
}

/// Static attitude (roll, pitch, yaw) from one accelerometer and one (calibrated)
/// magnetometer reading: exact when the device is at rest in an undisturbed field.
pub fn static_attitude(acc: &Vec3, mag: &Vec3, earth_field: &Vec3) -> Rpy {
    let (roll, pitch) = tilt_from_acc(acc);
    Rpy::new(roll, pitch, yaw_from_mag(mag, roll, pitch, earth_field))
}

/// Skew-symmetric cross-product matrix `[v]×`.
fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `exp` of a rotation vector as a unit quaternion (libm trig).
fn quat_exp(w: &Vec3) -> UnitQuaternion<f32> {
    let angle = libm::sqrtf(w.dot(w));
    if angle < 1e-9 {
        return UnitQuaternion::new_normalize(Quaternion::new(
            1.0,
            0.5 * w.x,
            0.5 * w.y,
            0.5 * w.z,
        ));
    }
    let (s, c) = (libm::sinf(0.5 * angle), libm::cosf(0.5 * angle));
    let k = s / angle;
    UnitQuaternion::new_normalize(Quaternion::new(c, k * w.x, k * w.y, k * w.z))
}

/// The error-state Kalman filter of the receiver's attitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeFilter {
    cfg: AttitudeConfig,
    earth_field: Vec3,
    q: UnitQuaternion<f32>,
    bias: Vec3,
    p: Mat6,
    mag_outliers: u16,
    still_for_s: f32,
    gyr_smooth: Vec3,
    gyr_dev: f32,
    acc_dev: f32,
    stats: AttitudeStats,
}

impl AttitudeFilter {
    /// A filter initialised from one accelerometer and one calibrated magnetometer reading
    /// (static attitude). When the magnetometer does not match the earth field, yaw starts
    /// at 0 with a σ of π and is acquired by later mag updates.
    pub fn new(cfg: AttitudeConfig, earth_field: Vec3, acc: &Vec3, mag: &Vec3) -> Self {
        let mut rpy = static_attitude(acc, mag, &earth_field);
        let b = earth_field.norm();
        let mag_ok = b > 0.0 && libm::fabsf(mag.norm() - b) <= cfg.mag_norm_gate * b;
        let yaw_sigma = if mag_ok {
            10f32.to_radians()
        } else {
            rpy.z = 0.0;
            core::f32::consts::PI
        };
        let tilt_sigma = 3f32.to_radians();
        let sb = cfg.bias_sigma0_rad_s;
        let p = Mat6::from_diagonal(&nalgebra::SVector::<f32, 6>::from([
            tilt_sigma * tilt_sigma,
            tilt_sigma * tilt_sigma,
            yaw_sigma * yaw_sigma,
            sb * sb,
            sb * sb,
            sb * sb,
        ]));
        let r = rotation_from_rpy(&rpy);
        let q = UnitQuaternion::from_matrix(&r);
        Self {
            cfg,
            earth_field,
            q,
            bias: Vec3::zeros(),
            p,
            mag_outliers: 0,
            still_for_s: 0.0,
            gyr_smooth: Vec3::zeros(),
            gyr_dev: 1.0,
            acc_dev: 1.0,
            stats: AttitudeStats::default(),
        }
    }

    /// `R_WR`, the rotation from body to world.
    pub fn rotation(&self) -> Mat3 {
        self.q.to_rotation_matrix().into_inner()
    }

    /// Roll, pitch, yaw (rad).
    pub fn rpy(&self) -> Rpy {
        rpy_from_rotation(&self.rotation())
    }

    /// Covariance of [`rpy`](Self::rpy) (rad²), mapped from the world-frame error angles.
    pub fn rpy_cov(&self) -> Mat3 {
        // rpy(exp([δθ]×) R) ≈ rpy(R) + J δθ, with J = ∂rpy(R(a) R)/∂a at a = 0.
        let (_, j, _) = compose_rpy(&Rpy::zeros(), &self.rpy());
        let c = j * self.p.fixed_view::<3, 3>(0, 0) * j.transpose();
        0.5 * (c + c.transpose())
    }

    /// Covariance of the world-frame error angles `δθ` (rad²).
    pub fn angle_cov(&self) -> Mat3 {
        self.p.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// Full 6×6 error-state covariance (`[δθ; δb]`).
    pub fn error_cov(&self) -> SMatrix<f32, 6, 6> {
        self.p
    }

    /// Estimated gyro bias, rad/s.
    pub fn gyro_bias(&self) -> Vec3 {
        self.bias
    }

    /// What the filter did with its measurements so far.
    pub fn stats(&self) -> AttitudeStats {
        self.stats
    }

    /// The configuration in use.
    pub fn config(&self) -> &AttitudeConfig {
        &self.cfg
    }

    /// Inflates the attitude and bias covariance after a data gap of `dt` seconds.
    pub fn inflate_for_gap(&mut self, dt: f32) {
        let dt = dt.max(0.0);
        let a = self.cfg.gyr_noise_rad_s * self.cfg.gyr_noise_rad_s * dt
            + self.cfg.bias_sigma0_rad_s * self.cfg.bias_sigma0_rad_s * dt * dt;
        for i in 0..3 {
            self.p[(i, i)] += a;
        }
        self.still_for_s = 0.0;
    }

    /// One IMU sample: gyro propagation over `dt`, then tilt, yaw and zero-rate updates.
    /// Inputs must be finite and `dt > 0` (checked by the caller, [`super::Motion`]).
    pub fn update(&mut self, dt: f32, acc: &Vec3, gyr: &Vec3, mag: Option<&Vec3>) {
        self.propagate(dt, gyr);
        self.track_stillness(dt, acc, gyr);
        self.tilt_update(acc);
        if let Some(m) = mag {
            self.yaw_update(m);
        }
        if self.still_for_s >= self.cfg.still_time_s {
            self.zero_rate_update(gyr);
        }
    }

    /// Bias-corrected angular rate for a raw gyro reading, rad/s.
    pub fn corrected_rate(&self, gyr: &Vec3) -> Vec3 {
        gyr - self.bias
    }

    /// Attitude extrapolated `dt` seconds ahead with the rate `rate` (body, rad/s).
    pub fn rotation_ahead(&self, rate: &Vec3, dt: f32) -> Mat3 {
        (self.q * quat_exp(&(rate * dt)))
            .to_rotation_matrix()
            .into_inner()
    }

    fn propagate(&mut self, dt: f32, gyr: &Vec3) {
        let w = self.corrected_rate(gyr);
        let r = self.rotation();
        self.q *= quat_exp(&(w * dt));
        // δθ' = −R δb: F = [[I, −R dt], [0, I]].
        let mut f = Mat6::identity();
        f.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r * dt));
        let c = &self.cfg;
        let qa = c.gyr_noise_rad_s * c.gyr_noise_rad_s * dt * dt
            + c.attitude_walk_rad_sqrt_s * c.attitude_walk_rad_sqrt_s * dt;
        let qb = c.bias_walk_rad_s_sqrt_s * c.bias_walk_rad_s_sqrt_s * dt;
        let mut p = f * self.p * f.transpose();
        for i in 0..3 {
            p[(i, i)] += qa;
            p[(i + 3, i + 3)] += qb;
        }
        self.p = 0.5 * (p + p.transpose());
    }

    fn track_stillness(&mut self, dt: f32, acc: &Vec3, gyr: &Vec3) {
        // Exponential smoothing over ≈ 0.25 s of the rate and of the deviations.
        let a = (dt / 0.25).min(1.0);
        self.gyr_smooth += (gyr - self.gyr_smooth) * a;
        let dev = (gyr - self.bias).norm();
        self.gyr_dev += (dev - self.gyr_dev) * a;
        self.acc_dev += (libm::fabsf(acc.norm() - GRAVITY) - self.acc_dev) * a;
        if self.gyr_dev < self.cfg.still_gyr_rad_s && self.acc_dev < self.cfg.still_acc_m_s2 {
            self.still_for_s += dt;
        } else {
            self.still_for_s = 0.0;
        }
    }

    /// Whether the device has been still long enough for zero-rate bias updates.
    pub fn is_still(&self) -> bool {
        self.still_for_s >= self.cfg.still_time_s
    }

    /// Applies an error-state correction with a (possibly row-zeroed) gain in Joseph form.
    fn correct<const M: usize>(
        &mut self,
        h: &SMatrix<f32, M, 6>,
        k: &SMatrix<f32, 6, M>,
        r: &SMatrix<f32, M, M>,
        innovation: &SMatrix<f32, M, 1>,
    ) {
        let dx = k * innovation;
        let ikh = Mat6::identity() - k * h;
        let p = ikh * self.p * ikh.transpose() + k * r * k.transpose();
        let dtheta = Vec3::new(dx[0], dx[1], dx[2]);
        let q = quat_exp(&dtheta) * self.q;
        let bias = self.bias + Vec3::new(dx[3], dx[4], dx[5]);
        // Commit only finite results: the filter state never becomes NaN.
        if p.iter().all(|x| x.is_finite())
            && bias.iter().all(|x| x.is_finite())
            && q.coords.iter().all(|x| x.is_finite())
        {
            self.p = 0.5 * (p + p.transpose());
            self.q = q;
            self.bias = bias;
        }
    }

    fn tilt_update(&mut self, acc: &Vec3) {
        let dev = libm::fabsf(acc.norm() - GRAVITY);
        if dev > self.cfg.acc_gate_m_s2 {
            self.stats.acc_gated = self.stats.acc_gated.saturating_add(1);
            return;
        }
        let r = self.rotation();
        let g = Vec3::new(0.0, 0.0, GRAVITY);
        // acc ≈ R_trueᵀ g = Rᵀ (I − [δθ]×) g = Rᵀ g + Rᵀ [g]× δθ.
        let mut h = SMatrix::<f32, 3, 6>::zeros();
        h.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(r.transpose() * skew(&g)));
        // Larger σ while moving: the gate lets through accelerations up to acc_gate.
        let sigma = self.cfg.acc_sigma_m_s2 + dev;
        let rn = Mat3::identity() * (sigma * sigma);
        let s = h * self.p * h.transpose() + rn;
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let mut k = self.p * h.transpose() * s_inv;
        // The accelerometer says nothing about yaw: never let it move yaw.
        k.row_mut(2).fill(0.0);
        let innovation = acc - r.transpose() * g;
        self.correct(&h, &k, &rn, &innovation);
        self.stats.acc_used = self.stats.acc_used.saturating_add(1);
    }

    fn yaw_update(&mut self, mag: &Vec3) {
        let b = self.earth_field;
        let b_norm = b.norm();
        let b_h = libm::sqrtf(b.x * b.x + b.y * b.y);
        let m_norm = mag.norm();
        if b_norm <= 0.0 || b_h < 1e-3 * b_norm || m_norm <= 0.0 {
            return;
        }
        let reject = |me: &mut Self| {
            me.stats.mag_rejected = me.stats.mag_rejected.saturating_add(1);
        };
        if libm::fabsf(m_norm - b_norm) > self.cfg.mag_norm_gate * b_norm {
            reject(self);
            return;
        }
        let r = self.rotation();
        let m_w = r * mag;
        // Inclination (dip, positive downward) of the measured field against the expected.
        let dip_meas = libm::asinf((-m_w.z / m_norm).clamp(-1.0, 1.0));
        let dip_exp = libm::asinf((-b.z / b_norm).clamp(-1.0, 1.0));
        if libm::fabsf(dip_meas - dip_exp) > self.cfg.mag_dip_gate_rad {
            reject(self);
            return;
        }
        // Tilt-compensated heading: the horizontal angle of R m against that of B_W.
        // yaw_true − yaw_est = angle(B_W) − angle(R_est m).
        let innovation = wrap_pi(libm::atan2f(b.y, b.x) - libm::atan2f(m_w.y, m_w.x));
        let mut h = SMatrix::<f32, 1, 6>::zeros();
        h[(0, 2)] = 1.0;
        // Noise: sensor noise across the horizontal component, plus the heading error a
        // tilt error causes through the vertical component (≈ tan(dip) · tilt).
        let m_h = libm::sqrtf(m_w.x * m_w.x + m_w.y * m_w.y).max(1e-3 * m_norm);
        let tan_dip = libm::fabsf(m_w.z) / m_h;
        let tilt_var = self.p[(0, 0)].max(self.p[(1, 1)]);
        let var = (self.cfg.mag_sigma_ut / m_h) * (self.cfg.mag_sigma_ut / m_h)
            + tan_dip * tan_dip * tilt_var;
        let s = self.p[(2, 2)] + var;
        if s <= 0.0 {
            return;
        }
        if innovation * innovation / s > self.cfg.mag_nis_gate {
            self.mag_outliers = self.mag_outliers.saturating_add(1);
            if self.mag_outliers < self.cfg.mag_reacquire_after {
                reject(self);
                return;
            }
            // Persistently inconsistent but the field itself looks right: the attitude is
            // off (e.g. after a gap); accept and let P absorb it.
            self.p[(2, 2)] += innovation * innovation;
        }
        self.mag_outliers = 0;
        let s = self.p[(2, 2)] + var;
        let mut k = self.p.column(2) / s;
        // The magnetometer never corrects roll or pitch (disturbances must not tilt us).
        k[0] = 0.0;
        k[1] = 0.0;
        let rn = SMatrix::<f32, 1, 1>::new(var);
        let inn = SMatrix::<f32, 1, 1>::new(innovation);
        self.correct(&h, &k.into_owned(), &rn, &inn);
        self.stats.mag_used = self.stats.mag_used.saturating_add(1);
    }

    fn zero_rate_update(&mut self, gyr: &Vec3) {
        // Still: the gyro reads its bias. z = gyr, h = b.
        let mut h = SMatrix::<f32, 3, 6>::zeros();
        h.fixed_view_mut::<3, 3>(0, 3).copy_from(&Mat3::identity());
        let sg = self.cfg.gyr_noise_rad_s.max(1e-4) + 0.5 * self.gyr_dev;
        let rn = Mat3::identity() * (sg * sg);
        let s = h * self.p * h.transpose() + rn;
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let k = self.p * h.transpose() * s_inv;
        let innovation = gyr - self.bias;
        self.correct(&h, &k, &rn, &innovation);
        self.stats.still_updates = self.stats.still_updates.saturating_add(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn earth() -> Vec3 {
        Vec3::new(21.792, 0.0, -42.768)
    }

    fn sample(rpy: &Rpy) -> (Vec3, Vec3) {
        let r = rotation_from_rpy(rpy);
        (
            r.transpose() * Vec3::new(0.0, 0.0, GRAVITY),
            r.transpose() * earth(),
        )
    }

    #[test]
    fn static_attitude_is_exact() {
        for &(ro, pi, ya) in &[
            (0.0, 0.0, 0.0),
            (0.2, -0.3, 1.0),
            (-0.5, 0.4, -2.5),
            (0.1, 0.25, 3.0),
            (1.0, -1.0, -0.7),
        ] {
            let rpy = Rpy::new(ro, pi, ya);
            let (acc, mag) = sample(&rpy);
            let est = static_attitude(&acc, &mag, &earth());
            let d = (est - rpy).map(wrap_pi);
            assert!(d.abs().max() < 1e-5, "{rpy:?} -> {est:?}");
            // The filter starts at the same attitude.
            let f = AttitudeFilter::new(AttitudeConfig::default(), earth(), &acc, &mag);
            assert!((f.rpy() - rpy).map(wrap_pi).abs().max() < 1e-5);
        }
    }

    #[test]
    fn constant_rate_integrates_exactly() {
        // A constant body rate about a tilted axis, with consistent acc and mag.
        let w = Vec3::new(0.1, -0.05, 0.4);
        let r0 = rotation_from_rpy(&Rpy::new(0.1, 0.2, 0.3));
        let (acc0, mag0) = (
            r0.transpose() * Vec3::new(0.0, 0.0, GRAVITY),
            r0.transpose() * earth(),
        );
        let mut f = AttitudeFilter::new(AttitudeConfig::default(), earth(), &acc0, &mag0);
        let dt = 0.01;
        let mut r = r0;
        for _ in 0..500 {
            r *= quat_exp(&(w * dt)).to_rotation_matrix().into_inner();
            let acc = r.transpose() * Vec3::new(0.0, 0.0, GRAVITY);
            let mag = r.transpose() * earth();
            f.update(dt, &acc, &w, Some(&mag));
        }
        let err = (f.rotation().transpose() * r - Mat3::identity())
            .abs()
            .max();
        assert!(err < 1e-3, "err {err}");
        assert!(f.gyro_bias().norm() < 1e-3);
        // Gyro only (no mag, acc gated out by a huge |acc|): pure integration.
        let mut g = AttitudeFilter::new(AttitudeConfig::default(), earth(), &acc0, &mag0);
        let mut r = r0;
        for _ in 0..500 {
            r *= quat_exp(&(w * dt)).to_rotation_matrix().into_inner();
            g.update(dt, &Vec3::new(0.0, 0.0, 30.0), &w, None);
        }
        let err = (g.rotation().transpose() * r - Mat3::identity())
            .abs()
            .max();
        assert!(err < 1e-4, "pure integration err {err}");
        assert_eq!(g.stats().acc_used, 0);
    }

    #[test]
    fn learns_gyro_bias_and_keeps_yaw_with_mag() {
        let rpy = Rpy::new(0.05, 0.15, -1.0);
        let (acc, mag) = sample(&rpy);
        let bias = Vec3::new(0.008, -0.006, 0.01);
        let mut f = AttitudeFilter::new(AttitudeConfig::default(), earth(), &acc, &mag);
        for _ in 0..3000 {
            f.update(0.01, &acc, &bias, Some(&mag));
        }
        assert!(f.is_still());
        assert!((f.gyro_bias() - bias).norm() < 1e-3, "{:?}", f.gyro_bias());
        assert!((f.rpy() - rpy).map(wrap_pi).abs().max() < 2e-3);
        let cov = f.rpy_cov();
        assert!(cov[(2, 2)] > 0.0 && cov[(2, 2)].sqrt() < 0.02);
    }

    #[test]
    fn disturbed_magnetometer_is_rejected() {
        let rpy = Rpy::new(0.0, 0.1, 0.5);
        let (acc, mag) = sample(&rpy);
        let mut f = AttitudeFilter::new(AttitudeConfig::default(), earth(), &acc, &mag);
        for _ in 0..100 {
            f.update(0.01, &acc, &Vec3::zeros(), Some(&mag));
        }
        let used = f.stats().mag_used;
        // A strong local field (a steel object): magnitude off by 40 %.
        let disturbed = mag * 1.4;
        // Same magnitude, rotated toward the vertical: inclination off.
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, 0.0));
        let tilted =
            r.transpose() * rotation_from_rpy(&Rpy::new(0.0, 0.3, 0.5)).transpose() * earth();
        for _ in 0..200 {
            f.update(0.01, &acc, &Vec3::zeros(), Some(&disturbed));
            f.update(0.01, &acc, &Vec3::zeros(), Some(&tilted));
        }
        assert_eq!(f.stats().mag_used, used);
        assert!(f.stats().mag_rejected >= 400);
        assert!((f.rpy() - rpy).map(wrap_pi).abs().max() < 2e-3);
    }

    #[test]
    fn mag_calibration_applies_offset_then_matrix() {
        let cal = MagCalibration {
            hard_iron: Vec3::new(1.0, 2.0, 3.0),
            soft_iron: Mat3::from_diagonal(&Vec3::new(2.0, 1.0, 0.5)),
        };
        let m = cal.apply(&Vec3::new(2.0, 2.0, 5.0));
        assert!((m - Vec3::new(2.0, 0.0, 1.0)).norm() < 1e-6);
    }
}
