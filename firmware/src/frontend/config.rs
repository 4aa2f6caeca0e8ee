//! Front-end configuration.

use super::calibration::Calibration;
use super::ranging::{Range, RangingConfig};
use super::{MAX_BLOCK, RING_BLOCKS};

/// Why a configuration or an input was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrontendError {
    /// A sample was NaN or infinite; it was not consumed.
    #[error("ADC sample NaN or infinite")]
    NonFiniteSample,
    /// The configuration is inconsistent (see [`FrontendConfig::validate`]).
    #[error("inconsistent front-end configuration")]
    InvalidConfig,
}

/// Sampling, demodulation, detection and calibration parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontendConfig {
    /// ADC output data rate (Hz). Default 8000 (ADS131M04, OSR 512, 8.192 MHz clock).
    pub sample_rate_hz: f32,
    /// Nominal intermediate frequency (Hz). Default 2000 = 457 kHz − 455 kHz LO, a
    /// quarter of the sample rate so that the mixer's local oscillator is 1, −j, −1, j.
    pub if_hz: f32,
    /// Samples per demodulated block; must hold a whole number of IF cycles. Default 16
    /// (2 ms): short enough that an 80 Hz offset turns the phase by only 58° per block
    /// (4 % amplitude loss, corrected), long enough to keep the per-block work small.
    pub block_len: usize,
    /// Largest carrier offset searched (Hz). The standard allows ±80 Hz; the margin
    /// covers the local oscillator's own tolerance.
    pub max_offset_hz: f32,
    /// Blocks in the sliding detection window. Default 16 (32 ms): half the shortest
    /// pulse, so the window fills inside every legal pulse.
    pub detect_blocks: usize,
    /// A pulse starts when the window's mean energy exceeds this multiple of the noise
    /// floor. Default 1.8 (≈5.5 standard deviations of the noise-only window mean;
    /// with `k_off`: `docs/decisions/energy-detector-thresholds.md`).
    pub k_on: f32,
    /// Blocks of the coherent detector's window ([`coherent`](super::coherent)); 0 turns it
    /// off. Default 32 (64 ms): as long as a power of two can be inside the standard's
    /// shortest pulse (70 ms = 35 blocks), so one window position holds only pulse.
    pub coherent_blocks: usize,
    /// Blocks between evaluations of the coherent detector. Default 2 (4 ms): a 70 ms
    /// pulse spans 34 whole blocks, so a 32-block window lies inside it at ≥ 2 positions
    /// and one of them is evaluated.
    pub coherent_hop: usize,
    /// Required false-alarm rate of the coherent detector (Hz): its threshold is set from
    /// it (`coherent::threshold`). Default one per 10 minutes.
    pub false_alarm_rate_hz: f32,
    /// A pulse ends when the window's mean energy falls below this multiple of the floor
    /// (default 1.3; `docs/decisions/energy-detector-thresholds.md`).
    pub k_off: f32,
    /// Pulses shorter than this (s) are discarded as interference; the standard's
    /// on-time is at least 70 ms.
    pub min_pulse_s: f32,
    /// Time constant of the noise-floor tracker (s).
    pub floor_time_constant_s: f32,
    /// Blocks averaged to seed the noise floor before detection starts.
    pub warmup_blocks: usize,
    /// A pulse is flagged [`Overlap`](super::PulseMeasurement::Overlap) when the energy a
    /// single carrier with a linearly drifting envelope leaves unexplained exceeds this
    /// fraction of the signal energy (beyond the noise allowance).
    pub max_residual_fraction: f32,
    /// …or when the energy in quadrature to the coils' common phase exceeds this
    /// fraction of the in-phase energy (beyond the noise allowance).
    pub max_quadrature_fraction: f32,
    /// Volts → A/m per coil.
    pub calibration: Calibration,
    /// The analog setting (IF range, PGA gain of the coil channels) at start-up; the
    /// ADC must be configured to it.
    pub range: Range,
    /// Automatic gain ranging (`None`: the setting stays at `range`).
    pub ranging: Option<RangingConfig>,
}

impl Default for FrontendConfig {
    fn default() -> Self {
        FrontendConfig {
            sample_rate_hz: 8000.0,
            if_hz: 2000.0,
            block_len: 16,
            max_offset_hz: 100.0,
            detect_blocks: 16,
            k_on: 1.8,
            k_off: 1.3,
            coherent_blocks: 32,
            coherent_hop: 2,
            false_alarm_rate_hz: 1.0 / 600.0,
            min_pulse_s: 0.05,
            floor_time_constant_s: 0.5,
            warmup_blocks: 32,
            // An interferer leaves at least the square of its share of the vector error
            // as residual energy (a partial overlap at a nearby carrier: error ρ·f,
            // residual ≈ ρ²·f), so this keeps a pulse only where the interferer's error
            // is ≤ the dominance ratio of the multi-victim rule (1 %, ICRA eq. 10).
            max_residual_fraction: super::DOMINANCE_RATIO * super::DOMINANCE_RATIO,
            // Same-carrier overlaps show only in quadrature; 1e-3 ≈ sin²(1.8°) leaves room
            // for the channels' phase-calibration error on a real board. Both thresholds:
            // docs/decisions/overlap-thresholds.md.
            max_quadrature_fraction: 1e-3,
            calibration: Calibration::default(),
            range: Range::HIGH_G1,
            ranging: None,
        }
    }
}

impl FrontendConfig {
    /// Block duration (s).
    pub fn block_s(&self) -> f32 {
        self.block_len as f32 / self.sample_rate_hz
    }

    /// Check the configuration: positive finite rates, IF below Nyquist with a whole
    /// number of cycles per block, block length in 4..=[`MAX_BLOCK`], offset search below
    /// half the block rate, detection windows well inside the buffer (the coherent one a
    /// power of two, 8 blocks or more, hop at most its length, a positive false-alarm
    /// rate), thresholds ordered
    /// `1 < k_off < k_on`, valid calibration, valid ranging starting on its ladder.
    pub fn validate(&self) -> Result<(), FrontendError> {
        let fs = self.sample_rate_hz;
        let cycles = self.if_hz * self.block_len as f32 / fs;
        let ok = fs.is_finite()
            && fs > 0.0
            && self.if_hz.is_finite()
            && self.if_hz > 0.0
            && self.if_hz < fs / 2.0
            && (4..=MAX_BLOCK).contains(&self.block_len)
            && libm::fabsf(cycles - libm::roundf(cycles)) < 1e-3
            && self.max_offset_hz.is_finite()
            && self.max_offset_hz > 0.0
            && self.max_offset_hz < 0.45 / self.block_s()
            && (2..=RING_BLOCKS / 4).contains(&self.detect_blocks)
            && (self.coherent_blocks == 0
                || (self.coherent_blocks.is_power_of_two()
                    && (8..=RING_BLOCKS / 4).contains(&self.coherent_blocks)
                    && (1..=self.coherent_blocks).contains(&self.coherent_hop)
                    && self.false_alarm_rate_hz.is_finite()
                    && self.false_alarm_rate_hz > 0.0))
            && self.k_off > 1.0
            && self.k_on > self.k_off
            && self.k_on.is_finite()
            && self.min_pulse_s.is_finite()
            && self.min_pulse_s >= 0.0
            && self.floor_time_constant_s.is_finite()
            && self.floor_time_constant_s > 0.0
            && self.warmup_blocks >= 1
            && self.max_residual_fraction.is_finite()
            && self.max_quadrature_fraction.is_finite()
            && self.calibration.is_valid()
            && self
                .ranging
                .is_none_or(|r| r.is_valid() && self.range.index().is_some());
        if ok {
            Ok(())
        } else {
            Err(FrontendError::InvalidConfig)
        }
    }
}
