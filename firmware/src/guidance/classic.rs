//! The receiver's "classic" mode: the classical directional search of commercial
//! three-antenna receivers (Piniés & Tardós, ICRA 2006, §II-A), run on the receiver's own
//! pulses and attitude, without the SOGs filter.
//!
//! One [`ClassicSearch::on_pulse`] per received pulse; [`ClassicSearch::display`] gives
//! the screen at any time (the arrow relative to the device's current yaw).
//!
//! # Phases
//! - **Secondary search** ([`Instruction::FollowFlux`]): the arrow is the horizontal
//!   projection of the pulse's field in `G` (`h_G = R_GR h_R`), the flux line. Its sign is
//!   not measured (sign-ambiguous pulses): it is chosen to agree with the current walking
//!   direction (at the first pulse, the device's forward axis). ICRA §II-A: "if after
//!   following the initial direction along 5 m the signal decreases, the rescuer must turn
//!   and follow the opposite direction" — when the smoothed |H| has not exceeded its best
//!   value over [`ClassicConfig::flip_after_m`] walked (dead-reckoned), the direction is
//!   reversed ([`Instruction::TurnAround`]).
//! - **Return to the peak** ([`Instruction::ReturnToPeak`]): when the signal fell after a
//!   peak whose distance reading was within [`ClassicConfig::peak_m`], the receiver walked
//!   over the victim: it sends the rescuer back along the flux line the distance walked
//!   since the peak.
//! - **Fine search** (bracketing, [`Instruction::LowerToSnow`], [`Instruction::Move`]):
//!   started when the distance reading falls below [`ClassicConfig::fine_m`] or after the
//!   return to the peak. The rescuer holds the receiver near the snow and moves it, point
//!   by point, along two perpendicular lines fixed in `G` (the flux line's last bearing,
//!   then across it), first with [`ClassicConfig::coarse_spacing_m`], then
//!   [`ClassicConfig::fine_spacing_m`]. On each line the receiver tracks the maximum of
//!   |H|: a line goes on while |H| grows, is tried on the other side when the first point
//!   is weaker than the centre, and ends two points past the maximum; the next line is
//!   centred on that maximum. The receiver does not measure the hand's motion: it counts
//!   points, each the move it asked for, and takes a point's reading from the first pulse
//!   that comes [`ClassicConfig::settle_s`] plus the move at [`ClassicConfig::hand_speed_m_s`]
//!   after the request (the hand has arrived and is still). Shown as "localized" only
//!   with a heading ([`ClassicConfig::heading_d2`]), else as the flux line.
//! - **Probe** ([`Instruction::Probe`]): after the last line, the arrow and distance lead
//!   back to the line's maximum: probe there.
//!
//! # The distance shown
//! Commercial receivers show a "flux-line distance" from |H|. Here it is the on-axis range
//! of a beacon with the nominal moment [`ClassicConfig::nominal_moment`] that gives the
//! measured |H|: `d = (2 m_nom / (4π |H|))^{1/3}` (the axis of the dipole field, ICRA
//! eq. 1). It is the true distance only for a nominal beacon seen on its axis; off axis it
//! reads up to `2^{1/3}` ≈ 1.26× long (the field on the equator is half that on the
//! axis), and a beacon of moment `m` reads
//! `(m_nom / m)^{1/3}` too far (0.7× … 1.5× over the standard's 3e-3 … 3e-2 A·m²).
//!
//! # Smoothing
//! A pulse is heard from |H| ≈ 3 σ_bkg (ICRA eq. 10: `σ² = σ_bkg² + (k_sen |H|)²` per
//! component), where one pulse's |H| is off by ~30 % and its direction by tens of degrees.
//! At 1 pulse/s and 1 m/s, |H| ∝ r⁻³ changes by < 15 % over 3 pulses beyond 20 m, so the
//! flip rule compares the mean |H| of the last [`SMOOTH_PULSES`] pulses (the noise of the
//! mean √3 smaller) and the flux-line direction sums the sign-aligned horizontal unit
//! directions weighted by their SNR `w = s²/(1+s²)`, `s = |H|/(√3 σ_bkg)`, forgetting them
//! over [`ClassicConfig::flux_memory_m`] walked. In the fine search |H| is far above
//! σ_bkg, its noise is `k_sen` = 3 % per reading, while one coarse spacing (0.5 m) at the
//! ≤ 3 m range of the fine search changes |H| by ≥ 15 % along the line: one pulse per point.
//!
//! Bad input (non-finite or zero field, time going back, negative or non-finite walk,
//! non-finite attitude) is refused with a [`ClassicError`] and leaves the state unchanged.

use crate::Vec3;
use crate::estimate::{Attitude, Pulse};
use crate::frame::{rotation_from_rpy, wrap_pi};
use crate::guidance::{
    GuidanceConfig, Status, flux_direction, heading_supports, relative_arrow, to_degrees_wrapped,
};

/// Pulses averaged for the flip rule (module docs, "Smoothing").
pub const SMOOTH_PULSES: usize = 3;

/// Largest walk accepted between two pulses, m: a running rescuer (≈ 3 m/s) over a lost
/// signal's gap of ten or more seconds; beyond it the dead reckoning is broken.
pub const MAX_WALK_M: f32 = 50.0;

/// Thresholds of the classic mode (module docs give the physics of each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicConfig {
    /// Nominal beacon moment of the distance reading, A·m² (the geometric mean of the
    /// standard's 3e-3 … 3e-2).
    pub nominal_moment: f32,
    /// Background noise per field component, A/m (ICRA eq. 10): the SNR weights.
    pub sigma_bkg: f32,
    /// Walked distance without a new maximum of the smoothed |H| that reverses the
    /// direction, m (ICRA §II-A: 5 m).
    pub flip_after_m: f32,
    /// A fall after a peak whose distance reading is within this (m) means the receiver
    /// passed over the victim: go back to the peak and start the fine search. About twice
    /// the largest range over a victim (3 m deep, receiver 1 m up, weak beacon off axis).
    pub peak_m: f32,
    /// Distance reading below which the fine search starts, m (commercial receivers
    /// switch to the fine search at ~3 m).
    pub fine_m: f32,
    /// Walked distance over which the flux-line direction forgets past pulses, m.
    pub flux_memory_m: f32,
    /// Point spacing of the first two bracketing lines, m.
    pub coarse_spacing_m: f32,
    /// Point spacing of the last two bracketing lines, m.
    pub fine_spacing_m: f32,
    /// Most points per side of a bracketing line (bounds a line at 12 × spacing).
    pub max_points: u8,
    /// Time for the rescuer to read the request and hold the receiver still, beside the
    /// move itself, s (≈ 0.5 s reading lag + 0.2 s to settle).
    pub settle_s: f32,
    /// Speed of the hand moving the receiver over the snow, m/s.
    pub hand_speed_m_s: f32,
    /// Height the receiver is lowered by at the start of the fine search, m (1 m → 0.2 m).
    pub lower_m: f32,
    /// No pulse for this long: "no signal", s (≈ 3 missed pulses of a 1 s beacon).
    pub signal_timeout_s: f32,
    /// The SOGs guidance's go-to-mean gate ([`GuidanceConfig::go_to_mean_d2`]): the fine
    /// search shows "localized" only with a heading that passes [`heading_supports`].
    pub heading_d2: f32,
}

impl Default for ClassicConfig {
    fn default() -> Self {
        Self {
            nominal_moment: 9.5e-3,
            sigma_bkg: 2.59e-9,
            flip_after_m: 5.0,
            peak_m: 8.0,
            fine_m: 3.0,
            flux_memory_m: 3.0,
            coarse_spacing_m: 0.5,
            fine_spacing_m: 0.2,
            max_points: 12,
            settle_s: 0.7,
            hand_speed_m_s: 0.5,
            lower_m: 0.8,
            signal_timeout_s: 3.5,
            heading_d2: GuidanceConfig::default().go_to_mean_d2,
        }
    }
}

impl ClassicConfig {
    /// Whether every threshold is finite and positive.
    pub fn is_valid(&self) -> bool {
        [
            self.nominal_moment,
            self.sigma_bkg,
            self.flip_after_m,
            self.peak_m,
            self.fine_m,
            self.flux_memory_m,
            self.coarse_spacing_m,
            self.fine_spacing_m,
            self.settle_s,
            self.hand_speed_m_s,
            self.lower_m,
            self.signal_timeout_s,
            self.heading_d2,
        ]
        .iter()
        .all(|v| v.is_finite() && *v > 0.0)
            && self.max_points > 0
    }

    /// The distance reading for a field magnitude `h` (A/m): the on-axis range of the
    /// nominal beacon (module docs), m.
    pub fn distance_reading(&self, h: f32) -> f32 {
        libm::cbrtf(2.0 * self.nominal_moment / (4.0 * core::f32::consts::PI * h.max(1e-30)))
    }
}

/// Why an input was refused (the state is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClassicError {
    /// A non-finite configuration value, or one not positive.
    #[error("configuration value not finite or not positive")]
    BadConfig,
    /// Non-finite pulse, attitude or walk.
    #[error("pulse, attitude or walk not finite")]
    NonFinite,
    /// The field vector is zero: no direction, no distance.
    #[error("zero field vector")]
    ZeroField,
    /// The pulse time is before the previous pulse's.
    #[error("pulse time before the previous pulse")]
    TimeNotIncreasing,
    /// A negative walked distance.
    #[error("negative walked distance")]
    NegativeWalk,
    /// A walked distance above [`MAX_WALK_M`].
    #[error("walked distance above the plausible maximum")]
    ImplausibleWalk,
}

/// What the rescuer is asked to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Instruction {
    /// No usable pulse (yet, or for too long).
    #[default]
    Search,
    /// Walk along the arrow (the flux line).
    FollowFlux,
    /// The signal fell over the last metres: turn around and follow the flux line back.
    TurnAround,
    /// Walk back along the arrow the distance shown, to the strongest point.
    ReturnToPeak,
    /// Stand and hold the receiver just above the snow (the fine search starts here).
    LowerToSnow,
    /// Fine search: move the receiver the distance shown along the arrow and hold it.
    Move,
    /// Probe at the distance shown along the arrow (0: here).
    Probe,
}

/// The classic mode's guidance after a pulse.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClassicOutput {
    /// What the rescuer is asked to do.
    pub instruction: Instruction,
    /// Bearing in `G` to walk or move along (rad, from north toward west).
    pub bearing: Option<f32>,
    /// Distance reading from |H| (module docs, "The distance shown"), m.
    pub distance_m: Option<f32>,
    /// Distance to walk or move along the bearing (return, fine search, probe), m.
    pub walk_m: Option<f32>,
    /// Smoothed |H| of the secondary search, or the last reading in the fine search, A/m.
    pub h_norm: f32,
    /// Index of the bracketing line (0 … 3) in the fine search.
    pub line: Option<u8>,
    /// Requests made so far: a new value is a new request (the receiver beeps); the
    /// fine search repeats its request on the pulses taken while the hand is moving.
    pub request: u32,
}

/// One bracketing line of the fine search.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Line {
    /// Index 0 … 3: even along `bearing0`, odd across; the first two at the coarse spacing.
    index: u8,
    /// Bearing of the line's positive direction in `G`, rad.
    bearing: f32,
    /// Where the receiver is asked to be, in points from the line's centre.
    pos: i16,
    /// Side being explored (+1 / −1) and whether the other side was tried.
    side: i16,
    reversed: bool,
    /// Consecutive readings weaker than the best.
    below: u8,
    best_h: f32,
    best_pos: i16,
    /// The reading at `pos` counts from this time on, s.
    ready_t: f32,
}

/// Phase of the search.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Following the flux line.
    Secondary,
    /// Walking back `remaining` m along `bearing` to the peak.
    Return { remaining: f32 },
    /// Bracketing.
    Fine(Line),
    /// Done: "probe here" (at the distance shown from the last point).
    Found,
}

/// The classic-mode state machine (module docs). Fixed size, no heap.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassicSearch {
    cfg: ClassicConfig,
    phase: Phase,
    /// Walking bearing in `G` (rad), once known.
    bearing: Option<f32>,
    /// SNR-weighted sum of sign-aligned horizontal flux directions.
    flux_acc: [f32; 2],
    recent: [f32; SMOOTH_PULSES],
    n_recent: usize,
    best_h: f32,
    since_best_m: f32,
    last_t: Option<f32>,
    pulses: u32,
    out: ClassicOutput,
    /// The last pulse's yaw variance passed [`heading_supports`].
    heading: bool,
}

/// What the classic mode shows; the application turns it into its display model (the
/// classic mode sits below the application and does not know its screen).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicScreen {
    /// Status word.
    pub status: Status,
    /// Arrow relative to the device's heading, degrees, positive to the left; `None`: none.
    pub arrow_deg: Option<f32>,
    /// Distance estimated from |H|, m.
    pub distance_m: Option<f32>,
    /// Distance to walk along the arrow, m.
    pub walk_m: Option<f32>,
    /// Pulses taken so far.
    pub pulses: u32,
    /// Time of the last pulse, s (0 before the first).
    pub t_s: f32,
}

impl ClassicSearch {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        if let Some(t) = self.last_t.as_mut() {
            *t -= shift_s;
        }
        if let Phase::Fine(line) = &mut self.phase {
            line.ready_t -= shift_s;
        }
    }

    /// A search waiting for its first pulse; refuses a configuration that is not valid.
    pub fn new(cfg: ClassicConfig) -> Result<Self, ClassicError> {
        if !cfg.is_valid() {
            return Err(ClassicError::BadConfig);
        }
        Ok(Self::waiting(cfg))
    }

    /// The state before the first pulse, for a configuration already checked.
    fn waiting(cfg: ClassicConfig) -> Self {
        Self {
            cfg,
            phase: Phase::Secondary,
            bearing: None,
            flux_acc: [0.0; 2],
            recent: [0.0; SMOOTH_PULSES],
            n_recent: 0,
            best_h: 0.0,
            since_best_m: 0.0,
            last_t: None,
            pulses: 0,
            out: ClassicOutput::default(),
            heading: false,
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &ClassicConfig {
        &self.cfg
    }

    /// The guidance after the last accepted pulse.
    pub fn output(&self) -> &ClassicOutput {
        &self.out
    }

    /// Pulses accepted so far.
    pub fn pulses(&self) -> u32 {
        self.pulses
    }

    /// Back to the start (a new search).
    pub fn reset(&mut self) {
        *self = Self::waiting(self.cfg);
    }

    /// One received pulse: its field in the body frame (sign arbitrary), the attitude at
    /// the pulse, and the horizontal distance walked since the previous pulse
    /// (dead-reckoned, m; `motion::Displacement::distance_m`). On error the state is
    /// unchanged.
    pub fn on_pulse(
        &mut self,
        pulse: &Pulse,
        attitude: &Attitude,
        walked_m: f32,
    ) -> Result<ClassicOutput, ClassicError> {
        let finite = pulse.t.is_finite()
            && pulse.h.iter().all(|v| v.is_finite())
            && attitude.rpy.iter().all(|v| v.is_finite())
            && walked_m.is_finite();
        if !finite {
            return Err(ClassicError::NonFinite);
        }
        if walked_m < 0.0 {
            return Err(ClassicError::NegativeWalk);
        }
        if walked_m > MAX_WALK_M {
            return Err(ClassicError::ImplausibleWalk);
        }
        if self.last_t.is_some_and(|t| pulse.t < t) {
            return Err(ClassicError::TimeNotIncreasing);
        }
        let h_g = rotation_from_rpy(&attitude.rpy) * pulse.h;
        let n = h_g.norm();
        if !n.is_finite() {
            return Err(ClassicError::NonFinite);
        }
        if n <= 0.0 {
            return Err(ClassicError::ZeroField);
        }
        self.last_t = Some(pulse.t);
        self.pulses = self.pulses.saturating_add(1);
        self.heading = heading_supports(attitude.cov[(2, 2)], self.cfg.heading_d2);
        let yaw = attitude.rpy.z;
        let before = self.phase;
        let request = self.out.request;
        self.out = match self.phase {
            Phase::Secondary => self.secondary(&h_g, n, walked_m, yaw),
            Phase::Return { remaining } => self.returning(&h_g, n, remaining - walked_m, yaw),
            Phase::Fine(line) => self.fine(line, n, pulse.t),
            Phase::Found => self.out,
        };
        self.out.request = if self.phase == before {
            request
        } else {
            request.saturating_add(1)
        };
        Ok(self.out)
    }

    /// The screen at time `t_now` (s) with the device's current yaw (rad): the arrow is the
    /// output's bearing relative to the device; "no signal" after the timeout.
    pub fn display(&self, t_now: f32, yaw: f32) -> ClassicScreen {
        let lost = self
            .last_t
            .is_none_or(|t| t_now - t > self.cfg.signal_timeout_s);
        let searching = matches!(self.phase, Phase::Secondary | Phase::Return { .. });
        let status = match self.out.instruction {
            _ if lost && searching => Status::NoSignal,
            Instruction::Search => Status::NoSignal,
            Instruction::FollowFlux | Instruction::TurnAround | Instruction::ReturnToPeak => {
                Status::FluxLine
            }
            // The bracketing lines are fixed in `G`: without a heading (no magnetometer)
            // the receiver does not claim to know where the victim is (issue 22's rule).
            Instruction::LowerToSnow | Instruction::Move if self.heading => Status::Localized,
            Instruction::LowerToSnow | Instruction::Move => Status::FluxLine,
            Instruction::Probe => Status::Probe,
        };
        let arrow = (status != Status::NoSignal)
            .then_some(self.out.bearing)
            .flatten()
            .map(|b| to_degrees_wrapped(relative_arrow(b, yaw)));
        ClassicScreen {
            status,
            arrow_deg: arrow,
            distance_m: self.out.distance_m,
            walk_m: self.out.walk_m,
            pulses: self.pulses,
            t_s: self.last_t.unwrap_or(0.0),
        }
    }

    /// Mean |H| of the last pulses, with `n` pushed.
    fn push_smoothed(&mut self, n: f32) -> f32 {
        self.recent.rotate_left(1);
        if let Some(last) = self.recent.last_mut() {
            *last = n;
        }
        self.n_recent = (self.n_recent + 1).min(SMOOTH_PULSES);
        let sum: f32 = self.recent.iter().rev().take(self.n_recent).sum();
        sum / self.n_recent.max(1) as f32
    }

    /// The flux-line bearing: this pulse's horizontal direction aligned with the walking
    /// direction, SNR-weighted into the forgetting sum (module docs).
    fn flux_bearing(&mut self, h_g: &Vec3, n: f32, walked_m: f32, yaw: f32) -> Option<f32> {
        let reference_b = self.bearing.unwrap_or(yaw);
        let reference = [libm::cosf(reference_b), libm::sinf(reference_b)];
        let forget = libm::expf(-walked_m / self.cfg.flux_memory_m);
        let [ax, ay] = self.flux_acc;
        // Keep the memory's sign consistent with the reference before adding the pulse.
        let sign = if ax * reference[0] + ay * reference[1] < 0.0 {
            -1.0
        } else {
            1.0
        };
        let (mut ax, mut ay) = (sign * ax * forget, sign * ay * forget);
        if let Some(d) = flux_direction(h_g, &reference) {
            let s = n / (libm::sqrtf(3.0) * self.cfg.sigma_bkg);
            let w = s * s / (1.0 + s * s);
            ax += w * d[0];
            ay += w * d[1];
        }
        self.flux_acc = [ax, ay];
        (ax * ax + ay * ay > 0.0).then(|| libm::atan2f(ay, ax))
    }

    /// Secondary search: follow the flux line, flip after 5 m without a new maximum.
    fn secondary(&mut self, h_g: &Vec3, n: f32, walked_m: f32, yaw: f32) -> ClassicOutput {
        let smooth = self.push_smoothed(n);
        let bearing = self.flux_bearing(h_g, n, walked_m, yaw);
        if bearing.is_some() {
            self.bearing = bearing;
        }
        let distance = self.cfg.distance_reading(smooth);
        let mut out = ClassicOutput {
            instruction: Instruction::FollowFlux,
            bearing: self.bearing,
            distance_m: Some(distance),
            walk_m: None,
            h_norm: smooth,
            line: None,
            request: 0,
        };
        if smooth > self.best_h {
            self.best_h = smooth;
            self.since_best_m = 0.0;
        } else {
            self.since_best_m += walked_m;
        }
        if self.since_best_m > self.cfg.flip_after_m {
            let back = self.bearing.map(|b| wrap_pi(b + core::f32::consts::PI));
            self.bearing = back;
            let [fx, fy] = self.flux_acc;
            self.flux_acc = [-fx, -fy];
            out.bearing = back;
            if self.cfg.distance_reading(self.best_h) <= self.cfg.peak_m {
                // Walked over the victim: back to the peak, then the fine search.
                let remaining = self.since_best_m;
                self.phase = Phase::Return { remaining };
                out.instruction = Instruction::ReturnToPeak;
                out.walk_m = Some(remaining);
                return out;
            }
            self.best_h = smooth;
            self.since_best_m = 0.0;
            out.instruction = Instruction::TurnAround;
            return out;
        }
        if distance <= self.cfg.fine_m {
            return self.start_fine(yaw);
        }
        out
    }

    /// Walking back to the peak; the fine search starts once there.
    fn returning(&mut self, h_g: &Vec3, n: f32, remaining: f32, yaw: f32) -> ClassicOutput {
        let smooth = self.push_smoothed(n);
        if remaining <= 0.0 || self.cfg.distance_reading(n) <= self.cfg.fine_m {
            return self.start_fine(yaw);
        }
        // Keep following the flux line's direction (its sign from the reversed bearing).
        if let Some(b) = self.flux_bearing(h_g, n, 0.0, yaw) {
            self.bearing = Some(b);
        }
        self.phase = Phase::Return { remaining };
        ClassicOutput {
            instruction: Instruction::ReturnToPeak,
            bearing: self.bearing,
            distance_m: Some(self.cfg.distance_reading(smooth)),
            walk_m: Some(remaining),
            h_norm: smooth,
            line: None,
            request: 0,
        }
    }

    /// Fine search: lower the receiver here; the first line runs along the walking bearing.
    fn start_fine(&mut self, yaw: f32) -> ClassicOutput {
        let bearing = self.bearing.unwrap_or(yaw);
        let t0 = self.last_t.unwrap_or(0.0);
        let line = Line {
            index: 0,
            bearing,
            pos: 0,
            side: 1,
            reversed: false,
            below: 0,
            best_h: 0.0,
            best_pos: 0,
            ready_t: t0 + self.cfg.settle_s + self.cfg.lower_m / self.cfg.hand_speed_m_s,
        };
        self.phase = Phase::Fine(line);
        ClassicOutput {
            instruction: Instruction::LowerToSnow,
            bearing: Some(bearing),
            distance_m: self.out.distance_m,
            walk_m: Some(0.0),
            h_norm: self.out.h_norm,
            line: Some(0),
            request: 0,
        }
    }

    /// Spacing of bracketing line `index`, m.
    fn spacing(&self, index: u8) -> f32 {
        if index < 2 {
            self.cfg.coarse_spacing_m
        } else {
            self.cfg.fine_spacing_m
        }
    }

    /// One reading of the fine search (module docs).
    fn fine(&mut self, mut line: Line, n: f32, t: f32) -> ClassicOutput {
        let hold = ClassicOutput {
            distance_m: Some(self.cfg.distance_reading(n)),
            h_norm: n,
            ..self.out
        };
        if t < line.ready_t {
            // The receiver is still on its way: this pulse is not at the point.
            return hold;
        }
        if n > line.best_h {
            line.best_h = n;
            line.best_pos = line.pos;
            line.below = 0;
        } else {
            line.below = line.below.saturating_add(1);
        }
        let steps_out = (line.pos * line.side).unsigned_abs();
        let next = if line.pos == 0 {
            Some(line.side)
        } else if line.below >= 1 && steps_out == 1 && !line.reversed {
            // The first point is weaker than the centre: the other side.
            line.side = -line.side;
            line.reversed = true;
            line.below = 0;
            Some(line.side)
        } else if line.below >= 2
            || steps_out >= u16::from(self.cfg.max_points)
            || (line.reversed && steps_out == 1 && line.below >= 1)
        {
            // Two points past the maximum, the line's end, or both sides of the centre
            // weaker than it: the line is done.
            None
        } else {
            Some(line.pos + line.side)
        };
        let spacing = self.spacing(line.index);
        match next {
            Some(target) => self.move_to(line, target, spacing, t, n),
            None => self.next_line(line, spacing, t, n),
        }
    }

    /// Ask for the receiver at point `target` of `line`.
    fn move_to(
        &mut self,
        mut line: Line,
        target: i16,
        spacing: f32,
        t: f32,
        n: f32,
    ) -> ClassicOutput {
        let delta = f32::from(target - line.pos) * spacing;
        line.pos = target;
        line.ready_t = t + self.cfg.settle_s + libm::fabsf(delta) / self.cfg.hand_speed_m_s;
        self.phase = Phase::Fine(line);
        let bearing = if delta < 0.0 {
            wrap_pi(line.bearing + core::f32::consts::PI)
        } else {
            line.bearing
        };
        ClassicOutput {
            instruction: Instruction::Move,
            bearing: Some(bearing),
            distance_m: Some(self.cfg.distance_reading(n)),
            walk_m: Some(libm::fabsf(delta)),
            h_norm: n,
            line: Some(line.index),
            request: 0,
        }
    }

    /// A line is done: the next one is centred on its maximum, across it; after the last,
    /// probe at the maximum.
    fn next_line(&mut self, line: Line, spacing: f32, t: f32, n: f32) -> ClassicOutput {
        let back = f32::from(line.best_pos - line.pos) * spacing;
        let back_bearing = if back < 0.0 {
            wrap_pi(line.bearing + core::f32::consts::PI)
        } else {
            line.bearing
        };
        if line.index >= 3 {
            self.phase = Phase::Found;
            return ClassicOutput {
                instruction: Instruction::Probe,
                bearing: Some(back_bearing),
                distance_m: Some(self.cfg.distance_reading(line.best_h)),
                walk_m: Some(libm::fabsf(back)),
                h_norm: line.best_h,
                line: Some(line.index),
                request: 0,
            };
        }
        let index = line.index + 1;
        // Lines alternate: along the first bearing, then across it (+90°, to the left).
        let bearing = if index % 2 == 1 {
            wrap_pi(line.bearing + core::f32::consts::FRAC_PI_2)
        } else {
            wrap_pi(line.bearing - core::f32::consts::FRAC_PI_2)
        };
        let new_spacing = self.spacing(index);
        // The new line's centre is the old maximum; its reading is kept, and the receiver
        // goes from there straight to the new line's first point: move `back` along the
        // old line, then one new spacing along the new one, shown as one move.
        let ox = back * libm::cosf(line.bearing) + new_spacing * libm::cosf(bearing);
        let oy = back * libm::sinf(line.bearing) + new_spacing * libm::sinf(bearing);
        let walk = libm::sqrtf(ox * ox + oy * oy);
        let next = Line {
            index,
            bearing,
            pos: 1,
            side: 1,
            reversed: false,
            below: 0,
            best_h: line.best_h,
            best_pos: 0,
            ready_t: t + self.cfg.settle_s + walk / self.cfg.hand_speed_m_s,
        };
        self.phase = Phase::Fine(next);
        ClassicOutput {
            instruction: Instruction::Move,
            bearing: Some(libm::atan2f(oy, ox)),
            distance_m: Some(self.cfg.distance_reading(n)),
            walk_m: Some(walk),
            h_norm: n,
            line: Some(index),
            request: 0,
        }
    }
}

#[cfg(test)]
mod tests;
