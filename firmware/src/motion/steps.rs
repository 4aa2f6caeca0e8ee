//! Step detection from peaks of the vertical acceleration, the step-length model and the
//! step-length calibration walk.
//!
//! Walking makes the device bob once per step; the vertical acceleration peaks when the
//! foot is placed on the ground (Ladetto; Kleiner et al. section II). The accelerometer
//! reading is projected onto world z with the attitude, low-pass filtered (2nd-order
//! Butterworth), and a step is a peak above `threshold_high` that is followed by a fall
//! below `threshold_low` (hysteresis) and is at least `min_interval_s` after the previous.

use super::MotionError;

/// Tuning of the step detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepDetectorConfig {
    /// A peak must exceed this vertical acceleration (m/s², gravity removed).
    pub threshold_high: f32,
    /// After a peak the signal must fall below this before the step counts (hysteresis).
    pub threshold_low: f32,
    /// Shortest time between two steps, s (≈ 3.3 steps/s).
    pub min_interval_s: f32,
    /// Longer than this without a step means the person stopped, s.
    pub max_interval_s: f32,
    /// Cut-off of the low-pass filter on the vertical acceleration, Hz.
    pub lowpass_hz: f32,
    /// |vertical acceleration| (m/s², gravity removed) below which the device counts as
    /// quiet: a walking gait swings through several m/s² every step.
    pub quiet_m_s2: f32,
    /// Time quiet (s) after which the walk has ended and the step under way when the
    /// walker stopped has been completed.
    pub stop_quiet_s: f32,
}

impl Default for StepDetectorConfig {
    fn default() -> Self {
        Self {
            threshold_high: 0.6,
            threshold_low: -0.2,
            min_interval_s: 0.3,
            max_interval_s: 1.2,
            lowpass_hz: 3.0,
            quiet_m_s2: 0.25,
            stop_quiet_s: 0.25,
        }
    }
}

/// One detected step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepEvent {
    /// Time of the acceleration peak, s.
    pub t_peak: f32,
    /// Peak-to-trough vertical acceleration of this step, m/s² (Weinberg's `a_max − a_min`).
    pub amplitude: f32,
    /// Time since the previous step, s (0 when this is the first step of a walk).
    pub period: f32,
}

/// Second-order Butterworth low-pass (bilinear transform), direct form II transposed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Biquad {
    b: [f32; 3],
    a: [f32; 2],
    z: [f32; 2],
}

impl Biquad {
    fn lowpass(fc: f32, fs: f32) -> Self {
        let k = libm::tanf(core::f32::consts::PI * (fc / fs).clamp(1e-4, 0.45));
        let q = core::f32::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Self {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
            z: [0.0; 2],
        }
    }

    fn step(&mut self, x: f32) -> f32 {
        let y = self.b[0] * x + self.z[0];
        self.z[0] = self.b[1] * x - self.a[0] * y + self.z[1];
        self.z[1] = self.b[2] * x - self.a[1] * y;
        y
    }
}

/// Peak detector on the vertical acceleration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepDetector {
    cfg: StepDetectorConfig,
    filter: Biquad,
    rate_hz: f32,
    in_peak: bool,
    peak: f32,
    t_peak: f32,
    trough: f32,
    last_step: Option<f32>,
}

impl StepDetector {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        self.t_peak -= shift_s;
        if let Some(t) = self.last_step.as_mut() {
            *t -= shift_s;
        }
    }

    /// A detector for samples arriving at about `rate_hz`.
    pub fn new(cfg: StepDetectorConfig, rate_hz: f32) -> Self {
        Self {
            cfg,
            filter: Biquad::lowpass(cfg.lowpass_hz, rate_hz),
            rate_hz,
            in_peak: false,
            peak: 0.0,
            t_peak: 0.0,
            trough: 0.0,
            last_step: None,
        }
    }

    /// Forgets the signal history (after a data gap).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg, self.rate_hz);
    }

    /// Time of the last detected step's peak, if any.
    pub fn last_step(&self) -> Option<f32> {
        self.last_step
    }

    /// Time of the highest sample of a peak that is above the high threshold but not yet
    /// confirmed (a step in progress), if any.
    pub fn pending_peak(&self) -> Option<f32> {
        self.in_peak.then_some(self.t_peak)
    }

    /// Feeds one sample of vertical acceleration (world z, gravity removed, m/s²) at `t`;
    /// returns the step whose peak has just been confirmed.
    pub fn update(&mut self, t: f32, a_vertical: f32) -> Option<StepEvent> {
        let a = self.filter.step(a_vertical);
        if let Some(last) = self.last_step
            && t - last > self.cfg.max_interval_s
            && !self.in_peak
        {
            // The walk stopped: the next step starts a new walk.
            self.last_step = None;
        }
        if self.in_peak {
            if a > self.peak {
                self.peak = a;
                self.t_peak = t;
            }
            if a < self.cfg.threshold_low {
                self.in_peak = false;
                let period = self.last_step.map_or(0.0, |l| self.t_peak - l);
                let ev = StepEvent {
                    t_peak: self.t_peak,
                    amplitude: self.peak - self.trough,
                    period,
                };
                self.last_step = Some(self.t_peak);
                self.trough = a;
                return Some(ev);
            }
        } else {
            self.trough = self.trough.min(a);
            let spaced = self
                .last_step
                .is_none_or(|l| t - l >= self.cfg.min_interval_s);
            if a > self.cfg.threshold_high && spaced {
                self.in_peak = true;
                self.peak = a;
                self.t_peak = t;
            }
        }
        None
    }
}

/// How long a step is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepLengthModel {
    /// A calibrated constant step length, m.
    Fixed {
        /// Step length, m.
        length_m: f32,
        /// Relative σ of the calibration (a walk-long scale error, e.g. 0.02).
        scale_sigma: f32,
    },
    /// Weinberg's model `L = k · (a_max − a_min)^¼` from the vertical acceleration swing.
    Weinberg {
        /// The person's constant k, m/(m/s²)^¼.
        k: f32,
        /// Relative σ of k (walk-long scale error).
        scale_sigma: f32,
    },
}

impl StepLengthModel {
    /// Shortest and longest step length the models return, m.
    pub const RANGE_M: (f32, f32) = (0.25, 1.2);

    /// Uncalibrated default: 0.7 m with a 20 % scale uncertainty.
    pub fn uncalibrated() -> Self {
        Self::Fixed {
            length_m: 0.7,
            scale_sigma: 0.2,
        }
    }

    /// A calibrated step length (`receiver.json` `pdr.step_length_m`, ≈ 2 % uncertain).
    pub fn calibrated(length_m: f32) -> Self {
        Self::Fixed {
            length_m,
            scale_sigma: 0.02,
        }
    }

    /// Length of a step with the given peak-to-trough vertical acceleration, m.
    pub fn length(&self, amplitude: f32) -> f32 {
        let (lo, hi) = Self::RANGE_M;
        match *self {
            Self::Fixed { length_m, .. } => length_m,
            Self::Weinberg { k, .. } => k * weinberg_factor(amplitude),
        }
        .clamp(lo, hi)
    }

    /// Relative σ of the walk-long scale (the calibration error, correlated over the walk).
    pub fn scale_sigma(&self) -> f32 {
        match *self {
            Self::Fixed { scale_sigma, .. } | Self::Weinberg { scale_sigma, .. } => scale_sigma,
        }
    }
}

/// Weinberg's `(a_max − a_min)^¼` (0 for a non-positive swing).
pub fn weinberg_factor(amplitude: f32) -> f32 {
    if amplitude > 0.0 {
        libm::sqrtf(libm::sqrtf(amplitude))
    } else {
        0.0
    }
}

/// Result of a calibration walk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationResult {
    /// Steps counted over the walk.
    pub steps: u32,
    /// Mean step length = distance / steps, m.
    pub step_length_m: f32,
    /// Weinberg k fitted to the same walk.
    pub weinberg_k: f32,
}

/// Step-length calibration: press a button at the start of a walk of known length, press
/// again at its end and enter the distance: step length = distance / steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepCalibration {
    start_steps: u32,
    start_weinberg: f32,
}

impl StepCalibration {
    /// Fewest steps a calibration walk must have.
    pub const MIN_STEPS: u32 = 10;

    /// Starts at the current totals (steps counted and Σ Weinberg factors so far).
    pub fn start(total_steps: u32, weinberg_sum: f32) -> Self {
        Self {
            start_steps: total_steps,
            start_weinberg: weinberg_sum,
        }
    }

    /// Ends with the current totals and the walked distance (m).
    pub fn finish(
        &self,
        total_steps: u32,
        weinberg_sum: f32,
        distance_m: f32,
    ) -> Result<CalibrationResult, MotionError> {
        if !distance_m.is_finite() || !(1.0..=1000.0).contains(&distance_m) {
            return Err(MotionError::InvalidArgument);
        }
        let steps = total_steps.saturating_sub(self.start_steps);
        if steps < Self::MIN_STEPS {
            return Err(MotionError::TooFewSteps { steps });
        }
        let step_length_m = distance_m / steps as f32;
        let (lo, hi) = StepLengthModel::RANGE_M;
        if !(lo..=hi).contains(&step_length_m) {
            return Err(MotionError::InvalidArgument);
        }
        let w = weinberg_sum - self.start_weinberg;
        let weinberg_k = if w > 0.0 { distance_m / w } else { 0.0 };
        Ok(CalibrationResult {
            steps,
            step_length_m,
            weinberg_k,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_a_synthetic_sinusoid() {
        // 1.8 steps/s, 2.5 m/s² amplitude, small noise-like ripple at 11 Hz.
        let mut d = StepDetector::new(StepDetectorConfig::default(), 100.0);
        let f = 1.8f32;
        let mut steps = heapless::Vec::<StepEvent, 64>::new();
        for k in 0..2000 {
            let t = k as f32 * 0.01;
            let a = 2.5 * (2.0 * core::f32::consts::PI * f * t).sin()
                + 0.3 * (2.0 * core::f32::consts::PI * 11.0 * t).sin();
            if let Some(s) = d.update(t, a) {
                steps.push(s).unwrap();
            }
        }
        // 20 s × 1.8 = 36 peaks.
        assert!((35..=36).contains(&steps.len()), "{}", steps.len());
        for s in steps.iter().skip(1) {
            assert!((s.period - 1.0 / f).abs() < 0.03, "{s:?}");
            assert!((s.amplitude - 5.0).abs() < 0.6, "{s:?}");
        }
    }

    #[test]
    fn ignores_small_motion_and_respects_min_interval() {
        let mut d = StepDetector::new(StepDetectorConfig::default(), 100.0);
        let mut n = 0;
        for k in 0..1000 {
            let t = k as f32 * 0.01;
            // Hand wobble: 0.4 m/s² at 1 Hz never crosses the threshold.
            if d.update(t, 0.4 * (core::f32::consts::TAU * t).sin())
                .is_some()
            {
                n += 1;
            }
        }
        assert_eq!(n, 0);
        // A 6 Hz vibration: at most one step per min_interval.
        let mut d = StepDetector::new(
            StepDetectorConfig {
                lowpass_hz: 20.0,
                ..StepDetectorConfig::default()
            },
            100.0,
        );
        for k in 0..1000 {
            let t = k as f32 * 0.01;
            if d.update(t, 3.0 * (core::f32::consts::TAU * 6.0 * t).sin())
                .is_some()
            {
                n += 1;
            }
        }
        assert!(n <= 34, "{n}");
    }

    #[test]
    fn calibration_walk() {
        let c = StepCalibration::start(100, 50.0);
        let r = c.finish(136, 50.0 + 36.0 * 1.5, 20.0).unwrap();
        assert_eq!(r.steps, 36);
        assert!((r.step_length_m - 20.0 / 36.0).abs() < 1e-6);
        assert!((r.weinberg_k - 20.0 / 54.0).abs() < 1e-6);
        assert_eq!(
            c.finish(105, 60.0, 20.0),
            Err(MotionError::TooFewSteps { steps: 5 })
        );
        assert_eq!(
            c.finish(136, 60.0, f32::NAN),
            Err(MotionError::InvalidArgument)
        );
        assert_eq!(
            c.finish(136, 60.0, 200.0),
            Err(MotionError::InvalidArgument)
        );
    }

    #[test]
    fn step_length_models() {
        assert_eq!(StepLengthModel::calibrated(0.56).length(3.0), 0.56);
        let w = StepLengthModel::Weinberg {
            k: 0.4,
            scale_sigma: 0.1,
        };
        assert!((w.length(16.0) - 0.8).abs() < 1e-6);
        assert_eq!(w.length(0.0), StepLengthModel::RANGE_M.0);
        assert_eq!(StepLengthModel::uncalibrated().scale_sigma(), 0.2);
    }
}
