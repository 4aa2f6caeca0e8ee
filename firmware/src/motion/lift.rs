//! Absolute vertical excursions from the accelerometer: a brisk lift-and-lower of the
//! device while standing (issue 6, "absolute range in fine search").
//!
//! Dead reckoning knows the walked distance only up to the walk-long scale factor, and the
//! dipole field is invariant under `r → s·r, m → s³·m`: near the victim the range (hence
//! the depth) is only as good as the step-length calibration. A short vertical motion of
//! the device, double-integrated from the world-vertical acceleration, is an *absolute*
//! displacement: over ~1–2 s between two zero-velocity instants the integration error is
//! a few centimetres, while |H| changes steeply with height near the victim.
//!
//! [`LiftTracker`] integrates the vertical velocity and position while the walker stands.
//! Whenever the device has been still for [`LiftConfig::zupt_s`] (zero-velocity update,
//! ZUPT), the velocity is reset; if it moved since the previous ZUPT, the residual
//! velocity (a constant-bias drift) is also taken out of the position. The track is
//! continuous across ZUPTs, and [`LiftTracker::take`] samples it at the pulse times: the
//! vertical position change between two pulses, with its variance.
//!
//! Walking does not move the device vertically on average (the step bounce comes back to
//! the same height at rest), so the track is frozen while walking and resumes once the
//! device has been still for [`LiftConfig::zupt_s`] after the walk ("settling", with
//! [`WALK_HEIGHT_SIGMA_M`] for the walk's unmeasured height): a rescuer who stops and
//! then lowers the receiver has the lowering measured even though the interval since the
//! previous pulse began with steps. A manoeuvre that starts before the device settled
//! (its start unmeasured) drops the interval.

/// Height uncertainty (m, 1σ) of the device after a walk relative to before it: the step
/// bounce is ≈ 2 cm and comes back to rest at the same height.
pub const WALK_HEIGHT_SIGMA_M: f32 = 0.02;

/// Tuning of the lift tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiftConfig {
    /// |vertical acceleration − bias| (m/s²) above which the device counts as moving.
    pub move_acc_m_s2: f32,
    /// |vertical acceleration − bias| (m/s²) below which the device counts as still.
    pub quiet_acc_m_s2: f32,
    /// Time still (s) that makes a zero-velocity update.
    pub zupt_s: f32,
    /// Longest manoeuvre between two zero-velocity updates (s); a longer one has drifted
    /// and is dropped.
    pub max_s: f32,
    /// Residual vertical accelerometer bias after its estimate while still (m/s², 1σ).
    pub bias_sigma_m_s2: f32,
    /// Accelerometer velocity random walk (m/s/√s): per-sample σ × √(sample period).
    pub velocity_walk: f32,
    /// Time constant of the vertical-bias estimate while still (s).
    pub bias_tau_s: f32,
}

impl Default for LiftConfig {
    fn default() -> Self {
        Self {
            move_acc_m_s2: 0.5,
            quiet_acc_m_s2: 0.25,
            zupt_s: 0.3,
            max_s: 4.0,
            bias_sigma_m_s2: 0.01,
            velocity_walk: 0.005,
            bias_tau_s: 0.5,
        }
    }
}

/// Vertical track of the device while standing (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiftTracker {
    cfg: LiftConfig,
    /// Vertical bias of the world-vertical acceleration, estimated while still (m/s²).
    bias: f32,
    /// Vertical position of the track (m, arbitrary origin) and velocity (m/s).
    z: f32,
    v: f32,
    /// Time since the last zero-velocity update (s).
    tau: f32,
    /// Time continuously still (s).
    quiet_s: f32,
    /// The device moved since the last zero-velocity update.
    moved: bool,
    /// Position at the last zero-velocity update.
    z_anchor: f32,
    /// Position and its error variance at the last pulse.
    z_pulse: f32,
    e_pulse: f32,
    /// Variance of the manoeuvres completed since the last pulse.
    carried_var: f32,
    /// A manoeuvre touched the interval since the last pulse.
    touched: bool,
    /// The interval since the last pulse is usable (no gap, no manoeuvre started before
    /// the device settled, none too long).
    valid: bool,
    /// After a walk, waiting for the device to be still before integrating again.
    settling: bool,
    /// The walker walked since the last pulse.
    walked: bool,
    /// Part of the manoeuvre under way was handed out at a pulse.
    open_out: bool,
}

impl LiftTracker {
    /// A tracker at rest.
    pub const fn new(cfg: LiftConfig) -> Self {
        Self {
            cfg,
            bias: 0.0,
            z: 0.0,
            v: 0.0,
            tau: 0.0,
            quiet_s: 0.0,
            moved: false,
            z_anchor: 0.0,
            z_pulse: 0.0,
            e_pulse: 0.0,
            carried_var: 0.0,
            touched: false,
            valid: false,
            settling: true,
            walked: false,
            open_out: false,
        }
    }

    /// Position error variance (m²) after `tau` s of integration from a zero velocity:
    /// residual bias `½ b τ²` and velocity random walk `q τ³ / 3`.
    fn drift_var(&self, tau: f32) -> f32 {
        let b = 0.5 * self.cfg.bias_sigma_m_s2 * tau * tau;
        let q = self.cfg.velocity_walk * self.cfg.velocity_walk;
        b * b + q * tau * tau * tau / 3.0
    }

    /// One sample: `dt` (s) since the previous one, world-vertical acceleration
    /// `a_vertical` (specific force minus g, m/s²), and whether the walker stands (no
    /// steps under way). Walking freezes the track until the device is still again; bad
    /// samples invalidate the interval up to the next pulse.
    pub fn update(&mut self, dt: f32, a_vertical: f32, standing: bool) {
        let dt_ok = dt.is_finite() && dt > 0.0;
        if !dt_ok || !a_vertical.is_finite() {
            self.valid = false;
            self.stop();
            return;
        }
        if !standing {
            // The height is taken as unchanged over the walk (see the module docs).
            if self.moved {
                if self.open_out {
                    // A manoeuvre handed out in part, then cut short by steps: its end is
                    // not measured.
                    self.valid = false;
                } else {
                    // The start of the walk (its first dip before the step is detected):
                    // part of the walk, not a manoeuvre.
                    self.z = self.z_anchor;
                }
            }
            self.walked = true;
            self.settling = true;
            self.quiet_s = 0.0;
            self.stop();
            return;
        }
        let a = a_vertical - self.bias;
        if self.settling {
            self.settle(dt, a);
            return;
        }
        self.tau += dt;
        let v0 = self.v;
        self.v += a * dt;
        self.z += 0.5 * (v0 + self.v) * dt;
        if libm::fabsf(a) > self.cfg.move_acc_m_s2 {
            self.moved = true;
        }
        if self.still_long_enough(dt, a) {
            // Zero-velocity update.
            if self.moved {
                // A constant bias grows the velocity error linearly: half of the final
                // velocity error times the duration is the position error.
                self.z -= 0.5 * self.v * self.tau;
                self.carried_var += 0.25 * self.drift_var(self.tau);
                self.touched = true;
            } else {
                self.z = self.z_anchor;
                let k = (dt / self.cfg.bias_tau_s.max(dt)).min(1.0);
                self.bias += k * (a_vertical - self.bias);
            }
            self.stop();
        } else if self.tau > self.cfg.max_s {
            self.valid = false;
            self.stop();
        }
    }

    /// Counts the time `|a|` (bias-corrected, m/s²) stays below the quiet threshold;
    /// true once it has lasted a zero-velocity update's [`LiftConfig::zupt_s`].
    fn still_long_enough(&mut self, dt: f32, a: f32) -> bool {
        if libm::fabsf(a) < self.cfg.quiet_acc_m_s2 {
            self.quiet_s += dt;
        } else {
            self.quiet_s = 0.0;
        }
        self.quiet_s >= self.cfg.zupt_s
    }

    /// After a walk: wait for [`LiftConfig::zupt_s`] of stillness before integrating; a
    /// manoeuvre under way meanwhile has an unmeasured start and drops the interval.
    fn settle(&mut self, dt: f32, a: f32) {
        if libm::fabsf(a) > self.cfg.move_acc_m_s2 {
            self.valid = false;
        }
        if self.still_long_enough(dt, a) {
            self.settling = false;
            self.quiet_s = 0.0;
            self.stop();
        }
    }

    /// Drops the interval up to the next pulse (e.g. after a gap in the IMU stream).
    pub fn interrupt(&mut self) {
        self.valid = false;
        self.stop();
    }

    /// Restart the integration at rest at the current position.
    fn stop(&mut self) {
        self.open_out = false;
        self.v = 0.0;
        self.tau = 0.0;
        self.moved = false;
        self.z_anchor = self.z;
    }

    /// Whether a manoeuvre is under way.
    pub fn is_moving(&self) -> bool {
        self.moved
    }

    /// At a pulse: the vertical position change (m, up positive) since the previous pulse
    /// and its variance (m²), when a manoeuvre touched the interval and the walker stood
    /// throughout; then a new interval starts.
    pub fn take(&mut self) -> Option<(f32, f32)> {
        let open = if self.moved {
            self.drift_var(self.tau)
        } else {
            0.0
        };
        let walk = if self.walked {
            WALK_HEIGHT_SIGMA_M * WALK_HEIGHT_SIGMA_M
        } else {
            0.0
        };
        let out = (self.valid && (self.touched || self.moved))
            .then_some((
                self.z - self.z_pulse,
                self.e_pulse + self.carried_var + open + walk,
            ))
            .filter(|(dz, var)| dz.is_finite() && var.is_finite());
        self.z_pulse = self.z;
        self.e_pulse = open;
        self.carried_var = 0.0;
        self.touched = self.moved;
        self.open_out = self.moved;
        self.valid = true;
        self.walked = false;
        out
    }

    /// As [`LiftTracker::take`], but only the manoeuvres completed (closed by a
    /// zero-velocity update) by now: one under way is left for a later pulse, and
    /// dropped as part of the walk if steps follow it (the first dip of a walk is seen
    /// before its step is detected). For walking, where only a deliberate lift or
    /// lowering is to be measured.
    pub fn take_closed(&mut self) -> Option<(f32, f32)> {
        if !self.moved {
            return self.take();
        }
        let walk = if self.walked {
            WALK_HEIGHT_SIGMA_M * WALK_HEIGHT_SIGMA_M
        } else {
            0.0
        };
        let out = (self.valid && self.touched)
            .then_some((
                self.z_anchor - self.z_pulse,
                self.e_pulse + self.carried_var + walk,
            ))
            .filter(|(dz, var)| dz.is_finite() && var.is_finite());
        self.z_pulse = self.z_anchor;
        self.e_pulse = 0.0;
        self.carried_var = 0.0;
        self.touched = false;
        self.valid = true;
        self.walked = false;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::PI;

    /// Vertical position of a raised-cosine lift of `height` over `period` s starting at
    /// `t0` (up, then down).
    fn lift_z(t: f32, t0: f32, height: f32, period: f32) -> f32 {
        let u = ((t - t0) / period).clamp(0.0, 1.0);
        0.5 * height * (1.0 - libm::cosf(2.0 * PI * u))
    }

    fn lift_acc(t: f32, t0: f32, height: f32, period: f32) -> f32 {
        let u = (t - t0) / period;
        if (0.0..=1.0).contains(&u) {
            let w = 2.0 * PI / period;
            0.5 * height * w * w * libm::cosf(2.0 * PI * u)
        } else {
            0.0
        }
    }

    /// Runs a lift through the tracker at 100 Hz with a constant acceleration bias and a
    /// deterministic pseudo-noise; pulses at `pulses`; returns what `take` gave.
    fn run(bias: f32, noise: f32, pulses: &[f32]) -> [Option<(f32, f32)>; 4] {
        let mut tr = LiftTracker::new(LiftConfig::default());
        let mut out = [None; 4];
        let mut next = 0;
        let mut seed = 12345u32;
        for k in 1..800 {
            let t = k as f32 * 0.01;
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let n = noise * ((seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 3.4;
            tr.update(0.01, lift_acc(t, 2.0, 0.4, 2.0) + bias + n, true);
            if next < pulses.len() && t >= pulses[next] - 1e-4 {
                out[next] = tr.take();
                next += 1;
            }
        }
        out
    }

    #[test]
    fn a_lift_sampled_at_the_pulses_gives_the_height_changes() {
        // Pulses before, at the top, after the lift and later.
        let r = run(0.0, 0.0, &[1.5, 3.0, 5.0, 7.0]);
        assert_eq!(r[0], None, "nothing happened before the lift");
        let (up, var_up) = r[1].unwrap();
        assert!((up - lift_z(3.0, 2.0, 0.4, 2.0)).abs() < 0.01, "up {up}");
        assert!(var_up > 0.0 && var_up.sqrt() < 0.05);
        let (down, var_down) = r[2].unwrap();
        assert!((down + 0.4).abs() < 0.01, "down {down}");
        assert!(var_down.sqrt() < 0.05);
        assert_eq!(r[3], None, "standing still afterwards: no absolute part");
    }

    #[test]
    fn a_bias_is_estimated_while_still_and_noise_stays_within_sigma() {
        let r = run(0.08, 0.05, &[1.5, 3.0, 5.0, 7.0]);
        let (up, var_up) = r[1].unwrap();
        assert!((up - 0.4).abs() < 3.0 * var_up.sqrt() + 0.01, "up {up}");
        let (down, var_down) = r[2].unwrap();
        assert!(
            (down + 0.4).abs() < 3.0 * var_down.sqrt() + 0.01,
            "down {down}"
        );
    }

    #[test]
    fn a_whole_lift_between_two_pulses_nets_zero() {
        let r = run(0.0, 0.0, &[1.5, 5.0, 7.0, 9.0]);
        let (dz, var) = r[1].unwrap();
        assert!(dz.abs() < 0.01 && var > 0.0, "dz {dz}");
    }

    #[test]
    fn walking_invalidates_the_interval() {
        let mut tr = LiftTracker::new(LiftConfig::default());
        for k in 1..300 {
            let t = k as f32 * 0.01;
            tr.update(0.01, lift_acc(t, 1.0, 0.4, 1.0), k < 150);
        }
        assert_eq!(tr.take(), None);
        // Standing still afterwards: nothing to report either.
        for _ in 0..100 {
            tr.update(0.01, 0.0, true);
        }
        assert_eq!(tr.take(), None);
    }

    #[test]
    fn a_too_long_manoeuvre_is_dropped() {
        let mut tr = LiftTracker::new(LiftConfig::default());
        tr.take();
        for _ in 0..50 {
            tr.update(0.01, 0.0, true);
        }
        // A slow, steady push (never still) for longer than `max_s`.
        for _ in 0..500 {
            tr.update(0.01, 0.6, true);
        }
        assert_eq!(tr.take(), None);
    }

    /// Vertical acceleration of a minimum-jerk move of `dz` over `period` s from `t0`.
    fn min_jerk_acc(t: f32, t0: f32, dz: f32, period: f32) -> f32 {
        let u = (t - t0) / period;
        if (0.0..=1.0).contains(&u) {
            dz / (period * period) * (60.0 * u - 180.0 * u * u + 120.0 * u * u * u)
        } else {
            0.0
        }
    }

    /// Walks (a 2.6 m/s² bounce) until t = 1 s, then stands and lowers the receiver
    /// 0.8 m over 1 s from `lower_at`, for `samples` 10 ms samples; `at_sample` sees the
    /// tracker after every one.
    fn walk_then_lower(
        lower_at: f32,
        samples: usize,
        mut at_sample: impl FnMut(usize, &mut LiftTracker),
    ) -> LiftTracker {
        let mut tr = LiftTracker::new(LiftConfig::default());
        for k in 1..samples {
            let t = k as f32 * 0.01;
            let walking = t < 1.0;
            let a = if walking {
                2.6 * libm::cosf(2.0 * PI * 1.8 * t)
            } else {
                min_jerk_acc(t, lower_at, -0.8, 1.0)
            };
            tr.update(0.01, a, !walking);
            at_sample(k, &mut tr);
        }
        tr
    }

    #[test]
    fn a_lowering_right_after_a_walk_is_measured_whole() {
        // A pulse during the walk; settled, the receiver is lowered from t = 1.6 s.
        let mut got = None;
        let mut tr = walk_then_lower(1.6, 400, |k, tr| {
            if k == 50 {
                assert_eq!(tr.take(), None, "walking alone is no manoeuvre");
            }
        });
        if let Some((dz, var)) = tr.take() {
            got = Some((dz, var));
            assert!((dz + 0.8).abs() < 0.01, "dz {dz}");
            // The walk's unmeasured height is in the variance.
            assert!(var >= WALK_HEIGHT_SIGMA_M * WALK_HEIGHT_SIGMA_M && var.sqrt() < 0.05);
        }
        assert!(got.is_some(), "the lowering was dropped");
    }

    #[test]
    fn a_move_starting_before_the_device_settled_drops_the_interval() {
        // The lowering starts 0.1 s after the last step: its start is unmeasured.
        let mut tr = walk_then_lower(1.1, 300, |_, _| {});
        assert_eq!(tr.take(), None);
    }

    #[test]
    fn the_first_dip_of_a_walk_is_not_a_manoeuvre_for_take_closed() {
        // Settled, then the first 0.2 s of a step (a dip) before the step detector calls
        // it walking; a pulse falls in the dip.
        let run = |closed: bool| {
            let mut tr = LiftTracker::new(LiftConfig::default());
            for _ in 0..100 {
                tr.update(0.01, 0.0, true);
            }
            let _ = tr.take();
            for k in 0..20 {
                tr.update(0.01, -2.0 * libm::sinf(PI * k as f32 / 20.0), true);
            }
            let mid = if closed { tr.take_closed() } else { tr.take() };
            for _ in 0..50 {
                tr.update(0.01, 0.0, false);
            }
            for _ in 0..100 {
                tr.update(0.01, 0.0, true);
            }
            let after = if closed { tr.take_closed() } else { tr.take() };
            (mid, after)
        };
        let (mid, after) = run(true);
        assert_eq!(mid, None, "a manoeuvre under way is left for later");
        assert_eq!(after, None, "and dropped as part of the walk");
        // The open variant (lift mode) hands the dip out at once.
        let (mid, _) = run(false);
        assert!(mid.is_some_and(|(dz, _)| dz < -0.01), "{mid:?}");
    }
}
