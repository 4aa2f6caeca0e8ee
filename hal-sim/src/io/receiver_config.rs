//! `receiver.json`: what a receiver may be told about its world (session-log spec).
//! Every key is optional; unknown keys are ignored; missing keys take the defaults below,
//! which are also the simulator's default world.
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Plausible transmitter moments, A·m² (EN 300 718 beacons are ≈ 3e-3 to 8e-2).
const MOMENT_RANGE: [f64; 2] = [1e-4, 1.0];
/// Plausible burial depths below the snow surface, m (negative: above the receiver's
/// snow plane, e.g. a victim up a slope).
const DEPTH_RANGE_M: [f64; 2] = [-2.0, 20.0];

/// A numeric value of the configuration by key (`None`: absent, not checked).
type Get = fn(&ReceiverConfig) -> Option<f64>;

/// Every numeric key, its plausible range and unit, in the order checked (the spec's
/// ranges table in `docs/session-log.md`).
const RANGES: &[(&str, Get, [f64; 2], &str)] = &[
    ("m_min", |c| Some(c.m_min), MOMENT_RANGE, "A·m²"),
    ("m_nom", |c| Some(c.m_nom), MOMENT_RANGE, "A·m²"),
    ("m_max", |c| Some(c.m_max), MOMENT_RANGE, "A·m²"),
    (
        "pulse_noise.sigma_bkg_A_per_m",
        |c| Some(c.pulse_noise.sigma_bkg_a_per_m),
        // A noise floor of zero is no receiver (the filter's pulse σ would vanish).
        [1e-12, 1e-5],
        "A/m",
    ),
    (
        "pulse_noise.k_sen",
        |c| Some(c.pulse_noise.k_sen),
        [0.0, 0.5],
        "",
    ),
    (
        "imu.hz",
        |c| Some(c.imu.hz),
        crate::io::session::IMU_HZ_RANGE,
        "Hz",
    ),
    (
        "imu.gyr_noise_rad_s",
        |c| Some(c.imu.gyr_noise_rad_s),
        [0.0, 1.0],
        "rad/s",
    ),
    (
        "imu.gyr_bias_max_rad_s",
        |c| Some(c.imu.gyr_bias_max_rad_s),
        [0.0, 1.0],
        "rad/s",
    ),
    (
        "imu.acc_noise_m_s2",
        |c| Some(c.imu.acc_noise_m_s2),
        [0.0, 10.0],
        "m/s²",
    ),
    (
        "imu.mag_noise_uT",
        |c| Some(c.imu.mag_noise_ut),
        [0.0, 50.0],
        "µT",
    ),
    (
        "victim_depth_range_m[0]",
        |c| Some(c.victim_depth_range_m[0]),
        DEPTH_RANGE_M,
        "m",
    ),
    (
        "victim_depth_range_m[1]",
        |c| Some(c.victim_depth_range_m[1]),
        DEPTH_RANGE_M,
        "m",
    ),
    (
        "receiver_height_m",
        |c| Some(c.receiver_height_m),
        [0.0, 3.0],
        "m",
    ),
    (
        "pdr.step_length_m",
        |c| c.pdr.as_ref().map(|p| p.step_length_m),
        [0.2, 1.5],
        "m",
    ),
];

/// What each known key must be: a number, a boolean, an object of these, or two numbers.
enum Kind {
    Number,
    Bool,
    Pair,
    Object(&'static [(&'static str, Kind)]),
    /// An object, or null (absent).
    OptObject(&'static [(&'static str, Kind)]),
}

const KEYS: &[(&str, Kind)] = &[
    ("m_min", Kind::Number),
    ("m_max", Kind::Number),
    ("m_nom", Kind::Number),
    ("sign_ambiguous", Kind::Bool),
    (
        "pulse_noise",
        Kind::Object(&[("sigma_bkg_A_per_m", Kind::Number), ("k_sen", Kind::Number)]),
    ),
    (
        "imu",
        Kind::Object(&[
            ("hz", Kind::Number),
            ("gyr_noise_rad_s", Kind::Number),
            ("gyr_bias_max_rad_s", Kind::Number),
            ("acc_noise_m_s2", Kind::Number),
            ("mag_noise_uT", Kind::Number),
        ]),
    ),
    ("victim_depth_range_m", Kind::Pair),
    ("receiver_height_m", Kind::Number),
    ("pdr", Kind::OptObject(&[("step_length_m", Kind::Number)])),
];

/// `Ok` when `v` is an object whose known keys have their kinds (unknown keys are
/// ignored, as the spec asks), else a message naming the key.
fn check_types(v: &serde_json::Value) -> Result<(), String> {
    fn object(prefix: &str, v: &serde_json::Value, keys: &[(&str, Kind)]) -> Result<(), String> {
        let name = if prefix.is_empty() {
            "receiver.json"
        } else {
            prefix
        };
        let map = v
            .as_object()
            .ok_or_else(|| format!("{name} must be a JSON object, found {}", kind_of(v)))?;
        for (key, kind) in keys {
            let Some(x) = map.get(*key) else { continue };
            let path = if prefix.is_empty() {
                (*key).to_string()
            } else {
                format!("{prefix}.{key}")
            };
            let ok = match kind {
                Kind::Number => x.is_number(),
                Kind::Bool => x.is_boolean(),
                Kind::Pair => x
                    .as_array()
                    .is_some_and(|a| a.len() == 2 && a.iter().all(|e| e.is_number())),
                Kind::Object(inner) => {
                    object(&path, x, inner)?;
                    true
                }
                Kind::OptObject(inner) => {
                    if !x.is_null() {
                        object(&path, x, inner)?;
                    }
                    true
                }
            };
            if !ok {
                let want = match kind {
                    Kind::Number => "a number",
                    Kind::Bool => "true or false",
                    _ => "two numbers [min, max]",
                };
                return Err(format!("{path} must be {want}, found {}", kind_of(x)));
            }
        }
        Ok(())
    }
    object("", v, KEYS)
}

fn kind_of(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Null => "null".into(),
        serde_json::Value::Bool(b) => b.to_string(),
        serde_json::Value::Number(n) => n.to_string(),
        serde_json::Value::String(_) => "a string".into(),
        serde_json::Value::Array(_) => "an array".into(),
        serde_json::Value::Object(_) => "an object".into(),
    }
}

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
    /// Parses `receiver.json` text: a JSON object whose known keys have the right types
    /// and lie in their plausible ranges ([`ReceiverConfig::validate`]); the error names
    /// the key and what is allowed.
    pub fn from_json(text: &str) -> anyhow::Result<Self> {
        let v: serde_json::Value = serde_json::from_str(text)?;
        check_types(&v).map_err(anyhow::Error::msg)?;
        let c: Self = serde_json::from_value(v)?;
        c.validate().map_err(anyhow::Error::msg)?;
        Ok(c)
    }

    /// `Ok` when every value is physically plausible (the ranges of
    /// `docs/session-log.md`), else a message naming the first key out of range and its
    /// allowed range.
    pub fn validate(&self) -> Result<(), String> {
        for (key, get, range, unit) in RANGES {
            if let Some(v) = get(self) {
                crate::io::session::check_range(key, v, *range, unit)?;
            }
        }
        if !(self.m_min <= self.m_nom && self.m_nom <= self.m_max) {
            return Err(format!(
                "m_min = {}, m_nom = {}, m_max = {}: need m_min <= m_nom <= m_max",
                self.m_min, self.m_nom, self.m_max
            ));
        }
        let [lo, hi] = self.victim_depth_range_m;
        if lo > hi {
            return Err(format!(
                "victim_depth_range_m = [{lo}, {hi}]: the first must not exceed the second"
            ));
        }
        Ok(())
    }

    /// Reads `receiver.json` from a file.
    pub fn read_file(path: &Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        // A byte-order mark (editors on some systems write one) is not part of the JSON.
        let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
        Self::from_json(text).with_context(|| format!("parsing {}", path.display()))
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

    #[test]
    fn implausible_values_are_refused_by_key_and_range() {
        let cases = [
            (
                r#"{"pdr":{"step_length_m":10}}"#,
                "pdr.step_length_m",
                "[0.2, 1.5]",
            ),
            (
                r#"{"pdr":{"step_length_m":1e-30}}"#,
                "pdr.step_length_m",
                "[0.2, 1.5]",
            ),
            (
                r#"{"receiver_height_m":1e6}"#,
                "receiver_height_m",
                "[0, 3]",
            ),
            (r#"{"receiver_height_m":-1}"#, "receiver_height_m", "[0, 3]"),
            (r#"{"imu":{"hz":1e308}}"#, "imu.hz", "[1, 10000]"),
            (r#"{"imu":{"hz":0}}"#, "imu.hz", "[1, 10000]"),
            (
                r#"{"imu":{"gyr_noise_rad_s":-0.1}}"#,
                "imu.gyr_noise_rad_s",
                "[0, 1]",
            ),
            (
                r#"{"imu":{"gyr_bias_max_rad_s":5}}"#,
                "imu.gyr_bias_max_rad_s",
                "[0, 1]",
            ),
            (
                r#"{"imu":{"acc_noise_m_s2":100}}"#,
                "imu.acc_noise_m_s2",
                "[0, 10]",
            ),
            (
                r#"{"imu":{"mag_noise_uT":1000}}"#,
                "imu.mag_noise_uT",
                "[0, 50]",
            ),
            (r#"{"m_min":0}"#, "m_min", "[0.0001, 1]"),
            (r#"{"m_max":5}"#, "m_max", "[0.0001, 1]"),
            (r#"{"m_nom":1e-9}"#, "m_nom", "[0.0001, 1]"),
            (
                r#"{"m_min":0.02,"m_max":0.01}"#,
                "m_min",
                "m_min <= m_nom <= m_max",
            ),
            (
                r#"{"pulse_noise":{"sigma_bkg_A_per_m":1}}"#,
                "pulse_noise.sigma_bkg_A_per_m",
                "[0.000000000001, 0.00001]",
            ),
            (
                r#"{"pulse_noise":{"k_sen":-0.1}}"#,
                "pulse_noise.k_sen",
                "[0, 0.5]",
            ),
            (
                r#"{"victim_depth_range_m":[0,100]}"#,
                "victim_depth_range_m[1]",
                "[-2, 20]",
            ),
            (
                r#"{"victim_depth_range_m":[3,1]}"#,
                "victim_depth_range_m",
                "must not exceed",
            ),
        ];
        for (text, key, range) in cases {
            let e = ReceiverConfig::from_json(text).unwrap_err().to_string();
            assert!(e.contains(key) && e.contains(range), "{text}: {e}");
        }
    }

    #[test]
    fn the_wrong_shape_is_refused_by_key() {
        let cases = [
            ("[1, 2]", "must be a JSON object"),
            ("3", "must be a JSON object"),
            ("\"x\"", "must be a JSON object"),
            (r#"{"m_min":"x"}"#, "m_min must be a number"),
            (
                r#"{"sign_ambiguous":1}"#,
                "sign_ambiguous must be true or false",
            ),
            (r#"{"imu":[100]}"#, "imu must be a JSON object"),
            (r#"{"imu":{"hz":"fast"}}"#, "imu.hz must be a number"),
            (
                r#"{"victim_depth_range_m":[1]}"#,
                "victim_depth_range_m must be two",
            ),
            (r#"{"pdr":5}"#, "pdr must be a JSON object"),
        ];
        for (text, want) in cases {
            let e = ReceiverConfig::from_json(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
        // An explicit null pdr is "not calibrated"; unknown keys of any shape are ignored.
        let c = ReceiverConfig::from_json(r#"{"pdr":null,"x":[1],"imu":{"y":"z"}}"#).unwrap();
        assert_eq!(c, ReceiverConfig::default());
    }

    #[test]
    fn every_numeric_key_has_a_range() {
        fn numbers(prefix: &str, keys: &[(&str, Kind)], out: &mut Vec<String>) {
            for (key, kind) in keys {
                let path = if prefix.is_empty() {
                    (*key).to_string()
                } else {
                    format!("{prefix}.{key}")
                };
                match kind {
                    Kind::Number => out.push(path),
                    Kind::Pair => {
                        out.push(format!("{path}[0]"));
                        out.push(format!("{path}[1]"));
                    }
                    Kind::Object(inner) | Kind::OptObject(inner) => numbers(&path, inner, out),
                    Kind::Bool => {}
                }
            }
        }
        let mut keys = Vec::new();
        numbers("", KEYS, &mut keys);
        let ranged: Vec<&str> = RANGES.iter().map(|r| r.0).collect();
        keys.sort();
        let mut sorted = ranged.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
        // Each range holds the default (the simulator's world) and refuses what is
        // just outside it, naming the key and the range.
        for (key, get, [lo, hi], _) in RANGES {
            let mut c = ReceiverConfig {
                pdr: Some(Pdr { step_length_m: 0.7 }),
                ..ReceiverConfig::default()
            };
            assert!(get(&c).is_some_and(|v| v >= *lo && v <= *hi), "{key}");
            let text = serde_json::to_value(&c).unwrap();
            for bad in [lo - 1e-3 * (hi - lo).max(1e-9), hi + 1e-3 * (hi - lo)] {
                let mut v = text.clone();
                let ptr = format!("/{}", key.replace(['.', '['], "/").replace(']', ""));
                *v.pointer_mut(&ptr).unwrap() = bad.into();
                c = serde_json::from_value(v).unwrap();
                let e = c.validate().unwrap_err();
                assert!(e.starts_with(&format!("{key} = ")), "{key}: {e}");
                assert!(e.contains(&format!("[{lo}, {hi}]")), "{key}: {e}");
            }
        }
    }

    #[test]
    fn the_defaults_are_plausible() {
        assert_eq!(ReceiverConfig::default().validate(), Ok(()));
        assert!(ReceiverConfig::from_json(&ReceiverConfig::default().to_json()).is_ok());
    }
}
