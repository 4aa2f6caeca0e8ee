//! Automatic gain ranging: which analog setting (IF range switch and the ADS131M04's PGA,
//! common to the three coils) the next pulse is measured in.
//!
//! The settings form one ladder of [`RUNGS`] rungs whose full scales double from rung to
//! rung: the high IF range at PGA 128 … 1 (rungs 0–7), then the low range (64× less
//! sensitive) at PGA 32 … 1 (rungs 8–13); see `docs/decisions/analog-dynamic-range.md`.
//! The high range comes first because at equal full scale its input-referred noise is
//! lower (the ADC's noise at PGA 1 is 4.5× its noise at PGA 128, the range switch's
//! attenuation 64×).
//!
//! The rule, in units of rung 0's full scale (a level `L` seen on rung `r` as a fraction
//! `x` of full scale is `L = x · 2^r`):
//! - after every pulse the front end reports its peak sample (`x`, or "clipped"); a
//!   clipped pulse counts as [`RangingConfig::saturated_steps`] rungs too strong;
//! - the recent level is the largest pulse level of the last [`RangingConfig::hold_s`]
//!   (longer than the standard's longest period, 1.3 s, so the strongest of several
//!   transmitters sets it) and the peak of the noise between pulses;
//! - nothing changes while the recent level stays within
//!   [`RangingConfig::low`] … [`RangingConfig::high`] of the current full scale
//!   (hysteresis: 8× wide for 2× steps); outside it the rung moves so that the level sits
//!   at [`RangingConfig::target`] or just below.
//!
//! Decisions are taken only at a pulse's end and, between pulses, once no pulse has been
//! heard for the hold time: never inside a pulse. The front end applies the change from
//! the next sample (re-seeding its noise floor, [`RangingConfig::settle_blocks`] after the
//! switch transient) and reports it as a [`RangeChange`] event.

use crate::drivers::ads131m04::Gain;

/// Number of rungs of the ladder.
pub const RUNGS: usize = 14;
/// Pulse levels remembered for the hold window (more than the pulses of the standard's
/// fastest transmitters in [`RangingConfig::hold_s`] with a few in view).
const RECENT: usize = 12;

/// The IF amplifier's range switch, common to the three coils.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IfRange {
    /// Full gain: the receiver's sensitivity is set by the environment's noise.
    #[default]
    High,
    /// Gain reduced by the calibration's `low_range_ratio` (≈ 64×), for fields within
    /// about a metre of a strong beacon.
    Low,
}

/// One analog setting: IF range and PGA gain (the same on the three coil channels).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Range {
    /// Position of the IF range switch.
    pub if_range: IfRange,
    /// PGA gain of ADC channels 0–2.
    pub gain: Gain,
}

#[cfg(feature = "defmt")]
impl defmt::Format for Range {
    fn format(&self, f: defmt::Formatter) {
        let r = match self.if_range {
            IfRange::High => "high",
            IfRange::Low => "low",
        };
        defmt::write!(f, "{=str} range, PGA {=u16}", r, self.gain.factor());
    }
}

impl Range {
    /// The most sensitive setting (rung 0).
    pub const MOST_SENSITIVE: Range = Range {
        if_range: IfRange::High,
        gain: Gain::G128,
    };
    /// High range at PGA 1 (rung 7): the setting without ranging.
    pub const HIGH_G1: Range = Range {
        if_range: IfRange::High,
        gain: Gain::G1,
    };

    /// The setting of rung `r` (0 = most sensitive), `None` past the ladder.
    pub fn rung(r: usize) -> Option<Range> {
        let (if_range, bits) = match r {
            0..=7 => (IfRange::High, 7 - r),
            8..=13 => (IfRange::Low, 13 - r),
            _ => return None,
        };
        Some(Range {
            if_range,
            gain: Gain::from_bits(bits as u16),
        })
    }

    /// This setting's rung, `None` for settings off the ladder (low range at PGA 64/128).
    pub fn index(self) -> Option<usize> {
        let bits = self.gain as usize;
        match self.if_range {
            IfRange::High => Some(7 - bits),
            IfRange::Low => (bits <= 5).then(|| 13 - bits),
        }
    }

    /// Full-scale input of the ADC at this setting, V.
    pub fn full_scale_v(self) -> f32 {
        self.gain.full_scale_v()
    }
}

/// Why the setting changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RangeReason {
    /// A pulse clipped.
    Saturated,
    /// A pulse (or the noise) peaked above [`RangingConfig::high`] of full scale.
    Strong,
    /// Everything heard over the hold time peaked below [`RangingConfig::low`].
    Weak,
}

/// A change of the analog setting: a loggable event. The caller applies `to` to the
/// hardware before it feeds the next sample.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RangeChange {
    /// When (s since the first sample).
    pub t_s: f32,
    /// Setting until now.
    pub from: Range,
    /// Setting from the next sample on.
    pub to: Range,
    /// Why.
    pub reason: RangeReason,
}

/// Parameters of the ranging rule (fractions of the ADC's full scale).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangingConfig {
    /// Step to a less sensitive rung when the recent level exceeds this. Default ½: the
    /// receiver turns and moves between pulses (a 2× rise from one pulse to the next is
    /// close to a beacon), so a pulse keeps one rung of headroom.
    pub high: f32,
    /// Where a change puts the recent level (at or just below). Default ¼.
    pub target: f32,
    /// Step to a more sensitive rung when the recent level is below this. Default 1/16:
    /// the ADC's own noise then still sits ≥ 8× below the peak, and the band
    /// `low … high` is 8× wide, so ordinary pulse-to-pulse changes never switch.
    pub low: f32,
    /// Rungs a clipped pulse counts as too strong (its true peak is unknown). Default 5:
    /// from the most sensitive rung three clipped pulses reach the least sensitive; an
    /// overshoot costs nothing but one pulse measured at ≥ 1/64 of full scale (far above
    /// the ADC's noise) before the band rule brings the gain back.
    pub saturated_steps: usize,
    /// How long a pulse level holds the setting, s. Default 2.8: two of the standard's
    /// longest periods (1.3 s) and a margin, so one missed pulse of the strongest
    /// transmitter does not let a weaker one raise the gain into its next pulse.
    pub hold_s: f32,
    /// Blocks discarded after a change while the analog chain and the ADC's sinc³ filter
    /// settle (and samples queued before the change drain). Default 4 (8 ms).
    pub settle_blocks: usize,
    /// Most sensitive rung allowed.
    pub min_rung: usize,
    /// Least sensitive rung allowed.
    pub max_rung: usize,
}

impl Default for RangingConfig {
    fn default() -> Self {
        RangingConfig {
            high: 0.5,
            target: 0.25,
            low: 1.0 / 16.0,
            saturated_steps: 5,
            hold_s: 2.8,
            settle_blocks: 4,
            min_rung: 0,
            max_rung: RUNGS - 1,
        }
    }
}

impl RangingConfig {
    /// Whether the thresholds are ordered `0 < 2·low ≤ target < high ≤ 1` (a change can
    /// never land outside the band), the hold time positive and the rungs on the ladder.
    pub fn is_valid(&self) -> bool {
        self.low > 0.0
            && 2.0 * self.low <= self.target
            && self.target < self.high
            && self.high <= 1.0
            && self.saturated_steps >= 1
            && self.hold_s.is_finite()
            && self.hold_s > 0.0
            && self.min_rung <= self.max_rung
            && self.max_rung < RUNGS
    }
}

/// The ranging rule's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ranger {
    cfg: RangingConfig,
    rung: usize,
    /// `(t_s, level)` of recent pulses, level in rung-0 full scales.
    recent: [(f32, f32); RECENT],
    next: usize,
    /// Peak of the noise between pulses (rung-0 full scales) in the current and the
    /// previous half hold window, and when the current one began.
    quiet: [f32; 2],
    quiet_start_s: f32,
    last_pulse_s: f32,
}

impl Ranger {
    /// The rule with configuration `cfg` (assumed valid), starting on rung `rung`.
    pub fn new(cfg: RangingConfig, rung: usize) -> Self {
        Ranger {
            cfg,
            rung: rung.clamp(cfg.min_rung, cfg.max_rung),
            recent: [(f32::NEG_INFINITY, 0.0); RECENT],
            next: 0,
            quiet: [0.0; 2],
            quiet_start_s: 0.0,
            last_pulse_s: f32::NEG_INFINITY,
        }
    }

    /// The current rung.
    pub fn rung(&self) -> usize {
        self.rung
    }

    /// Make `rung` current (the hardware is known to be there), forgetting nothing.
    pub fn force(&mut self, rung: usize) {
        self.rung = rung.min(RUNGS - 1);
    }

    fn scale(rung: usize) -> f32 {
        (1u32 << rung.min(31)) as f32
    }

    /// The largest level of the hold window ending at `t_s`.
    fn recent_level(&self, t_s: f32) -> f32 {
        let pulses = self
            .recent
            .iter()
            .filter(|(t, _)| *t >= t_s - self.cfg.hold_s)
            .fold(0.0f32, |m, (_, l)| m.max(*l));
        pulses.max(self.quiet[0]).max(self.quiet[1])
    }

    /// The rung that puts `level` at the target or just below it.
    fn rung_for(&self, level: f32) -> usize {
        let mut r = self.cfg.min_rung;
        while r < self.cfg.max_rung && level > self.cfg.target * Self::scale(r) {
            r += 1;
        }
        r
    }

    /// Applies the band rule at `t_s`; `Some(new rung)` when the rung changes.
    fn decide(&mut self, t_s: f32, clipped: bool) -> Option<(usize, RangeReason)> {
        let level = self.recent_level(t_s);
        let x = level / Self::scale(self.rung);
        let (to, reason) = if clipped {
            (self.rung_for(level), RangeReason::Saturated)
        } else if x > self.cfg.high {
            (self.rung_for(level), RangeReason::Strong)
        } else if x < self.cfg.low {
            (self.rung_for(level), RangeReason::Weak)
        } else {
            return None;
        };
        if to == self.rung {
            return None;
        }
        self.rung = to;
        Some((to, reason))
    }

    /// A pulse ended at `t_s` whose largest sample was `peak` of full scale on the current
    /// rung (`clipped`: some sample sat at full scale). Returns the new rung if it changes.
    pub fn on_pulse(&mut self, t_s: f32, peak: f32, clipped: bool) -> Option<(usize, RangeReason)> {
        let s = Self::scale(self.rung);
        let level = if clipped {
            self.cfg.target * Self::scale(self.rung + self.cfg.saturated_steps)
        } else if peak.is_finite() {
            peak.max(0.0) * s
        } else {
            // A non-finite peak cannot come from real samples; treat it as clipped.
            self.cfg.target * Self::scale(self.rung + self.cfg.saturated_steps)
        };
        if let Some(slot) = self.recent.get_mut(self.next) {
            *slot = (t_s, level);
        }
        self.next = (self.next + 1) % RECENT;
        self.last_pulse_s = t_s;
        self.decide(t_s, clipped || !peak.is_finite())
    }

    /// A block of noise between pulses at `t_s` peaked at `peak` of full scale on the
    /// current rung. Once no pulse has been heard for the hold time, returns the new rung
    /// if the level calls for one.
    pub fn on_quiet(&mut self, t_s: f32, peak: f32) -> Option<(usize, RangeReason)> {
        if t_s - self.quiet_start_s > 0.5 * self.cfg.hold_s {
            self.quiet = [0.0, self.quiet[0]];
            self.quiet_start_s = t_s;
        }
        if peak.is_finite() {
            self.quiet[0] = self.quiet[0].max(peak.max(0.0) * Self::scale(self.rung));
        }
        if t_s - self.last_pulse_s < self.cfg.hold_s {
            return None;
        }
        self.decide(t_s, false)
    }

    /// Forget the noise peaks (after a change: the new rung's noise is measured afresh).
    pub fn reset_quiet(&mut self, t_s: f32) {
        self.quiet = [0.0; 2];
        self.quiet_start_s = t_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ladder_runs_from_high_pga_128_to_low_pga_1() {
        assert_eq!(Range::rung(0), Some(Range::MOST_SENSITIVE));
        assert_eq!(Range::rung(7), Some(Range::HIGH_G1));
        assert_eq!(
            Range::rung(8),
            Some(Range {
                if_range: IfRange::Low,
                gain: Gain::G32
            })
        );
        assert_eq!(
            Range::rung(13),
            Some(Range {
                if_range: IfRange::Low,
                gain: Gain::G1
            })
        );
        assert_eq!(Range::rung(RUNGS), None);
        for r in 0..RUNGS {
            assert_eq!(Range::rung(r).and_then(Range::index), Some(r));
        }
        let off = Range {
            if_range: IfRange::Low,
            gain: Gain::G64,
        };
        assert_eq!(off.index(), None);
    }

    #[test]
    fn a_clipped_pulse_steps_down_and_a_strong_one_lands_at_the_target() {
        let cfg = RangingConfig::default();
        let mut r = Ranger::new(cfg, 0);
        assert_eq!(
            r.on_pulse(1.0, 1.0, true),
            Some((5, RangeReason::Saturated))
        );
        assert_eq!(
            r.on_pulse(2.0, 1.0, true),
            Some((10, RangeReason::Saturated))
        );
        // 0.9 of full scale on rung 10 is level 0.9·1024 = 921.6: rung 12 puts it at 0.225.
        assert_eq!(r.on_pulse(3.0, 0.9, false), Some((12, RangeReason::Strong)));
        // Clipping at the least sensitive rung cannot go further.
        let mut r = Ranger::new(cfg, RUNGS - 1);
        assert_eq!(r.on_pulse(1.0, 1.0, true), None);
        assert_eq!(r.rung(), RUNGS - 1);
    }

    #[test]
    fn the_band_holds_and_weak_pulses_raise_the_gain_after_the_hold() {
        let cfg = RangingConfig::default();
        let mut r = Ranger::new(cfg, 6);
        // Anything within 1/16 … 1/2 of full scale leaves the rung alone.
        for (k, x) in [0.07, 0.45, 0.2, 0.1, 0.49].iter().enumerate() {
            assert_eq!(r.on_pulse(k as f32, *x, false), None, "{x}");
        }
        // A pulse at 1/40 of full scale while a 0.49 one is within the hold time: kept.
        assert_eq!(r.on_pulse(5.0, 0.025, false), None);
        // Once the strong pulse has aged out (hold 2.8 s), the weak level decides:
        // 0.025·64 = 1.6 → rung 3 (0.2 of full scale).
        assert_eq!(r.on_pulse(7.5, 0.025, false), Some((3, RangeReason::Weak)));
    }

    #[test]
    fn a_strong_and_a_weak_transmitter_do_not_make_the_gain_oscillate() {
        let cfg = RangingConfig::default();
        let mut r = Ranger::new(cfg, 9);
        let mut changes = 0;
        // A: 0.3 of full scale on rung 9, period 1.3 s; B: 1000× weaker, period 0.7 s.
        let (mut ta, mut tb) = (0.1f32, 0.4f32);
        for _ in 0..40 {
            let scale = Ranger::scale(r.rung());
            let (t, level) = if ta < tb {
                ta += 1.3;
                (ta - 1.3, 0.3 * 512.0)
            } else {
                tb += 0.7;
                (tb - 0.7, 0.3 * 512.0 / 1000.0)
            };
            let peak = (level / scale).min(1.0);
            if r.on_pulse(t, peak, peak >= 1.0).is_some() {
                changes += 1;
            }
        }
        assert_eq!(changes, 0);
        assert_eq!(r.rung(), 9);
    }

    #[test]
    fn quiet_raises_the_gain_only_after_the_hold_and_not_above_the_noise() {
        let cfg = RangingConfig::default();
        let mut r = Ranger::new(cfg, 10);
        assert_eq!(r.on_pulse(1.0, 0.3, false), None);
        // Noise at 1e-3 of full scale on rung 10: level ≈ 1.02.
        let mut t = 1.0;
        let mut change = None;
        while t < 10.0 && change.is_none() {
            t += 0.002;
            change = r.on_quiet(t, 1e-3);
        }
        let (to, reason) = change.unwrap();
        assert!(
            t >= 1.0 + cfg.hold_s,
            "no change before the hold ran out ({t})"
        );
        assert_eq!(reason, RangeReason::Weak);
        // The noise must land at or below the target: 1.024 > 0.25·4, so rung 3.
        assert_eq!(to, 3);
        // Strong noise on a sensitive rung never raises the gain further.
        let mut r = Ranger::new(cfg, 0);
        assert_eq!(r.on_quiet(10.0, 0.3), None);
        assert_eq!(r.rung(), 0);
    }

    #[test]
    fn bad_peaks_count_as_clipped_and_the_config_is_checked() {
        let cfg = RangingConfig::default();
        assert!(cfg.is_valid());
        let mut r = Ranger::new(cfg, 2);
        assert_eq!(
            r.on_pulse(1.0, f32::NAN, false),
            Some((7, RangeReason::Saturated))
        );
        assert_eq!(r.on_quiet(9.0, f32::INFINITY), Some((0, RangeReason::Weak)));
        for bad in [
            RangingConfig { low: 0.2, ..cfg },
            RangingConfig { high: 0.2, ..cfg },
            RangingConfig { high: 1.5, ..cfg },
            RangingConfig {
                hold_s: f32::NAN,
                ..cfg
            },
            RangingConfig {
                max_rung: RUNGS,
                ..cfg
            },
            RangingConfig {
                saturated_steps: 0,
                ..cfg
            },
        ] {
            assert!(!bad.is_valid(), "{bad:?}");
        }
    }
}
