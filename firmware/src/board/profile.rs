//! The reference board, described once: what the board binary configures and what
//! `hal-sim`'s emulated board draws its units around.
//!
//! Reference board: Adafruit Feather STM32F405 Express, a TI ADS131M04 digitising the
//! three antenna coils' IF (8 kSPS), a Bosch BMI160 (accelerometer + gyroscope) and an
//! ST LSM303AGR (magnetometer) on I2C. The analog chain in front of the ADC (ferrite
//! coils, tuned LNAs, 455 kHz mixer, 2 kHz IF band-pass, see [`crate::frontend`]) has a
//! two-position IF range switch (one GPIO) beside the ADC's per-channel PGA, because the
//! PGA alone spans too little of the field's dynamic range: see
//! `docs/decisions/analog-dynamic-range.md`.

use crate::Vec3;
use crate::app::{AppConfig, SearchMode};
use crate::drivers::ads131m04::{self, Channels, Gain, Osr, PowerMode, WordLength};
use crate::drivers::imu::{ACC_LSB_M_S2, GYR_LSB_RAD_S, MAG_LSB_UT, Mounting};
pub use crate::frontend::IfRange;
use crate::frontend::{Calibration, FrontendConfig, Range, RangingConfig};
use crate::victims::{MAX_VICTIMS, VICTIM_CAPACITY};

/// Everything the firmware needs to know about one board design.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardProfile {
    /// Human-readable name of the design.
    pub name: &'static str,
    /// The antenna's analog chain: nominal calibration and the IF range switch.
    pub analog: AnalogProfile,
    /// The antenna ADC's configuration and noise.
    pub adc: AdcProfile,
    /// The IMU chips' mounting, rates and ranges.
    pub imu: ImuProfile,
    /// How far a built unit's actual parameters spread about the nominal ones (1 σ).
    pub tolerances: UnitTolerances,
    /// Fixed capacities of the firmware on this board's RAM.
    pub capacity: Capacity,
    /// Factory defaults of the settings.
    pub defaults: Defaults,
}

/// The antenna's analog chain (coils → LNA → mixer → IF amplifier → ADC inputs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnalogProfile {
    /// Nominal per-coil calibration (the design values: what an uncalibrated unit uses).
    pub nominal: Calibration,
    /// Local oscillator of the mixer, Hz (457 kHz − the IF).
    pub lo_hz: f32,
    /// Nominal intermediate frequency, Hz.
    pub if_hz: f32,
}

/// The antenna ADC as the board runs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdcProfile {
    /// The driver configuration applied at start-up.
    pub config: ads131m04::Config,
    /// CLKIN of the ADC, Hz (its own 8.192 MHz oscillator).
    pub clkin_hz: f32,
    /// Input-referred noise of one conversion per PGA gain (index = `Gain as usize`) at
    /// this OSR, V rms (TI SBAS946 table 7-1 at OSR 512; gains 16–64 interpolated).
    pub input_noise_v_rms: [f32; 8],
}

/// Mounting, rates and ranges of the IMU chips.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuProfile {
    /// Chip axes → body axes (BMI160, LSM303AGR magnetometer).
    pub mounting: Mounting,
    /// Sample rate of all three sensors, Hz.
    pub rate_hz: f32,
    /// Largest accelerometer reading that is not clipped, m/s² (±8 g setting).
    pub acc_full_scale_m_s2: f32,
    /// Largest gyroscope reading that is not clipped, rad/s (±500 °/s setting).
    pub gyr_full_scale_rad_s: f32,
    /// Largest magnetometer reading that is not clipped, µT.
    pub mag_full_scale_ut: f32,
}

/// 1-σ spread of a built unit's parameters about the profile's nominal values; `hal-sim`
/// draws every simulated unit from these (see `docs/decisions/unit-tolerances.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitTolerances {
    /// Relative spread of each coil's gain (ferrite permeability, tuning, amplifier gain).
    pub coil_gain_rel: f32,
    /// Spread of each channel's phase lag at the IF, rad (tuned-circuit detuning).
    pub coil_phase_rad: f32,
    /// Spread of each ADC channel's DC offset, V.
    pub adc_offset_v: f32,
    /// Relative spread of the IF range switch's ratio per channel (resistor tolerance).
    pub low_range_ratio_rel: f32,
    /// Spread of the low range's extra phase lag per channel, rad.
    pub low_range_phase_rad: f32,
    /// Spread of each component of the magnetometer's hard-iron offset, µT.
    pub mag_hard_iron_ut: f32,
    /// Spread of each element of the magnetometer's soft-iron distortion (a symmetric
    /// matrix `I + E`).
    pub mag_soft_iron: f32,
    /// Spread of each IMU chip's small-angle misalignment about each body axis, rad.
    pub imu_misalignment_rad: f32,
}

/// Fixed capacities chosen for the board's RAM (192 KB: 128 KB SRAM + 64 KB CCM).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacity {
    /// Victims tracked at once.
    pub victims: usize,
    /// Gaussian components of all victims' mixtures together.
    pub components: usize,
}

/// Factory defaults of the unit's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Defaults {
    /// Local geomagnetic field in the geographic frame (north, west, up), µT, declination
    /// folded in (48 µT at 63° inclination: the Alps).
    pub earth_field_ut: [f32; 3],
    /// The user's step length, m (`None`: not calibrated yet).
    pub step_length_m: Option<f32>,
    /// How the receiver guides.
    pub search_mode: SearchMode,
}

/// Degrees to radians for the constants below.
const DEG: f32 = core::f32::consts::PI / 180.0;

/// The reference board.
pub const REFERENCE: BoardProfile = BoardProfile {
    name: "Feather STM32F405 + ADS131M04 + BMI160 + LSM303AGR",
    analog: AnalogProfile {
        nominal: Calibration {
            // High range: 4 mA/m per V puts the ADC's noise at PGA 128 (1.7 µV) 16 dB below
            // the environment's; coil y's leads are crossed on the antenna board.
            gain_a_per_m_per_v: [4.0e-3, -4.0e-3, 4.0e-3],
            offset_v: [0.0; 3],
            phase_rad: [0.0; 3],
            low_range_ratio: [64.0; 3],
            low_range_phase_rad: [0.0; 3],
        },
        lo_hz: 455_000.0,
        if_hz: 2_000.0,
    },
    adc: AdcProfile {
        config: ads131m04::Config {
            osr: Osr::Osr512,
            power: PowerMode::HighResolution,
            channels: Channels::ALL,
            // The coils start on the most sensitive rung of the gain ranging
            // ([`crate::frontend::Range::MOST_SENSITIVE`]); the spare stays at 1.
            gains: [Gain::G128, Gain::G128, Gain::G128, Gain::G1],
            word_length: WordLength::Bits24,
        },
        clkin_hz: 8_192_000.0,
        input_noise_v_rms: [
            7.56e-6, 6.62e-6, 6.37e-6, 3.82e-6, 2.6e-6, 2.1e-6, 1.85e-6, 1.69e-6,
        ],
    },
    imu: ImuProfile {
        mounting: Mounting::REFERENCE,
        rate_hz: 100.0,
        acc_full_scale_m_s2: 32767.0 * ACC_LSB_M_S2,
        gyr_full_scale_rad_s: 32767.0 * GYR_LSB_RAD_S,
        mag_full_scale_ut: 32767.0 * MAG_LSB_UT,
    },
    tolerances: UnitTolerances {
        coil_gain_rel: 0.03,
        coil_phase_rad: 3.0 * DEG,
        adc_offset_v: 1.0e-3,
        low_range_ratio_rel: 0.01,
        low_range_phase_rad: 1.0 * DEG,
        mag_hard_iron_ut: 10.0,
        mag_soft_iron: 0.03,
        imu_misalignment_rad: 0.5 * DEG,
    },
    capacity: Capacity {
        victims: MAX_VICTIMS,
        components: MAX_VICTIMS * VICTIM_CAPACITY,
    },
    defaults: Defaults {
        earth_field_ut: [21.79, 0.0, -42.77],
        step_length_m: None,
        search_mode: SearchMode::Sog,
    },
};

impl BoardProfile {
    /// ADC output data rate, Hz (8 kSPS on the reference board).
    pub fn sample_rate_hz(&self) -> f32 {
        self.adc.config.data_rate_hz(self.adc.clkin_hz)
    }

    /// The pulse DSP's configuration for this board with the unit's calibration `cal`
    /// (the nominal one, [`AnalogProfile::nominal`], until the unit is calibrated): gain
    /// ranging on, starting from the ADC configuration's coil gain in the high IF range.
    pub fn frontend_config(&self, cal: &Calibration) -> FrontendConfig {
        FrontendConfig {
            sample_rate_hz: self.sample_rate_hz(),
            if_hz: self.analog.if_hz,
            calibration: *cal,
            range: self.start_range(),
            ranging: Some(RangingConfig::default()),
            ..FrontendConfig::default()
        }
    }

    /// The analog setting the board starts in: the high IF range at the ADC
    /// configuration's gain of coil channel 0.
    pub fn start_range(&self) -> Range {
        Range {
            if_range: IfRange::High,
            gain: self.adc.config.gains[0],
        }
    }

    /// The application's configuration for this board: the defaults of
    /// [`AppConfig::new`] for the earth field (µT, in W) and step length given, with the
    /// IMU's rate and clipping limits.
    pub fn app_config(&self, earth_field_ut: Vec3, step_length_m: Option<f32>) -> AppConfig {
        let mut cfg = AppConfig::new(earth_field_ut, step_length_m);
        cfg.motion.imu_hz = self.imu.rate_hz;
        cfg.motion.acc_range_m_s2 = self.imu.acc_full_scale_m_s2;
        cfg.motion.gyr_range_rad_s = self.imu.gyr_full_scale_rad_s;
        cfg.motion.mag_range_ut = self.imu.mag_full_scale_ut;
        cfg.mode = self.defaults.search_mode;
        cfg
    }

    /// The factory-default earth field as a vector (µT, in W).
    pub fn default_earth_field(&self) -> Vec3 {
        let e = self.defaults.earth_field_ut;
        Vec3::new(e[0], e[1], e[2])
    }

    /// Full scale of a coil channel (A/m of IF amplitude) at a PGA gain and IF range,
    /// with the nominal calibration.
    pub fn full_scale_a_per_m(&self, coil: usize, gain: Gain, range: IfRange) -> f32 {
        let c = &self.analog.nominal;
        let g = c.gain_a_per_m_per_v.get(coil).copied().unwrap_or(0.0);
        let ratio = match range {
            IfRange::High => 1.0,
            IfRange::Low => c.low_range_ratio.get(coil).copied().unwrap_or(1.0),
        };
        libm::fabsf(g) * ratio * gain.full_scale_v()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_board_runs_the_dsp_at_8_ksps_with_the_if_at_a_quarter_of_it() {
        let p = REFERENCE;
        assert_eq!(p.sample_rate_hz(), 8000.0);
        assert_eq!(p.analog.lo_hz + p.analog.if_hz, 457_000.0);
        let cfg = p.frontend_config(&p.analog.nominal);
        assert_eq!(cfg.validate(), Ok(()));
        assert_eq!(cfg.if_hz * 4.0, cfg.sample_rate_hz);
    }

    #[test]
    fn ranges_span_the_environment_noise_to_a_shallow_strong_beacon() {
        let p = REFERENCE;
        // Environment noise per sample at the ADC: σ_bkg = 2.59e-9 A/m per component of a
        // 70 ms pulse is 4.3e-8 A/m per 8 kSPS sample (√(0.07 · 8000 / 2) = 16.7).
        let emi = 2.59e-9 * 16.73;
        let adc =
            p.adc.input_noise_v_rms[Gain::G128 as usize] * p.analog.nominal.gain_a_per_m_per_v[0];
        assert!(adc < 0.25 * emi, "ADC noise {adc} vs EMI {emi}");
        // Strongest transmitter (3e-2 A·m²) on its axis 0.3 m away: 0.18 A/m.
        let h = 2.0 * 3e-2 / (4.0 * core::f32::consts::PI * 0.3f32.powi(3));
        let fs = p.full_scale_a_per_m(0, Gain::G1, IfRange::Low);
        assert!(fs > 1.5 * h, "full scale {fs} vs {h}");
        // Consecutive steps of the ladder are 2× apart, the two ranges meet.
        let hi1 = p.full_scale_a_per_m(0, Gain::G1, IfRange::High);
        let lo64 = p.full_scale_a_per_m(0, Gain::G64, IfRange::Low);
        assert!((hi1 / lo64 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn app_config_takes_the_imu_limits() {
        let p = REFERENCE;
        let cfg = p.app_config(p.default_earth_field(), Some(0.7));
        assert_eq!(cfg.motion.imu_hz, 100.0);
        assert!((cfg.motion.acc_range_m_s2 - 8.0 * 9.80665).abs() < 0.01);
        assert_eq!(p.capacity.victims, MAX_VICTIMS);
    }
}
