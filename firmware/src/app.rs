//! The application: one state machine that owns the receiver's pipeline,
//! IMU → attitude and dead reckoning ([`crate::motion`]) → SOGs filter
//! ([`crate::estimate`]) → search control ([`crate::guidance`]) → [`DisplayModel`].
//!
//! [`Receiver`] is hardware-free: it takes samples and returns values. The board binary
//! and `hal-sim` drive this same type; neither re-implements any of it.
//!
//! # Memory: keep one instance, never move it
//! The SOGs filter is ≈ 63 KB ([`crate::estimate::SOG_CAPACITY`] components), so a
//! [`Receiver`] must not be passed by value or copied around on the board (the stack is
//! far smaller). The board keeps exactly one in a `static` in `.ccmram` (a `NOLOAD`
//! section that the runtime does not zero: its owner initializes it):
//!
//! ```ignore
//! #[unsafe(link_section = ".ccmram")]
//! static mut RECEIVER: MaybeUninit<Receiver> = MaybeUninit::uninit();
//! // once, at start-up (the only place that touches the static):
//! let rx: &'static mut Receiver = Receiver::emplace(unsafe { &mut *addr_of_mut!(RECEIVER) }, cfg)?;
//! ```
//!
//! [`Receiver::emplace`] writes the new receiver straight into its slot. The pulse front
//! end ([`Frontend`], ≈ 14 KB) is not part of the receiver, so the receiver alone fits
//! the 64 KB CCM; the board keeps the front end in main SRAM and lends it to
//! [`Receiver::on_adc_sample`].
//!
//! # Errors
//! Every input is checked; a refused input returns an [`AppError`] and leaves the
//! receiver exactly as it was. Nothing here panics or allocates.

use core::mem::MaybeUninit;

use crate::Vec3;
use crate::estimate::{
    self, Attitude, DefaultSog, EstimateError, Estimator, SogConfig, StepOutcome, VictimEstimate,
};
use crate::frame::rotation_from_rpy;
use crate::frontend::{Frontend, FrontendError, PulseMeasurement};
use crate::guidance::{
    Guidance, GuidanceConfig, GuidanceInput, GuidanceOutput, Status, relative_arrow,
    to_degrees_wrapped,
};
use crate::motion::{Motion, MotionConfig, MotionError};

/// Why an input was refused (the receiver's state is then unchanged).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AppError {
    /// The IMU sample was refused by the motion pipeline.
    Motion(MotionError),
    /// The pulse was refused by the estimator.
    Estimate(EstimateError),
    /// The ADC sample was refused by the front end.
    Frontend(FrontendError),
    /// A time or vector was NaN or infinite.
    NonFinite,
}

impl From<MotionError> for AppError {
    fn from(e: MotionError) -> Self {
        AppError::Motion(e)
    }
}

impl From<EstimateError> for AppError {
    fn from(e: EstimateError) -> Self {
        AppError::Estimate(e)
    }
}

impl From<FrontendError> for AppError {
    fn from(e: FrontendError) -> Self {
        AppError::Frontend(e)
    }
}

/// Configuration of the whole pipeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppConfig {
    /// Attitude, step detection and dead reckoning.
    pub motion: MotionConfig,
    /// The SOGs filter.
    pub sog: SogConfig,
    /// The search control.
    pub guidance: GuidanceConfig,
    /// Seconds without a pulse after which the display says "no signal".
    pub signal_timeout_s: f32,
}

impl AppConfig {
    /// Defaults for the given earth field (µT, in `W`) and calibrated step length (m;
    /// `None`: uncalibrated), with the filter's scale prior and the guidance's receiver
    /// height taken from them.
    pub fn new(earth_field_ut: Vec3, step_length_m: Option<f32>) -> Self {
        let motion = MotionConfig::new(earth_field_ut, step_length_m);
        // The filter's scale prior is the step-length model's own relative uncertainty
        // (≈2 % calibrated, ≈20 % for the uncalibrated default), so both agree.
        let sog = SogConfig {
            scale_sigma: motion.step_length.scale_sigma(),
            ..SogConfig::default()
        };
        let guidance = GuidanceConfig {
            receiver_height_m: sog.receiver_height,
            ..GuidanceConfig::default()
        };
        Self {
            motion,
            sog,
            guidance,
            signal_timeout_s: 3.5,
        }
    }
}

/// Everything the display shows (the screen draws only this, see [`crate::display`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DisplayModel {
    /// Status word.
    pub status: Status,
    /// Arrow relative to the device's current heading, degrees, positive to the left, in
    /// (-180, 180]; `None`: no direction to show.
    pub arrow_deg: Option<f32>,
    /// Straight-line (3-D) distance to the victim estimate, m.
    pub distance_m: Option<f32>,
    /// Horizontal distance to the victim estimate, m.
    pub horizontal_m: Option<f32>,
    /// Burial depth below the snow surface, m (fine search only).
    pub depth_m: Option<f32>,
    /// Horizontal distance to walk along the arrow, m (to the estimate, or to the
    /// bracketing point beside it in the fine search); 0 when probing.
    pub walk_m: Option<f32>,
    /// Uncertainty of the victim's horizontal position: largest horizontal σ, m.
    pub uncertainty_m: Option<f32>,
    /// Transmitters heard (distinct front-end sources; 1 without source attribution).
    pub victims: u8,
    /// The last pulse was withheld by the front end (overlapping transmitters, clipping).
    pub overlap: bool,
    /// Pulses processed so far (a new value means a new estimate).
    pub pulses: u32,
    /// Time of the last pulse, s.
    pub t_s: f32,
    /// Fine search: "LIFT" — stand and lift the receiver ≈ 0.4 m and lower it within
    /// ~2 s (an absolute vertical displacement that pins the depth); steps are not
    /// counted meanwhile.
    pub lift: bool,
}

/// Counters of refused or skipped inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AppStats {
    /// IMU samples refused.
    pub imu_refused: u32,
    /// Gaps in the IMU stream bridged by a resynchronization.
    pub imu_gaps: u32,
    /// Pulses refused.
    pub pulses_refused: u32,
    /// Pulses withheld by the front end (overlap, clipping, truncation).
    pub pulses_withheld: u32,
    /// Pulses of other transmitters than the tracked one (left to the multi-victim search).
    pub other_source: u32,
    /// Mixture re-initializations.
    pub reinitializations: u32,
    /// Pulses the estimator's outlier gate withheld (no component explains them).
    pub pulses_gated: u32,
}

/// The receiver application (see the module docs for how the board stores it).
#[derive(Debug, Clone)]
pub struct Receiver {
    filter: DefaultSog,
    motion: Motion,
    guidance: Guidance,
    cfg: AppConfig,
    last: GuidanceOutput,
    last_outcome: Option<StepOutcome>,
    last_pulse_t: Option<f32>,
    t_now: f32,
    pulses: u32,
    /// Bit i: front-end source i has been heard.
    sources: u8,
    /// The source the estimator tracks (the first one heard).
    tracked: Option<u8>,
    overlap: bool,
    stats: AppStats,
    /// Time of the front end's first sample on the IMU clock, s.
    adc_epoch_s: f32,
}

impl Receiver {
    /// A receiver waiting for its first samples; `InvalidConfig` when the filter refuses
    /// the configuration. On the board use [`Receiver::emplace`] instead (no 63 KB move).
    pub fn new(cfg: AppConfig) -> Result<Self, AppError> {
        Ok(Self {
            filter: DefaultSog::new(cfg.sog)?,
            motion: Motion::new(cfg.motion),
            guidance: Guidance::new(cfg.guidance),
            cfg,
            last: GuidanceOutput::default(),
            last_outcome: None,
            last_pulse_t: None,
            t_now: 0.0,
            pulses: 0,
            sources: 0,
            tracked: None,
            overlap: false,
            stats: AppStats::default(),
            adc_epoch_s: 0.0,
        })
    }

    /// Builds a receiver in `slot` (e.g. a `static` in `.ccmram`) and returns it.
    pub fn emplace(
        slot: &mut MaybeUninit<Receiver>,
        cfg: AppConfig,
    ) -> Result<&mut Receiver, AppError> {
        Ok(slot.write(Self::new(cfg)?))
    }

    /// Starts a new search with the same configuration.
    pub fn reset(&mut self) {
        self.filter.reset();
        self.motion = Motion::new(self.cfg.motion);
        self.guidance.reset();
        self.last = GuidanceOutput::default();
        self.last_outcome = None;
        self.last_pulse_t = None;
        self.pulses = 0;
        self.sources = 0;
        self.tracked = None;
        self.overlap = false;
        self.stats = AppStats::default();
    }

    /// The configuration in use.
    pub fn config(&self) -> &AppConfig {
        &self.cfg
    }

    /// The SOGs filter (read-only, e.g. to plot its components).
    pub fn filter(&self) -> &DefaultSog {
        &self.filter
    }

    /// The motion pipeline (read-only).
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The estimator's current belief, or `None` before initialization.
    pub fn estimate(&self) -> Option<VictimEstimate> {
        self.filter.estimate()
    }

    /// The search control's answer to the last pulse.
    pub fn guidance(&self) -> &GuidanceOutput {
        &self.last
    }

    /// What the estimator did with the last accepted pulse.
    pub fn last_outcome(&self) -> Option<StepOutcome> {
        self.last_outcome
    }

    /// Counters of refused and skipped inputs.
    pub fn stats(&self) -> &AppStats {
        &self.stats
    }

    /// One IMU sample at `t` (s): specific force (m/s²), rate (rad/s), flux density (µT;
    /// `None` when the magnetometer gave none), body frame. A gap in the stream is
    /// bridged (the motion pipeline resynchronizes and inflates its uncertainty).
    pub fn on_imu(
        &mut self,
        t: f32,
        acc: &Vec3,
        gyr: &Vec3,
        mag: Option<&Vec3>,
    ) -> Result<(), AppError> {
        let r = match self.motion.on_imu_sample(t, acc, gyr, mag) {
            Err(MotionError::Gap { .. }) => {
                // Resynchronize on a copy so that a refused sample leaves no trace.
                // `resync` takes its argument as the last sample's time: resync to one
                // period before `t`, so that `t` is then an ordinary next sample (resync
                // to `t` itself refused every sample after a gap as not increasing).
                let mut m = self.motion.clone();
                m.resync(t - 1.0 / self.cfg.motion.imu_hz)
                    .and_then(|()| m.on_imu_sample(t, acc, gyr, mag))
                    .map(|()| {
                        self.motion = m;
                        self.stats.imu_gaps = self.stats.imu_gaps.saturating_add(1);
                    })
            }
            r => r,
        };
        match r {
            Ok(()) => {
                self.t_now = t;
                // The lift prompt lasts while pulses come; without them, steps count again.
                if self.motion.lift_mode() && !self.display_model().lift {
                    self.motion.set_lift_mode(false);
                }
                Ok(())
            }
            Err(e) => {
                self.stats.imu_refused = self.stats.imu_refused.saturating_add(1);
                Err(AppError::Motion(e))
            }
        }
    }

    /// One received pulse at `t` (s, the IMU's clock): the field vector in the body frame
    /// (A/m, overall sign arbitrary) and the front end's source attribution. Pulses of a
    /// source other than the first one heard are counted but not estimated (multi-victim
    /// search is a later step). Returns the new display.
    pub fn on_pulse(
        &mut self,
        t: f32,
        h_body: &Vec3,
        src: Option<u8>,
    ) -> Result<DisplayModel, AppError> {
        if !t.is_finite() || !h_body.iter().all(|v| v.is_finite()) {
            self.stats.pulses_refused = self.stats.pulses_refused.saturating_add(1);
            return Err(AppError::NonFinite);
        }
        let src_bit = src.map_or(1, |s| 1u8.checked_shl(u32::from(s)).unwrap_or(0x80));
        if let (Some(s), Some(tracked)) = (src, self.tracked)
            && s != tracked
        {
            self.sources |= src_bit;
            self.stats.other_source = self.stats.other_source.saturating_add(1);
            return Ok(self.display_model());
        }
        // Work on a copy of the motion state: the displacement is only consumed when the
        // estimator accepts the pulse.
        let mut motion = self.motion.clone();
        let d = motion.take_displacement(t);
        let displacement = estimate::Displacement {
            translation: d.translation,
            rotation: d.rotation,
            cov: d.cov,
            absolute: d.absolute,
            absolute_cov: d.absolute_cov,
        };
        let (rpy, cov) = motion.attitude();
        let attitude = Attitude { rpy, cov };
        let pulse = estimate::Pulse { h: *h_body, t };
        let report = match self.filter.step(&displacement, &attitude, &pulse) {
            Ok(r) => r,
            Err(e) => {
                self.stats.pulses_refused = self.stats.pulses_refused.saturating_add(1);
                return Err(AppError::Estimate(e));
            }
        };
        self.motion = motion;
        self.tracked = self.tracked.or(src);
        self.sources |= src_bit;
        self.overlap = false;
        self.pulses = self.pulses.saturating_add(1);
        self.last_pulse_t = Some(t);
        self.t_now = self.t_now.max(t);
        self.last_outcome = Some(report.outcome);
        let reinitialized = report.outcome == StepOutcome::Reinitialized;
        if reinitialized {
            self.stats.reinitializations = self.stats.reinitializations.saturating_add(1);
        }
        let gated = report.outcome == StepOutcome::Withheld;
        if gated {
            self.stats.pulses_gated = self.stats.pulses_gated.saturating_add(1);
        }
        // The pulse's field in G_k for the flux line: h_G = R_GR(rpy) h_R.
        let h_g = rotation_from_rpy(&rpy) * h_body;
        self.last = self.guidance.update(&GuidanceInput {
            // An outlier's field would bend the flux line the wrong way.
            h_g: (!gated).then_some(h_g),
            walked_m: d.distance_m,
            yaw: rpy.z,
            estimate: self.filter.estimate(),
            reinitialized,
        });
        self.motion.set_lift_mode(self.last.lift);
        Ok(self.display_model())
    }

    /// Sets the time (s, on the IMU's clock) of the front end's first ADC sample, so that
    /// its pulse times ([`crate::frontend::Pulse::t_s`]) can be put on the IMU's clock.
    pub fn set_adc_epoch(&mut self, t0_s: f32) -> Result<(), AppError> {
        if !t0_s.is_finite() {
            return Err(AppError::NonFinite);
        }
        self.adc_epoch_s = t0_s;
        Ok(())
    }

    /// One simultaneous sample of the three coils (V at the ADC) through `frontend`
    /// (kept outside the receiver, see the module docs). When a pulse ends: a field
    /// pulse goes through [`Receiver::on_pulse`]; a withheld one (overlap, clipping,
    /// truncation) only sets [`DisplayModel::overlap`]. Returns the display on a pulse.
    pub fn on_adc_sample(
        &mut self,
        frontend: &mut Frontend,
        volts: [f32; 3],
        clipped: bool,
    ) -> Result<Option<DisplayModel>, AppError> {
        let Some(p) = frontend.push(volts, clipped)? else {
            return Ok(None);
        };
        let t = self.adc_epoch_s + p.t_s;
        match p.measurement {
            PulseMeasurement::Field(h) => self.on_pulse(t, &h, p.src).map(Some),
            PulseMeasurement::Overlap
            | PulseMeasurement::Saturated
            | PulseMeasurement::Truncated => Ok(Some(self.on_withheld_pulse())),
        }
    }

    /// A pulse the front end withheld (overlap, clipping, truncation): flags it on the
    /// display ([`DisplayModel::overlap`]) until the next field pulse and counts it.
    /// For callers that run the front end themselves (the board logs each pulse first).
    pub fn on_withheld_pulse(&mut self) -> DisplayModel {
        self.overlap = true;
        self.stats.pulses_withheld = self.stats.pulses_withheld.saturating_add(1);
        self.display_model()
    }

    /// The display now: the last pulse's guidance, with the arrow turned by the device's
    /// current heading (the compass keeps the arrow right between pulses), and "no
    /// signal" when no pulse came for [`AppConfig::signal_timeout_s`].
    pub fn display_model(&self) -> DisplayModel {
        let g = &self.last;
        let yaw = self.motion.attitude().0.z;
        let timed_out = self
            .last_pulse_t
            .is_none_or(|t| self.t_now - t > self.cfg.signal_timeout_s);
        let (status, arrow_deg) = if timed_out && g.status != Status::Probe {
            (Status::NoSignal, None)
        } else {
            (
                g.status,
                g.bearing
                    .map(|b| to_degrees_wrapped(relative_arrow(b, yaw)))
                    .filter(|a| a.is_finite()),
            )
        };
        DisplayModel {
            status,
            arrow_deg,
            distance_m: g.distance_m,
            horizontal_m: g.horizontal_m,
            depth_m: g.depth_m,
            walk_m: g.walk_m,
            uncertainty_m: g.sigma_h_m,
            victims: self.sources.count_ones() as u8,
            overlap: self.overlap,
            pulses: self.pulses,
            t_s: self.last_pulse_t.unwrap_or(0.0),
            lift: g.lift && !timed_out,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rotation_from_rpy;
    use crate::frontend::FrontendConfig;

    fn config() -> AppConfig {
        AppConfig::new(Vec3::new(21.0, 0.0, -42.0), Some(0.56))
    }

    fn level_imu(rx: &mut Receiver, t0: f32, n: usize) -> f32 {
        let earth = Vec3::new(21.0, 0.0, -42.0);
        let mut t = t0;
        for _ in 0..n {
            t += 0.01;
            rx.on_imu(
                t,
                &Vec3::new(0.0, 0.0, 9.80665),
                &Vec3::zeros(),
                Some(&earth),
            )
            .unwrap();
        }
        t
    }

    #[test]
    fn fits_in_the_core_coupled_ram() {
        let bytes = core::mem::size_of::<Receiver>();
        assert!(bytes <= 64 * 1024, "Receiver is {bytes} bytes");
    }

    #[test]
    fn bad_inputs_are_refused_and_leave_the_state_intact() {
        let mut rx = Receiver::new(config()).unwrap();
        let t = level_imu(&mut rx, 0.0, 50);
        // A dipole 20 m north, 1 m down, moment along north.
        let h =
            crate::dipole::field(&Vec3::new(-20.0, 0.0, 2.0), &Vec3::new(0.02, 0.0, 0.0)).unwrap();
        let d0 = rx.on_pulse(t, &h, None).unwrap();
        assert_eq!(d0.pulses, 1);
        assert_ne!(d0.status, Status::NoSignal);
        let snapshot = format!("{:?}", rx);
        let nan = Vec3::new(f32::NAN, 0.0, 0.0);
        assert_eq!(rx.on_pulse(t + 1.0, &nan, None), Err(AppError::NonFinite));
        assert_eq!(
            rx.on_pulse(f32::INFINITY, &h, None),
            Err(AppError::NonFinite)
        );
        assert_eq!(
            rx.on_pulse(t - 1.0, &h, None),
            Err(AppError::Estimate(EstimateError::TimeWentBackwards))
        );
        assert_eq!(
            rx.on_pulse(t + 1.0, &Vec3::zeros(), None),
            Err(AppError::Estimate(EstimateError::ZeroField))
        );
        assert!(matches!(
            rx.on_imu(t + 0.01, &nan, &Vec3::zeros(), None),
            Err(AppError::Motion(MotionError::NonFinite))
        ));
        assert!(matches!(
            rx.on_imu(t - 0.5, &Vec3::z(), &Vec3::zeros(), None),
            Err(AppError::Motion(MotionError::TimeNotIncreasing))
        ));
        // Everything but the refusal counters is unchanged.
        let mut after = format!("{:?}", rx);
        let stats = *rx.stats();
        assert_eq!((stats.pulses_refused, stats.imu_refused), (4, 2));
        after = after.replace(
            &format!("{:?}", stats),
            &format!("{:?}", AppStats::default()),
        );
        assert_eq!(snapshot, after);
        assert_eq!(rx.display_model(), d0);
    }

    #[test]
    fn flux_line_then_display_turns_with_the_device() {
        let mut rx = Receiver::new(config()).unwrap();
        let t = level_imu(&mut rx, 0.0, 50);
        assert_eq!(rx.display_model().status, Status::NoSignal);
        // Beacon 30 m to the west, moment along west: field along ±west at the receiver.
        let h =
            crate::dipole::field(&Vec3::new(0.0, -30.0, 2.0), &Vec3::new(0.0, 0.02, 0.0)).unwrap();
        let d = rx.on_pulse(t, &h, None).unwrap();
        assert_eq!(d.status, Status::FluxLine);
        assert_eq!(d.victims, 1);
        let a = d.arrow_deg.unwrap();
        assert!((a.abs() - 90.0).abs() < 5.0, "arrow {a}");
        assert!(d.uncertainty_m.is_some());
        // Turn the device 90° to the left (toward west) at rest: the arrow turns with it.
        let earth = Vec3::new(21.0, 0.0, -42.0);
        let r = rotation_from_rpy(&Vec3::new(0.0, 0.0, core::f32::consts::FRAC_PI_2));
        let mut tt = t;
        for _ in 0..300 {
            tt += 0.01;
            let _ = rx.on_imu(
                tt,
                &Vec3::new(0.0, 0.0, 9.80665),
                &Vec3::zeros(),
                Some(&(r.transpose() * earth)),
            );
        }
        let turned = rx.display_model().arrow_deg.unwrap();
        assert!((turned - (a - 90.0)).abs() < 15.0, "{a} → {turned}");
        // No pulse for long: no signal.
        let _ = level_imu(&mut rx, tt, 400);
        assert_eq!(rx.display_model().status, Status::NoSignal);
    }

    #[test]
    fn other_sources_are_counted_not_estimated() {
        let mut rx = Receiver::new(config()).unwrap();
        let t = level_imu(&mut rx, 0.0, 20);
        let h = Vec3::new(1e-6, 2e-7, -3e-7);
        rx.on_pulse(t, &h, Some(0)).unwrap();
        let d = rx.on_pulse(t + 0.3, &h, Some(2)).unwrap();
        assert_eq!((d.victims, d.pulses), (2, 1));
        assert_eq!(rx.stats().other_source, 1);
    }

    #[test]
    fn adc_samples_drive_the_front_end() {
        let mut rx = Receiver::new(config()).unwrap();
        let mut fe = Frontend::new(FrontendConfig::default()).unwrap();
        assert!(rx.set_adc_epoch(f32::NAN).is_err());
        assert!(matches!(
            rx.on_adc_sample(&mut fe, [f32::NAN, 0.0, 0.0], false),
            Err(AppError::Frontend(FrontendError::NonFiniteSample))
        ));
        // Noise only: no pulse.
        let mut seed = 1u32;
        for _ in 0..2000 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let v = (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
            assert_eq!(
                rx.on_adc_sample(&mut fe, [v * 1e-6, v * 1e-6, -v * 1e-6], false),
                Ok(None)
            );
        }
    }

    #[test]
    fn emplace_builds_in_a_slot() {
        let mut slot = Box::new(MaybeUninit::<Receiver>::uninit());
        let rx = Receiver::emplace(&mut slot, config()).unwrap();
        assert_eq!(rx.display_model().pulses, 0);
        let mut bad = config();
        bad.sog.m_min = -1.0;
        assert!(matches!(
            Receiver::new(bad),
            Err(AppError::Estimate(EstimateError::InvalidConfig))
        ));
    }
}
