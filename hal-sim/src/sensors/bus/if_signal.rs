//! The antenna's analog chain: the three coils' intermediate-frequency (IF) voltages at the
//! ADC inputs, sampled from the world.
//!
//! Per sample time `t` and coil `i` (body axis x, y, z):
//!
//! `v_i(t) = Σ_tx on_tx(t) · (h_i(t) + e_i) · cos(2π f_tx t + φ_tx − lag_i) / g_i + n_i(t) / g_i + off_i`
//!
//! - `h(t)`: the transmitter's field in the body frame (`World`'s truth, A/m), `e`: a
//!   per-pulse sensor error of σ `k_sen·|H|` per component (the proportional term of the
//!   ICRA 2006 eq. 10 noise model), constant over the pulse;
//! - `f_tx = IF + (carrier − 457 kHz)`: the LO sits at 455 kHz so the 2 kHz IF carries the
//!   carrier offset with its sign; `φ_tx`: the transmitter's free-running carrier phase
//!   (drawn once per transmitter);
//! - `g_i`, `lag_i`, `off_i`: each channel's gain (A/m per V), phase lag at the IF and DC
//!   offset — the unit's actual [`AnalogChain`], drawn about the board profile's nominal
//!   values ([`super::unit`]); the DSP holds the nominal or a bench calibration, never
//!   these exact values. In the low position of the IF range switch ([`RangeSwitch`], a
//!   GPIO the firmware drives) the gain is `g_i · ratio_i` and the lag `lag_i + lag_low_i`;
//! - `n(t)`: white EMI background per coil, σ per sample `σ_bkg / √(2/N₇₀)` with
//!   `N₇₀ = 0.070 s · f_s`: the per-component σ of a 70 ms pulse's demodulated amplitude is
//!   then `σ_bkg` (the session-log's `pulse_noise.sigma_bkg_A_per_m`), as in the DSP's tests.
use crate::world::World;
use crate::world::physics::V3;
use crate::world::transmitter::CARRIER_HZ;
use firmware::frontend::{Calibration, IfRange};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::cell::Cell;
use std::convert::Infallible;
use std::f64::consts::TAU;
use std::rc::Rc;

/// Frequency of the receiver's local oscillator, Hz (457 kHz − 2 kHz).
pub const LO_HZ: f64 = 455_000.0;
/// Nominal intermediate frequency, Hz.
pub const IF_HZ: f64 = CARRIER_HZ - LO_HZ;
/// Shortest pulse of the standard, s: `σ_bkg` is the per-component σ of a pulse this long.
pub const REFERENCE_PULSE_S: f64 = 0.070;

/// Gain, phase lag and offset of the three coil channels: one unit's actual analog chain
/// (see [`super::unit::Unit`], which draws it about the board profile's nominal values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnalogChain {
    /// Field per IF amplitude in the high range, A/m per V (negative: coil wired reversed).
    pub gain_a_per_m_per_v: [f64; 3],
    /// Phase lag of each channel at the IF in the high range, rad.
    pub phase_rad: [f64; 3],
    /// DC offset at each ADC input, V.
    pub offset_v: [f64; 3],
    /// How many times more field per volt the low range of the IF range switch gives.
    pub low_range_ratio: [f64; 3],
    /// Extra phase lag of each channel in the low range, rad.
    pub low_range_phase_rad: [f64; 3],
}

impl AnalogChain {
    /// A chain whose parameters are exactly `cal`'s (the design values when `cal` is the
    /// profile's nominal calibration).
    pub fn from_calibration(cal: &Calibration) -> Self {
        Self {
            gain_a_per_m_per_v: cal.gain_a_per_m_per_v.map(f64::from),
            phase_rad: cal.phase_rad.map(f64::from),
            offset_v: cal.offset_v.map(f64::from),
            low_range_ratio: cal.low_range_ratio.map(f64::from),
            low_range_phase_rad: cal.low_range_phase_rad.map(f64::from),
        }
    }

    /// This chain's exact parameters as a [`Calibration`]: the truth a calibration is
    /// scored against. The DSP is never given it; it holds the profile's nominal
    /// calibration or the unit's bench calibration.
    pub fn true_calibration(&self) -> Calibration {
        Calibration {
            gain_a_per_m_per_v: self.gain_a_per_m_per_v.map(|g| g as f32),
            offset_v: self.offset_v.map(|x| x as f32),
            phase_rad: self.phase_rad.map(|x| x as f32),
            low_range_ratio: self.low_range_ratio.map(|x| x as f32),
            low_range_phase_rad: self.low_range_phase_rad.map(|x| x as f32),
        }
    }
}

impl AnalogChain {
    /// Field per volt at ADC channel `i` (A/m per V) in IF range `range`.
    pub fn gain(&self, i: usize, range: IfRange) -> f64 {
        let g = self.gain_a_per_m_per_v[i];
        match range {
            IfRange::High => g,
            IfRange::Low => g * self.low_range_ratio[i],
        }
    }

    /// Phase lag of channel `i` at the IF in range `range`, rad.
    pub fn lag(&self, i: usize, range: IfRange) -> f64 {
        let l = self.phase_rad[i];
        match range {
            IfRange::High => l,
            IfRange::Low => l + self.low_range_phase_rad[i],
        }
    }
}

/// The IF amplifier's range switch: a GPIO output of the MCU (high = low range: the
/// analog switch across the IF amplifier's feedback closes), shared with the signal
/// source that reads its position. Starts in the high range.
#[derive(Debug, Clone, Default)]
pub struct RangeSwitch(Rc<Cell<IfRange>>);

impl RangeSwitch {
    /// A switch in the high range.
    pub fn new() -> Self {
        Self::default()
    }

    /// The switch's position.
    pub fn get(&self) -> IfRange {
        self.0.get()
    }

    /// Moves the switch (what the firmware does through the pin).
    pub fn set(&self, range: IfRange) {
        self.0.set(range);
    }
}

impl embedded_hal::digital::ErrorType for RangeSwitch {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for RangeSwitch {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.set(IfRange::High);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.set(IfRange::Low);
        Ok(())
    }
}

/// Per-sample EMI σ (A/m per coil) that gives `sigma_bkg` per component on a 70 ms pulse
/// sampled at `sample_rate_hz`.
pub fn sample_sigma(sigma_bkg: f64, sample_rate_hz: f64) -> f64 {
    sigma_bkg * (REFERENCE_PULSE_S * sample_rate_hz / 2.0).sqrt()
}

/// Something that gives the ADC's four input voltages at a time.
pub trait AnalogInput {
    /// Voltages at ADC channels 0–3 at time `t` (s).
    fn volts(&mut self, t: f64) -> [f64; 4];
}

/// The sensor error drawn for one transmitter's current pulse.
#[derive(Debug, Clone, Copy)]
struct PulseError {
    pulse: i64,
    e: V3,
}

/// The three coils' IF voltages from a [`World`] (channel 3, the spare, reads 0 V).
#[derive(Debug, Clone)]
pub struct IfSignal<'w> {
    world: &'w World,
    chain: AnalogChain,
    sigma_sample: f64,
    k_sen: f64,
    seed: u64,
    noise: ChaCha8Rng,
    phase: Vec<f64>,
    errors: Vec<Option<PulseError>>,
    switch: RangeSwitch,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

impl<'w> IfSignal<'w> {
    /// The antenna in `world` behind `chain`, with EMI of `sigma_bkg` A/m (per component of
    /// a 70 ms pulse at `sample_rate_hz`) and proportional error `k_sen`; all random draws
    /// come from `seed`.
    pub fn new(
        world: &'w World,
        chain: AnalogChain,
        sigma_bkg: f64,
        k_sen: f64,
        sample_rate_hz: f64,
        seed: u64,
    ) -> Self {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        r.set_stream(1);
        let phase = world
            .transmitters
            .iter()
            .map(|_| r.random_range(0.0..TAU))
            .collect();
        let mut noise = ChaCha8Rng::seed_from_u64(seed);
        noise.set_stream(2);
        Self {
            world,
            chain,
            sigma_sample: sample_sigma(sigma_bkg, sample_rate_hz),
            k_sen,
            seed,
            noise,
            phase,
            errors: vec![None; world.transmitters.len()],
            switch: RangeSwitch::new(),
        }
    }

    /// The same source behind the IF range switch `switch` (by default its own, always in
    /// the high range).
    pub fn with_switch(mut self, switch: RangeSwitch) -> Self {
        self.switch = switch;
        self
    }

    /// The field (A/m, body frame) each coil sees at `t` from every transmitter that is on,
    /// with the per-pulse sensor error, and the IF phase argument of each: `(h, arg)`.
    fn sources(&mut self, t: f64) -> Vec<(V3, f64)> {
        let world = self.world;
        let mut out = Vec::new();
        let mut state = None;
        for (i, tx) in world.transmitters.iter().enumerate() {
            if !tx.is_on(t) {
                continue;
            }
            let s = state.get_or_insert_with(|| world.rescuer_state(t));
            let Some(h_w) = tx.field_at(&s.p) else {
                continue;
            };
            let h = s.rot.transpose() * h_w;
            let pulse = ((t - tx.phase_s) / tx.period_s).floor() as i64;
            let e = match self.errors.get(i).copied().flatten() {
                Some(pe) if pe.pulse == pulse => pe.e,
                _ => {
                    // One draw per (transmitter, pulse), independent of sampling order.
                    let mut r =
                        ChaCha8Rng::seed_from_u64(self.seed ^ (pulse as u64).rotate_left(20));
                    r.set_stream(16 + i as u64);
                    let sigma = self.k_sen * h.norm();
                    let e = V3::new(gauss(&mut r), gauss(&mut r), gauss(&mut r)) * sigma;
                    if let Some(slot) = self.errors.get_mut(i) {
                        *slot = Some(PulseError { pulse, e });
                    }
                    e
                }
            };
            let f = IF_HZ + (tx.carrier_hz - CARRIER_HZ);
            let phase = self.phase.get(i).copied().unwrap_or(0.0);
            // Keep the argument small: reduce the time modulo the period first.
            let arg = TAU * (f * t).fract() + phase;
            out.push((h + e, arg));
        }
        out
    }
}

impl AnalogInput for IfSignal<'_> {
    fn volts(&mut self, t: f64) -> [f64; 4] {
        let sources = self.sources(t);
        let c = self.chain;
        let range = self.switch.get();
        let mut v = [0.0; 4];
        for (i, out) in v.iter_mut().take(3).enumerate() {
            let lag = c.lag(i, range);
            let field: f64 = sources
                .iter()
                .map(|(h, arg)| h[i] * (arg - lag).cos())
                .sum();
            let n = self.sigma_sample * gauss(&mut self.noise);
            *out = (field + n) / c.gain(i, range) + c.offset_v[i];
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_sample_noise_gives_sigma_bkg_on_a_70_ms_pulse() {
        // σ_h = σ_s·√(2/N), N = 560 at 8 kSPS.
        let s = sample_sigma(2.59e-9, 8000.0);
        assert!((s * (2.0f64 / 560.0).sqrt() - 2.59e-9).abs() < 1e-15);
        assert!((IF_HZ - 2000.0).abs() < 1e-9);
    }
}
