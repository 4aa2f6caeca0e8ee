//! `receiver.json`: what a receiver may be told about its world (session-log spec).
//! Every key is optional; unknown keys are ignored; missing keys take the defaults below,
//! which are also the simulator's default world.
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Pulse noise model: per-component σ² = `sigma_bkg`² + (`k_sen`·|H|)² (ICRA 2006 eq. 10).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PulseNoise {
    /// Background (EMI) standard deviation per component, A/m. The default 2.59e-9 A/m is
    /// about the field of a mid-power beacon (≈1e-2 A·m²) 80 m away on its axis, the EMI
    /// level Mimmo, Bernard & Marconi measured in the field.
    #[serde(rename = "sigma_bkg_A_per_m")]
    pub sigma_bkg_a_per_m: f64,
    /// Sensor error proportional to |H| (relative standard deviation per component).
    pub k_sen: f64,
}

impl Default for PulseNoise {
    fn default() -> Self {
        Self {
            sigma_bkg_a_per_m: 2.59e-9,
            k_sen: 0.03,
        }
    }
}

/// The IMU's rate and noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ImuNoise {
    /// Sample rate, Hz.
    pub hz: f64,
    /// Gyro white noise per sample, rad/s.
    pub gyr_noise_rad_s: f64,
    /// Largest constant gyro bias per axis, rad/s.
    pub gyr_bias_max_rad_s: f64,
    /// Accelerometer white noise per sample, m/s².
    pub acc_noise_m_s2: f64,
    /// Magnetometer white noise per sample, µT.
    #[serde(rename = "mag_noise_uT")]
    pub mag_noise_ut: f64,
}

impl Default for ImuNoise {
    fn default() -> Self {
        Self {
            hz: 100.0,
            gyr_noise_rad_s: 0.005,
            gyr_bias_max_rad_s: 0.01,
            acc_noise_m_s2: 0.05,
            mag_noise_ut: 0.3,
        }
    }
}

/// Pedestrian dead-reckoning calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pdr {
    /// The user's calibrated mean step length at normal pace, m (≈2 % uncertain).
    pub step_length_m: f64,
}

/// The whole `receiver.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ReceiverConfig {
    /// Smallest transmitter magnetic moment, A·m².
    pub m_min: f64,
    /// Largest transmitter magnetic moment, A·m².
    pub m_max: f64,
    /// Nominal transmitter magnetic moment, A·m².
    pub m_nom: f64,
    /// Whether the overall sign of each pulse vector is unknown.
    pub sign_ambiguous: bool,
    /// Pulse noise model.
    pub pulse_noise: PulseNoise,
    /// IMU rate and noise.
    pub imu: ImuNoise,
    /// Burial depth range below the snow surface, m.
    pub victim_depth_range_m: [f64; 2],
    /// The receiver's usual height above the snow surface, m.
    pub receiver_height_m: f64,
    /// Step-length calibration; absent when not calibrated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pdr: Option<Pdr>,
}

impl Default for ReceiverConfig {
    fn default() -> Self {
        Self {
            m_min: 3e-3,
            m_max: 3e-2,
            m_nom: 9.49e-3,
            sign_ambiguous: true,
            pulse_noise: PulseNoise::default(),
            imu: ImuNoise::default(),
            victim_depth_range_m: [0.3, 3.0],
            receiver_height_m: 1.0,
            pdr: None,
        }
    }
}

impl ReceiverConfig {
    /// Parses `receiver.json` text.
    pub fn from_json(text: &str) -> anyhow::Result<Self> {
        Ok(serde_json::from_str(text)?)
    }

    /// Reads `receiver.json` from a file.
    pub fn read_file(path: &Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        Self::from_json(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// The JSON text (one line, keys in the spec's order).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_spec_example_and_defaults() {
        let text = r#"{"m_min":0.025,"m_max":0.075,"m_nom":0.05,"sign_ambiguous":true,
 "pulse_noise":{"sigma_bkg_A_per_m":2.59e-9,"k_sen":0.03},
 "imu":{"hz":100.0,"gyr_noise_rad_s":0.005,"gyr_bias_max_rad_s":0.01,
        "acc_noise_m_s2":0.05,"mag_noise_uT":0.3},
 "victim_depth_range_m":[0.0,5.0],"receiver_height_m":1.0,
 "pdr":{"step_length_m":0.56}, "future_key": [1, 2]}"#;
        let c = ReceiverConfig::from_json(text).unwrap();
        assert_eq!(c.m_max, 0.075);
        assert_eq!(c.pulse_noise, PulseNoise::default());
        assert_eq!(c.imu, ImuNoise::default());
        assert_eq!(
            c.pdr,
            Some(Pdr {
                step_length_m: 0.56
            })
        );
        let d = ReceiverConfig::from_json(r#"{"imu":{"hz":50.0}}"#).unwrap();
        assert_eq!(d.imu.hz, 50.0);
        assert_eq!(d.imu.acc_noise_m_s2, 0.05);
        assert_eq!(d.pdr, None);
        let back = ReceiverConfig::from_json(&c.to_json()).unwrap();
        assert_eq!(back, c);
        assert!(ReceiverConfig::from_json("{\"m_min\":\"x\"}").is_err());
    }
}
