//! The application: one state machine that owns the receiver's pipeline,
//! IMU → attitude and dead reckoning ([`crate::motion`]) → SOGs filter
//! ([`crate::estimate`]) → search control ([`crate::guidance`]) → [`DisplayModel`].
//!
//! [`Receiver`] is hardware-free: it takes samples and returns values. The board binary
//! and `hal-sim` drive this same type; neither re-implements any of it.
//!
//! # Several victims
//! Each transmitter the front end separates (`src`) gets its own SOGs mixture in a
//! [`VictimBank`] (see [`crate::victims`]); a pulse updates only its victim's mixture.
//! The guidance follows one *target*: the nearest unmarked victim (switching only when
//! another is clearly nearer, so the arrow does not flap). [`Receiver::mark`] flags the
//! target as found and moves on to the next; marked victims stay in the list
//! ([`DisplayModel::list`]).
//!
//! # Memory: keep one instance, never move it
//! The victim bank is ≈ 85 KB ([`crate::victims::MAX_VICTIMS`] mixtures of
//! [`crate::victims::VICTIM_CAPACITY`] components), so a
//! [`Receiver`] must not be passed by value or copied around on the board (the stack is
//! far smaller). The board keeps exactly one in a `static` in `.uninit` SRAM (a `NOLOAD`
//! section that the runtime does not zero: its owner initializes it):
//!
//! ```ignore
//! #[unsafe(link_section = ".uninit.RECEIVER")]
//! static mut RECEIVER: MaybeUninit<Receiver> = MaybeUninit::uninit();
//! // once, at start-up (the only place that touches the static):
//! let rx: &'static mut Receiver = Receiver::emplace(unsafe { &mut *addr_of_mut!(RECEIVER) }, cfg)?;
//! ```
//!
//! [`Receiver::emplace`] writes the new receiver straight into its slot. The pulse front
//! end ([`Frontend`], ≈ 14 KB) is not part of the receiver: the board keeps it and the
//! ADC sample queue in the 64 KB CCM and lends it to [`Receiver::on_adc_sample`].
//!
//! # Time
//! Inputs carry integer time stamps ([`Instant`], µs since boot). Inside, the pipeline
//! computes in `f32` seconds from an [`Epoch`] that follows the present (moved in whole
//! 256 s steps, every stored time stamp shifted with it), so the resolution stays ≤ 61 µs
//! at any uptime; a stream shifted by whole seconds gives bit-identical results.
//!
//! # Errors
//! Every input is checked; a refused input returns an [`AppError`] and leaves the
//! receiver exactly as it was. Nothing here panics or allocates.

use core::mem::MaybeUninit;

use crate::Vec3;
use crate::estimate::{self, Attitude, Estimator, SogConfig, StepOutcome, VictimEstimate};
use crate::frame::rotation_from_rpy;
use crate::frontend::{Frontend, PulseMeasurement};
use crate::guidance::classic::{ClassicConfig, ClassicError, ClassicSearch};
use crate::guidance::{
    Guidance, GuidanceConfig, GuidanceInput, GuidanceOutput, HeightPrompt, Status,
    heading_supports, relative_arrow, to_degrees_wrapped,
};
use crate::motion::{Motion, MotionConfig, MotionError};
use crate::timebase::{Epoch, Instant, pulse_centre_us};
use crate::victims::{MAX_VICTIMS, MotionCut, Victim, VictimBank, VictimSog};

mod error;
pub use crate::display::{DisplayModel, VictimRow};
pub use error::AppError;

/// A target whose own pulses have not come for this long (s) gives way to a heard
/// unmarked victim: several signal timeouts, longer than most overlaps of two pulse
/// trains (tens of pulses), so the arrow does not hop between victims in overlaps.
pub const TARGET_SILENT_S: f32 = 15.0;
/// The target switches to another unmarked victim only when that one is nearer than this
/// fraction of the target's horizontal distance...
const SWITCH_RATIO: f32 = 0.6;
/// ...and the target is farther than this (m): never in its fine search.
const SWITCH_MIN_M: f32 = 8.0;

/// How the receiver guides the rescuer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SearchMode {
    /// The SOGs estimator per victim with its guidance (the default).
    #[default]
    Sog,
    /// The classical directional search (ICRA 2006 §II-A, [`crate::guidance::classic`]): flux line,
    /// turn-around on a falling signal, bracketing fine search; one transmitter, no
    /// estimator. For rescuers trained on classic receivers, or as a fallback.
    Classic,
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
    /// SOGs guidance or the classic directional search.
    pub mode: SearchMode,
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
            mode: SearchMode::Sog,
        }
    }
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
    /// Pulses of transmitters that found the victim list full.
    pub other_source: u32,
    /// Mixture re-initializations.
    pub reinitializations: u32,
    /// Pulses the estimator's outlier gate withheld (no component explains them).
    pub pulses_gated: u32,
}

/// The receiver application (see the module docs for how the board stores it).
#[derive(Debug, Clone)]
pub struct Receiver {
    bank: VictimBank,
    /// Slot of the victim the guidance leads to.
    target: Option<usize>,
    motion: Motion,
    guidance: Guidance,
    cfg: AppConfig,
    last: GuidanceOutput,
    last_outcome: Option<StepOutcome>,
    last_pulse_t: Option<f32>,
    /// Time of the last withheld pulse.
    last_withheld_t: Option<f32>,
    t_now: f32,
    pulses: u32,
    overlap: bool,
    stats: AppStats,
    /// Time of the front end's first sample on the IMU clock.
    adc_epoch: Instant,
    /// The origin of the `f32` seconds every part of the pipeline computes with (every
    /// stored time stamp above and inside is relative to it; see [`Epoch`]).
    epoch: Epoch,
    /// The classic directional search, in [`SearchMode::Classic`] only.
    classic: Option<ClassicSearch>,
}

/// The motion cut at a pulse at `t` when several victims share the motion
/// ([`Motion::take_split`]).
fn split_cut(motion: &mut Motion, t: f32) -> MotionCut {
    let split = motion.take_split(t);
    MotionCut {
        cut: to_estimate(&split.cut),
        partial: to_estimate(&split.partial),
        back: to_estimate(&split.back),
        distance_m: split.cut.distance_m,
        partial_m: split.partial.distance_m,
        steps: split.cut.steps,
        standing: split.standing,
        floors: Some(motion.config().noise),
    }
}

/// The classic mode's thresholds with this receiver's pulse noise and signal timeout.
fn classic_config(cfg: &AppConfig) -> ClassicConfig {
    ClassicConfig {
        sigma_bkg: cfg.sog.sigma_bkg,
        signal_timeout_s: cfg.signal_timeout_s,
        heading_d2: cfg.guidance.go_to_mean_d2,
        ..ClassicConfig::default()
    }
}

impl Receiver {
    /// A receiver waiting for its first samples; `InvalidConfig` when the filter refuses
    /// the configuration. On the board use [`Receiver::emplace`] instead (no 88 KB move).
    pub fn new(cfg: AppConfig) -> Result<Self, AppError> {
        Self::check_config(&cfg)?;
        Ok(Self::new_checked(cfg))
    }

    /// Whether [`Receiver::new`] accepts `cfg`, without building anything.
    fn check_config(cfg: &AppConfig) -> Result<(), AppError> {
        VictimSog::check_config(&cfg.sog)?;
        if cfg.mode == SearchMode::Classic {
            ClassicSearch::new(classic_config(cfg))?;
        }
        Ok(())
    }

    /// [`Receiver::new`] for a configuration already checked: infallible, so that
    /// [`Receiver::emplace`] builds the receiver straight into its slot.
    #[inline(always)]
    fn new_checked(cfg: AppConfig) -> Self {
        Self {
            bank: VictimBank::new_checked(cfg.sog),
            target: None,
            motion: Motion::new(cfg.motion),
            guidance: Guidance::new(cfg.guidance),
            cfg,
            last: GuidanceOutput::default(),
            last_outcome: None,
            last_pulse_t: None,
            last_withheld_t: None,
            t_now: 0.0,
            pulses: 0,
            overlap: false,
            stats: AppStats::default(),
            adc_epoch: Instant::ZERO,
            epoch: Epoch::new(),
            classic: match cfg.mode {
                SearchMode::Sog => None,
                SearchMode::Classic => ClassicSearch::new(classic_config(&cfg)).ok(),
            },
        }
    }

    /// Builds a receiver in `slot` (e.g. a `static` in `.uninit` RAM) and returns it.
    pub fn emplace(
        slot: &mut MaybeUninit<Receiver>,
        cfg: AppConfig,
    ) -> Result<&mut Receiver, AppError> {
        // Checked first, then built infallibly into the slot: a `Result<Receiver>`
        // temporary would put the whole ≈ 88 KB receiver on the stack.
        Self::check_config(&cfg)?;
        Ok(slot.write(Self::new_checked(cfg)))
    }

    /// Starts a new search with the same configuration.
    pub fn reset(&mut self) {
        if let Some(c) = self.classic.as_mut() {
            c.reset();
        }
        self.bank.reset();
        self.target = None;
        self.motion = Motion::new(self.cfg.motion);
        self.guidance.reset();
        self.last = GuidanceOutput::default();
        self.last_outcome = None;
        self.last_pulse_t = None;
        self.last_withheld_t = None;
        self.pulses = 0;
        self.overlap = false;
        self.stats = AppStats::default();
    }

    /// The configuration in use.
    pub fn config(&self) -> &AppConfig {
        &self.cfg
    }

    /// The target victim's SOGs filter (the first slot's without a target), read-only,
    /// e.g. to plot its components.
    pub fn filter(&self) -> &VictimSog {
        self.bank.filter(self.target.unwrap_or(0))
    }

    /// Every victim's mixture and list state.
    pub fn victims(&self) -> &VictimBank {
        &self.bank
    }

    /// Slot (list number − 1) of the victim the guidance leads to.
    pub fn target(&self) -> Option<usize> {
        self.target
    }

    /// The motion pipeline (read-only).
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The target victim's current belief, or `None` before initialization.
    pub fn estimate(&self) -> Option<VictimEstimate> {
        self.filter().estimate()
    }

    /// The rescuer marks the target victim as found: the guidance moves on to the nearest
    /// unmarked victim. Returns the marked victim's list number; `NoTarget` (nothing
    /// changed) when no victim is being guided to.
    pub fn mark(&mut self) -> Result<u8, AppError> {
        let i = self.target.ok_or(AppError::NoTarget)?;
        if !self.bank.mark(i) {
            return Err(AppError::NoTarget);
        }
        self.set_target(None);
        self.select_target();
        Ok(u8::try_from(i).unwrap_or(u8::MAX).saturating_add(1))
    }

    /// A pulse in the classic mode: the directional search takes the field, the attitude
    /// and the distance walked since the last pulse; the motion is consumed only when it
    /// accepts the pulse.
    fn on_pulse_classic(&mut self, t: f32, h_body: &Vec3) -> Result<DisplayModel, AppError> {
        let mut motion = self.motion.clone();
        let d = motion.take_displacement(t);
        let (rpy, cov) = motion.attitude();
        let pulse = estimate::Pulse { h: *h_body, t };
        let Some(classic) = self.classic.as_mut() else {
            return Err(AppError::Classic(ClassicError::BadConfig));
        };
        if let Err(e) = classic.on_pulse(&pulse, &Attitude { rpy, cov }, d.distance_m) {
            self.stats.pulses_refused = self.stats.pulses_refused.saturating_add(1);
            return Err(AppError::Classic(e));
        }
        self.motion = motion;
        self.overlap = false;
        self.pulses = self.pulses.saturating_add(1);
        self.last_pulse_t = Some(t);
        self.t_now = self.t_now.max(t);
        Ok(self.display_model())
    }

    /// Changes the target; a new target starts a new search control.
    fn set_target(&mut self, target: Option<usize>) {
        if target != self.target {
            self.target = target;
            self.guidance.reset();
            self.last = GuidanceOutput::default();
            self.motion.set_lift_mode(false);
        }
    }

    /// Keeps the target unless it was marked or dropped, or another unmarked victim is
    /// much nearer and the target is not close (hysteresis: the arrow must not flap
    /// between two victims at similar distances).
    fn select_target(&mut self) {
        // Only the target's own pulses renew its guidance: a target silent for
        // TARGET_SILENT_S (its track lost, or a long overlap) while another unmarked
        // victim is heard gives way to the nearest heard one (else the rescuer is left
        // with "no signal" and walks off). Shorter silences (overlaps) keep it.
        let heard_since = self.t_now - self.cfg.signal_timeout_s;
        let heard = self.bank.nearest_unmarked_heard_since(heard_since);
        let current = self
            .target
            .and_then(|i| self.bank.get(i).map(|v| (i, v)))
            .filter(|(_, v)| !v.marked())
            .filter(|(_, v)| self.t_now - v.last_t() <= TARGET_SILENT_S || heard.is_none());
        let nearest = if current.is_none() {
            heard.or_else(|| self.bank.nearest_unmarked())
        } else {
            self.bank.nearest_unmarked()
        };
        let next = match (current, nearest) {
            (None, n) => n.map(|n| n.0),
            (Some((c, v)), Some((n, dn))) if n != c => match v.position_now() {
                Some(p) => {
                    let dc = p.xy().norm();
                    if dc > SWITCH_MIN_M && dn < SWITCH_RATIO * dc {
                        Some(n)
                    } else {
                        Some(c)
                    }
                }
                None => Some(n),
            },
            (Some((c, _)), _) => Some(c),
        };
        if next.is_some() || current.is_none() {
            self.set_target(next);
        }
    }

    /// The receiver's height above the snow (m): the configured holding height
    /// ([`GuidanceConfig::receiver_height_m`]) plus the vertical moves the accelerometer
    /// measured while standing and handed to the estimator (lowering to the snow, raising
    /// again; a lift nets zero), so that the depth shown, `−p_z − height`, stays right.
    /// A move the rescuer made while walking is not measured: the height (like the
    /// estimator) does not see it.
    pub fn height_m(&self) -> f32 {
        (self.cfg.guidance.receiver_height_m + self.motion.vertical_m()).max(0.0)
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

    /// One IMU sample at `t`: specific force (m/s²), rate (rad/s), flux density (µT;
    /// `None` when the magnetometer gave none), body frame. A gap in the stream is
    /// bridged (the motion pipeline resynchronizes and inflates its uncertainty).
    pub fn on_imu(
        &mut self,
        t: Instant,
        acc: &Vec3,
        gyr: &Vec3,
        mag: Option<&Vec3>,
    ) -> Result<(), AppError> {
        let before = self.epoch;
        let rel = self.epoch.seconds(t);
        let r = self.on_imu_at(rel, acc, gyr, mag);
        self.settle_epoch(before, rel, r.is_ok());
        r
    }

    /// [`Receiver::on_imu`] at `t` s from the epoch.
    fn on_imu_at(
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
                // The lift and height prompts last while pulses come; without them, steps
                // count again.
                if self.motion.lift_mode() && !self.prompt_shown() {
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

    /// One received pulse at `t` (the IMU's clock): the field vector in the body frame
    /// (A/m, overall sign arbitrary) and the front end's source attribution (`None`: a
    /// single transmitter). The pulse updates its own victim's mixture (a new victim gets
    /// a free slot; when the list is full the pulse is counted in
    /// [`AppStats::other_source`]); the guidance follows the target victim. Returns the
    /// new display.
    pub fn on_pulse(
        &mut self,
        t: Instant,
        h_body: &Vec3,
        src: Option<u8>,
    ) -> Result<DisplayModel, AppError> {
        let before = self.epoch;
        let rel = self.epoch.seconds(t);
        let r = self.on_pulse_at(rel, h_body, src);
        self.settle_epoch(before, rel, r.is_ok());
        r
    }

    /// After an input at `rel` s from the epoch: a refused one leaves the epoch as it
    /// was (`before`); an accepted one moves it on when due, every stored time stamp
    /// with it.
    fn settle_epoch(&mut self, before: Epoch, rel: f32, accepted: bool) {
        if !accepted {
            self.epoch = before;
            return;
        }
        let shift = self.epoch.rebase_due(rel);
        if shift > 0.0 {
            self.rebase(shift);
        }
    }

    /// Moves the epoch `shift` s (a multiple of [`Epoch::STEP_S`]) later and every stored
    /// time stamp with it.
    fn rebase(&mut self, shift: f32) {
        self.epoch.advance(shift);
        self.t_now -= shift;
        for t in [&mut self.last_pulse_t, &mut self.last_withheld_t]
            .into_iter()
            .flatten()
        {
            *t -= shift;
        }
        self.motion.rebase(shift);
        self.bank.rebase(shift);
        if let Some(c) = self.classic.as_mut() {
            c.rebase(shift);
        }
    }

    /// `t` as the `f32` seconds the pipeline computes with (from the current epoch), for
    /// a host that queries [`Receiver::motion`] or [`Receiver::victims`] at a time.
    pub fn seconds(&self, t: Instant) -> f32 {
        self.epoch.peek(t)
    }

    /// A time the pipeline reports (`f32` s from the epoch, e.g. [`Victim::last_t`]) in
    /// seconds since boot.
    pub fn secs_since_boot(&self, rel: f32) -> f64 {
        self.epoch.secs_f64(rel)
    }

    /// [`Receiver::on_pulse`] at `t` s from the epoch.
    fn on_pulse_at(
        &mut self,
        t: f32,
        h_body: &Vec3,
        src: Option<u8>,
    ) -> Result<DisplayModel, AppError> {
        if !t.is_finite() || !h_body.iter().all(|v| v.is_finite()) {
            self.stats.pulses_refused = self.stats.pulses_refused.saturating_add(1);
            return Err(AppError::NonFinite);
        }
        if self.classic.is_some() {
            return self.on_pulse_classic(t, h_body);
        }
        // A source not in the list may be a listed victim's transmitter under a new track
        // id: the victim whose mixture explains the pulse takes it (see
        // `VictimBank::reassociate`), before a slot is taken or the pulse dropped.
        if self.bank.slot_of(src).is_none() && !self.bank.is_empty() {
            let mut m = self.motion.clone();
            let cut = split_cut(&mut m, t);
            let (rpy, cov) = m.attitude();
            let pulse = estimate::Pulse { h: *h_body, t };
            let _ = self
                .bank
                .reassociate(src, &cut, &Attitude { rpy, cov }, &pulse);
        }
        let Some(slot) = self.bank.slot_for(src, t) else {
            self.stats.other_source = self.stats.other_source.saturating_add(1);
            return Ok(self.display_model());
        };
        let fresh = !self.bank.get(slot).is_some_and(|v| v.has_src(src));
        // The display said "no signal" before this pulse (as in `display_model`).
        let signal_lost = !fresh
            && self
                .bank
                .get(slot)
                .is_some_and(|v| t - self.last_heard_t(v) > self.cfg.signal_timeout_s);
        // Work on a copy of the motion state: the displacement is only consumed when the
        // estimator accepts the pulse.
        let mut motion = self.motion.clone();
        // A lone victim (the list holds only this pulse's own) takes the whole interval
        // as the single filter did; with several, the cut is split (see `take_split`).
        let lone = match self.bank.len() {
            0 => true,
            1 => self.bank.get(slot).is_some_and(|v| v.has_src(src)),
            _ => false,
        };
        let cut = if lone {
            let d = motion.take_displacement(t);
            MotionCut {
                cut: to_estimate(&d),
                partial: estimate::Displacement::zero(),
                back: estimate::Displacement::zero(),
                distance_m: d.distance_m,
                partial_m: 0.0,
                steps: d.steps,
                standing: false,
                floors: None,
            }
        } else {
            split_cut(&mut motion, t)
        };
        let (rpy, cov) = motion.attitude();
        let attitude = Attitude { rpy, cov };
        let pulse = estimate::Pulse { h: *h_body, t };
        // A mixture (re)initialized on this pulse puts the victim below the receiver's
        // height now, lowered or not (with several victims, mixtures start all along the
        // search, also while the receiver is low).
        self.bank.set_receiver_height(self.height_m());
        let stepped = self.bank.step(slot, src, &cut, &attitude, &pulse);
        let (report, own) = match stepped {
            Ok(r) => r,
            Err(e) => {
                self.stats.pulses_refused = self.stats.pulses_refused.saturating_add(1);
                return Err(AppError::Estimate(e));
            }
        };
        self.motion = motion;
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
        self.bank.drop_lost(t);
        // A target dropped, or its slot given to another transmitter, is no longer one.
        if self
            .target
            .is_some_and(|i| self.bank.get(i).is_none() || (fresh && i == slot))
        {
            self.set_target(None);
        }
        if self.target.is_none() && self.bank.get(slot).is_some_and(|v| !v.marked()) {
            // The first victim heard leads until a nearer one is localized.
            self.set_target(Some(slot));
        }
        self.select_target();
        if self.target == Some(slot) {
            // The pulse's field in G_k for the flux line: h_G = R_GR(rpy) h_R.
            let h_g = rotation_from_rpy(&rpy) * h_body;
            self.last = self.guidance.update(&GuidanceInput {
                // An outlier's field would bend the flux line the wrong way.
                h_g: (!gated).then_some(h_g),
                walked_m: own.distance_m,
                yaw: rpy.z,
                yaw_var: cov.m33,
                estimate: self.bank.filter(slot).estimate(),
                reinitialized,
                signal_lost,
                height_m: Some(self.height_m()),
                // Several victims: no lowering. Each lowering and the raise before the
                // walk to the next victim make the rescuer stand ≈ 3 s; measured on
                // `multi-report` seeds 1–50 (604 victims), lowering every victim took the
                // median time to find all from 119 to 130 s for a per-victim error of
                // 0.037 instead of 0.051 m, both well within what the probe reaches. With
                // one victim the lowering is nearly free (the stand overlaps the fine
                // search's own) and pays.
                lower_allowed: self.bank.len() <= 1,
            });
            // Lifting, lowering or raising the receiver: stand, steps not counted.
            self.motion
                .set_lift_mode(self.last.lift || self.last.height_prompt != HeightPrompt::None);
        }
        Ok(self.display_model())
    }

    /// Sets the time (on the IMU's clock) of the front end's first ADC sample, so that
    /// its pulses ([`crate::frontend::Pulse::start_sample`]) can be put on the IMU's clock.
    pub fn set_adc_epoch(&mut self, t0: Instant) {
        self.adc_epoch = t0;
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
        // The pulse centre from the integer sample index (the front end's `t_s` is f32
        // seconds since its first sample and loses resolution with uptime).
        let rate = frontend.config().sample_rate_hz;
        let t = self
            .adc_epoch
            .plus_micros(pulse_centre_us(p.start_sample, p.duration_s, rate));
        match p.measurement {
            PulseMeasurement::Field(h) => self.on_pulse(t, &h, p.src).map(Some),
            PulseMeasurement::Overlap
            | PulseMeasurement::Saturated
            | PulseMeasurement::Truncated => Ok(Some(self.on_withheld(t))),
        }
    }

    /// A pulse the front end withheld at `t` (s; overlapping transmitters, clipping,
    /// truncation): no estimator sees it; the display flags it, and the target's signal
    /// does not time out meanwhile (its pulses are likely among the withheld). Returns
    /// the display.
    pub fn on_withheld(&mut self, t: Instant) -> DisplayModel {
        let before = self.epoch;
        let rel = self.epoch.seconds(t);
        let d = self.on_withheld_at(rel);
        self.settle_epoch(before, rel, true);
        d
    }

    /// [`Receiver::on_withheld`] at `t` s from the epoch.
    fn on_withheld_at(&mut self, t: f32) -> DisplayModel {
        if t.is_finite() {
            self.last_withheld_t = Some(self.last_withheld_t.map_or(t, |w| w.max(t)));
        }
        self.bank.note_withheld(t);
        self.overlap = true;
        self.stats.pulses_withheld = self.stats.pulses_withheld.saturating_add(1);
        self.display_model()
    }

    /// When victim `v` was last heard (s): its own last pulse, or a later withheld
    /// (overlapping) pulse, which may have been its own.
    fn last_heard_t(&self, v: &Victim) -> f32 {
        v.last_t().max(self.last_withheld_t.unwrap_or(f32::MIN))
    }

    /// The display now: the last pulse's guidance, with the arrow turned by the device's
    /// current heading (the compass keeps the arrow right between pulses), and "no
    /// signal" when no pulse came for [`AppConfig::signal_timeout_s`] — then with an
    /// arrow to where a localized target is now, the walk since its last pulse included.
    pub fn display_model(&self) -> DisplayModel {
        let g = &self.last;
        let yaw = self.motion.attitude().0.z;
        if let Some(c) = &self.classic {
            let d = c.display(self.t_now, yaw);
            return DisplayModel {
                overlap: self.overlap,
                height_m: self.height_m(),
                // The classic search reports its f32 time from the epoch.
                t_s: self.epoch.secs_f64(d.t_s),
                ..DisplayModel::from(d)
            };
        }
        let timed_out = self.target_timed_out();
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
        let list = self.victim_list(yaw);
        // A target whose own pulses do not come is shown where its mixture puts it now
        // (carried over the walk since its last pulse), so the rescuer walks there instead
        // of searching blindly; its next own pulse brings the search control's guidance
        // back. Several victims (withheld in a long overlap, or just chosen after a mark):
        // any estimate, shown as localized. One victim (its transmitter paused, or the
        // pulses lost in interference): only a mixture the search control had trusted
        // (localized), under "no signal"; a flux-line mixture does not say where to go.
        let several = self.bank.len() >= 2;
        // Without a heading (no magnetometer) no position is shown as a place to walk
        // to (see `guidance::heading_supports`).
        let heading = heading_supports(
            self.motion.attitude().1.m33,
            self.guidance.config().go_to_mean_d2,
        );
        let silent =
            (status == Status::NoSignal && heading && (several || g.status == Status::Localized))
                .then(|| self.target_position_now())
                .flatten()
                .and_then(|p| {
                    let arrow = arrow_deg_to(&p, yaw);
                    arrow
                        .is_finite()
                        .then_some((arrow, p.xy().norm(), p.norm()))
                });
        let (status, arrow_deg, walk_m, horizontal_m, distance_m) = match silent {
            Some((arrow, h, d)) => {
                let shown = if several {
                    Status::Localized
                } else {
                    Status::NoSignal
                };
                (shown, Some(arrow), Some(h), Some(h), Some(d))
            }
            None => (status, arrow_deg, g.walk_m, g.horizontal_m, g.distance_m),
        };
        DisplayModel {
            status,
            arrow_deg,
            distance_m,
            horizontal_m,
            depth_m: g.depth_m,
            walk_m,
            uncertainty_m: g.sigma_h_m,
            victims: u8::try_from(self.bank.len()).unwrap_or(u8::MAX),
            overlap: self.overlap,
            pulses: self.pulses,
            t_s: self
                .target
                .and_then(|i| self.bank.get(i))
                .map(Victim::last_t)
                .or(self.last_pulse_t)
                .map_or(0.0, |t| self.epoch.secs_f64(t)),
            lift: g.lift && !timed_out,
            height_prompt: if timed_out {
                HeightPrompt::None
            } else {
                g.height_prompt
            },
            height_m: self.height_m(),
            list,
            target: self
                .target
                .map(|i| u8::try_from(i).unwrap_or(u8::MAX).saturating_add(1)),
            found: u8::try_from(self.bank.active().filter(|(_, v)| v.marked()).count())
                .unwrap_or(u8::MAX),
        }
    }

    /// Whether the target's own pulses stopped for longer than the signal timeout (or
    /// there is no target). Withheld (overlapping) pulses keep the target alive: its own
    /// may be among them; another victim's pulses do not guide to this one.
    fn target_timed_out(&self) -> bool {
        self.target
            .and_then(|i| self.bank.get(i))
            .map(|v| self.last_heard_t(v))
            .is_none_or(|t| self.t_now - t > self.cfg.signal_timeout_s)
    }

    /// Whether the display shows a lift or height prompt, without building it (the
    /// check runs on every IMU sample).
    fn prompt_shown(&self) -> bool {
        if self.classic.is_some() {
            let d = self.display_model();
            return d.lift || d.height_prompt != HeightPrompt::None;
        }
        !self.target_timed_out()
            && (self.last.lift || self.last.height_prompt != HeightPrompt::None)
    }

    /// The target victim's position relative to the receiver now: its estimate carried
    /// over the motion since its last pulse, the running interval included (closed on a
    /// copy of the motion state, which is left as it is).
    fn target_position_now(&self) -> Option<Vec3> {
        let v = self.target.and_then(|i| self.bank.get(i))?;
        let more = self.motion.clone().take_displacement(self.t_now);
        v.position_after(&to_estimate(&more))
    }

    /// The victim list now: distance and direction to each victim's estimate.
    fn victim_list(&self, yaw: f32) -> [Option<VictimRow>; MAX_VICTIMS] {
        let mut list = [None; MAX_VICTIMS];
        for (i, v) in self.bank.active() {
            let p = v.position_now();
            let row = VictimRow {
                number: u8::try_from(i).unwrap_or(u8::MAX).saturating_add(1),
                distance_m: p.map(|p| p.xy().norm()),
                arrow_deg: p.map(|p| arrow_deg_to(&p, yaw)).filter(|a| a.is_finite()),
                marked: v.marked(),
                target: self.target == Some(i),
            };
            if let Some(slot) = list.get_mut(i) {
                *slot = Some(row);
            }
        }
        list
    }
}

/// The arrow (degrees, positive left, in (-180, 180]) to the position `p` relative to the
/// receiver, for a device heading `yaw`.
fn arrow_deg_to(p: &Vec3, yaw: f32) -> f32 {
    to_degrees_wrapped(relative_arrow(libm::atan2f(p.y, p.x), yaw))
}

/// The motion pipeline's displacement as the estimators take it.
fn to_estimate(d: &crate::motion::Displacement) -> estimate::Displacement {
    estimate::Displacement {
        translation: d.translation,
        rotation: d.rotation,
        cov: d.cov,
        absolute: d.absolute,
        absolute_cov: d.absolute_cov,
    }
}

#[cfg(test)]
#[path = "app_uptime_tests.rs"]
mod uptime_tests;

#[cfg(test)]
#[path = "app_tests.rs"]
mod tests;
