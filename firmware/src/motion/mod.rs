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
mod tests;
