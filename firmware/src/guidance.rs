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

use crate::Vec3;
use crate::estimate::VictimEstimate;
use crate::frame::wrap_pi;

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
            if !self.localized
                && horizontal_mahalanobis2(e) >= self.cfg.go_to_mean_d2
                && sigma_h <= self.cfg.concentrated_ratio * dist_h
            {
                self.localized = true;
            }
        }
        let height = input.height_m.filter(|h| h.is_finite());
        out.height_prompt = self.height_prompt(est.as_ref(), height, walked, input.lower_allowed);
        match (&est, self.localized) {
            (Some(e), true) => self.walk_to_mean(e, yaw, height, &mut out),
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

/// Unit horizontal flux-line direction in `G` for the field `h`, with the sign that
/// agrees with `reference` (a horizontal direction); `None` when the field is vertical.
pub fn flux_direction(h: &Vec3, reference: &[f32; 2]) -> Option<[f32; 2]> {
    let n = libm::sqrtf(h.x * h.x + h.y * h.y);
    // A field within ~0.5° of vertical has no usable horizontal direction.
    if !n.is_finite() || n <= 1e-2 * h.norm() || n == 0.0 {
        return None;
    }
    let (x, y) = (h.x / n, h.y / n);
    if x * reference[0] + y * reference[1] < 0.0 {
        Some([-x, -y])
    } else {
        Some([x, y])
    }
}

/// Squared horizontal Mahalanobis distance of the receiver (the origin of `G_k`) from the
/// mixture mean, with the mixture covariance of IROS eq. 18 (0 if it is singular).
pub fn horizontal_mahalanobis2(est: &VictimEstimate) -> f32 {
    let c = &est.cov;
    let (a, b, d) = (c[(0, 0)], c[(0, 1)], c[(1, 1)]);
    let det = a * d - b * b;
    if det.is_nan() || det <= 0.0 {
        return 0.0;
    }
    let (x, y) = (est.p.x, est.p.y);
    let m = (d * x * x - 2.0 * b * x * y + a * y * y) / det;
    if m.is_finite() { m } else { 0.0 }
}

/// Unit principal axis (horizontal, `G`) and largest standard deviation (m) of the
/// horizontal block of the covariance `cov`.
pub fn horizontal_axis(cov: &crate::Mat3) -> ([f32; 2], f32) {
    let (a, b, c) = (cov[(0, 0)], cov[(0, 1)], cov[(1, 1)]);
    let half = 0.5 * (a - c);
    let lmax = 0.5 * (a + c) + libm::sqrtf(half * half + b * b);
    // Eigenvector of [[a, b], [b, c]] for lmax.
    let (vx, vy) = if libm::fabsf(b) > 1e-12 {
        (lmax - c, b)
    } else if a >= c {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let n = libm::sqrtf(vx * vx + vy * vy);
    let axis = if n > 0.0 && n.is_finite() {
        [vx / n, vy / n]
    } else {
        [1.0, 0.0]
    };
    let sigma = libm::sqrtf(lmax.max(0.0));
    (axis, if sigma.is_finite() { sigma } else { f32::MAX })
}

/// A bearing in `G` (rad) relative to the device's yaw: positive to the left, (-π, π].
pub fn relative_arrow(bearing: f32, yaw: f32) -> f32 {
    wrap_pi(bearing - yaw)
}

/// Radians to degrees in (-180, 180] (the session-log replay's `arrow_deg`).
pub fn to_degrees_wrapped(a: f32) -> f32 {
    let d = wrap_pi(a) * (180.0 / core::f32::consts::PI);
    if d <= -180.0 { 180.0 } else { d }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Mat3;
    use core::f32::consts::{FRAC_PI_2, PI};

    fn est(p: Vec3, sigma: f32) -> VictimEstimate {
        VictimEstimate {
            p,
            cov: Mat3::from_diagonal(&Vec3::new(sigma * sigma, sigma * sigma, 0.04)),
            moment: Vec3::new(0.0, 0.0, 0.02),
            scale: 1.0,
            scale_sigma: 0.02,
            rpy: Vec3::zeros(),
            n_components: 1,
            max_weight: 1.0,
        }
    }

    fn input(h: Vec3, walked: f32, yaw: f32, e: Option<VictimEstimate>) -> GuidanceInput {
        GuidanceInput {
            h_g: Some(h),
            walked_m: walked,
            yaw,
            estimate: e,
            reinitialized: false,
            signal_lost: false,
            height_m: None,
            lower_allowed: true,
        }
    }

    #[test]
    fn flux_sign_follows_the_heading_then_the_previous_direction() {
        let mut g = Guidance::new(GuidanceConfig::default());
        // Facing north, field along ±north: walk north whatever the pulse's sign.
        let o = g.update(&input(Vec3::new(-1e-6, 0.0, 3e-7), 0.0, 0.0, None));
        assert_eq!(o.status, Status::FluxLine);
        assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
        // The next pulse with the opposite sign and slightly turned keeps going north-ish.
        let o = g.update(&input(Vec3::new(1.1e-6, -1e-7, 0.0), 1.0, 0.3, None));
        let b = o.bearing.unwrap_or(PI);
        assert!(b.abs() < 0.2, "bearing {b}");
        // Arrow relative to the device: yaw 0.3 rad, bearing ≈ -0.09 → to the right.
        assert!(
            o.arrow
                .is_some_and(|a| a < 0.0 && (a - (b - 0.3)).abs() < 1e-5)
        );
        // Facing south first picks the southern sign.
        let mut g = Guidance::new(GuidanceConfig::default());
        let o = g.update(&input(Vec3::new(1e-6, 0.0, 0.0), 0.0, PI, None));
        assert!(o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5));
    }

    #[test]
    fn flux_direction_flips_when_the_signal_falls_over_five_metres() {
        let mut g = Guidance::new(GuidanceConfig::default());
        let mut h = 1e-6;
        let mut bearing = 0.0;
        for _ in 0..7 {
            let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
            bearing = o.bearing.unwrap_or(f32::NAN);
            h *= 0.9; // walking away: falling signal
        }
        assert!(
            (bearing.abs() - PI).abs() < 1e-5,
            "turned around: {bearing}"
        );
        // A growing signal never flips.
        let mut g = Guidance::new(GuidanceConfig::default());
        for k in 0..20 {
            let o = g.update(&input(
                Vec3::new(1e-7 * (1.0 + k as f32), 0.0, 0.0),
                1.0,
                0.0,
                None,
            ));
            assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
        }
    }

    #[test]
    fn a_weak_signal_lost_on_the_flux_line_turns_the_direction_back() {
        let cfg = GuidanceConfig::default();
        // Walking north along a flux line at the edge of reception (|H| ≈ 5 σ_bkg):
        // the pulses stop, the rescuer turns back on "no signal", the pulses return.
        let weak = 5.0 * cfg.sigma_bkg;
        let walk_out = |g: &mut Guidance| {
            for _ in 0..4 {
                let o = g.update(&input(Vec3::new(weak, 0.0, 0.0), 1.0, 0.0, None));
                assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
            }
        };
        let back = |lost: bool, h: f32| GuidanceInput {
            signal_lost: lost,
            ..input(Vec3::new(h, 0.0, 0.0), 4.0, PI, None)
        };
        let mut g = Guidance::new(cfg);
        walk_out(&mut g);
        let o = g.update(&back(true, weak));
        assert!(
            o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5),
            "sent back south: {:?}",
            o.bearing
        );
        // Without the loss the old direction holds (the 5 m rule has not fired).
        let mut g = Guidance::new(cfg);
        walk_out(&mut g);
        assert!(
            g.update(&back(false, weak))
                .bearing
                .is_some_and(|b| b.abs() < 1e-5)
        );
        // A strong signal is not lost by walking a few metres: the direction holds.
        let mut g = Guidance::new(cfg);
        for _ in 0..4 {
            let _ = g.update(&input(Vec3::new(1e-6, 0.0, 0.0), 1.0, 0.0, None));
        }
        assert!(
            g.update(&back(true, 1e-6))
                .bearing
                .is_some_and(|b| b.abs() < 1e-5)
        );
    }

    #[test]
    fn a_vertical_field_keeps_the_heading_and_no_pulse_gives_no_signal() {
        let mut g = Guidance::new(GuidanceConfig::default());
        // No horizontal direction: straight on along the device's heading (yaw 0.3).
        let o = g.update(&input(Vec3::new(0.0, 0.0, 1e-6), 0.0, 0.3, None));
        assert_eq!(o.status, Status::FluxLine);
        assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5), "{:?}", o.arrow);
        assert!(o.bearing.is_some_and(|b| (b - 0.3).abs() < 1e-5));
        let o = g.update(&GuidanceInput {
            h_g: None,
            walked_m: 0.0,
            yaw: 0.0,
            estimate: None,
            reinitialized: false,
            signal_lost: false,
            height_m: None,
            lower_allowed: true,
        });
        assert_eq!(o, GuidanceOutput::default());
        // NaNs are ignored rather than propagated.
        let o = g.update(&input(
            Vec3::new(f32::NAN, 1.0, 0.0),
            f32::NAN,
            f32::NAN,
            None,
        ));
        assert_eq!(o.status, Status::NoSignal);
    }

    #[test]
    fn a_horizontal_field_within_the_noise_does_not_steer_the_flux_line() {
        let cfg = GuidanceConfig::default();
        let sigma = cfg.sigma_bkg;
        let mut g = Guidance::new(cfg);
        // A clear horizontal field along x (20 σ) sets the direction.
        let o = g.update(&input(Vec3::new(20.0 * sigma, 0.0, 0.0), 1.0, 0.0, None));
        assert!(o.bearing.is_some_and(|b| b.abs() < 1e-3), "{:?}", o.bearing);
        // Then a near-vertical field of the same strength (no flip) whose horizontal part
        // (1.5 σ, along y) is below flux_min_snr × the reading σ (1.17 σ at 20 σ): the
        // direction is held, over many pulses.
        let vertical = |horizontal: f32| libm::sqrtf(400.0 - horizontal * horizontal) * sigma;
        let weak = Vec3::new(0.0, 1.5 * sigma, vertical(1.5));
        for _ in 0..10 {
            let o = g.update(&input(weak, 1.0, 0.0, None));
            assert_eq!(o.status, Status::FluxLine);
            assert!(o.bearing.is_some_and(|b| b.abs() < 1e-3), "{:?}", o.bearing);
        }
        // The same horizontal part at 4 σ steers again (toward ±y).
        let clear = Vec3::new(0.0, 4.0 * sigma, vertical(4.0));
        let mut b = 0.0;
        for _ in 0..10 {
            b = g
                .update(&input(clear, 1.0, 0.0, None))
                .bearing
                .unwrap_or(0.0);
        }
        assert!((b.abs() - FRAC_PI_2).abs() < 0.05, "{b}");
    }

    #[test]
    fn switches_to_the_mean_when_far_in_mahalanobis_distance_and_latches() {
        let mut g = Guidance::new(GuidanceConfig::default());
        let h = Vec3::new(1e-6, 0.0, 0.0);
        // Broad belief around the receiver: keep following the flux line.
        let o = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(5.0, 5.0, -2.0), 10.0)),
        ));
        assert_eq!(o.status, Status::FluxLine);
        assert!(o.distance_m.is_none() && o.sigma_h_m.is_some());
        // Concentrated and 3σ away: go to the mean (to the west = 90° left).
        let o = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(0.0, 20.0, -2.0), 2.0)),
        ));
        assert_eq!(o.status, Status::Localized);
        assert!(o.arrow.is_some_and(|a| (a - FRAC_PI_2).abs() < 1e-5));
        assert!(
            o.distance_m
                .is_some_and(|d| (d - 404f32.sqrt()).abs() < 1e-3)
        );
        assert!(o.depth_m.is_none());
        // Latched while walking in (the receiver falls inside the ellipse).
        let o = g.update(&input(
            h,
            1.0,
            FRAC_PI_2,
            Some(est(Vec3::new(0.0, 2.5, -2.0), 1.0)),
        ));
        assert_eq!(o.status, Status::Localized);
        assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5));
        assert!(o.depth_m.is_some_and(|d| (d - 1.0).abs() < 1e-5));
        // A re-initialized mixture drops back to the flux line.
        let mut i = input(h, 1.0, 0.0, Some(est(Vec3::new(0.0, 2.5, -2.0), 30.0)));
        i.reinitialized = true;
        assert_eq!(g.update(&i).status, Status::FluxLine);
    }

    #[test]
    fn probe_needs_a_tight_belief_right_below_for_two_pulses() {
        let mut g = Guidance::new(GuidanceConfig::default());
        let h = Vec3::new(1e-4, 0.0, 0.0);
        let o = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0)),
        ));
        assert_eq!(o.status, Status::Localized);
        // Close but 0.7 m off (beyond reach): not yet.
        let o = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(0.7, 0.0, -2.0), 0.05)),
        ));
        assert_eq!(o.status, Status::Localized);
        // Within 0.3 m and 3σ = 0.15 m: first pulse confirms, the second probes.
        let e = Some(est(Vec3::new(0.2, 0.0, -2.2), 0.05));
        assert_eq!(g.update(&input(h, 0.5, 0.0, e)).status, Status::Localized);
        let o = g.update(&input(h, 0.0, 0.0, e));
        assert_eq!(o.status, Status::Probe);
        assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-4));
        assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5));
        // Latched.
        let e = Some(est(Vec3::new(0.35, 0.0, -2.2), 0.05));
        assert_eq!(g.update(&input(h, 0.0, 0.0, e)).status, Status::Probe);
    }

    #[test]
    fn an_uncertain_depth_over_the_mean_asks_for_a_lift_before_probing() {
        let cfg = GuidanceConfig::default();
        let mut g = Guidance::new(cfg);
        let h = Vec3::new(1e-4, 0.0, 0.0);
        let _ = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0)),
        ));
        let mut wide = est(Vec3::new(0.1, 0.0, -2.2), 0.05);
        wide.cov[(2, 2)] = 0.3 * 0.3;
        // Far from the mean: no lift even with a wide depth.
        let mut far = wide;
        far.p.x = 2.0;
        assert!(!g.update(&input(h, 1.0, 0.0, Some(far))).lift);
        // Over it: lift (no probe meanwhile), at most `lift_max_pulses` times.
        for _ in 0..cfg.lift_max_pulses {
            let o = g.update(&input(h, 0.0, 0.0, Some(wide)));
            assert!(o.lift && o.status == Status::Localized);
        }
        let o = g.update(&input(h, 0.0, 0.0, Some(wide)));
        assert!(!o.lift && o.status == Status::Probe);
        // A pinned depth probes without a lift.
        let mut g = Guidance::new(cfg);
        let _ = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0)),
        ));
        let mut tight = wide;
        tight.cov[(2, 2)] = 0.1 * 0.1;
        assert!(!g.update(&input(h, 0.0, 0.0, Some(tight))).lift);
        assert_eq!(
            g.update(&input(h, 0.0, 0.0, Some(tight))).status,
            Status::Probe
        );
    }

    /// The probe thresholds the fine-search tests' σ values are placed against (radius
    /// 0.3 m, plateau ceiling 0.15 m); the rules' logic does not depend on the values.
    fn probe_rule_03() -> GuidanceConfig {
        GuidanceConfig {
            probe_radius_m: 0.3,
            probe_plateau_max_sigma_m: 0.15,
            ..GuidanceConfig::default()
        }
    }

    #[test]
    fn over_a_wide_mean_the_arrow_brackets_it_then_times_out() {
        // A fixed 0.5 m offset (the range-scaled one has its own test).
        let cfg = GuidanceConfig {
            bracket_range_ratio: 0.0,
            ..probe_rule_03()
        };
        let mut g = Guidance::new(cfg);
        let h = Vec3::new(1e-4, 0.0, 0.0);
        let _ = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0)),
        ));
        // Over the mean (0.1 m) but σ = 0.4 m: bracket, no probe yet; the same side
        // until the receiver has reached it.
        let e = Some(est(Vec3::new(0.1, 0.0, -2.0), 0.4));
        let a = g.update(&input(h, 0.0, 0.0, e));
        let b = g.update(&input(h, 0.0, 0.0, e));
        assert_eq!(a.status, Status::Localized);
        let (ba, bb) = (a.bearing.unwrap_or(9.0), b.bearing.unwrap_or(9.0));
        assert!(wrap_pi(ba - bb).abs() < 1e-5, "{ba} {bb}");
        assert!(
            a.walk_m
                .is_some_and(|w| (w - 0.6).abs() < 1e-4 || (w - 0.4).abs() < 1e-4)
        );
        // At the bracketing point (0.5 m beyond the mean): back across the mean to the
        // other side.
        let side = [libm::cosf(ba), libm::sinf(ba)];
        let at = |k: f32| Some(est(Vec3::new(0.1 - k * side[0], -k * side[1], -2.0), 0.4));
        let c = g.update(&input(h, 0.5, 0.0, at(b.walk_m.unwrap_or(0.0))));
        let bc = c.bearing.unwrap_or(9.0);
        assert!((wrap_pi(bc - ba).abs() - PI).abs() < 0.05, "{ba} {bc}");
        let d = g.update(&input(h, 0.5, 0.0, e));
        let bd = d.bearing.unwrap_or(9.0);
        assert!((wrap_pi(bd - ba).abs() - PI).abs() < 1e-3, "{ba} {bd}");
        // Standing over the mean, it times out into "probe here".
        let mut n = 0;
        let mut last = d.status;
        while last != Status::Probe && n < 100 {
            last = g.update(&input(h, 0.0, 0.0, e)).status;
            n += 1;
        }
        assert_eq!(last, Status::Probe);
        // The pulses before the loop that were within reach of the mean count too (a, b
        // and d; c if the bracketing point lay within reach).
        let before = [a, b, c, d]
            .iter()
            .filter(|o| {
                o.horizontal_m
                    .is_some_and(|h| h <= cfg.probe_reach_m.max(0.4))
            })
            .count();
        assert_eq!(n + before, usize::from(cfg.probe_timeout_pulses));
    }

    /// Localizes a fresh guidance (a concentrated belief 30 m away).
    fn localized(cfg: GuidanceConfig) -> Guidance {
        let mut g = Guidance::new(cfg);
        let h = Vec3::new(1e-4, 0.0, 0.0);
        let o = g.update(&input(
            h,
            1.0,
            0.0,
            Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0)),
        ));
        assert_eq!(o.status, Status::Localized);
        g
    }

    /// Pulses standing over a mean 0.2 m away until "probe here" (at most 40), with the
    /// horizontal σ of pulse k given by `sigma(k)`.
    fn pulses_to_probe(g: &mut Guidance, sigma: impl Fn(usize) -> f32) -> Option<usize> {
        let h = Vec3::new(1e-4, 0.0, 0.0);
        (0..40).find(|&k| {
            let e = est(Vec3::new(0.2, 0.0, -2.0), sigma(k));
            g.update(&input(h, 0.0, 0.0, Some(e))).status == Status::Probe
        })
    }

    #[test]
    fn the_bracketing_offset_grows_with_the_range_between_one_and_two_steps() {
        let cfg = probe_rule_03();
        let h = Vec3::new(1e-4, 0.0, 0.0);
        // Over a wide mean (σ 0.4 m) 0.1 m ahead at depth z: the walk is the offset ± 0.1.
        let walk_over = |z: f32| {
            let mut g = Guidance::new(cfg);
            let far = est(Vec3::new(30.0, 0.0, z), 2.0);
            let _ = g.update(&input(h, 1.0, 0.0, Some(far)));
            let o = g.update(&input(h, 0.0, 0.0, Some(est(Vec3::new(0.1, 0.0, z), 0.4))));
            o.walk_m.unwrap_or(f32::NAN)
        };
        let near = |w: f32, b: f32| (w - b - 0.1).abs() < 1e-3 || (w - b + 0.1).abs() < 1e-3;
        // Shallow: the least offset; 2.5 m deep: 0.35 × 2.5 m; 5 m deep: capped at 1 m.
        let range = |z: f32| libm::sqrtf(0.01 + z * z);
        assert!(near(walk_over(-1.0), 0.5), "{}", walk_over(-1.0));
        let mid = cfg.bracket_range_ratio * range(-2.5);
        assert!(near(walk_over(-2.5), mid), "{} {mid}", walk_over(-2.5));
        assert!(near(walk_over(-5.0), 1.0), "{}", walk_over(-5.0));
        // A bad ratio falls back to the least offset instead of a NaN target.
        let mut g = Guidance::new(GuidanceConfig {
            bracket_range_ratio: f32::NAN,
            ..cfg
        });
        let far = est(Vec3::new(30.0, 0.0, -2.5), 2.0);
        let _ = g.update(&input(h, 1.0, 0.0, Some(far)));
        let o = g.update(&input(
            h,
            0.0,
            0.0,
            Some(est(Vec3::new(0.1, 0.0, -2.5), 0.4)),
        ));
        assert!(o.walk_m.is_some_and(|w| near(w, 0.5)), "{:?}", o.walk_m);
    }

    #[test]
    fn a_levelled_off_sigma_probes_before_the_timeout() {
        let cfg = GuidanceConfig {
            probe_timeout_pulses: 30,
            ..probe_rule_03()
        };
        let n = usize::from(cfg.probe_plateau_pulses);
        // σ stuck at 0.12 m (3σ > the 0.3 m probe radius, below the plateau bound):
        // "probe here" once it has not shrunk for `probe_plateau_pulses` pulses — the
        // first pulse sets the best σ, so the probe comes on pulse index n.
        let mut g = localized(cfg);
        assert_eq!(pulses_to_probe(&mut g, |_| 0.12), Some(n));
        // Shrinking by 15 % every second pulse until pulse 4, then level at 0.101 m: the
        // plateau counts from pulse 4.
        let mut g = localized(cfg);
        let shrinking = |k: usize| 0.14 * libm::powf(0.85, (k / 2) as f32).max(0.101 / 0.14);
        let k = pulses_to_probe(&mut g, shrinking).unwrap_or(usize::MAX);
        assert_eq!(k, 4 + n, "the last progress on pulse 4");
        // A wide belief that stopped shrinking is not trusted: only the timeout probes.
        let mut g = localized(cfg);
        assert_eq!(
            pulses_to_probe(&mut g, |_| 0.2),
            Some(usize::from(cfg.probe_timeout_pulses) - 1)
        );
        // Disabled: the timeout again.
        let mut g = localized(GuidanceConfig {
            probe_plateau_pulses: 0,
            ..cfg
        });
        assert_eq!(
            pulses_to_probe(&mut g, |_| 0.12),
            Some(usize::from(cfg.probe_timeout_pulses) - 1)
        );
    }

    #[test]
    fn one_jump_of_the_estimate_does_not_restart_the_timeout() {
        let cfg = probe_rule_03();
        let timeout = usize::from(cfg.probe_timeout_pulses);
        // A wide belief (no plateau probe) 0.2 m away, except on the pulses in `jumps`,
        // where it is 3 m away (beyond the bracketing span): the pulse of the probe.
        let run = |jumps: &[usize]| {
            let mut g = localized(cfg);
            let h = Vec3::new(1e-4, 0.0, 0.0);
            (0..60).find(|k| {
                let x = if jumps.contains(k) { 3.0 } else { 0.2 };
                let e = est(Vec3::new(x, 0.0, -2.0), 0.2);
                g.update(&input(h, 0.0, 0.0, Some(e))).status == Status::Probe
            })
        };
        assert_eq!(run(&[]), Some(timeout - 1));
        // One jump: that pulse is not over the mean, the count goes on.
        assert_eq!(run(&[5]), Some(timeout));
        // Two in a row: the rescuer left, the count starts again after them.
        assert_eq!(run(&[5, 6]), Some(7 + timeout - 1));
    }

    #[test]
    fn an_inconclusive_signal_does_not_flip_the_flux_line() {
        // At the edge of reception: |H| ≈ 5 σ_bkg, fluctuating by ±σ_bkg (never a
        // significant decrease), over 40 m: keep the direction.
        let cfg = GuidanceConfig::default();
        let mut g = Guidance::new(cfg);
        for k in 0..40 {
            let wiggle = if k % 3 == 0 { 1.0 } else { -0.6 };
            let h = cfg.sigma_bkg * (5.0 + wiggle);
            let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
            assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5), "pulse {k}");
        }
        // A significant fall (walking away: |H| ∝ r⁻³) still flips it within 5 m + a few.
        let mut h = 5.0 * cfg.sigma_bkg;
        let mut flipped = false;
        for _ in 0..12 {
            h *= 0.85;
            let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
            flipped |= o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5);
        }
        assert!(flipped);
    }

    #[test]
    fn angles_and_helpers() {
        assert!((to_degrees_wrapped(-PI) - 180.0).abs() < 1e-4);
        assert!((to_degrees_wrapped(FRAC_PI_2) - 90.0).abs() < 1e-4);
        assert!((relative_arrow(0.1, 2.0 * PI + 0.2) + 0.1).abs() < 1e-5);
        let e = est(Vec3::new(3.0, 4.0, 0.0), 1.0);
        assert!((horizontal_mahalanobis2(&e) - 25.0).abs() < 1e-3);
        let mut c = Mat3::zeros();
        c[(0, 0)] = 1.0;
        c[(1, 1)] = 1.0;
        c[(0, 1)] = 0.5;
        c[(1, 0)] = 0.5;
        let (axis, s) = horizontal_axis(&c);
        assert!((s - 1.5f32.sqrt()).abs() < 1e-5);
        assert!((axis[0] - axis[1]).abs() < 1e-5);
        assert!(flux_direction(&Vec3::new(0.0, 0.0, 1.0), &[1.0, 0.0]).is_none());
    }

    /// A search localized from 30 m away (so that the mean near the receiver is trusted).
    fn localized_search(cfg: GuidanceConfig) -> Guidance {
        let mut g = Guidance::new(cfg);
        let far = est(Vec3::new(30.0, 0.0, -2.0), 2.0);
        let _ = g.update(&input(Vec3::new(1e-4, 0.0, 0.0), 1.0, 0.0, Some(far)));
        assert!(g.is_localized());
        g
    }

    fn at_height(e: VictimEstimate, height: Option<f32>) -> GuidanceInput {
        GuidanceInput {
            height_m: height,
            ..input(Vec3::new(1e-4, 0.0, 0.0), 0.0, 0.0, Some(e))
        }
    }

    #[test]
    fn a_rescuer_who_ignores_the_lowering_is_asked_a_few_times_then_left_alone() {
        let cfg = GuidanceConfig::default();
        let mut g = localized_search(cfg);
        // 1.5 m from the mean, 1.2 m deep below the snow, the receiver at 1 m.
        let near = est(Vec3::new(1.5, 0.0, -2.2), 0.3);
        // Farther than `lower_within_m`: not yet.
        let o = g.update(&at_height(est(Vec3::new(2.5, 0.0, -2.2), 0.3), Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        // Shown first, then through `height_prompt_pulses` intervals of standing.
        for _ in 0..=cfg.height_prompt_pulses {
            let o = g.update(&at_height(near, Some(1.0)));
            assert_eq!(o.height_prompt, HeightPrompt::Lower);
            assert_eq!(o.status, Status::Localized);
            assert!(!o.lift);
            // The depth below the snow from the current height.
            assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
        }
        // Ignored: not asked again in this search, even over the mean; the search goes on.
        for _ in 0..20 {
            let o = g.update(&at_height(near, Some(1.0)));
            assert_eq!(o.height_prompt, HeightPrompt::None);
        }
        let o = g.update(&at_height(est(Vec3::new(0.1, 0.0, -2.2), 0.05), Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
    }

    #[test]
    fn the_lowering_prompt_waits_for_a_walking_rescuer_to_stand_within_a_limit() {
        let cfg = GuidanceConfig::default();
        let near = est(Vec3::new(1.5, 0.0, -2.2), 0.3);
        let walking = |walked: f32| GuidanceInput {
            walked_m: walked,
            ..at_height(near, Some(1.0))
        };
        // Steps still under way on the first pulses: the prompt stays on, then runs for
        // the standing intervals.
        let mut g = localized_search(cfg);
        for _ in 0..3 {
            assert_eq!(g.update(&walking(0.6)).height_prompt, HeightPrompt::Lower);
        }
        for _ in 0..cfg.height_prompt_pulses {
            assert_eq!(g.update(&walking(0.0)).height_prompt, HeightPrompt::Lower);
        }
        assert_eq!(g.update(&walking(0.0)).height_prompt, HeightPrompt::None);
        // A rescuer who walks on regardless is asked on a bounded number of pulses.
        let mut g = localized_search(cfg);
        let most = usize::from(cfg.height_prompt_pulses) * usize::from(PROMPT_SHOWN_FACTOR);
        let shown = (0..100)
            .filter(|_| g.update(&walking(0.6)).height_prompt == HeightPrompt::Lower)
            .count();
        assert_eq!(shown, most);
    }

    #[test]
    fn probe_here_is_confirmed_by_pulses_after_the_lowering() {
        let cfg = GuidanceConfig::default();
        let mut g = localized_search(cfg);
        // Right over a tight mean at 1 m: "probe here" would need two pulses, but the
        // lowering comes first, as often as it is shown.
        let over = est(Vec3::new(0.05, 0.0, -2.2), 0.05);
        for _ in 0..3 {
            let o = g.update(&at_height(over, Some(1.0)));
            assert_eq!(o.height_prompt, HeightPrompt::Lower);
            assert_eq!(o.status, Status::Localized);
        }
        // Lowered: the pulses from 1 m up confirm nothing; two at the snow do.
        let low = est(Vec3::new(0.05, 0.0, -1.4), 0.05);
        let o = g.update(&at_height(low, Some(0.2)));
        assert_eq!(
            (o.height_prompt, o.status),
            (HeightPrompt::None, Status::Localized)
        );
        assert_eq!(g.update(&at_height(low, Some(0.2))).status, Status::Probe);
    }

    #[test]
    fn a_lowered_receiver_ends_the_prompt_and_the_depth_follows_the_height() {
        let cfg = GuidanceConfig::default();
        let mut g = localized_search(cfg);
        let o = g.update(&at_height(est(Vec3::new(1.5, 0.0, -2.2), 0.3), Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::Lower);
        // Lowered by 0.8 m: the victim is 0.8 m less below the receiver, the depth below
        // the snow is the same.
        let o = g.update(&at_height(est(Vec3::new(1.5, 0.0, -1.4), 0.3), Some(0.2)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
        // Lowered, a wide depth asks for no lift (the lowering pinned the range).
        let mut wide = est(Vec3::new(0.1, 0.0, -1.4), 0.05);
        wide.cov[(2, 2)] = 0.3 * 0.3;
        let o = g.update(&at_height(wide, Some(0.2)));
        assert!(!o.lift && o.height_prompt == HeightPrompt::None);
    }

    #[test]
    fn a_shallow_victim_is_lowered_to_but_an_untracked_height_is_not() {
        let cfg = GuidanceConfig::default();
        // 0.5 m deep: lowered to 0.2 m it is 0.7 m below the receiver, and the estimator's
        // initialization prior follows the tracked height (`set_receiver_height`).
        let mut g = localized_search(cfg);
        let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -1.5), 0.3), Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::Lower);
        // Deep, but the caller tracks no height.
        let mut g = localized_search(cfg);
        let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -3.0), 0.3), None));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        assert!(o.depth_m.is_some_and(|d| (d - 2.0).abs() < 1e-5));
        // Switched off.
        let mut g = localized_search(GuidanceConfig {
            lower_within_m: 0.0,
            ..cfg
        });
        let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -3.0), 0.3), Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        // Withheld by the caller (several victims): no prompt, and "probe here" is not
        // held back by one.
        let mut g = localized_search(cfg);
        let withheld = |e: VictimEstimate| GuidanceInput {
            lower_allowed: false,
            ..at_height(e, Some(1.0))
        };
        let o = g.update(&withheld(est(Vec3::new(1.0, 0.0, -3.0), 0.3)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
        let over = est(Vec3::new(0.05, 0.0, -3.0), 0.05);
        let _ = g.update(&withheld(over));
        assert_eq!(g.update(&withheld(over)).status, Status::Probe);
    }

    #[test]
    fn a_lowered_receiver_far_from_the_mean_is_asked_to_be_raised() {
        let cfg = GuidanceConfig::default();
        let mut g = localized_search(cfg);
        let near = est(Vec3::new(1.0, 0.0, -1.4), 0.3);
        assert_eq!(
            g.update(&at_height(near, Some(0.2))).height_prompt,
            HeightPrompt::None
        );
        // The mean moved 10 m away (e.g. the next victim): raise, a few pulses at most.
        let far = est(Vec3::new(10.0, 0.0, -1.4), 0.5);
        for _ in 0..=cfg.height_prompt_pulses {
            assert_eq!(
                g.update(&at_height(far, Some(0.2))).height_prompt,
                HeightPrompt::Raise
            );
        }
        assert_eq!(
            g.update(&at_height(far, Some(0.2))).height_prompt,
            HeightPrompt::None
        );
        // Raised: nothing more to ask; no lowering asked again this far away.
        assert_eq!(
            g.update(&at_height(far, Some(1.0))).height_prompt,
            HeightPrompt::None
        );
    }
}
