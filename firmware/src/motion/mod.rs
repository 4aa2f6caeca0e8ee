//! The rescuer's own motion from the IMU: attitude, steps, dead reckoning and the
//! displacement between pulses that the estimator consumes (IROS 2006 eq. 4).
//!
//! - [`attitude`]: error-state Kalman filter of roll/pitch/yaw and gyro bias from
//!   acc/gyr/mag, with magnetometer calibration and disturbance rejection.
//! - [`steps`]: step detection on the vertical acceleration, step-length models and the
//!   calibration walk.
//! - [`pdr`]: Kleiner et al. eq. 1–3, the per-step pose and covariance propagation.
//! - [`displacement`]: the per-pulse-interval displacement and its covariance `Q_k`.
//!
//! [`Motion`] ties them together: feed it every IMU sample with [`Motion::on_imu`], and
//! at every pulse take the displacement since the previous pulse with
//! [`Motion::take_displacement`].
//!
//! The walk-long scale error (the step-length calibration error) is correlated over the
//! whole walk and is **not** in the per-interval `Q_k`; [`Motion::scale_sigma`] exposes its
//! relative σ so the estimator can model it as a state.

pub mod attitude;
pub mod displacement;
pub mod lift;
pub mod pdr;
pub mod steps;

pub use attitude::{AttitudeConfig, AttitudeFilter, MagCalibration, static_attitude};
pub use displacement::{Displacement, Interval, Mat6, PdrNoise};
pub use lift::{LiftConfig, LiftTracker};
pub use pdr::PdrPose;
pub use steps::{
    CalibrationResult, StepCalibration, StepDetector, StepDetectorConfig, StepEvent,
    StepLengthModel,
};

use crate::frame::{Rpy, wrap_pi};
use crate::{Mat3, Vec3};
use attitude::GRAVITY;

/// In lift mode, a step this recent (s) means the walker is still finishing the walk.
const LIFT_STEP_GUARD_S: f32 = 0.8;

/// Why an IMU sample or a request was refused (the state is then unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotionError {
    /// A NaN or infinite value.
    #[error("IMU reading NaN or infinite")]
    NonFinite,
    /// A reading at or beyond its sensor's full-scale range.
    #[error("IMU reading at or beyond full scale")]
    Saturated,
    /// The sample's time is not after the previous sample's.
    #[error("IMU sample time not after the previous sample")]
    TimeNotIncreasing,
    /// Too long since the previous sample (s); call [`Motion::resync`] to continue.
    #[error("gap of {dt} s since the previous IMU sample")]
    Gap {
        /// Time since the previous sample, s.
        dt: f32,
    },
    /// A calibration walk with too few steps.
    #[error("calibration walk with too few steps ({steps})")]
    TooFewSteps {
        /// Steps counted.
        steps: u32,
    },
    /// An argument out of its valid range.
    #[error("argument out of its valid range")]
    InvalidArgument,
    /// `finish_calibration` without `start_calibration`.
    #[error("no calibration walk started")]
    NoCalibration,
}

/// Configuration of the motion pipeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionConfig {
    /// The local earth field in W, µT (declination folded in: x is north of W).
    pub earth_field_ut: Vec3,
    /// IMU sample rate, Hz.
    pub imu_hz: f32,
    /// Step-length model.
    pub step_length: StepLengthModel,
    /// Attitude filter tuning.
    pub attitude: AttitudeConfig,
    /// Step detector tuning.
    pub steps: StepDetectorConfig,
    /// Dead-reckoning noise.
    pub noise: PdrNoise,
    /// Magnetometer hard/soft-iron calibration.
    pub mag_calibration: MagCalibration,
    /// Accelerometer full scale, m/s² (a reading with |component| ≥ this is saturated).
    pub acc_range_m_s2: f32,
    /// Gyro full scale, rad/s.
    pub gyr_range_rad_s: f32,
    /// Magnetometer full scale, µT.
    pub mag_range_ut: f32,
    /// Longest accepted time between samples, s.
    pub max_gap_s: f32,
    /// Add the tilt's share of the heading error to the reported yaw variance
    /// ([`Motion::attitude`], [`tilt_heading_var`]).
    pub tilt_heading: bool,
}

impl MotionConfig {
    /// Defaults for a 100 Hz IMU (±16 g, ±2000 °/s, ±4900 µT) with the given earth field and
    /// calibrated step length (`None`: uncalibrated, 0.7 m ± 20 %).
    pub fn new(earth_field_ut: Vec3, step_length_m: Option<f32>) -> Self {
        Self {
            earth_field_ut,
            imu_hz: 100.0,
            step_length: step_length_m
                .filter(|l| l.is_finite() && *l > 0.0)
                .map_or_else(StepLengthModel::uncalibrated, StepLengthModel::calibrated),
            attitude: AttitudeConfig::default(),
            steps: StepDetectorConfig::default(),
            noise: PdrNoise::default(),
            mag_calibration: MagCalibration::identity(),
            acc_range_m_s2: 156.9,
            gyr_range_rad_s: 34.9,
            mag_range_ut: 4900.0,
            max_gap_s: 0.1,
            tilt_heading: true,
        }
    }
}

/// Circular mean of yaw samples (sums of sin and cos).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct YawMean {
    s: f32,
    c: f32,
}

impl YawMean {
    fn add(&mut self, yaw: f32) {
        self.s += libm::sinf(yaw);
        self.c += libm::cosf(yaw);
    }

    fn mean(&self, fallback: f32) -> f32 {
        if self.s * self.s + self.c * self.c > 1e-12 {
            libm::atan2f(self.s, self.c)
        } else {
            fallback
        }
    }
}

/// The heading variance a tilt error causes in a tilt-compensated magnetometer heading,
/// `tan²(dip) · max(σ²_roll, σ²_pitch)` (rad²; 0 for a field without a horizontal
/// component): a tilt δ about the horizontal axis along the field moves its vertical
/// component `B_z` by `δ · B_z` across it, turning the heading by `δ · B_z / B_h`.
pub fn tilt_heading_var(earth_field_ut: &Vec3, rpy_cov: &Mat3) -> f32 {
    let b = earth_field_ut;
    let b_h = libm::sqrtf(b.x * b.x + b.y * b.y);
    if b_h.is_nan() || b_h <= 1e-3 * b.norm() {
        return 0.0;
    }
    let tan_dip = b.z / b_h;
    let tilt = rpy_cov[(0, 0)].max(rpy_cov[(1, 1)]).max(0.0);
    tan_dip * tan_dip * tilt
}

/// State once the first sample has arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Running {
    att: AttitudeFilter,
    interval: Interval,
    t_last: f32,
    rate: Vec3,
    yaw_mean: YawMean,
    last_length: f32,
    period: f32,
    /// The walker was standing when the current interval began (no step under way,
    /// pending or overdue).
    standing_at_open: bool,
    /// Time the vertical acceleration has stayed quiet (s, see
    /// [`StepDetectorConfig::quiet_m_s2`]).
    quiet_s: f32,
}

/// Attitude, step detection and dead reckoning from IMU samples; displacement per pulse.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    cfg: MotionConfig,
    det: StepDetector,
    run: Option<Running>,
    total_steps: u32,
    weinberg_sum: f32,
    distance_m: f32,
    calibration: Option<StepCalibration>,
    lift: LiftTracker,
    lift_mode: bool,
    /// Lift mode held after it was turned off until the manoeuvre under way ends.
    lift_hold: bool,
    /// Sum of the accelerometer-measured vertical displacements handed out so far (m, up
    /// positive): the device's height change since the start (see [`Motion::vertical_m`]).
    vertical_m: f32,
}

/// A pulse's cut of the motion when several victims share it ([`Motion::take_split`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitDisplacement {
    /// The motion since the previous cut, without the step in progress.
    pub cut: Displacement,
    /// The step in progress credited at the pulse, from `R_k` to `R_k` moved.
    pub partial: Displacement,
    /// Its inverse: where the pulse's own victim's next motion starts.
    pub back: Displacement,
    /// The walker stood through the cut (for the victim's interval floors).
    pub standing: bool,
}

impl SplitDisplacement {
    /// Before the first IMU sample: an unknown cut (σ 1 m, 0.5 rad), no step in progress.
    fn unknown() -> Self {
        let zero = Displacement::still(0.0, 0.0);
        Self {
            cut: Displacement::still(1.0, 0.5),
            partial: zero,
            back: zero,
            standing: false,
        }
    }
}

/// An accelerometer lift (`(dz, var)`: the world-vertical excursion and its variance)
/// attached to a displacement as an absolute, unscaled part, in the axes of the interval's
/// start `R_{k-1}`.
fn attach_lift(lift: Option<(f32, f32)>, interval: &Interval, d: &mut Displacement) {
    let Some((dz, var)) = lift else { return };
    // The world-vertical excursion in R_{k-1} axes: R_{k-1}ᵀ e_z = row 2 of R_{k-1}.
    let r0 = interval.start_rotation();
    let e = Vec3::new(r0[(2, 0)], r0[(2, 1)], r0[(2, 2)]);
    d.absolute = e * dz;
    // Rank one, plus 1 mm² so that the correlations stay within [-1, 1] in f32.
    d.absolute_cov = e * e.transpose() * var.max(0.0) + Mat3::identity() * 1e-6;
}

/// The lift tracker's vertical excursion since the previous pulse, also added to the
/// running height change `vertical_m` ([`Motion::vertical_m`]). `open`: in lift mode, a
/// manoeuvre under way is handed out in part (the pulse at the top of a lift sees it);
/// otherwise only completed ones (see [`LiftTracker::take_closed`]).
fn take_lift(lift: &mut LiftTracker, vertical_m: &mut f32, open: bool) -> Option<(f32, f32)> {
    let out = if open {
        lift.take()
    } else {
        lift.take_closed()
    };
    if let Some((dz, _)) = out {
        *vertical_m += dz;
    }
    out
}

/// Where a pulse cuts the running interval.
struct Cut {
    t: f32,
    rk: Mat3,
    yaw_now: f32,
    /// The walker stood through the whole interval (no step at its start, none since).
    standing: bool,
    partial: f32,
    var: f32,
    bias_var: f32,
}

impl Motion {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        self.det.rebase(shift_s);
        if let Some(r) = self.run.as_mut() {
            r.t_last -= shift_s;
            r.interval.rebase(shift_s);
        }
    }

    /// A pipeline waiting for its first IMU sample.
    pub fn new(cfg: MotionConfig) -> Self {
        Self {
            det: StepDetector::new(cfg.steps, cfg.imu_hz),
            cfg,
            run: None,
            total_steps: 0,
            weinberg_sum: 0.0,
            distance_m: 0.0,
            calibration: None,
            lift: LiftTracker::new(LiftConfig::default()),
            lift_mode: false,
            lift_hold: false,
            vertical_m: 0.0,
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &MotionConfig {
        &self.cfg
    }

    /// One IMU sample: time (s), specific force (m/s²), rate (rad/s), flux density (µT),
    /// all in the body frame. On error the state is unchanged.
    pub fn on_imu(
        &mut self,
        t: f32,
        acc: &Vec3,
        gyr: &Vec3,
        mag: &Vec3,
    ) -> Result<(), MotionError> {
        self.on_imu_sample(t, acc, gyr, Some(mag))
    }

    /// Like [`on_imu`](Self::on_imu) with an optional magnetometer reading (a sample
    /// without one propagates and corrects tilt only).
    pub fn on_imu_sample(
        &mut self,
        t: f32,
        acc: &Vec3,
        gyr: &Vec3,
        mag: Option<&Vec3>,
    ) -> Result<(), MotionError> {
        // A magnetometer axis at or beyond full scale loses this sample's heading aid
        // only: the accelerometer and gyro readings are still good (the replay adapter
        // does the same, so the board and a replay of its log agree).
        let range = self.cfg.mag_range_ut;
        let mag = mag.filter(|m| !m.iter().any(|x| x.is_finite() && libm::fabsf(*x) >= range));
        self.check(t, acc, gyr, mag)?;
        let mut next = self.clone();
        next.apply(t, acc, gyr, mag);
        let ok = next.run.as_ref().is_some_and(|r| {
            r.att.rpy().iter().all(|x| x.is_finite())
                && r.att.gyro_bias().iter().all(|x| x.is_finite())
                && r.interval.pose().cov.iter().all(|x| x.is_finite())
        }) && next.distance_m.is_finite();
        if !ok {
            return Err(MotionError::NonFinite);
        }
        *self = next;
        Ok(())
    }

    fn check(&self, t: f32, acc: &Vec3, gyr: &Vec3, mag: Option<&Vec3>) -> Result<(), MotionError> {
        let finite = |v: &Vec3| v.iter().all(|x| x.is_finite());
        if !t.is_finite() || !finite(acc) || !finite(gyr) || !mag.is_none_or(finite) {
            return Err(MotionError::NonFinite);
        }
        let within = |v: &Vec3, r: f32| v.iter().all(|x| libm::fabsf(*x) < r);
        // A saturated magnetometer was already dropped by `on_imu_sample`.
        if !within(acc, self.cfg.acc_range_m_s2) || !within(gyr, self.cfg.gyr_range_rad_s) {
            return Err(MotionError::Saturated);
        }
        if let Some(r) = &self.run {
            let dt = t - r.t_last;
            if dt <= 0.0 {
                return Err(MotionError::TimeNotIncreasing);
            }
            if dt > self.cfg.max_gap_s {
                return Err(MotionError::Gap { dt });
            }
        }
        Ok(())
    }

    fn apply(&mut self, t: f32, acc: &Vec3, gyr: &Vec3, mag: Option<&Vec3>) {
        let mag = mag.map(|m| self.cfg.mag_calibration.apply(m));
        let Some(run) = self.run.as_mut() else {
            let att = AttitudeFilter::new(
                self.cfg.attitude,
                self.cfg.earth_field_ut,
                acc,
                &mag.unwrap_or_else(Vec3::zeros),
            );
            self.run = Some(Running {
                interval: Interval::new(t, att.rotation()),
                att,
                t_last: t,
                rate: gyr - att.gyro_bias(),
                yaw_mean: YawMean::default(),
                last_length: self.cfg.step_length.length(0.0),
                period: 1.0 / 1.8,
                standing_at_open: false,
                quiet_s: 0.0,
            });
            return;
        };
        let dt = t - run.t_last;
        run.att.update(dt, acc, gyr, mag.as_ref());
        run.t_last = t;
        run.rate = run.att.corrected_rate(gyr);
        let r = run.att.rotation();
        let yaw = rpy_yaw(&r);
        run.yaw_mean.add(yaw);
        // Vertical specific force in W minus g: the step's vertical acceleration.
        let a_vertical = (r * acc).z - GRAVITY;
        run.quiet_s = if libm::fabsf(a_vertical) < self.cfg.steps.quiet_m_s2 {
            run.quiet_s + dt.max(0.0)
        } else {
            0.0
        };
        if run.quiet_s >= self.cfg.steps.stop_quiet_s {
            // Standing: the next step's heading is the yaw from when the walk starts, not
            // the mean over the stand (a turn on the spot before the step would bend it
            // by up to half the turn: 90° sideways for a turn-around).
            run.yaw_mean = YawMean::default();
        }
        // Standing: no step under way. In lift mode (the walker was asked to stand and
        // lift), a step within the last `LIFT_STEP_GUARD_S` still means walking (the
        // walk finishing after the prompt); otherwise the lift's vertical acceleration
        // must not be taken for steps.
        let pending = self.det.pending_peak().is_some();
        let since_step = self.det.last_step().map_or(f32::INFINITY, |ls| t - ls);
        // A lift under way when the prompt goes off is finished in lift mode.
        if !self.lift_mode && self.lift_hold && !self.lift.is_moving() {
            self.lift_hold = false;
        }
        let lift_mode = self.lift_mode || self.lift_hold;
        let standing = if lift_mode {
            !pending && since_step > LIFT_STEP_GUARD_S
        } else {
            !pending && since_step > self.cfg.steps.max_interval_s
        };
        self.lift.update(dt, a_vertical, standing);
        if lift_mode && standing {
            return;
        }
        let Some(ev) = self.det.update(t, a_vertical) else {
            return;
        };
        let model = self.cfg.step_length;
        let length = model.length(ev.amplitude);
        let heading = run.yaw_mean.mean(yaw);
        run.yaw_mean = YawMean::default();
        // The first step of a walk also carries the start-up (a shorter, weaker first step
        // may go undetected): extra half-step σ.
        let start_up = if ev.period > 0.0 { 0.0 } else { 0.5 * length };
        let rel = self.cfg.noise.step_rel_sigma * length;
        let sd = libm::sqrtf(rel * rel + start_up * start_up);
        run.interval
            .add_stride(ev.t_peak, length, heading, sd * sd, &self.cfg.noise);
        run.interval.count_step();
        run.last_length = length;
        let (lo, hi) = (self.cfg.steps.min_interval_s, self.cfg.steps.max_interval_s);
        if (lo..=hi).contains(&ev.period) {
            run.period += 0.3 * (ev.period - run.period);
        }
        self.total_steps = self.total_steps.saturating_add(1);
        self.weinberg_sum += steps::weinberg_factor(ev.amplitude);
        self.distance_m += length;
    }

    /// The displacement since the previous call (or since the first sample), closed at the
    /// pulse time `t_pulse` (IROS 2006 eq. 4), and a new interval started there.
    ///
    /// The step in progress is credited by the fraction of the step period elapsed since the
    /// last step (taken back from the next interval), so that a pulse between two steps does
    /// not see the walk in quanta of a whole step. Before the first IMU sample it returns
    /// "still" with a σ of 1 m and 0.5 rad. A non-finite `t_pulse` is treated as the last
    /// sample's time.
    pub fn take_displacement(&mut self, t_pulse: f32) -> Displacement {
        let Some(c) = self.cut_at(t_pulse) else {
            return Displacement::still(1.0, 0.5);
        };
        let noise = self.cfg.noise;
        let Some(run) = self.run.as_mut() else {
            return Displacement::still(1.0, 0.5);
        };
        let mut closing = run.interval;
        if c.standing {
            closing.mark_standing();
        }
        if c.partial != 0.0 {
            closing.add_stride(c.t, c.partial, c.yaw_now, c.var, &noise);
        }
        let mut d = closing.close(c.t, &c.rk, &noise, c.bias_var);
        let open = self.lift_mode || self.lift_hold;
        let lift = take_lift(&mut self.lift, &mut self.vertical_m, open);
        attach_lift(lift, &closing, &mut d);
        let mut next = Interval::new(c.t, c.rk);
        if c.partial != 0.0 {
            next.add_stride(c.t, -c.partial, c.yaw_now, c.var, &noise);
        }
        run.interval = next;
        d
    }

    /// [`Motion::take_displacement`] for several victims: the interval is cut at the pulse
    /// *without* the step in progress, which is returned apart (`partial`, in `R_k`
    /// axes) with its inverse (`back`). The pulse's own victim composes `cut ⊕ partial`
    /// (the same motion as `take_displacement`) and starts its next motion from `back`;
    /// every other victim composes `cut` only. So the partial step credited at another
    /// victim's pulse never enters a victim's motion twice (once forward, once back,
    /// with independent variances), and a victim's `Q_k` does not grow with the number
    /// of transmitters heard in between.
    pub fn take_split(&mut self, t_pulse: f32) -> SplitDisplacement {
        let zero = Displacement::still(0.0, 0.0);
        let Some(c) = self.cut_at(t_pulse) else {
            return SplitDisplacement::unknown();
        };
        let noise = self.cfg.noise;
        let Some(run) = self.run.as_mut() else {
            return SplitDisplacement::unknown();
        };
        let mut closing = run.interval;
        if c.standing {
            closing.mark_standing();
        }
        // The per-interval floors (undetected start/stop or the hand's sway, vertical bob,
        // translation and rotation floors) belong to each victim's own interval, not to
        // every cut: added at each of the pulses of several transmitters they grew a
        // victim's Q_k with the number heard in between. The cut is closed without them;
        // the pulse's own victim adds them once for its whole interval
        // (`PdrNoise::interval_floors`, see `victims::VictimBank::step`).
        let floorless = PdrNoise {
            translation_floor_m: 0.0,
            vertical_sigma_m: 0.0,
            rotation_floor_rad: 0.0,
            undetected_motion_m: 0.0,
            standing_motion_m: 0.0,
            ..noise
        };
        let mut cut = closing.close(c.t, &c.rk, &floorless, c.bias_var);
        let open = self.lift_mode || self.lift_hold;
        let lift = take_lift(&mut self.lift, &mut self.vertical_m, open);
        attach_lift(lift, &closing, &mut cut);
        run.interval = Interval::new(c.t, c.rk);
        // The partial step carries its own stride errors only (the floors come once per
        // victim interval, see above).
        let bare = PdrNoise {
            translation_floor_m: 0.0,
            vertical_sigma_m: 0.0,
            rotation_floor_rad: 0.0,
            undetected_motion_m: 0.0,
            heading_common_sigma_rad: 0.0,
            ..noise
        };
        let stride = |d: f32| {
            if c.partial != 0.0 {
                let mut i = Interval::new(c.t, c.rk);
                i.add_stride(c.t, d, c.yaw_now, c.var, &bare);
                i.close(c.t, &c.rk, &bare, 0.0)
            } else {
                zero
            }
        };
        SplitDisplacement {
            cut,
            partial: stride(c.partial),
            back: stride(-c.partial),
            standing: c.standing,
        }
    }

    /// Where and how to cut the running interval at `t_pulse`: the attitude there and the
    /// step in progress (`None` before the first IMU sample).
    fn cut_at(&mut self, t_pulse: f32) -> Option<Cut> {
        let noise = self.cfg.noise;
        let max_gap = self.cfg.max_gap_s;
        let last_step = self.det.last_step();
        let pending = self.det.pending_peak();
        let max_interval = self.cfg.steps.max_interval_s;
        let stop_quiet_s = self.cfg.steps.stop_quiet_s;
        let run = self.run.as_mut()?;
        let t = if t_pulse.is_finite() {
            t_pulse
        } else {
            run.t_last
        };
        // Attitude at the pulse: extrapolate from the last sample with the last rate.
        let ahead = (t - run.t_last).clamp(-max_gap, max_gap);
        let rk = run.att.rotation_ahead(&run.rate, ahead);
        let yaw_now = run.yaw_mean.mean(rpy_yaw(&rk));
        // Where the walker is within the gait at the pulse, in steps from the position the
        // counted steps stand for. A step is counted whole at its acceleration peak, which
        // comes in the middle of the step (the lowest point of the body's bob): walking,
        // the device is half a step behind the count at each peak and catches up over the
        // next half period; a walker who stops completes the step under way, so standing,
        // the count is exact. So, with f the fraction of a step period since the last
        // peak: walking `f − ½` (negative just after a peak: the count runs ahead); the
        // next step's first half (f > ½) is walked only if the walk goes on, an overdue
        // step (1 < f < 2) means slowing down or stopping (between nothing and half a
        // step, a large σ); quiet, or two periods without a step: stopped, nothing. A
        // pending peak stands for `½ + since` (the first half of its step, plus the time
        // since). Crediting `f` from the peak instead ran half a step ahead of the walk
        // whenever a pulse came during a walk and dropped it at the next pulse after the
        // stop: measured in the closed-loop fine search's stop-and-go, +0.08 m forward
        // per interval with steps and −0.13 m per interval standing after them, 2–5 % of
        // the intervals beyond the χ² 99.9 % point.
        let f = match last_step {
            Some(ls) if t - ls < max_interval && run.period > 0.0 => (t - ls) / run.period,
            _ => 2.0,
        };
        let stopped = pending.is_none() && (f >= 2.0 || run.quiet_s >= stop_quiet_s);
        let (frac, sigma_steps) = if let Some(tp) = pending {
            let since = ((t - tp) / run.period.max(0.1)).clamp(0.0, 0.5);
            match last_step {
                Some(_) => (0.5 + since, noise.partial_step_sigma),
                None => (0.5 + since, 0.5),
            }
        } else if stopped {
            (0.0, 0.0)
        } else if f <= 1.0 {
            (f.max(0.0) - 0.5, noise.partial_step_sigma)
        } else {
            (0.25, 0.25)
        };
        let partial = frac * run.last_length;
        let sp = sigma_steps * run.last_length;
        // Standing now: no step pending and none within two step periods (f ≥ 2). An
        // interval stood through from end to end carries the hand's sway only.
        let standing_now = stopped;
        let standing = run.standing_at_open && standing_now && run.interval.steps() == 0;
        run.standing_at_open = standing_now;
        // Residual gyro-bias uncertainty drifts the relative rotation over the interval.
        let pb = run.att.error_cov();
        let bias_var = pb[(3, 3)].max(pb[(4, 4)]).max(pb[(5, 5)]);
        Some(Cut {
            t,
            rk,
            yaw_now,
            standing,
            partial,
            var: sp * sp,
            bias_var,
        })
    }

    /// Roll, pitch, yaw of the body in W (rad) and their covariance (rad²). Before the first
    /// sample: zeros with σ = π.
    ///
    /// The yaw variance includes the heading error a tilt error causes through the field's
    /// vertical component (`tan²(dip) · σ²_tilt`, see [`tilt_heading_var`]): the attitude
    /// filter takes that term as white per-sample noise, which 100 magnetometer updates a
    /// second average away, while a tilt error from walking accelerations lasts seconds.
    /// Measured on `paper` (100 seeds, `hal-sim/examples/imu_att.rs`): yaw error 1.1° RMS,
    /// lag-1 (one pulse) correlation 0.9, against 0.26° declared without this term.
    pub fn attitude(&self) -> (Rpy, Mat3) {
        match &self.run {
            Some(r) => {
                let mut cov = r.att.rpy_cov();
                if self.cfg.tilt_heading {
                    cov[(2, 2)] += tilt_heading_var(&self.cfg.earth_field_ut, &cov);
                }
                (r.att.rpy(), cov)
            }
            None => (
                Rpy::zeros(),
                Mat3::identity() * (core::f32::consts::PI * core::f32::consts::PI),
            ),
        }
    }

    /// The attitude filter, once the first sample has arrived.
    pub fn attitude_filter(&self) -> Option<&AttitudeFilter> {
        self.run.as_ref().map(|r| &r.att)
    }

    /// Relative σ of the walk-long step-length scale error (not in any `Q_k`).
    pub fn scale_sigma(&self) -> f32 {
        self.cfg.step_length.scale_sigma()
    }

    /// Steps detected since the start.
    pub fn total_steps(&self) -> u32 {
        self.total_steps
    }

    /// Distance walked since the start (sum of step lengths), m.
    pub fn total_distance_m(&self) -> f32 {
        self.distance_m
    }

    /// Current step cadence estimate, steps/s (0 before the first sample).
    pub fn cadence_hz(&self) -> f32 {
        self.run
            .as_ref()
            .filter(|r| r.period > 0.0)
            .map_or(0.0, |r| 1.0 / r.period)
    }

    /// Replaces the step-length model (e.g. after a calibration walk).
    pub fn set_step_length_model(&mut self, model: StepLengthModel) {
        self.cfg.step_length = model;
    }

    /// Replaces the magnetometer calibration.
    pub fn set_mag_calibration(&mut self, cal: MagCalibration) {
        self.cfg.mag_calibration = cal;
    }

    /// Continues after a [`MotionError::Gap`]: accepts `t` as the last sample time, inflates
    /// the attitude covariance for the gap and restarts step detection. The steps missed
    /// in the gap are lost (the current interval only knows the walk around it).
    pub fn resync(&mut self, t: f32) -> Result<(), MotionError> {
        let Some(run) = self.run.as_mut() else {
            return Ok(());
        };
        if !t.is_finite() {
            return Err(MotionError::NonFinite);
        }
        if t <= run.t_last {
            return Err(MotionError::TimeNotIncreasing);
        }
        run.att.inflate_for_gap(t - run.t_last);
        run.t_last = t;
        self.det.reset();
        self.lift.interrupt();
        Ok(())
    }

    /// Lift mode (the display asks the walker to stand and lift the device): step
    /// detection is suspended so that the lift's vertical acceleration is not taken for
    /// steps, and the lift is tracked as standing.
    /// A lift under way when it is turned off is still finished in lift mode.
    pub fn set_lift_mode(&mut self, on: bool) {
        self.lift_mode = on;
        self.lift_hold |= on;
    }

    /// Height change of the device since the start (m, up positive): the sum of the
    /// vertical displacements measured by the accelerometer while standing (lifts,
    /// lowering to the snow and raising again) and handed to the estimator at the pulses.
    /// Vertical moves made while walking are not measured (nor seen by the estimator).
    pub fn vertical_m(&self) -> f32 {
        self.vertical_m
    }

    /// Whether lift mode is on (see [`set_lift_mode`](Self::set_lift_mode)).
    pub fn lift_mode(&self) -> bool {
        self.lift_mode
    }

    /// Button press at the start of a calibration walk.
    pub fn start_calibration(&mut self) {
        self.calibration = Some(StepCalibration::start(self.total_steps, self.weinberg_sum));
    }

    /// Button press at the end of a calibration walk of `distance_m` metres: on success the
    /// calibrated step length replaces the step-length model.
    pub fn finish_calibration(
        &mut self,
        distance_m: f32,
    ) -> Result<CalibrationResult, MotionError> {
        let cal = self.calibration.ok_or(MotionError::NoCalibration)?;
        let r = cal.finish(self.total_steps, self.weinberg_sum, distance_m)?;
        self.cfg.step_length = StepLengthModel::calibrated(r.step_length_m);
        self.calibration = None;
        Ok(r)
    }
}

/// Yaw of a rotation matrix (rad), as in [`crate::frame::rpy_from_rotation`].
fn rpy_yaw(r: &Mat3) -> f32 {
    wrap_pi(libm::atan2f(r[(1, 0)], r[(0, 0)]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rotation_from_rpy;

    fn earth() -> Vec3 {
        Vec3::new(21.792, 0.0, -42.768)
    }

    fn level_sample(yaw: f32) -> (Vec3, Vec3) {
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, yaw));
        (
            r.transpose() * Vec3::new(0.0, 0.0, GRAVITY),
            r.transpose() * earth(),
        )
    }

    fn running() -> Motion {
        let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let (acc, mag) = level_sample(0.3);
        for k in 0..50 {
            m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
                .unwrap();
        }
        m
    }

    #[test]
    fn tilt_heading_variance_is_tan_dip_squared_times_tilt() {
        let cov = Mat3::from_diagonal(&Vec3::new(1e-4, 4e-4, 1e-6));
        let tan_dip = 42.768 / 21.792;
        let v = tilt_heading_var(&earth(), &cov);
        assert!((v - tan_dip * tan_dip * 4e-4).abs() < 1e-7, "{v}");
        // A vertical field has no heading: nothing to add (and no division by zero).
        assert_eq!(tilt_heading_var(&Vec3::new(0.0, 0.0, -50.0), &cov), 0.0);
        let off = MotionConfig {
            tilt_heading: false,
            ..MotionConfig::new(earth(), Some(0.6))
        };
        let mut m = Motion::new(off);
        let mut on = running();
        let (acc, mag) = level_sample(0.3);
        for k in 0..50 {
            m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
                .unwrap();
        }
        let (a, b) = (m.attitude().1, on.attitude().1);
        let extra = tilt_heading_var(&earth(), &a);
        assert!(extra > 0.0);
        assert!((b[(2, 2)] - a[(2, 2)] - extra).abs() < 1e-9);
        let _ = on.take_displacement(0.5);
    }

    /// A sustained horizontal acceleration (a walker's surge lasting seconds, which the
    /// attitude filter takes for white noise) tilts the estimate, and the tilt turns the
    /// magnetometer heading by ≈ tan(dip) · tilt: the reported yaw σ covers that error.
    #[test]
    fn yaw_sigma_covers_the_heading_error_of_a_tilt_error() {
        let mut m = running();
        let (acc, mag) = level_sample(0.3);
        let surge = acc + Vec3::new(0.5, 0.0, 0.0);
        let mut worst: f32 = 0.0;
        for k in 50..550 {
            m.on_imu(k as f32 * 0.01, &surge, &Vec3::zeros(), &mag)
                .unwrap();
            let (rpy, cov) = m.attitude();
            let err = wrap_pi(rpy.z - 0.3);
            worst = worst.max(err.abs() / cov[(2, 2)].sqrt());
        }
        assert!(worst < 3.0, "yaw error {worst} σ");
        let (rpy, cov) = m.attitude();
        // The test does exercise a heading error beyond the filter's own yaw σ.
        let own = m
            .attitude_filter()
            .map(|f| f.rpy_cov()[(2, 2)])
            .unwrap_or(0.0);
        assert!(
            wrap_pi(rpy.z - 0.3).abs() > 3.0 * own.sqrt(),
            "{rpy:?} {cov:?}"
        );
    }

    #[test]
    fn a_saturated_magnetometer_drops_the_heading_aid_only() {
        let (acc, mag) = level_sample(0.3);
        let gyr = Vec3::new(0.0, 0.0, 0.2);
        for axis in 0..3 {
            let mut with = running();
            let mut without = running();
            let mut sat = mag;
            sat[axis] = if axis == 1 { -4900.0 } else { 6000.0 };
            for k in 1..=20 {
                let t = 0.5 + 0.01 * k as f32;
                with.on_imu_sample(t, &acc, &gyr, Some(&sat)).unwrap();
                without.on_imu_sample(t, &acc, &gyr, None).unwrap();
            }
            // Fed as a sample without magnetometer: acc and gyro still move the state.
            assert_eq!(with, without, "axis {axis}");
            assert_ne!(with, running());
        }
        // A non-finite magnetometer reading is still refused.
        let mut m = running();
        let nan = Vec3::new(0.0, f32::NAN, 0.0);
        assert_eq!(
            m.on_imu_sample(0.51, &acc, &gyr, Some(&nan)),
            Err(MotionError::NonFinite)
        );
    }

    #[test]
    fn bad_input_leaves_state_unchanged() {
        let mut m = running();
        let before = m.clone();
        let (acc, mag) = level_sample(0.3);
        let z = Vec3::zeros();
        let nan = Vec3::new(f32::NAN, 0.0, 0.0);
        let inf = Vec3::new(0.0, f32::INFINITY, 0.0);
        let t = 0.5;
        assert_eq!(m.on_imu(t, &nan, &z, &mag), Err(MotionError::NonFinite));
        assert_eq!(m.on_imu(t, &acc, &inf, &mag), Err(MotionError::NonFinite));
        assert_eq!(m.on_imu(t, &acc, &z, &nan), Err(MotionError::NonFinite));
        assert_eq!(
            m.on_imu(f32::NAN, &acc, &z, &mag),
            Err(MotionError::NonFinite)
        );
        let sat = Vec3::new(0.0, 0.0, 160.0);
        assert_eq!(m.on_imu(t, &sat, &z, &mag), Err(MotionError::Saturated));
        let spin = Vec3::new(35.0, 0.0, 0.0);
        assert_eq!(m.on_imu(t, &acc, &spin, &mag), Err(MotionError::Saturated));
        assert_eq!(
            m.on_imu(49.0 * 0.01, &acc, &z, &mag),
            Err(MotionError::TimeNotIncreasing)
        );
        assert_eq!(
            m.on_imu(0.2, &acc, &z, &mag),
            Err(MotionError::TimeNotIncreasing)
        );
        assert!(matches!(
            m.on_imu(1.0, &acc, &z, &mag),
            Err(MotionError::Gap { .. })
        ));
        assert_eq!(m, before);
        // After a gap, resync lets the samples flow again.
        m.resync(1.0).unwrap();
        m.on_imu(1.01, &acc, &z, &mag).unwrap();
        // A calibration without a start, and with too few steps.
        assert_eq!(m.finish_calibration(20.0), Err(MotionError::NoCalibration));
        m.start_calibration();
        assert_eq!(
            m.finish_calibration(20.0),
            Err(MotionError::TooFewSteps { steps: 0 })
        );
    }

    #[test]
    fn standing_still_gives_a_still_displacement() {
        let mut m = running();
        let d0 = m.take_displacement(0.495);
        let (acc, mag) = level_sample(0.3);
        for k in 50..150 {
            m.on_imu(k as f32 * 0.01, &acc, &Vec3::zeros(), &mag)
                .unwrap();
        }
        let d = m.take_displacement(1.495);
        assert!(d0.translation.norm() < 1e-6 && d.translation.norm() < 1e-6);
        assert!(d.rotation.norm() < 1e-3);
        assert_eq!(d.steps, 0);
        let (rpy, cov) = m.attitude();
        assert!((rpy - Rpy::new(0.0, 0.05, 0.3)).norm() < 1e-3);
        assert!(cov[(2, 2)] > 0.0);
        assert!((m.scale_sigma() - 0.02).abs() < 1e-7);
    }

    #[test]
    fn lowering_and_raising_in_lift_mode_track_the_height() {
        // Standing, device pitched 0.05 rad: lowered 0.8 m over 1 s from t = 2 s
        // (minimum jerk), pulses during and after; then raised again from t = 6 s.
        let mut m = running();
        m.set_lift_mode(true);
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, 0.3));
        let mag = r.transpose() * earth();
        let jerk = |t: f32, t0: f32, dz: f32| {
            let u = t - t0;
            if (0.0..=1.0).contains(&u) {
                dz * (60.0 * u - 180.0 * u * u + 120.0 * u * u * u)
            } else {
                0.0
            }
        };
        let mut after_lowering = f32::NAN;
        for k in 50..900 {
            let t = k as f32 * 0.01;
            let a = jerk(t, 2.0, -0.8) + jerk(t, 6.0, 0.8);
            let acc = r.transpose() * Vec3::new(0.0, 0.0, a + GRAVITY);
            m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            if k % 90 == 0 {
                let _ = m.take_displacement(t);
            }
            if k == 500 {
                after_lowering = m.vertical_m();
            }
        }
        let _ = m.take_displacement(9.0);
        assert!((after_lowering + 0.8).abs() < 0.02, "{after_lowering}");
        assert!(m.vertical_m().abs() < 0.02, "raised: {}", m.vertical_m());
        assert_eq!(m.total_steps(), 0, "the moves are not taken for steps");
        // A rescuer who ignores the prompt: nothing measured, nothing changes.
        let mut still = running();
        still.set_lift_mode(true);
        let acc = r.transpose() * Vec3::new(0.0, 0.0, GRAVITY);
        for k in 50..400 {
            let t = k as f32 * 0.01;
            still.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            if k % 90 == 0 {
                let _ = still.take_displacement(t);
            }
        }
        assert_eq!(still.vertical_m(), 0.0);
    }

    #[test]
    fn a_lift_in_lift_mode_gives_the_absolute_vertical_part() {
        // Standing, device pitched 0.05 rad, yaw 0.3: a 0.4 m raised-cosine lift over
        // 2 s from t = 2 s; pulses before, at the top and after.
        let mut m = running();
        m.set_lift_mode(true);
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.05, 0.3));
        let mag = r.transpose() * earth();
        let w = 2.0 * core::f32::consts::PI / 2.0;
        let mut got = [Displacement::still(0.0, 0.0); 3];
        let pulses = [1.5f32, 3.0, 5.0];
        let mut next = 0;
        for k in 50..600 {
            let t = k as f32 * 0.01;
            let a = if (2.0..=4.0).contains(&t) {
                0.2 * w * w * libm::cosf(w * (t - 2.0))
            } else {
                0.0
            };
            let acc = r.transpose() * Vec3::new(0.0, 0.0, a + GRAVITY);
            m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            if next < 3 && t >= pulses[next] - 1e-4 {
                got[next] = m.take_displacement(t);
                next += 1;
            }
        }
        assert_eq!(got[0].absolute, Vec3::zeros());
        assert_eq!(m.total_steps(), 0, "the lift is not taken for steps");
        // In R_{k-1} axes; back in W it is vertical.
        let up = r * got[1].absolute;
        assert!((up - Vec3::new(0.0, 0.0, 0.4)).norm() < 0.02, "{up:?}");
        let down = r * got[2].absolute;
        assert!((down + Vec3::new(0.0, 0.0, 0.4)).norm() < 0.02, "{down:?}");
        let var_w = r * got[1].absolute_cov * r.transpose();
        assert!(var_w[(2, 2)] > 0.0 && var_w[(2, 2)].sqrt() < 0.05);
        assert!(var_w[(0, 0)] < 1e-5);
        assert!(got.iter().all(|d| d.translation.norm() < 1e-6));
    }

    #[test]
    fn synthetic_walk_counts_steps_and_moves_forward() {
        // Walk north-west (yaw 0.8) at 1.8 steps/s with a 2.5 m/s² vertical bob.
        let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let yaw = 0.8f32;
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, yaw));
        let mag = r.transpose() * earth();
        let f = 1.8f32;
        let mut total = Vec3::zeros();
        let mut steps = 0u32;
        for k in 0..1000 {
            let t = k as f32 * 0.01;
            let a_w = Vec3::new(0.0, 0.0, 2.5 * (2.0 * core::f32::consts::PI * f * t).sin());
            let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
            m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            if k % 100 == 99 {
                let d = m.take_displacement(t);
                total += r * d.translation;
                steps += d.steps as u32;
            }
        }
        // 10 s × 1.8 = 18 peaks (the first needs the filter to settle).
        assert!((17..=18).contains(&m.total_steps()), "{}", m.total_steps());
        assert_eq!(steps, m.total_steps());
        let dir = Vec3::new(yaw.cos(), yaw.sin(), 0.0);
        let along = total.dot(&dir);
        assert!((along - 0.6 * steps as f32).abs() < 0.61, "{along}");
        assert!((total - dir * along).norm() < 0.05);
    }

    /// Feeds 100 Hz samples of a level device from `t0` for `secs` s: yaw `yaw(t)` (its
    /// rate on the gyro), and the bob of a walk (the sim's gait: one upward acceleration
    /// peak in the middle of each step) while `phase(t)` advances, none when it stands.
    fn feed(
        m: &mut Motion,
        t0: f32,
        secs: f32,
        yaw: impl Fn(f32) -> f32,
        phase: impl Fn(f32) -> Option<f32>,
    ) -> f32 {
        let n = (secs * 100.0).round() as usize;
        let mut t = t0;
        for k in 1..=n {
            t = t0 + k as f32 * 0.01;
            let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, yaw(t)));
            let rate = (yaw(t + 0.005) - yaw(t - 0.005)) / 0.01;
            // z = B (cos 2πφ − 1) at 1.8 steps/s, B = 2 cm: z'' = −B (2π·1.8)² cos 2πφ.
            let w = core::f32::consts::TAU * 1.8;
            let az = phase(t).map_or(0.0, |ph| {
                -0.02 * w * w * libm::cosf(core::f32::consts::TAU * ph)
            });
            let acc = r.transpose() * Vec3::new(0.0, 0.0, GRAVITY + az);
            m.on_imu(
                t,
                &acc,
                &Vec3::new(0.0, 0.0, rate),
                &(r.transpose() * earth()),
            )
            .unwrap();
        }
        t
    }

    /// Two steps from rest, at 1.8 steps/s from `t0` (phase 0 → 2).
    fn two_steps(t0: f32) -> impl Fn(f32) -> Option<f32> {
        move |t| {
            let ph = (t - t0) * 1.8;
            (0.0..2.0).contains(&ph).then_some(ph)
        }
    }

    #[test]
    fn a_pulse_during_a_short_walk_and_one_after_it_split_the_two_steps_right() {
        // Stand 1 s, walk two steps (t 1.0 – 2.11 s), a pulse at 2.0 s (φ = 1.8: 1.8 steps
        // walked), stand, a pulse at 3.5 s (2 steps walked, 0.2 of them since the pulse).
        let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let yaw = |_: f32| 0.3f32;
        let t = feed(&mut m, 0.0, 1.0, yaw, |_| None);
        let d0 = m.take_displacement(t);
        let t = feed(&mut m, t, 1.0, yaw, two_steps(1.0));
        let d1 = m.take_displacement(t);
        let t = feed(&mut m, t, 1.5, yaw, two_steps(1.0));
        let d2 = m.take_displacement(t);
        assert!(d0.translation.norm() < 1e-6);
        assert_eq!(d1.steps + d2.steps, 2, "{d1:?} {d2:?}");
        // The device frame is the walking frame (level, facing the walk): forward is x.
        assert!(
            (d1.translation.x - 1.8 * 0.6).abs() < 0.1,
            "{:?}",
            d1.translation
        );
        // After the stop the remaining 0.2 step, not the half step the count ran ahead
        // taken back (the walker standing would seem to move 0.2–0.3 m backwards).
        assert!(
            (d2.translation.x - 0.2 * 0.6).abs() < 0.1,
            "{:?}",
            d2.translation
        );
        assert!((d1.translation.x + d2.translation.x - 1.2).abs() < 0.02);
        // Each within its own σ (consistent, not merely unbiased).
        let sd = |d: &Displacement| libm::sqrtf(d.cov[(0, 0)]);
        assert!((d1.translation.x - 1.08).abs() < 3.0 * sd(&d1), "{d1:?}");
        assert!(
            (d2.translation.x - 0.12).abs() < 3.0 * sd(&d2) + 0.03,
            "{d2:?}"
        );
    }

    #[test]
    fn a_turn_on_the_spot_does_not_bend_the_next_step() {
        // Stand facing yaw 0.3, turn around on the spot (π in 1.5 s), stand 0.5 s, walk
        // two steps: they go along the new yaw. The mean yaw since the last step (the
        // stand before the turn included) pointed them up to 90° sideways.
        let mut m = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let yaw = |t: f32| 0.3 + core::f32::consts::PI * ((t - 1.0) / 1.5).clamp(0.0, 1.0);
        let t = feed(&mut m, 0.0, 1.0, yaw, |_| None);
        let _ = m.take_displacement(t);
        let t = feed(&mut m, t, 3.0, yaw, |_| None);
        let r0 = rotation_from_rpy(&Rpy::new(0.0, 0.0, yaw(t)));
        let _ = m.take_displacement(t);
        let t = feed(&mut m, t, 2.0, yaw, two_steps(4.0));
        let d = m.take_displacement(t);
        assert_eq!(d.steps, 2);
        let along = r0 * d.translation;
        let dir = Vec3::new(libm::cosf(yaw(t)), libm::sinf(yaw(t)), 0.0);
        assert!((along.dot(&dir) - 1.2).abs() < 0.05, "{along:?}");
        assert!((along - dir * along.dot(&dir)).norm() < 0.05, "{along:?}");
    }

    #[test]
    fn split_cuts_compose_to_the_single_interval_without_inflating_q() {
        // One victim's pulses every 1.1 s, other victims' pulses at 0.37 s between them.
        // Victim A through take_split (composing every cut, its own pulse adding the
        // partial step and restarting from `back`) must match a receiver hearing A alone
        // (take_displacement at A's pulses); composing whole take_displacement cuts
        // instead adds the partial step's variance twice at every other pulse.
        use crate::estimate::Displacement as E;
        use crate::victims::compose;
        let e = |d: &Displacement| E {
            translation: d.translation,
            rotation: d.rotation,
            cov: d.cov,
            absolute: d.absolute,
            absolute_cov: d.absolute_cov,
        };
        let mut split = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let (mut alone, mut naive) = (split.clone(), split.clone());
        let yaw = 0.8f32;
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, yaw));
        let mag = r.transpose() * earth();
        let (mut pend_split, mut pend_naive) = (E::zero(), E::zero());
        let (mut worst, mut infl_split, mut infl_naive) = (0.0f32, 0.0f32, 0.0f32);
        let (mut split_steps, mut split_standing) = (0u32, true);
        for k in 0..1200 {
            let t = k as f32 * 0.01;
            let a_w = Vec3::new(
                0.0,
                0.0,
                2.5 * (2.0 * core::f32::consts::PI * 1.8 * t).sin(),
            );
            let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
            for m in [&mut split, &mut alone, &mut naive] {
                m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            }
            let own = k % 110 == 109;
            if !(own || k % 37 == 36) {
                continue;
            }
            let s = split.take_split(t);
            pend_split = compose(&pend_split, &e(&s.cut)).unwrap();
            split_steps += u32::from(s.cut.steps);
            split_standing &= s.standing;
            pend_naive = compose(&pend_naive, &e(&naive.take_displacement(t))).unwrap();
            if own {
                let mut full = compose(&pend_split, &e(&s.partial)).unwrap();
                full.cov += split
                    .config()
                    .noise
                    .interval_floors(split_steps, split_standing);
                let d = e(&alone.take_displacement(t));
                if k > 300 {
                    worst = worst.max((full.translation - d.translation).norm());
                    let tr = |c: &crate::estimate::Mat6| c[(0, 0)] + c[(1, 1)];
                    infl_split = infl_split.max(tr(&full.cov) / tr(&d.cov));
                    infl_naive = infl_naive.max(tr(&pend_naive.cov) / tr(&d.cov));
                }
                pend_split = e(&s.back);
                (split_steps, split_standing) = (0, true);
                pend_naive = E::zero();
            }
        }
        assert!(worst < 0.02, "{worst}");
        // Neither the partial step nor the per-interval floors come with every cut: the
        // victim's Q_k stays that of a receiver hearing it alone.
        assert!(
            infl_naive > infl_split * 1.05 && infl_split < 1.2,
            "{infl_naive} vs {infl_split}"
        );
    }

    #[test]
    fn a_lone_victim_gets_the_same_displacement_from_take_split() {
        use crate::estimate::Displacement as E;
        let e = |d: &Displacement| E {
            translation: d.translation,
            rotation: d.rotation,
            cov: d.cov,
            absolute: d.absolute,
            absolute_cov: d.absolute_cov,
        };
        let mut split = Motion::new(MotionConfig::new(earth(), Some(0.6)));
        let mut alone = split.clone();
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.1, -0.4));
        let mag = r.transpose() * earth();
        let mut back = E::zero();
        for k in 0..900 {
            let t = k as f32 * 0.01;
            let a_w = Vec3::new(
                0.0,
                0.0,
                2.5 * (2.0 * core::f32::consts::PI * 1.7 * t).sin(),
            );
            let acc = r.transpose() * (a_w + Vec3::new(0.0, 0.0, GRAVITY));
            split.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            alone.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
            if k % 93 == 92 {
                let s = split.take_split(t);
                let own = crate::victims::compose(&back, &e(&s.cut)).unwrap();
                let mut own = crate::victims::compose(&own, &e(&s.partial)).unwrap();
                // The floors come once per victim interval (here: one cut per interval).
                own.cov += split
                    .config()
                    .noise
                    .interval_floors(u32::from(s.cut.steps), s.standing);
                let d = alone.take_displacement(t);
                assert!((own.translation - d.translation).norm() < 1e-3, "{k}");
                let (a, b) = (
                    own.cov[(0, 0)] + own.cov[(1, 1)],
                    d.cov[(0, 0)] + d.cov[(1, 1)],
                );
                // Equal but for the heading errors of the partial step, applied to it
                // apart instead of to the whole interval (measured ≤ 11 %).
                assert!((a - b).abs() <= 0.15 * b, "{k}: {a} vs {b}");
                back = e(&s.back);
            }
        }
    }

    #[test]
    fn calibration_walk_sets_the_step_length() {
        let mut m = Motion::new(MotionConfig::new(earth(), None));
        let r = rotation_from_rpy(&Rpy::new(0.0, 0.0, 0.0));
        let mag = r.transpose() * earth();
        for k in 0..2500 {
            let t = k as f32 * 0.01;
            if k == 100 {
                m.start_calibration();
            }
            let az = if k >= 100 {
                2.5 * (2.0 * core::f32::consts::PI * 1.8 * t).sin()
            } else {
                0.0
            };
            let acc = Vec3::new(0.0, 0.0, GRAVITY + az);
            m.on_imu(t, &acc, &Vec3::zeros(), &mag).unwrap();
        }
        let n = m.total_steps();
        let res = m.finish_calibration(20.0).unwrap();
        assert_eq!(res.steps, n);
        assert!((res.step_length_m - 20.0 / n as f32).abs() < 1e-5);
        assert!((m.scale_sigma() - 0.02).abs() < 1e-7);
    }
}
