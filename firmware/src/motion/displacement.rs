//! The receiver's displacement between two pulses (Piniés, Tardós & Neira, IROS 2006,
//! section II-A, eq. 4): `x_{R_k}` seen from `R_{k-1}` = [translation in `R_{k-1}`;
//! rotation `R_{k-1} → R_k` as roll/pitch/yaw], with its covariance `Q_k`.
//!
//! The steps of the interval are dead-reckoned with Kleiner et al. eq. 1–3 ([`PdrPose`])
//! in the level frame `L = Rz(yaw_{k-1})` of the previous pulse: each step first turns the
//! PDR heading to the step's mean device yaw relative to `yaw_{k-1}` (the turn's variance
//! is the gyro drift since the previous heading event), then strides its length. At the
//! pulse a last turn brings θ to `yaw_k − yaw_{k-1}`, so θ's error is the relative yaw
//! error of the displacement's rotation and its correlation with the translation is the
//! one eq. 2 accumulated.
//!
//! **Not included in `Q_k`:** the walk-long scale error of the step length (the
//! calibration error). It is the same for every interval, so adding it per interval would
//! treat it as independent noise and both under-state its effect over the walk and
//! over-state it on short intervals. [`super::Motion::scale_sigma`] gives its relative σ so
//! that the estimator can carry it as a state (a scale factor on the translation).

use super::pdr::PdrPose;
use crate::frame::{Rpy, compose_rpy, rot_z, rpy_from_rotation, wrap_pi};
use crate::{Mat3, Vec3};
use nalgebra::SMatrix;

/// A 6×6 `f32` matrix: the covariance of `[translation; rotation]` (a displacement's, and the
/// attitude filter's error state); the one definition, re-exported by `estimate`.
pub type Mat6 = SMatrix<f32, 6, 6>;

/// The receiver's motion between two pulses (IROS 2006 eq. 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Displacement {
    /// Translation from `R_{k-1}` to `R_k` in `R_{k-1}` axes, m (dead-reckoned at the
    /// nominal step length: the walk-long scale error is not in `cov`).
    pub translation: Vec3,
    /// Rotation `R_{k-1} → R_k` as roll, pitch, yaw, rad.
    pub rotation: Rpy,
    /// Covariance `Q_k` of `[translation; rotation]` (m², m·rad, rad²), per-interval errors
    /// only (see the module docs).
    pub cov: Mat6,
    /// Steps detected in the interval.
    pub steps: u16,
    /// Distance walked in the interval along the path, m.
    pub distance_m: f32,
    /// Absolute (not dead-reckoned, hence unscaled) part of the translation in `R_{k-1}`
    /// axes, m: the accelerometer-integrated vertical excursion of a lift
    /// ([`super::LiftTracker`]); zero when there is none.
    pub absolute: Vec3,
    /// Covariance of `absolute`, m².
    pub absolute_cov: Mat3,
}

impl Displacement {
    /// No motion, with the given σ per translation axis (m) and per angle (rad).
    pub fn still(sigma_t: f32, sigma_r: f32) -> Self {
        let mut cov = Mat6::zeros();
        for i in 0..3 {
            cov[(i, i)] = sigma_t * sigma_t;
            cov[(i + 3, i + 3)] = sigma_r * sigma_r;
        }
        Self {
            translation: Vec3::zeros(),
            rotation: Rpy::zeros(),
            cov,
            steps: 0,
            distance_m: 0.0,
            absolute: Vec3::zeros(),
            absolute_cov: Mat3::zeros(),
        }
    }
}

/// Noise model of the dead reckoning between pulses. The floors' values and what they
/// were measured against: `docs/decisions/pdr-noise-floors.md`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdrNoise {
    /// Relative σ of one step's length around the model (step-to-step variation).
    pub step_rel_sigma: f32,
    /// σ of the extrapolated fraction of the step in progress at a pulse, in steps.
    pub partial_step_sigma: f32,
    /// σ of the walking direction of each step, independent from step to step, rad.
    pub heading_step_sigma_rad: f32,
    /// σ of the angle between walking direction and device heading, common to the whole
    /// interval (the hand wobbles slowly), rad.
    pub heading_common_sigma_rad: f32,
    /// Relative-rotation random walk between pulses (gyro noise and residual bias), rad/√s.
    pub rotation_walk_rad_sqrt_s: f32,
    /// Floor on the σ of each angle of the relative rotation, rad.
    pub rotation_floor_rad: f32,
    /// σ of the vertical translation per interval, m (bob of the hand, flat ground).
    pub vertical_sigma_m: f32,
    /// Additional vertical σ per metre walked (unknown slope).
    pub vertical_per_m: f32,
    /// Floor on the σ of each translation axis, m.
    pub translation_floor_m: f32,
    /// Distance from the walker's turning axis to the device, m (hand-held ahead).
    pub lever_arm_m: f32,
    /// Horizontal σ of an interval without a detected step, m (starting or stopping).
    pub undetected_motion_m: f32,
    /// Horizontal σ of an interval the walker stood through (no step, none pending and
    /// none overdue at either end), m: the hand's sway only.
    pub standing_motion_m: f32,
}

impl Default for PdrNoise {
    fn default() -> Self {
        Self {
            step_rel_sigma: 0.05,
            partial_step_sigma: 0.15,
            heading_step_sigma_rad: 0.035,
            heading_common_sigma_rad: 0.07,
            rotation_walk_rad_sqrt_s: 0.004,
            rotation_floor_rad: 0.004,
            vertical_sigma_m: 0.03,
            vertical_per_m: 0.05,
            translation_floor_m: 0.01,
            lever_arm_m: 0.35,
            undetected_motion_m: 0.1,
            standing_motion_m: 0.03,
        }
    }
}

impl PdrNoise {
    /// The per-interval floors [`Interval::close`] adds, as a diagonal covariance of
    /// `[translation; rotation]`, for an interval of `steps` detected steps (`standing`:
    /// the walker stood through all of it): translation and rotation floors, the
    /// vertical bob, and without a step the hand's sway or an undetected start/stop.
    /// Several victims add them once per victim interval ([`super::Motion::take_split`]).
    pub fn interval_floors(&self, steps: u32, standing: bool) -> Mat6 {
        let tf = self.translation_floor_m * self.translation_floor_m;
        let fr = self.rotation_floor_rad * self.rotation_floor_rad;
        let undetected = match (steps, standing) {
            (0, true) => self.standing_motion_m,
            (0, false) => self.undetected_motion_m,
            _ => 0.0,
        };
        let h = tf + undetected * undetected;
        let v = tf + self.vertical_sigma_m * self.vertical_sigma_m;
        Mat6::from_diagonal(&nalgebra::Vector6::new(h, h, v, fr, fr, fr))
    }
}

/// Accumulates the steps of one pulse interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    t0: f32,
    r0: Mat3,
    yaw0: f32,
    t_event: f32,
    pdr: PdrPose,
    steps: u16,
    distance: f32,
    /// The walker stood through the whole interval (see [`Interval::mark_standing`]).
    standing: bool,
}

impl Interval {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        self.t0 -= shift_s;
        self.t_event -= shift_s;
    }

    /// The attitude `R_{W R_{k-1}}` at the start of the interval.
    pub fn start_rotation(&self) -> &Mat3 {
        &self.r0
    }

    /// An interval starting at time `t0` with the attitude `r0 = R_{W R_{k-1}}`.
    pub fn new(t0: f32, r0: Mat3) -> Self {
        let yaw0 = rpy_from_rotation(&r0).z;
        Self {
            t0,
            r0,
            yaw0,
            t_event: t0,
            pdr: PdrPose::origin(0.0),
            steps: 0,
            distance: 0.0,
            standing: false,
        }
    }

    /// Marks the interval as stood through: no step was under way at its start, none was
    /// detected, pending or overdue at its end. Its horizontal σ without steps is then
    /// [`PdrNoise::standing_motion_m`] instead of [`PdrNoise::undetected_motion_m`].
    pub fn mark_standing(&mut self) {
        self.standing = true;
    }

    /// Start time, s.
    pub fn start(&self) -> f32 {
        self.t0
    }

    /// Steps so far.
    pub fn steps(&self) -> u16 {
        self.steps
    }

    /// The PDR pose in the interval's level frame.
    pub fn pose(&self) -> &PdrPose {
        &self.pdr
    }

    /// Adds a stride of `d` metres (negative: take back a stride credited earlier) along the
    /// world yaw `heading` at time `t`, with length variance `var_d`.
    pub fn add_stride(&mut self, t: f32, d: f32, heading: f32, var_d: f32, noise: &PdrNoise) {
        self.turn_to(t, heading, noise);
        let (x, y) = (self.pdr.x, self.pdr.y);
        // Kleiner eq. 1–2 with the heading already turned: stride along θ.
        self.pdr.propagate(d, 0.0, var_d, 0.0);
        let s = noise.heading_step_sigma_rad;
        self.pdr
            .add_stride_direction_noise(self.pdr.x - x, self.pdr.y - y, s * s);
        self.distance += d;
    }

    /// Counts a detected step (its stride is added with [`add_stride`](Self::add_stride)).
    pub fn count_step(&mut self) {
        self.steps = self.steps.saturating_add(1);
    }

    /// Turns the PDR heading to the world yaw `heading` (Kleiner eq. 1 with `d = 0`); the
    /// turn's variance is the gyro drift since the previous heading event.
    fn turn_to(&mut self, t: f32, heading: f32, noise: &PdrNoise) {
        let rel = wrap_pi(heading - self.yaw0);
        let alpha = wrap_pi(rel - self.pdr.theta);
        let dt = (t - self.t_event).max(0.0);
        let w = noise.rotation_walk_rad_sqrt_s;
        self.pdr.propagate(0.0, alpha, 0.0, w * w * dt);
        self.t_event = self.t_event.max(t);
    }

    /// Closes the interval at the pulse time `t` with the attitude `rk = R_{W R_k}`.
    /// `bias_var` is the variance of the residual gyro bias (rad²/s²), which drifts the
    /// relative rotation by `b·Δt`.
    pub fn close(&self, t: f32, rk: &Mat3, noise: &PdrNoise, bias_var: f32) -> Displacement {
        let mut pdr = *self;
        let yaw_k = rpy_from_rotation(rk).z;
        pdr.turn_to(t, yaw_k, noise);
        let p = &mut pdr.pdr;
        // Direction error common to all strides of the interval: rotates the whole
        // translation about z (∂/∂e = (−y, x)).
        let c = noise.heading_common_sigma_rad;
        let (x, y) = (p.x, p.y);
        p.add_stride_direction_noise(x, y, c * c);

        // Error vector e = [x, y, z (level frame L); Δδθ (world rotation error, 3)].
        let dt = (t - self.t0).max(0.0);
        let w = noise.rotation_walk_rad_sqrt_s;
        let floor_r = noise.rotation_floor_rad * noise.rotation_floor_rad;
        let tf = noise.translation_floor_m * noise.translation_floor_m;
        let mut c6 = Mat6::zeros();
        c6[(0, 0)] = p.cov[(0, 0)] + tf;
        c6[(0, 1)] = p.cov[(0, 1)];
        c6[(1, 0)] = p.cov[(1, 0)];
        c6[(1, 1)] = p.cov[(1, 1)] + tf;
        let vz = noise.vertical_sigma_m + noise.vertical_per_m * libm::fabsf(self.distance);
        c6[(2, 2)] = vz * vz + tf;
        let drift = bias_var.max(0.0) * dt * dt;
        c6[(3, 3)] = w * w * dt + floor_r + drift;
        c6[(4, 4)] = w * w * dt + floor_r + drift;
        c6[(5, 5)] = p.cov[(2, 2)] + floor_r + drift;
        // The device turns about the walker, not about itself: a turn of Δyaw moves it by
        // up to lever·|Δyaw| sideways, and a start or stop within the interval may have
        // moved it without a detected step.
        // The device held `lever_arm_m` ahead of the turning axis moves along the chord,
        // 2 L |sin(Δyaw / 2)|, not the arc L |Δyaw| (0.7 m, not 1.1 m, for a turn-around).
        // Where the walker pivots is unknown (about the body, or about the device held
        // over a spot), so the chord is noise, not a mean displacement.
        let lever = 2.0 * noise.lever_arm_m * libm::fabsf(libm::sinf(0.5 * p.theta));
        // A start or stop without a detected step may move the device; standing through
        // the interval leaves only the hand's sway.
        let undetected = match (self.steps, self.standing) {
            (0, true) => noise.standing_motion_m,
            (0, false) => noise.undetected_motion_m,
            _ => 0.0,
        };
        let extra = lever * lever + undetected * undetected;
        c6[(0, 0)] += extra;
        c6[(1, 1)] += extra;
        for i in 0..2 {
            c6[(i, 5)] = p.cov[(i, 2)];
            c6[(5, i)] = p.cov[(2, i)];
        }

        // Mean: the level-frame translation seen from R_{k-1}: t_R = R_{k-1}ᵀ Rz(yaw_{k-1}) t_L.
        let t_map = self.r0.transpose() * rot_z(self.yaw0);
        let translation = t_map * Vec3::new(p.x, p.y, 0.0);
        // Rotation: rel = R_{k-1}ᵀ R_k. With world-frame errors δ_{k-1}, δ_k,
        // R̂_{k-1}ᵀ R̂_k ≈ rel · exp([R_kᵀ (δ_k − δ_{k-1})]×), so the rpy error is
        // J_b R_kᵀ Δδ with J_b = ∂rpy(rel · R(b))/∂b at b = 0 (b ≈ rotation vector there).
        let rel = self.r0.transpose() * rk;
        let rel_rpy = rpy_from_rotation(&rel);
        let (_, _, jb) = compose_rpy(&rel_rpy, &Rpy::zeros());
        let j_rot = jb * rk.transpose();
        let mut b = Mat6::zeros();
        b.fixed_view_mut::<3, 3>(0, 0).copy_from(&t_map);
        b.fixed_view_mut::<3, 3>(3, 3).copy_from(&j_rot);
        let q = b * c6 * b.transpose();
        Displacement {
            translation,
            rotation: rel_rpy,
            cov: 0.5 * (q + q.transpose()),
            steps: self.steps,
            distance_m: self.distance,
            absolute: Vec3::zeros(),
            absolute_cov: Mat3::zeros(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rotation_from_rpy;

    #[test]
    fn straight_steps_give_translation_and_closed_form_covariance() {
        let noise = PdrNoise {
            heading_common_sigma_rad: 0.0,
            rotation_walk_rad_sqrt_s: 0.0,
            rotation_floor_rad: 0.0,
            translation_floor_m: 0.0,
            undetected_motion_m: 0.0,
            ..PdrNoise::default()
        };
        // Level device facing yaw 1.0, walks 3 steps of 0.6 m along yaw 1.0.
        let r0 = rotation_from_rpy(&Rpy::new(0.0, 0.0, 1.0));
        let mut iv = Interval::new(0.0, r0);
        let var_d = (0.05f32 * 0.6).powi(2);
        for k in 0..3 {
            iv.add_stride(0.5 * k as f32, 0.6, 1.0, var_d, &noise);
            iv.count_step();
        }
        let d = iv.close(1.5, &r0, &noise, 0.0);
        assert!((d.translation - Vec3::new(1.8, 0.0, 0.0)).norm() < 1e-5);
        assert!(d.rotation.norm() < 1e-6);
        assert_eq!(d.steps, 3);
        // Along track: 3 var_d; across: Σ d² σ_step² = 3 · 0.36 · σ².
        let s = noise.heading_step_sigma_rad;
        assert!((d.cov[(0, 0)] - 3.0 * var_d).abs() < 1e-7);
        assert!((d.cov[(1, 1)] - 3.0 * 0.36 * s * s).abs() < 1e-6);
        assert!(d.cov[(0, 1)].abs() < 1e-7);
        assert!((d.cov[(2, 2)] - (0.03f32 + 0.05 * 1.8).powi(2)).abs() < 1e-6);
    }

    #[test]
    fn heading_drift_correlates_translation_and_rotation() {
        let noise = PdrNoise {
            heading_common_sigma_rad: 0.0,
            heading_step_sigma_rad: 0.0,
            rotation_floor_rad: 0.0,
            translation_floor_m: 0.0,
            undetected_motion_m: 0.0,
            ..PdrNoise::default()
        };
        let r0 = Mat3::identity();
        let mut iv = Interval::new(0.0, r0);
        iv.add_stride(0.5, 1.0, 0.0, 0.0, &noise);
        let d = iv.close(1.0, &r0, &noise, 0.0);
        // θ drift var q·0.5 before the stride: y var = d² q 0.5, yaw var = q·1.0,
        // cov(y, yaw) = d q 0.5.
        let q = noise.rotation_walk_rad_sqrt_s.powi(2);
        assert!((d.cov[(1, 1)] - 0.5 * q).abs() < 1e-9);
        assert!((d.cov[(5, 5)] - q).abs() < 1e-9);
        assert!((d.cov[(1, 5)] - 0.5 * q).abs() < 1e-9);
        assert!((d.cov[(5, 1)] - d.cov[(1, 5)]).abs() < 1e-12);
    }

    #[test]
    fn rotation_and_tilted_translation() {
        let noise = PdrNoise::default();
        let r0 = rotation_from_rpy(&Rpy::new(0.05, 0.2, -0.5));
        let rk = rotation_from_rpy(&Rpy::new(-0.02, 0.15, 0.3));
        let mut iv = Interval::new(0.0, r0);
        iv.add_stride(0.4, 0.7, -0.5, 0.0, &noise);
        let d = iv.close(0.9, &rk, &noise, 0.0);
        let rel = r0.transpose() * rk;
        let back = rotation_from_rpy(&d.rotation);
        assert!((back - rel).abs().max() < 1e-5);
        // Translation: 0.7 m along the world heading −0.5, seen from the tilted R_{k-1}.
        let t_w = Vec3::new(0.7 * (-0.5f32).cos(), 0.7 * (-0.5f32).sin(), 0.0);
        assert!((d.translation - r0.transpose() * t_w).norm() < 1e-5);
        // Q is symmetric positive semi-definite.
        let e = d.cov.symmetric_eigenvalues();
        assert!(e.min() > -1e-9, "{e:?}");
    }

    #[test]
    fn standing_and_turning_without_steps_have_their_own_noise() {
        let noise = PdrNoise {
            translation_floor_m: 0.0,
            heading_common_sigma_rad: 0.0,
            ..PdrNoise::default()
        };
        let r0 = Mat3::identity();
        let horizontal = |d: &Displacement| d.cov[(0, 0)] + d.cov[(1, 1)];
        // No step, not known to be standing: a start or stop may have moved the device.
        let iv = Interval::new(0.0, r0);
        let d = iv.close(1.0, &r0, &noise, 0.0);
        let u = noise.undetected_motion_m;
        assert!(
            (horizontal(&d) - 2.0 * u * u).abs() < 1e-6,
            "{}",
            horizontal(&d)
        );
        // Stood through: the hand's sway only.
        let mut iv = Interval::new(0.0, r0);
        iv.mark_standing();
        let d = iv.close(1.0, &r0, &noise, 0.0);
        let s = noise.standing_motion_m;
        assert!(
            (horizontal(&d) - 2.0 * s * s).abs() < 1e-6,
            "{}",
            horizontal(&d)
        );
        assert!(d.translation.norm() < 1e-6);
        // A turn-around on the spot: the device 0.35 m ahead of the turning axis may
        // have moved by the chord 2 L sin(θ/2) = 0.7 m (per horizontal axis), not the arc.
        let rk = rotation_from_rpy(&Rpy::new(0.0, 0.0, core::f32::consts::PI - 1e-3));
        let mut iv = Interval::new(0.0, r0);
        iv.mark_standing();
        let d = iv.close(1.0, &rk, &noise, 0.0);
        let chord = 2.0 * noise.lever_arm_m * libm::sinf(0.5 * (core::f32::consts::PI - 1e-3));
        let expect = 2.0 * (chord * chord + s * s);
        assert!(
            (horizontal(&d) - expect).abs() < 1e-3 * expect,
            "{} {expect}",
            horizontal(&d)
        );
    }
}
