//! Search control: which way the rescuer should walk, from the pulses and the SOGs belief
//! (Piniés, Tardós & Neira, IROS 2006, §III-C; Piniés & Tardós, ICRA 2006, §V-D).
//!
//! "Initially, the rescuer is directed to follow the direction of the magnetic flux
//! lines. When the receiver position is far enough (in terms of Mahalanobis distance)
//! from the mean of the SOGs distribution, the rescuer is directed towards this mean."
//!
//! The state machine, one [`Guidance::update`] per received pulse:
//! - [`Status::FluxLine`]: the arrow is the horizontal projection of the measured field
//!   in `G_k`. Its sign is not measured (sign-ambiguous pulses); it is chosen to agree
//!   with the previous walking direction, and flipped when |H| has not grown over the
//!   last [`GuidanceConfig::flip_after_m`] walked — the classical directional search
//!   (ICRA 2006 §II-A: "if after following the initial direction along 5 m the signal
//!   decreases, the rescuer must turn and follow the opposite direction"). Far away the
//!   pulses are barely above the background noise (a pulse is heard from |H| ≈ 3 σ_bkg,
//!   where one pulse's direction is off by tens of degrees), so the direction is the
//!   principal axis of the sign-free tensor `Σ w h_xy h_xyᵀ / |h_xy|²` of the recent
//!   pulses (forgotten over [`GuidanceConfig::flux_memory_m`] walked), each weighted by
//!   its signal-to-noise ratio `w = s² / (1 + s²)`, `s = |H| / (√3 σ_bkg)`; a pulse
//!   whose horizontal field is within [`GuidanceConfig::flux_min_snr`] reading σ does not
//!   enter it (the rescuer keeps the last direction, or the heading before any); and the
//!   flip rule compares a smoothed |H| (mean of the last pulses), so that one noisy pulse
//!   neither flips nor holds the direction.
//! - [`Status::Localized`]: once the receiver lies outside the belief's 3σ ellipse
//!   (horizontal squared Mahalanobis distance of the receiver from the mixture mean,
//!   IROS eq. 18, above [`GuidanceConfig::go_to_mean_d2`]) and the mixture is
//!   concentrated (its largest horizontal σ below the distance to its mean), the arrow
//!   points at the mean, and stays there (latched) until the estimator re-initializes.
//!   Within [`GuidanceConfig::fine_search_m`] the depth is shown (the fine search).
//!   Standing over the mean while the belief is still wider than the probe radius, the
//!   arrow alternates to either side of the mean along the belief's most uncertain
//!   horizontal axis (the classical bracketing, the offset growing with the range, see
//!   [`GuidanceConfig::bracket_range_ratio`]): a single spot cannot separate the
//!   transmitter's position from its moment.
//! - [`Status::Probe`]: the issue's rule, "probe here when the horizontal distance is
//!   below the estimate's uncertainty": the horizontal distance to the mean is within
//!   `max(probe_reach, σ_h)` (the rescuer probes at the mean the arrow points to, within
//!   reach), and either `3σ_h ≤ probe_radius` on [`GuidanceConfig::probe_confirm_pulses`]
//!   consecutive pulses, or σ_h has levelled off — the σ actually reached, no longer
//!   shrinking by 10 % over [`GuidanceConfig::probe_plateau_pulses`] pulses, and at most
//!   [`GuidanceConfig::probe_plateau_max_sigma_m`] — (or, the backstop, the receiver has
//!   been over the mean for [`GuidanceConfig::probe_timeout_pulses`] pulses): probe here.
//!   Near the victim the belief's σ levels off at ≈ 0.1 m (the dead reckoning of the
//!   stop-and-go walk), above the fixed `probe_radius / 3`: waiting for the fixed bound
//!   cost most rescues the whole timeout without sharpening the estimate.
//!   Without a heading (see [`heading_supports`]) nothing is walked to, but "probe here"
//!   still shows on the strict rule, without an arrow: the distance to the mean and its
//!   σ do not depend on the heading.
//! - [`Status::NoSignal`]: no usable pulse.
//! - Height prompts ([`HeightPrompt`], beyond the papers): localized within
//!   [`GuidanceConfig::lower_within_m`] of the mean, a receiver tracked above
//!   [`GuidanceConfig::low_height_m`] is asked once to be lowered to the snow (the range,
//!   hence the pulse noise k_sen·|H| of ICRA 2006 eq. 10 and the position error, shrinks
//!   by the lowering, and the measured 0.8 m move pins the range); a lowered receiver
//!   whose mean is farther than [`GuidanceConfig::raise_beyond_m`] is asked to be raised.
//!   The depth shown is below the snow from the tracked height
//!   ([`GuidanceInput::height_m`]). "Probe here" waits while a prompt shows, and is
//!   confirmed by pulses after it; the lowering prompt stays until the rescuer has stood
//!   through [`GuidanceConfig::height_prompt_pulses`] pulses of it.
//!
//! Angles: bearings in `G` are measured from north toward west (counter-clockwise seen
//! from above, like yaw); the arrow is the bearing minus the device's yaw, positive to
//! the left, in (-π, π]. Everything is `f32`, trig through `libm`.

pub mod classic;
mod geometry;

pub use geometry::{
    flux_direction, heading_supports, horizontal_axis, horizontal_mahalanobis2, relative_arrow,
    to_degrees_wrapped,
};

use crate::Vec3;
use crate::estimate::VictimEstimate;

/// What the display says the rescuer should do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Status {
    /// No usable pulse (yet, or for too long).
    #[default]
    NoSignal,
    /// Follow the flux line (the belief is not trusted yet).
    FluxLine,
    /// Walk to the estimated victim position.
    Localized,
    /// Probe here.
    Probe,
}

impl Status {
    /// The status word of the session-log replay output (`searching`, `flux-line`,
    /// `localized`, `probe`).
    pub fn as_str(&self) -> &'static str {
        match self {
            Status::NoSignal => "searching",
            Status::FluxLine => "flux-line",
            Status::Localized => "localized",
            Status::Probe => "probe",
        }
    }
}

/// A prompt to change the receiver's height above the snow (fine search).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HeightPrompt {
    /// Keep the receiver where it is.
    #[default]
    None,
    /// Fine search: stand and lower the receiver to the snow surface. The pulse noise is
    /// dominated by `k_sen |H|` near the victim (ICRA 2006 eq. 10), so the position error
    /// grows with the range: a 0.3 m deep victim is 1.3 m from a receiver held at 1 m but
    /// 0.5 m from one at 0.2 m. The lowering itself is an absolute vertical displacement
    /// measured by the accelerometer ([`crate::motion::LiftTracker`]) while |H| changes
    /// steeply, which pins the range like the lift.
    Lower,
    /// Low, but no longer in the fine search (e.g. another victim to walk to): stand and
    /// raise the receiver to the walking height, so that the move is measured.
    Raise,
}

/// Thresholds of the search control.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceConfig {
    /// Horizontal squared Mahalanobis distance of the receiver from the mixture mean above
    /// which the rescuer is sent to the mean (IROS §III-C). 9 = outside the 3σ ellipse.
    pub go_to_mean_d2: f32,
    /// The mixture counts as concentrated when its largest horizontal σ is at most this
    /// fraction of the horizontal distance to its mean.
    pub concentrated_ratio: f32,
    /// Flux-line mode: flip the walking direction when, over this distance walked (m),
    /// |H| has not exceeded its best value and has fallen significantly below it (by
    /// [`flip_margin_sigma`](Self::flip_margin_sigma) reading σ), the classical 5 m rule.
    pub flip_after_m: f32,
    /// Significance of the decrease that flips the flux-line direction, in σ of one |H|
    /// reading (`√(σ_bkg² + (k_sen |H|)²)`, ICRA 2006 eq. 10).
    pub flip_margin_sigma: f32,
    /// Flux-line mode: a signal lost ([`GuidanceInput::signal_lost`]) after a smoothed
    /// |H| below this many σ_bkg was lost by walking out of range, and the flux-line
    /// direction is reversed. At the edge of reception the receiver only hears the pulses
    /// above its threshold, so a falling |H| shows as missing pulses, not as smaller
    /// readings, and the 5 m rule never fires: the rescuer who turned back on "no
    /// signal" was sent out again on the old direction when the pulses came back. From
    /// a stronger signal the loss is not the walk (|H| ∝ r⁻³ does not fall to the
    /// threshold over a few metres): the transmitter paused, or pulses were withheld.
    pub edge_h_sigma: f32,
    /// Sensor noise proportional to |H| (ICRA 2006 eq. 10), for the flip significance.
    pub k_sen: f32,
    /// Horizontal distance (m) below which the fine search (depth display) starts.
    pub fine_search_m: f32,
    /// Probe radius (m): "probe here" needs `3σ_h` at most this. 0.45 m (the victim
    /// within a probing spiral's reach with 99 %): measured in the closed-loop rescues
    /// (`rescue-report --probe-tradeoff`), radii from 0.15 to 0.6 m leave the probe-point
    /// error's median at 0.05–0.06 m while the steps grow as the radius shrinks — standing
    /// longer over the mean does not sharpen the estimate.
    pub probe_radius_m: f32,
    /// Consecutive pulses on which the probe condition must hold.
    pub probe_confirm_pulses: u8,
    /// Pulses spent over the mean (within the probe radius) after which the rescuer is
    /// told to probe even if the belief is still wider than the probe radius.
    pub probe_timeout_pulses: u8,
    /// Offset (m) to either side of the mean when bracketing it (about one step), the
    /// least: see [`bracket_range_ratio`](Self::bracket_range_ratio).
    pub bracket_m: f32,
    /// The bracketing offset grows with the range to the mean, to this fraction of it,
    /// up to twice [`bracket_m`](Self::bracket_m): over a deep victim the field's
    /// direction turns slowly with the horizontal position (the angle subtended by the
    /// offset is about offset / range), so one step to either side gains less and less
    /// bearing as the depth grows. Measured in the closed-loop rescues (0.35 against a
    /// fixed 0.5 m): probe-point error max 0.32 → 0.25 m and 0.47 → 0.38 m on two sets
    /// of 100 seeds, medians and steps unchanged (0: a fixed offset).
    pub bracket_range_ratio: f32,
    /// Horizontal distance (m) to the mean within which "probe here" may be given: the
    /// rescuer probes at the mean the display points to, within reach without a step.
    pub probe_reach_m: f32,
    /// Over the mean, "probe here" once the belief's horizontal σ has not fallen below
    /// [`probe_plateau_ratio`](Self::probe_plateau_ratio) × its best for this many
    /// pulses: standing and bracketing no longer sharpen it (0: never).
    pub probe_plateau_pulses: u8,
    /// Relative decrease of the horizontal σ that counts as progress for
    /// [`probe_plateau_pulses`](Self::probe_plateau_pulses).
    pub probe_plateau_ratio: f32,
    /// Largest horizontal σ (m) at which a plateau may end the search: a wider belief
    /// that stopped shrinking is not trusted for the probe (a filter gone off track also
    /// stops shrinking).
    pub probe_plateau_max_sigma_m: f32,
    /// Receiver height above the snow (m): the displayed depth is the burial depth below
    /// the surface, `−p_z − receiver_height`.
    pub receiver_height_m: f32,
    /// Background noise per field component (A/m), ICRA 2006 eq. 10: weights the
    /// flux-line pulses by their signal-to-noise ratio.
    pub sigma_bkg: f32,
    /// Walked distance (m) over which the flux-line direction forgets past pulses.
    pub flux_memory_m: f32,
    /// A pulse steers the flux line only when its horizontal field is at least this many
    /// σ of one field component's reading (`√(σ_bkg² + (k_sen |H|)²)`, ICRA 2006 eq. 10):
    /// below, the horizontal direction is mostly noise (≈ 1/SNR rad), and the rescuer
    /// keeps walking the last steered direction (the classical "keep going while the
    /// signal grows", with the 5 m rule still turning back). Near the equator of a
    /// near-vertical moment the field is nearly vertical; at the edge of reception its
    /// horizontal part is below the noise, and an arrow that follows each pulse's noisy
    /// direction walked the rescuer in circles (seed 3025: 170 pulses on the flux line).
    pub flux_min_snr: f32,
    /// Fine search: within this horizontal distance (m) of the mean, a depth σ above
    /// [`lift_depth_sigma_m`](Self::lift_depth_sigma_m) asks the rescuer to stand and
    /// lift the receiver (an absolute vertical displacement that pins the range, see
    /// [`crate::motion::LiftTracker`]).
    pub lift_within_m: f32,
    /// Depth σ (m) above which the lift is asked for.
    pub lift_depth_sigma_m: f32,
    /// Most pulses on which the lift is asked for in one search (0: never); "probe
    /// here" waits while it is.
    pub lift_max_pulses: u8,
    /// Localized within this horizontal distance (m) of the mean, a receiver higher than
    /// [`low_height_m`](Self::low_height_m) is asked to be lowered to the snow, once per
    /// search ([`HeightPrompt::Lower`]; 0: never). About where the fine search goes step
    /// by step: the range is then mostly the depth plus the receiver's height.
    pub lower_within_m: f32,
    /// A receiver at most this high above the snow (m) counts as lowered.
    pub low_height_m: f32,
    /// A lowered receiver is asked to be raised again ([`HeightPrompt::Raise`]) when the
    /// mean is farther than this (m), e.g. the next victim after a mark.
    pub raise_beyond_m: f32,
    /// Pulse intervals the rescuer may stand through with a height prompt on before it is
    /// withdrawn (a rescuer who ignores it is not asked again; one who walks on is asked
    /// on at most [`PROMPT_SHOWN_FACTOR`] times as many pulses); "probe here" waits while
    /// it is shown.
    /// Counting every pulse let the prompt run out while the rescuer was finishing the
    /// steps under way: the lowering made a second later went unmeasured (the device
    /// was no longer in lift mode), and the filter took the receiver for 0.8 m higher
    /// than it was (seeds 1012, 1037: probe 0.38 and 0.28 m off, depth 0.55 and 0.84 m
    /// off).
    pub height_prompt_pulses: u8,
}

impl GuidanceConfig {
    /// Variance (A²/m²) of one field component's reading at a field of squared magnitude
    /// `h2` (ICRA 2006 eq. 10: background plus the part proportional to |H|).
    fn reading_var(&self, h2: f32) -> f32 {
        self.sigma_bkg * self.sigma_bkg + self.k_sen * self.k_sen * h2
    }
}

/// A pulse interval with less dead-reckoned walk than this (m) counts as standing, for
/// [`GuidanceConfig::height_prompt_pulses`] (a standing interval dead-reckons to 0).
pub const PROMPT_STANDING_M: f32 = 0.1;

/// A height prompt is shown on at most this many times
/// [`GuidanceConfig::height_prompt_pulses`] pulses, standing or not.
pub const PROMPT_SHOWN_FACTOR: u8 = 3;

impl Default for GuidanceConfig {
    fn default() -> Self {
        Self {
            go_to_mean_d2: 9.0,
            concentrated_ratio: 1.0,
            flip_after_m: 5.0,
            flip_margin_sigma: 2.0,
            edge_h_sigma: 10.0,
            k_sen: 0.03,
            fine_search_m: 3.0,
            probe_radius_m: 0.45,
            probe_confirm_pulses: 2,
            probe_timeout_pulses: 16,
            bracket_m: 0.5,
            bracket_range_ratio: 0.35,
            probe_reach_m: 0.5,
            probe_plateau_pulses: 6,
            probe_plateau_ratio: 0.9,
            probe_plateau_max_sigma_m: 0.225,
            receiver_height_m: 1.0,
            sigma_bkg: 2.59e-9,
            flux_memory_m: 3.0,
            flux_min_snr: 2.0,
            lift_within_m: 1.0,
            lift_depth_sigma_m: 0.2,
            lift_max_pulses: 6,
            lower_within_m: 2.0,
            low_height_m: 0.5,
            raise_beyond_m: 6.0,
            height_prompt_pulses: 4,
        }
    }
}

/// What the search control needs from one pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceInput {
    /// The pulse's field vector rotated into `G_k` (A/m, overall sign arbitrary), or
    /// `None` when the pulse gave no vector.
    pub h_g: Option<Vec3>,
    /// Distance walked since the previous pulse (m).
    pub walked_m: f32,
    /// Device yaw at the pulse (rad, from north toward west).
    pub yaw: f32,
    /// Variance of that yaw (rad², the attitude filter's): without a magnetometer the
    /// heading is not known and the belief cannot be walked to (see [`heading_supports`]);
    /// not finite: unknown.
    pub yaw_var: f32,
    /// The estimator's belief after this pulse.
    pub estimate: Option<VictimEstimate>,
    /// The estimator rebuilt its mixture on this pulse: forget the latched target.
    pub reinitialized: bool,
    /// No pulse came for longer than the signal timeout before this one (the display
    /// said "no signal").
    pub signal_lost: bool,
    /// The receiver's height above the snow (m) as tracked from the measured vertical
    /// moves; `None`: not tracked (the configured
    /// [`receiver_height_m`](GuidanceConfig::receiver_height_m), no height prompts).
    pub height_m: Option<f32>,
    /// Whether the receiver may be asked to be lowered to the snow (the application
    /// withholds it with several victims, see `app::Receiver`).
    pub lower_allowed: bool,
}

/// The search control's answer for one pulse.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GuidanceOutput {
    /// Status word.
    pub status: Status,
    /// Direction to walk in `G` (rad, from north toward west), if any.
    pub bearing: Option<f32>,
    /// That direction relative to the device's yaw at the pulse (rad, positive left,
    /// in (-π, π]).
    pub arrow: Option<f32>,
    /// Straight-line (3-D) distance to the mixture mean (m), once localized.
    pub distance_m: Option<f32>,
    /// Horizontal distance to the mixture mean (m), once localized.
    pub horizontal_m: Option<f32>,
    /// Burial depth below the snow surface (m), in the fine search.
    pub depth_m: Option<f32>,
    /// Horizontal distance (m) to walk along the arrow: to the mean, or to the bracketing
    /// point beside it (the fine search's "steps to go").
    pub walk_m: Option<f32>,
    /// Largest horizontal standard deviation of the belief (m), once initialized.
    pub sigma_h_m: Option<f32>,
    /// Fine search: stand and lift the receiver (≈ 0.4 m up and down within ~2 s), the
    /// depth is too uncertain (see [`GuidanceConfig::lift_depth_sigma_m`]).
    pub lift: bool,
    /// Lower the receiver to the snow, or raise it again (see [`HeightPrompt`]).
    pub height_prompt: HeightPrompt,
}

/// The search-control state machine (IROS §III-C).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Guidance {
    cfg: GuidanceConfig,
    /// Previous flux-line walking direction in `G` (unit, horizontal).
    flux_dir: Option<[f32; 2]>,
    /// Sign-free horizontal direction tensor `[xx, xy, yy]` of the recent pulses.
    flux_tensor: [f32; 3],
    /// Smoothed |H| (A/m; 0 before the first pulse).
    smooth_h: f32,
    /// Largest smoothed |H| since the last flip, and the distance walked since it was seen.
    best_h: f32,
    walked_since_best: f32,
    /// Latched: the belief has been trusted (walking to the mean).
    localized: bool,
    /// Consecutive pulses satisfying the probe condition.
    probe_count: u8,
    /// Pulses spent over the mean (bracketing).
    over_mean: u8,
    /// Smallest horizontal σ (m) seen over the mean, and the pulses since it was.
    best_sigma: f32,
    since_best_sigma: u8,
    /// Consecutive pulses with the mean beyond the bracketing span: two end the stay over
    /// the mean (one is the estimate jumping, not the rescuer leaving).
    far_pulses: u8,
    /// Current bracketing offset direction from the mean (unit, horizontal, in `G`,
    /// which is north-aligned, so it stays valid as the receiver moves).
    bracket_dir: Option<[f32; 2]>,
    /// Latched probe.
    probing: bool,
    /// Pulses on which the lift was asked for.
    lift_pulses: u8,
    /// The height prompt shown on the last pulse, and on how many pulses in a row.
    prompt: HeightPrompt,
    prompt_pulses: u8,
    /// Pulses on which the current height prompt was shown, standing or not.
    prompt_shown: u8,
    /// The lowering was asked for in this search (asked once).
    lower_asked: bool,
}

impl Guidance {
    /// A search control with thresholds `cfg`, starting in flux-line mode.
    pub const fn new(cfg: GuidanceConfig) -> Self {
        Self {
            cfg,
            flux_dir: None,
            flux_tensor: [0.0; 3],
            smooth_h: 0.0,
            best_h: 0.0,
            walked_since_best: 0.0,
            localized: false,
            probe_count: 0,
            over_mean: 0,
            best_sigma: f32::MAX,
            since_best_sigma: 0,
            far_pulses: 0,
            bracket_dir: None,
            probing: false,
            lift_pulses: 0,
            prompt: HeightPrompt::None,
            prompt_pulses: 0,
            prompt_shown: 0,
            lower_asked: false,
        }
    }

    /// The thresholds in use.
    pub fn config(&self) -> &GuidanceConfig {
        &self.cfg
    }

    /// Whether the rescuer is being sent to the mixture mean (latched).
    pub fn is_localized(&self) -> bool {
        self.localized
    }

    /// Forgets the search (a new search starts in flux-line mode).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// One pulse: the new arrow and status. Non-finite inputs are treated as absent.
    pub fn update(&mut self, input: &GuidanceInput) -> GuidanceOutput {
        let walked = if input.walked_m.is_finite() {
            input.walked_m.max(0.0)
        } else {
            0.0
        };
        let yaw = if input.yaw.is_finite() {
            input.yaw
        } else {
            0.0
        };
        let h_g = input.h_g.filter(|h| h.iter().all(|v| v.is_finite()));
        let est = input
            .estimate
            .filter(|e| e.p.iter().all(|v| v.is_finite()) && e.cov.iter().all(|v| v.is_finite()));
        if input.reinitialized || est.is_none() {
            self.localized = false;
            self.probing = false;
            self.probe_count = 0;
            self.over_mean = 0;
            self.best_sigma = f32::MAX;
            self.since_best_sigma = 0;
            self.far_pulses = 0;
            self.lift_pulses = 0;
            self.bracket_dir = None;
        }
        if input.signal_lost && !self.localized {
            self.turn_back_if_walked_out();
        }
        // Classical flux-line bookkeeping runs in every mode, so that a fallback from
        // the mean to the flux line starts with a sensible direction.
        let flux = h_g.and_then(|h| self.flux_line(&h, walked, yaw));

        let mut out = GuidanceOutput::default();
        if let Some(e) = &est {
            let (_, sigma_h) = horizontal_axis(&e.cov);
            out.sigma_h_m = Some(sigma_h);
            let dist_h = libm::sqrtf(e.p.x * e.p.x + e.p.y * e.p.y);
            // IROS §III-C: trust the mean once the receiver is far from it in Mahalanobis
            // distance and the belief is concentrated.
            let heading = heading_supports(input.yaw_var, self.cfg.go_to_mean_d2);
            if !self.localized
                && heading
                && horizontal_mahalanobis2(e) >= self.cfg.go_to_mean_d2
                && sigma_h <= self.cfg.concentrated_ratio * dist_h
            {
                self.localized = true;
            }
            // The heading lost since (the magnetometer gone for long): the arrow to the
            // mean is no longer supported; back to the flux line, which needs no heading.
            // A probe under way stays: at the mean the heading moves nothing.
            if self.localized && !heading && !self.probing {
                self.localized = false;
                self.probe_count = 0;
                self.over_mean = 0;
                self.far_pulses = 0;
                self.bracket_dir = None;
            }
            if !self.localized && !heading && !self.probing {
                self.probe_without_heading(e);
            }
        }
        let height = input.height_m.filter(|h| h.is_finite());
        out.height_prompt = self.height_prompt(est.as_ref(), height, walked, input.lower_allowed);
        match (&est, self.localized) {
            (Some(e), true) => self.walk_to_mean(e, yaw, height, &mut out),
            (Some(e), false) if self.probing => self.probe_here(e, height, &mut out),
            _ => {
                if let Some(b) = flux {
                    out.status = Status::FluxLine;
                    out.bearing = Some(b);
                    out.arrow = Some(relative_arrow(b, yaw));
                }
            }
        }
        out
    }

    /// The signal was lost on the flux line: from a weak signal, the rescuer walked out of
    /// range (the classical rule "if the signal decreases, turn around", ICRA §II-A, with
    /// the loss as the decrease; see [`GuidanceConfig::edge_h_sigma`]): reverse the
    /// direction and restart the |H| comparison from the next pulses.
    fn turn_back_if_walked_out(&mut self) {
        let edge = self.cfg.edge_h_sigma * self.cfg.sigma_bkg;
        if self.smooth_h <= 0.0 || self.smooth_h >= edge {
            return;
        }
        if let Some(d) = self.flux_dir.as_mut() {
            d[0] = -d[0];
            d[1] = -d[1];
        }
        self.smooth_h = 0.0;
        self.best_h = 0.0;
        self.walked_since_best = 0.0;
    }

    /// Flux-line direction in `G` (rad) for the field `h` (ICRA §II-A, IROS §III-C).
    fn flux_line(&mut self, h: &Vec3, walked: f32, yaw: f32) -> Option<f32> {
        let raw = h.norm();
        if !raw.is_finite() {
            return None;
        }
        // Smoothed |H|: the mean of about the last three pulses.
        self.smooth_h = if self.smooth_h > 0.0 {
            0.5 * (self.smooth_h + raw)
        } else {
            raw
        };
        let n = self.smooth_h;
        // Classical rule: if |H| has decreased over the last `flip_after_m`, turn around.
        // "Decreased" must be significant: at the edge of reception one reading is
        // ±σ_bkg on |H| ≈ 3…10 σ_bkg, and the best of many noisy readings lies above the
        // true value, so "not grown" alone flips at random and traps the rescuer on a
        // few metres of flux line. Walking the wrong way along a flux line makes |H|
        // (∝ r⁻³) fall fast; near the dipole's equator either way leads in (the line is a
        // loop r = L sin²θ), so holding the direction while |H| is inconclusive costs
        // little.
        let margin = self.cfg.flip_margin_sigma
            * libm::sqrtf(self.cfg.reading_var(self.best_h * self.best_h));
        if n > self.best_h {
            self.best_h = n;
            self.walked_since_best = 0.0;
        } else {
            self.walked_since_best += walked;
            if self.walked_since_best > self.cfg.flip_after_m && n < self.best_h - margin {
                if let Some(d) = self.flux_dir.as_mut() {
                    d[0] = -d[0];
                    d[1] = -d[1];
                }
                self.best_h = n;
                self.walked_since_best = 0.0;
            }
        }
        // The previous walking direction (or, first, the device's heading) picks the sign.
        let reference = self.flux_dir.unwrap_or([libm::cosf(yaw), libm::sinf(yaw)]);
        // No significant horizontal field yet: straight on, the way the rescuer walks.
        let axis = self.average_axis(h, walked).unwrap_or(reference);
        let d = flux_direction(&Vec3::new(axis[0], axis[1], 0.0), &reference)?;
        self.flux_dir = Some(d);
        Some(libm::atan2f(d[1], d[0]))
    }

    /// Adds the pulse `h` to the sign-free direction tensor (after forgetting over the
    /// distance `walked`) and returns its principal horizontal axis (unit, either sign).
    fn average_axis(&mut self, h: &Vec3, walked: f32) -> Option<[f32; 2]> {
        let c = &self.cfg;
        let keep = if c.flux_memory_m > 0.0 {
            libm::expf(-walked / c.flux_memory_m)
        } else {
            0.0
        };
        for v in self.flux_tensor.iter_mut() {
            *v *= keep;
        }
        let nh2 = h.x * h.x + h.y * h.y;
        // A field within ~0.5° of vertical has no usable horizontal direction, nor one
        // whose horizontal part is within the reading noise.
        let noise2 = c.reading_var(h.norm_squared());
        let significant = nh2 >= c.flux_min_snr * c.flux_min_snr * noise2;
        if significant && nh2.is_finite() && nh2 > 1e-4 * h.norm_squared() && nh2 > 0.0 {
            let s2 = if c.sigma_bkg > 0.0 {
                h.norm_squared() / (3.0 * c.sigma_bkg * c.sigma_bkg)
            } else {
                f32::MAX
            };
            let w = if s2.is_finite() { s2 / (1.0 + s2) } else { 1.0 };
            self.flux_tensor[0] += w * h.x * h.x / nh2;
            self.flux_tensor[1] += w * h.x * h.y / nh2;
            self.flux_tensor[2] += w * h.y * h.y / nh2;
        }
        let [a, b, d] = self.flux_tensor;
        if a + d <= 0.0 || !(a + d).is_finite() {
            return None;
        }
        let mut m = crate::Mat3::zeros();
        m[(0, 0)] = a;
        m[(0, 1)] = b;
        m[(1, 0)] = b;
        m[(1, 1)] = d;
        Some(horizontal_axis(&m).0)
    }

    /// Without a heading: "probe here" on the strict rule alone (within reach of the mean,
    /// `3σ_h ≤ probe_radius` on [`GuidanceConfig::probe_confirm_pulses`] pulses). Both
    /// are yaw-free: a heading error turns the belief about the receiver, which changes
    /// neither the horizontal distance to its mean nor its σ. The plateau and timeout
    /// rules count pulses of the bracketing, which needs a heading, so they do not apply.
    fn probe_without_heading(&mut self, e: &VictimEstimate) {
        let c = &self.cfg;
        let (_, sigma_h) = horizontal_axis(&e.cov);
        let dist_h = libm::sqrtf(e.p.x * e.p.x + e.p.y * e.p.y);
        let over = dist_h <= c.probe_reach_m.max(sigma_h);
        let sure = 3.0 * sigma_h <= c.probe_radius_m;
        self.probe_count = if over && sure {
            self.probe_count.saturating_add(1)
        } else {
            0
        };
        self.probing = self.probe_count >= c.probe_confirm_pulses;
    }

    /// Probing without a heading: the distances, no arrow (no direction is supported; the
    /// mean is within the probe's reach).
    fn probe_here(&self, e: &VictimEstimate, height: Option<f32>, out: &mut GuidanceOutput) {
        let c = &self.cfg;
        let dist_h = libm::sqrtf(e.p.x * e.p.x + e.p.y * e.p.y);
        out.status = Status::Probe;
        out.distance_m = Some(e.p.norm());
        out.horizontal_m = Some(dist_h);
        let h = height.unwrap_or(c.receiver_height_m).max(0.0);
        out.depth_m = Some((-e.p.z - h).max(0.0));
        out.walk_m = Some(0.0);
    }

    /// Localized: walk to the mean, bracket it, or probe.
    fn walk_to_mean(
        &mut self,
        e: &VictimEstimate,
        yaw: f32,
        height: Option<f32>,
        out: &mut GuidanceOutput,
    ) {
        let c = self.cfg;
        let (axis, sigma_h) = horizontal_axis(&e.cov);
        let dist_h = libm::sqrtf(e.p.x * e.p.x + e.p.y * e.p.y);
        out.distance_m = Some(e.p.norm());
        out.horizontal_m = Some(dist_h);
        if dist_h <= c.fine_search_m {
            // The receiver's current height: the depth stays right once it is lowered.
            let h = height.unwrap_or(c.receiver_height_m).max(0.0);
            out.depth_m = Some((-e.p.z - h).max(0.0));
        }
        let sure = 3.0 * sigma_h <= c.probe_radius_m;
        // The rule: the horizontal distance is below the estimate's uncertainty
        // (or within reach of the probe).
        let over = dist_h <= c.probe_reach_m.max(sigma_h);
        if over && sure {
            self.probe_count = self.probe_count.saturating_add(1);
        } else {
            self.probe_count = 0;
        }
        let bracket = self.bracket_offset(e);
        let beyond = dist_h > 2.0 * bracket + c.probe_reach_m;
        self.far_pulses = if beyond {
            self.far_pulses.saturating_add(1)
        } else {
            0
        };
        if self.far_pulses >= 2 {
            self.over_mean = 0;
            self.best_sigma = f32::MAX;
            self.since_best_sigma = 0;
        }
        let plateau = !beyond && self.sigma_plateau(over, sigma_h);
        if over {
            self.over_mean = self.over_mean.saturating_add(1);
        }
        // Depth (range) pinned by the scale only: ask for a lift first.
        let sigma_z = libm::sqrtf(e.cov[(2, 2)].max(0.0));
        // Lowered to the snow, the lowering pinned the range: no lift (measured: a lift
        // near the snow added failures without calibration, see the rescue report).
        let lowered = height.is_some_and(|h| h <= c.low_height_m);
        out.lift = !self.probing
            && !lowered
            && out.height_prompt == HeightPrompt::None
            && dist_h <= c.lift_within_m
            && sigma_z > c.lift_depth_sigma_m
            && self.lift_pulses < c.lift_max_pulses;
        if out.lift {
            self.lift_pulses = self.lift_pulses.saturating_add(1);
        } else if out.height_prompt != HeightPrompt::None {
            // Stand and move the receiver first: no probe meanwhile, and the pulses before
            // the move confirm nothing: the lowered receiver's first pulses must (seed 71
            // without calibration probed on the first pulse at the snow, the depth still
            // 0.85 m off from the pulses 1 m up).
            self.probe_count = 0;
        } else if self.probe_count >= c.probe_confirm_pulses
            || self.over_mean >= c.probe_timeout_pulses
            || (over && plateau)
        {
            self.probing = true;
        }
        let mut target = [e.p.x, e.p.y];
        if self.probing {
            out.status = Status::Probe;
        } else {
            out.status = Status::Localized;
            let dir = self.bracket_direction(e, axis, bracket);
            if over && !sure {
                // Bracket the mean along its most uncertain horizontal axis.
                target[0] += dir[0] * bracket;
                target[1] += dir[1] * bracket;
            }
        }
        let b = libm::atan2f(target[1], target[0]);
        let walk = libm::sqrtf(target[0] * target[0] + target[1] * target[1]);
        out.walk_m = Some(if self.probing { 0.0 } else { walk });
        out.bearing = Some(b);
        out.arrow = Some(relative_arrow(b, yaw));
    }
}

impl Guidance {
    /// The height prompt for this pulse: lower the receiver once the fine search starts
    /// (localized, mean within [`GuidanceConfig::lower_within_m`]), raise it when the
    /// mean of a lowered receiver is farther than [`GuidanceConfig::raise_beyond_m`];
    /// each shown until the rescuer has stood through
    /// [`GuidanceConfig::height_prompt_pulses`] pulse intervals with it on (`walked` m
    /// since the previous pulse), and the lowering asked for once per search. Nothing without a
    /// tracked height.
    fn height_prompt(
        &mut self,
        e: Option<&VictimEstimate>,
        height: Option<f32>,
        walked: f32,
        lower_allowed: bool,
    ) -> HeightPrompt {
        let c = &self.cfg;
        let (Some(h), Some(e)) = (height, e) else {
            self.prompt = HeightPrompt::None;
            self.prompt_pulses = 0;
            self.prompt_shown = 0;
            return HeightPrompt::None;
        };
        let dist_h = libm::sqrtf(e.p.x * e.p.x + e.p.y * e.p.y);
        let want = if h > c.low_height_m {
            if lower_allowed && self.localized && !self.lower_asked && dist_h <= c.lower_within_m {
                HeightPrompt::Lower
            } else {
                HeightPrompt::None
            }
        } else if dist_h > c.raise_beyond_m {
            HeightPrompt::Raise
        } else {
            HeightPrompt::None
        };
        // A lowered receiver ends the lowering prompt for good (asked once).
        if self.prompt == HeightPrompt::Lower && want != HeightPrompt::Lower {
            self.lower_asked = true;
        }
        if want == HeightPrompt::None || want != self.prompt {
            self.prompt_pulses = 0;
            self.prompt_shown = 0;
        }
        self.prompt = want;
        let most_shown = c.height_prompt_pulses.saturating_mul(PROMPT_SHOWN_FACTOR);
        if want == HeightPrompt::None
            || self.prompt_pulses >= c.height_prompt_pulses
            || self.prompt_shown >= most_shown
        {
            if want == HeightPrompt::Lower {
                self.lower_asked = true;
            }
            return HeightPrompt::None;
        }
        // Counted from the second showing: the interval before the first one preceded
        // the prompt.
        if self.prompt_shown > 0 && walked <= PROMPT_STANDING_M {
            self.prompt_pulses = self.prompt_pulses.saturating_add(1);
        }
        self.prompt_shown = self.prompt_shown.saturating_add(1);
        want
    }

    /// Whether the belief's horizontal σ has stopped shrinking near the mean: the σ
    /// actually reached, as opposed to the fixed `probe_radius / 3`. Counted while the
    /// receiver is within the bracketing span of the mean (the fine search's geometry;
    /// the caller skips pulses beyond it and restarts after two in a row);
    /// progress is a fall below `probe_plateau_ratio` × the best σ so far.
    fn sigma_plateau(&mut self, over: bool, sigma_h: f32) -> bool {
        let c = &self.cfg;
        if c.probe_plateau_pulses == 0 {
            return false;
        }
        if sigma_h < c.probe_plateau_ratio * self.best_sigma {
            self.best_sigma = sigma_h;
            self.since_best_sigma = 0;
        } else {
            self.since_best_sigma = self.since_best_sigma.saturating_add(1);
        }
        over && sigma_h <= c.probe_plateau_max_sigma_m
            && self.since_best_sigma >= c.probe_plateau_pulses
    }

    /// The bracketing offset (m) for the belief `e`: [`GuidanceConfig::bracket_range_ratio`]
    /// × the range to the mean, within [`GuidanceConfig::bracket_m`] and twice that (a
    /// non-finite range or ratio gives the least).
    fn bracket_offset(&self, e: &VictimEstimate) -> f32 {
        let c = &self.cfg;
        // f32::max ignores a NaN operand: a bad ratio or range falls back to bracket_m.
        (c.bracket_range_ratio * e.p.norm())
            .max(c.bracket_m)
            .min(2.0 * c.bracket_m)
    }

    /// The side of the mean to bracket toward: along the belief's most uncertain axis
    /// `axis`, on the side of the previous bracketing point until the receiver has
    /// reached it (within the probe radius), then the other side. Turning to the other
    /// side on every pulse instead would turn the rescuer around on each pulse while the
    /// bracketing point is still steps away: no baseline is gained, and each turn about
    /// the walker moves the hand-held receiver by an unknown lever arm, which the dead
    /// reckoning must count as noise.
    fn bracket_direction(&mut self, e: &VictimEstimate, axis: [f32; 2], b: f32) -> [f32; 2] {
        let mut dir = match self.bracket_dir {
            // The principal axis has no sign: keep the one of the current side.
            Some(d) if d[0] * axis[0] + d[1] * axis[1] < 0.0 => [-axis[0], -axis[1]],
            _ => axis,
        };
        if self.bracket_dir.is_some() {
            let (tx, ty) = (e.p.x + dir[0] * b, e.p.y + dir[1] * b);
            if libm::sqrtf(tx * tx + ty * ty) <= self.cfg.probe_radius_m {
                dir = [-dir[0], -dir[1]];
            }
        }
        self.bracket_dir = Some(dir);
        dir
    }
}

#[cfg(test)]
mod tests;
