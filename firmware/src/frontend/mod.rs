//! Antenna pulse DSP: from the ADC's intermediate-frequency samples to one field vector
//! per transmitter pulse.
//!
//! # Analog chain
//! Three orthogonal ferrite-rod coils (x forward, y left, z up: the body frame R of the
//! session-log spec) each feed a tuned low-noise amplifier at 457 kHz, then a mixer
//! with a common 455 kHz local oscillator (the classic AM IF, so ceramic filters fit)
//! and a band-pass around the 2 kHz difference. The three IF signals reach channels
//! 0–2 of a TI ADS131M04 ([`crate::drivers::ads131m04`]) whose modulators sample
//! simultaneously at 8 kSPS (8.192 MHz clock, OSR 512, high-resolution mode), so the
//! coils' relative phases — the field vector's relative signs — survive to the DSP.
//! The IF, 2 kHz, is a quarter of the sample rate: the digital local oscillator is the
//! sequence 1, −j, −1, j, and a carrier off by the standard's ±80 Hz lands at
//! 1920–2080 Hz, far from DC and Nyquist. Because the LO sits below the carrier, the
//! IF offset has the carrier offset's sign.
//!
//! # Processing (per sample, per 2 ms block, per pulse)
//! 1. Each sample is mixed with the IF local oscillator and summed over a 16-sample
//!    (2 ms) block: one complex phasor per coil and block, scaled so its modulus is the
//!    IF amplitude, then calibrated to A/m ([`Calibration`]). An 80 Hz offset turns the
//!    phasor by 58° per block, which costs only 4 % of amplitude inside a block; the
//!    loss is undone once the offset is known.
//! 2. The three coils' block energies are summed; a 32 ms sliding mean is compared with
//!    an adaptive noise floor (a mean of the per-block energy tracked with a 0.5 s time
//!    constant, fed only from blocks at least a window away from any pulse so pulses
//!    never leak into it). Above `k_on`× the floor a pulse starts, below `k_off`× it
//!    ends.
//! 3. At the pulse's end its blocks are taken from a ring buffer: edges are placed where
//!    the energy crosses halfway between floor and pulse level; pulses shorter than
//!    50 ms are dropped (the standard's on-time is ≥ 70 ms). The timestamp is the
//!    pulse centre.
//! 4. The carrier offset is the peak of the coils' summed periodogram of the block
//!    phasors (zero-padded FFT of ≤ 512 points, refined by a parabola and a
//!    golden-section search): this is the maximum-likelihood estimate and, once
//!    removed, the whole pulse is integrated coherently.
//! 5. The three complex amplitudes are rotated onto their common phase
//!    `φ = ½ arg Σ c_i²`; the real parts are the field vector with correct relative
//!    signs, the overall sign unknown (reported with the largest component positive).
//! 6. A single transmitter leaves only noise after the fit of one carrier whose
//!    envelope may drift linearly (the receiver moves and turns during a pulse), once
//!    the mixer's known image leakage is taken out, and almost nothing in quadrature.
//!    Two overlapping transmitters break one or the other, and the pulse is reported as
//!    [`PulseMeasurement::Overlap`] instead of a wrong vector: an interferer leaves at
//!    least the square of its share of the vector error as residual energy, so a
//!    residual above [`DOMINANCE_RATIO`]² of the signal (beyond the noise allowance)
//!    withholds the pulse — a pulse is kept only when any other transmitter under it is
//!    ≈ 40 dB weaker (the multi-victim rule of [`overlap_verdict`]). Weak pulses are
//!    limited by the noise allowance instead (an interferer hidden in the noise of a
//!    40 σ_bkg pulse can still shift its vector by ≈ 25 %; the estimator's χ² gate is
//!    the defence there).
//! 7. A [`TransmitterTracker`] attributes each pulse to a transmitter by its period
//!    (1000 ± 300 ms) and carrier offset: the pulse's `src`.
//!
//! # Cost and memory
//! Per sample: 6 multiply-adds. Per block (500 Hz): ~60 operations. Per pulse: three
//! FFTs of ≤ 512 points (64–128 points for a 70–100 ms pulse) and ~12 passes over the
//! pulse's blocks. [`Frontend`] holds ≈ 14 KB: a 512 ms ring of block phasors
//! ([`RING_BLOCKS`]), the FFT buffer and its power spectrum ([`MAX_FFT`]).

mod analysis;
mod calibration;
mod coherent;
mod complex;
mod config;
mod dominance;
mod fft;
mod pulse;
mod ranging;
mod tracker;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_ranging;

pub use calibration::Calibration;
pub use complex::C32;
pub use config::{FrontendConfig, FrontendError};
pub use dominance::{DOMINANCE_RATIO, DominanceError, OverlapVerdict, overlap_verdict};
pub use pulse::{Pulse, PulseMeasurement};
pub use ranging::{IfRange, RUNGS, Range, RangeChange, RangeReason, Ranger, RangingConfig};
pub use tracker::{
    DORMANT_S, ESTABLISHED_HITS, MAX_TRACKS, PERIOD_MAX_S, PERIOD_MIN_S, Track, TransmitterTracker,
};

use analysis::{BlockView, Pulse0, analyse};
use core::f32::consts::PI;

/// Longest block (samples) a configuration may use.
pub const MAX_BLOCK: usize = 64;
/// Blocks kept in the ring buffer (512 ms at 2 ms blocks): the longest pulse, or pair
/// of overlapping pulses, that can be analysed.
pub const RING_BLOCKS: usize = 256;
/// Largest FFT (points) of the carrier search; twice [`RING_BLOCKS`] for zero padding.
pub const MAX_FFT: usize = 2 * RING_BLOCKS;

/// Largest block energy kept ((A/m)²): a field of 10⁶ A/m, nine decades above the
/// strongest real pulse, and low enough that no sum or square of block phasors over the
/// ring and the FFT (≤ 512 points) can overflow `f32`. A block above it is treated as
/// clipped (see `on_block`).
const ENERGY_CEILING: f32 = 1e12;

/// Counters of what the front end has seen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrontendStats {
    /// Pulses reported (any measurement).
    pub pulses: u32,
    /// Detections discarded as shorter than the minimum pulse.
    pub rejected_short: u32,
    /// Pulses reported as overlapping.
    pub overlaps: u32,
    /// Pulses reported as saturated.
    pub saturated: u32,
    /// Pulses reported as truncated.
    pub truncated: u32,
    /// Changes of the analog setting (gain ranging).
    pub range_changes: u32,
}

/// Per-coil complex calibration of the block phasors in IF range `range`: field per
/// volt at the ADC input and the channel's phase lag undone. The ADC's PGA is divided out
/// by the driver (`to_volts`); its gain error (TI SBAS946: ±0.5 % at most, far less
/// between gains) is not calibrated.
fn coil_calibration(c: &Calibration, range: IfRange) -> [C32; 3] {
    [0, 1, 2].map(|i| {
        let mut g = c.gain_a_per_m_per_v.get(i).copied().unwrap_or(1.0);
        let mut ph = c.phase_rad.get(i).copied().unwrap_or(0.0);
        if range == IfRange::Low {
            g *= c.low_range_ratio.get(i).copied().unwrap_or(1.0);
            ph += c.low_range_phase_rad.get(i).copied().unwrap_or(0.0);
        }
        // A lag of φ shows as e^{−jφ} on the phasor: undo it.
        C32::cis(ph).scale(g)
    })
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Tracking the floor, waiting for a pulse.
    Idle,
    /// In a pulse first detected at absolute block `detected` — by the energy detector
    /// (`energy`), or only by the coherent one so far, whose best window ended at block
    /// `best` (statistic `z`) and which last fired at block `last_hit`.
    InPulse {
        detected: u64,
        energy: bool,
        best: u64,
        z: f32,
        last_hit: u64,
    },
}

/// The pulse front end: feed it coil samples, get [`Pulse`]s.
#[derive(Debug, Clone)]
pub struct Frontend {
    cfg: FrontendConfig,
    lo: [C32; MAX_BLOCK],
    cal: [C32; 3],
    acc: [C32; 3],
    in_block: usize,
    block_saturated: bool,
    ring: [[C32; 3]; RING_BLOCKS],
    energy: [f32; RING_BLOCKS],
    saturated: [bool; RING_BLOCKS],
    /// Each block's IF amplitude plus offset (largest coil) as a fraction of its
    /// setting's full scale.
    peak: [f32; RING_BLOCKS],
    blocks: u64,
    floor: f32,
    /// Blocks up to this count are a switch transient: ignored.
    settle_until: u64,
    /// Blocks up to this count seed the noise floor (no detection).
    warm_until: u64,
    /// Blocks that have seeded the floor since the last (re)start.
    seeded: u64,
    range: Range,
    ranger: Option<Ranger>,
    change: Option<RangeChange>,
    alpha: f32,
    state: State,
    quiet_from: u64,
    /// Threshold of the coherent detector (χ²₆, from the false-alarm rate).
    eta: f32,
    /// Floor updates since the last (re)seed: the coherent detector waits for the floor
    /// to settle (one time constant) before it trusts its threshold.
    updates: u64,
    fft: [C32; MAX_FFT],
    power: [f32; MAX_FFT],
    tracker: TransmitterTracker,
    stats: FrontendStats,
}

impl Frontend {
    /// A front end with configuration `cfg` (checked with [`FrontendConfig::validate`]).
    pub fn new(cfg: FrontendConfig) -> Result<Self, FrontendError> {
        cfg.validate()?;
        let l = cfg.block_len;
        let mut lo = [C32::ZERO; MAX_BLOCK];
        // Scaled by 2/L so that a block phasor's modulus is the IF amplitude.
        for (n, z) in lo.iter_mut().take(l).enumerate() {
            *z = C32::cis(-2.0 * PI * cfg.if_hz * n as f32 / cfg.sample_rate_hz)
                .scale(2.0 / l as f32);
        }
        let cal = coil_calibration(&cfg.calibration, cfg.range.if_range);
        let alpha = (cfg.block_s() / cfg.floor_time_constant_s).min(1.0);
        let ranger = cfg
            .ranging
            .map(|r| Ranger::new(r, cfg.range.index().unwrap_or(0)));
        Ok(Frontend {
            cfg,
            lo,
            cal,
            acc: [C32::ZERO; 3],
            in_block: 0,
            block_saturated: false,
            ring: [[C32::ZERO; 3]; RING_BLOCKS],
            energy: [0.0; RING_BLOCKS],
            saturated: [false; RING_BLOCKS],
            peak: [0.0; RING_BLOCKS],
            blocks: 0,
            floor: 0.0,
            settle_until: 0,
            warm_until: cfg.warmup_blocks.max(cfg.detect_blocks) as u64,
            seeded: 0,
            range: cfg.range,
            ranger,
            change: None,
            alpha,
            state: State::Idle,
            quiet_from: 0,
            eta: coherent::threshold(&cfg),
            updates: 0,
            fft: [C32::ZERO; MAX_FFT],
            power: [0.0; MAX_FFT],
            tracker: TransmitterTracker::new(),
            stats: FrontendStats::default(),
        })
    }

    /// The configuration in use.
    pub fn config(&self) -> &FrontendConfig {
        &self.cfg
    }

    /// The current noise floor: mean energy of one block over the three coils ((A/m)²).
    pub fn noise_floor(&self) -> f32 {
        self.floor
    }

    /// Per-component standard deviation (A/m) a pulse of `duration_s` would have at the
    /// current noise floor.
    pub fn sigma_for_pulse(&self, duration_s: f32) -> f32 {
        let n = (duration_s / self.cfg.block_s()).max(1.0);
        libm::sqrtf(self.floor / (6.0 * n))
    }

    /// Counters.
    pub fn stats(&self) -> FrontendStats {
        self.stats
    }

    /// The transmitter tracker.
    pub fn tracker(&self) -> &TransmitterTracker {
        &self.tracker
    }

    /// The analog setting the next sample must be taken in.
    pub fn range(&self) -> Range {
        self.range
    }

    /// The last change of the analog setting not yet taken, if any: the caller applies
    /// its `to` to the hardware (PGA gains, IF range switch) before the next sample, and
    /// may log it. Changes happen only between pulses (see [`ranging`](RangingConfig)).
    pub fn take_range_change(&mut self) -> Option<RangeChange> {
        self.change.take()
    }

    /// `samples` samples already taken in the old setting are still to come (a queue
    /// between the ADC's interrupt and the DSP): discard them with the settling, so the
    /// new calibration is never applied to them. Call right after a change.
    pub fn extend_settle(&mut self, samples: usize) {
        let l = self.cfg.block_len.max(1);
        let blocks = samples.div_ceil(l) as u64;
        if self.settle_until >= self.blocks {
            self.settle_until += blocks;
            self.warm_until += blocks;
        }
    }

    /// The hardware is at `range` (e.g. a gain write failed): calibrate from the next
    /// sample for it and re-seed the noise floor. A setting off the ladder while ranging
    /// is [`FrontendError::InvalidConfig`] and changes nothing.
    pub fn set_range(&mut self, range: Range) -> Result<(), FrontendError> {
        if let Some(r) = self.ranger.as_mut() {
            r.force(range.index().ok_or(FrontendError::InvalidConfig)?);
        }
        self.switch_to(range);
        Ok(())
    }

    /// Use `range` from the next sample on: new calibration, settle, re-seed the floor.
    fn switch_to(&mut self, range: Range) {
        self.range = range;
        self.cal = coil_calibration(&self.cfg.calibration, range.if_range);
        self.state = State::Idle;
        self.settle_until = self.blocks + self.cfg.ranging.map_or(0, |r| r.settle_blocks) as u64;
        self.warm_until =
            self.settle_until + self.cfg.warmup_blocks.max(self.cfg.detect_blocks) as u64;
        self.seeded = 0;
        self.updates = 0;
        self.floor = 0.0;
        // The partial block holds samples of the old setting: start the next one afresh.
        self.acc = [C32::ZERO; 3];
        self.in_block = 0;
        self.block_saturated = false;
        let t = self.now();
        if let Some(r) = self.ranger.as_mut() {
            r.reset_quiet(t);
        }
    }

    /// Apply a decision of the ranging rule.
    fn ranged(&mut self, decision: Option<(usize, RangeReason)>) {
        let Some((rung, reason)) = decision else {
            return;
        };
        let Some(to) = Range::rung(rung) else { return };
        let from = self.change.map_or(self.range, |c| c.from);
        let t_s = self.now();
        self.switch_to(to);
        self.stats.range_changes += 1;
        self.change = Some(RangeChange {
            t_s,
            from,
            to,
            reason,
        });
    }

    /// Time of the end of the last whole block, s, in `f32` (≈ 0.25 ms resolution after
    /// an hour, plenty for the ranging's hold time; the `f64` of [`Self::seconds`] costs a
    /// software division per block on the M4F).
    fn now(&self) -> f32 {
        self.blocks as f32 * self.cfg.block_s()
    }

    fn peak_at(&self, b: u64) -> f32 {
        self.peak.get(Self::ring_index(b)).copied().unwrap_or(0.0)
    }

    /// Samples consumed so far.
    pub fn samples(&self) -> u64 {
        self.blocks * self.cfg.block_len as u64 + self.in_block as u64
    }

    /// Feed one simultaneous sample of the three coils (V at the ADC) and whether any of
    /// them clipped. Returns a pulse when one has just ended. A non-finite sample is
    /// refused with [`FrontendError::NonFiniteSample`] and not consumed.
    pub fn push(&mut self, volts: [f32; 3], clipped: bool) -> Result<Option<Pulse>, FrontendError> {
        if !volts.iter().all(|v| v.is_finite()) {
            return Err(FrontendError::NonFiniteSample);
        }
        let lo = self.lo.get(self.in_block).copied().unwrap_or(C32::ZERO);
        for ((a, v), off) in self
            .acc
            .iter_mut()
            .zip(volts)
            .zip(self.cfg.calibration.offset_v)
        {
            *a += lo.scale(v - off);
        }
        self.block_saturated |= clipped;
        self.in_block += 1;
        if self.in_block < self.cfg.block_len {
            return Ok(None);
        }
        let mut p = [C32::ZERO; 3];
        for ((out, a), k) in p.iter_mut().zip(self.acc).zip(self.cal) {
            *out = a * k;
        }
        let sat = self.block_saturated;
        // The block's peak for the gain ranging: the IF amplitude the block phasor
        // measures (its modulus, V) plus the channel's DC offset, per coil — a per-sample
        // |v| maximum would cost ≈ 40 instructions per sample on the M4F for the same
        // answer on a pulse (clipping itself is flagged by the ADC).
        let mut amp = 0.0f32;
        for (a, off) in self.acc.iter().zip(self.cfg.calibration.offset_v) {
            amp = amp.max(libm::sqrtf(a.norm_sqr()) + libm::fabsf(off));
        }
        let peak = amp / self.range.full_scale_v();
        self.acc = [C32::ZERO; 3];
        self.in_block = 0;
        self.block_saturated = false;
        Ok(self.on_block(p, sat, peak))
    }

    fn ring_index(b: u64) -> usize {
        (b % RING_BLOCKS as u64) as usize
    }

    fn on_block(&mut self, p: [C32; 3], sat: bool, peak: f32) -> Option<Pulse> {
        let e: f32 = p.iter().map(|z| z.norm_sqr()).sum();
        // Guard the floor and statistics against an absurd (overflowing) block: no real
        // signal comes near the ceiling, so such a block is clipped garbage. Its energy is
        // capped so that sums over the whole ring (the detection window, the pulse
        // analysis) stay finite — an infinite window would become the noise floor and
        // deafen the receiver — its phasors are zeroed so no ∞/NaN reaches the analysis,
        // and it is flagged saturated so a pulse containing it is withheld.
        let (p, e, sat) = if e.is_finite() && e <= ENERGY_CEILING {
            (p, e, sat)
        } else {
            ([C32::ZERO; 3], ENERGY_CEILING, true)
        };
        let b = self.blocks;
        let i = Self::ring_index(b);
        if let (Some(r), Some(en), Some(s), Some(pk)) = (
            self.ring.get_mut(i),
            self.energy.get_mut(i),
            self.saturated.get_mut(i),
            self.peak.get_mut(i),
        ) {
            *r = p;
            *en = e;
            *s = sat;
            *pk = peak;
        }
        self.blocks += 1;
        if self.blocks <= self.settle_until {
            // The switch transient after a change of setting: not noise, not signal.
            self.quiet_from = self.blocks;
            return None;
        }
        if self.blocks <= self.warm_until {
            // Seed the floor with the plain mean of the first blocks (after start-up or
            // a change of setting, whose noise may differ by orders of magnitude).
            self.seeded += 1;
            self.floor += (e - self.floor) / self.seeded as f32;
            self.quiet_from = self.blocks;
            return None;
        }
        let w = self.cfg.detect_blocks as u64;
        let window: f32 = (0..w).map(|k| self.energy_at(b - k)).sum::<f32>() / w as f32;
        let energy_hit = window > self.cfg.k_on * self.floor;
        match self.state {
            State::Idle => {
                let coherent = if energy_hit {
                    None
                } else {
                    self.coherent_hit(b)
                };
                if energy_hit {
                    self.state = State::InPulse {
                        detected: b,
                        energy: true,
                        best: b,
                        z: 0.0,
                        last_hit: b,
                    };
                } else if let Some(z) = coherent {
                    self.state = State::InPulse {
                        detected: b,
                        energy: false,
                        best: b,
                        z,
                        last_hit: b,
                    };
                } else if b >= self.quiet_from + w {
                    // Update from the block one window back: a pulse now being detected
                    // cannot have leaked into it. Clamp single outliers (EMI clicks).
                    let old = self
                        .energy_at(b - w)
                        .min(3.0 * self.floor.max(f32::MIN_POSITIVE));
                    self.floor += self.alpha * (old - self.floor);
                    self.updates += 1;
                    // The same block's peak is the noise the setting must hold.
                    if self.ranger.is_some() {
                        let t = self.now();
                        let peak = self.peak_at(b - w);
                        let d = self.ranger.as_mut().and_then(|r| r.on_quiet(t, peak));
                        self.ranged(d);
                    }
                }
                None
            }
            State::InPulse {
                mut detected,
                mut energy,
                mut best,
                mut z,
                mut last_hit,
            } => {
                if !energy && energy_hit {
                    // Stronger after all: from here the energy detector's pulse, exactly
                    // as if it had found it first.
                    energy = true;
                    detected = b;
                }
                // The best coherent window is kept either way: a pulse too weak for the
                // energy edges takes its edges from it (`analysis::analyse`).
                if let Some(zb) = self.coherent_hit(b) {
                    last_hit = b;
                    if zb > z {
                        z = zb;
                        best = b;
                    }
                }
                self.state = State::InPulse {
                    detected,
                    energy,
                    best,
                    z,
                    last_hit,
                };
                // The pulse began at most one window before its detection (the energy
                // window, or the coherent one, which may have fired near its end); keep
                // a margin.
                let back = if energy {
                    w + 4
                } else {
                    2 * self.cfg.coherent_blocks as u64 + 4
                };
                let first = detected
                    .saturating_sub(back)
                    .max(self.blocks.saturating_sub(RING_BLOCKS as u64));
                let len = (b + 1 - first) as usize;
                if len >= RING_BLOCKS - 1 {
                    // A pulse this long is a continuous interferer: report it and take
                    // its level as the new floor so detection recovers.
                    self.state = State::Idle;
                    self.quiet_from = b + 1;
                    self.floor = self.floor.max(window);
                    self.stats.truncated += 1;
                    self.stats.pulses += 1;
                    let t0 = first * self.cfg.block_len as u64;
                    let sat = (first..=b).any(|k| self.saturated_at(k));
                    let peak = self.peak_over(first, len);
                    let t = self.now();
                    let d = self.ranger.as_mut().and_then(|r| r.on_pulse(t, peak, sat));
                    self.ranged(d);
                    return Some(Pulse {
                        t_s: self.seconds(t0) + 0.5 * len as f32 * self.cfg.block_s(),
                        start_sample: t0,
                        duration_s: len as f32 * self.cfg.block_s(),
                        carrier_offset_hz: 0.0,
                        sigma_a_per_m: 0.0,
                        residual_fraction: 0.0,
                        quadrature_fraction: 0.0,
                        amplitude: [C32::ZERO; 3],
                        src: None,
                        measurement: PulseMeasurement::Truncated,
                    });
                }
                if energy && window < self.cfg.k_off * self.floor {
                    self.state = State::Idle;
                    self.quiet_from = b + 1;
                    let anchor = (z > 0.0 && best >= first).then(|| (best - first) as usize);
                    return self.finish(first, len, Pulse0 { energy, anchor });
                }
                // A coherent pulse is over once the window has moved a whole length past
                // the last position that fired: nothing of it can still be coming.
                if !energy && b >= last_hit + self.cfg.coherent_blocks as u64 {
                    self.state = State::Idle;
                    self.quiet_from = b + 1;
                    let anchor = Some(best.saturating_sub(first) as usize);
                    return self.finish(first, len, Pulse0 { energy, anchor });
                }
                None
            }
        }
    }

    fn energy_at(&self, b: u64) -> f32 {
        self.energy.get(Self::ring_index(b)).copied().unwrap_or(0.0)
    }

    fn saturated_at(&self, b: u64) -> bool {
        self.saturated
            .get(Self::ring_index(b))
            .copied()
            .unwrap_or(false)
    }

    /// Largest block peak of blocks `first .. first + len`.
    fn peak_over(&self, first: u64, len: usize) -> f32 {
        (first..first + len as u64).fold(0.0f32, |m, k| m.max(self.peak_at(k)))
    }

    fn seconds(&self, sample: u64) -> f32 {
        // f64 keeps the division exact over long sessions; it runs once per pulse.
        let fs = self.cfg.sample_rate_hz as f64;
        (sample as f64 / fs) as f32
    }

    /// The coherent detector at block `b` (an evaluation block, the floor settled, the
    /// window clear of the last pulse): its statistic when it exceeds the threshold.
    fn coherent_hit(&mut self, b: u64) -> Option<f32> {
        let w = self.cfg.coherent_blocks as u64;
        let settled = self.seeded + self.updates >= libm::ceilf(1.0 / self.alpha) as u64;
        // The window must hold no block of the last pulse (nor of a switch transient):
        // its tail would fire again.
        let clear = b + 1 >= self.quiet_from + w;
        if w == 0 || !settled || !clear || !(b + 1).is_multiple_of(self.cfg.coherent_hop as u64) {
            return None;
        }
        let (z, _) = coherent::statistic(
            &self.ring,
            Self::ring_index(b),
            &self.cfg,
            self.floor,
            &mut self.fft,
            &mut self.power,
        );
        (z > self.eta).then_some(z)
    }

    /// Analyse blocks `first .. first + len` after a pulse ended (`how`: see
    /// [`analyse`]).
    fn finish(&mut self, first: u64, len: usize, how: Pulse0) -> Option<Pulse> {
        let view = BlockView {
            blocks: &self.ring,
            energy: &self.energy,
            saturated: &self.saturated,
            first: Self::ring_index(first),
            len,
        };
        let a = analyse(
            &view,
            self.floor,
            &self.cfg,
            how,
            &mut self.fft,
            &mut self.power,
        )?;
        let duration_s = a.len as f32 * self.cfg.block_s();
        if duration_s < self.cfg.min_pulse_s {
            self.stats.rejected_short += 1;
            return None;
        }
        // The pulse is over and nothing of it is left to measure: the moment to change
        // the setting for the next one.
        let peak = self.peak_over(first, len);
        let t = self.now();
        let d = self
            .ranger
            .as_mut()
            .and_then(|r| r.on_pulse(t, peak, a.saturated));
        self.ranged(d);
        let l = self.cfg.block_len as u64;
        let start_sample = (first + a.start as u64) * l;
        let t_s = self.seconds(start_sample) + 0.5 * duration_s;
        let measurement = if a.saturated {
            self.stats.saturated += 1;
            PulseMeasurement::Saturated
        } else if a.overlap {
            self.stats.overlaps += 1;
            PulseMeasurement::Overlap
        } else {
            PulseMeasurement::Field(a.h)
        };
        // Overlapped pulses have no trustworthy timing or carrier for the tracker.
        let src = if a.overlap {
            // ...but the transmitters expected there are kept alive across it.
            self.tracker.occluded(t_s);
            None
        } else {
            self.tracker.assign(t_s, a.offset_hz)
        };
        self.stats.pulses += 1;
        Some(Pulse {
            t_s,
            start_sample,
            duration_s,
            carrier_offset_hz: a.offset_hz,
            sigma_a_per_m: a.sigma,
            residual_fraction: a.residual_fraction,
            quadrature_fraction: a.quadrature_fraction,
            amplitude: a.amplitude,
            src,
            measurement,
        })
    }
}
