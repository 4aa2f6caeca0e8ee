//! Measurement-level sensor models: they sample the world's truth and add noise, giving
//! the session log's `imu` and `pulse` records.
//!
//! Output resolution (like an ADC's): `acc` 1e-4 m/s², `gyr` 1e-5 rad/s, `mag` 1e-3 µT,
//! pulse `h` 5 significant digits, pulse `t` 1e-4 s. All are far below the noise; they
//! keep the log compact.

pub mod bus;
pub mod faults;
use crate::io::receiver_config::{ImuNoise, PulseNoise};
use crate::io::session::{Imu, Pulse};
use crate::world::World;
use crate::world::physics::V3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Everything noisy about the receiver's sensors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorConfig {
    /// IMU rate and noise.
    pub imu: ImuNoise,
    /// Pulse vector noise.
    pub pulse: PulseNoise,
    /// Rx sensitivity floor: a pulse whose true |H| is below `detect_factor × sigma_bkg`
    /// is not received (no `pulse` record). Default 3.
    pub detect_factor: f64,
    /// Whether the overall sign of each pulse vector is random.
    pub sign_ambiguous: bool,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            imu: ImuNoise::default(),
            pulse: PulseNoise::default(),
            detect_factor: 3.0,
            sign_ambiguous: true,
        }
    }
}

impl SensorConfig {
    /// The same sensors without any noise, bias or sign flips (for tests).
    pub fn noise_free() -> Self {
        Self {
            imu: ImuNoise {
                gyr_noise_rad_s: 0.0,
                gyr_bias_max_rad_s: 0.0,
                acc_noise_m_s2: 0.0,
                mag_noise_ut: 0.0,
                ..ImuNoise::default()
            },
            pulse: PulseNoise {
                sigma_bkg_a_per_m: 0.0,
                k_sen: 0.0,
            },
            detect_factor: 0.0,
            sign_ambiguous: false,
        }
    }
}

/// Rounds to a multiple of `1/inv` (with `inv` an integer power of ten, the result prints
/// as that decimal).
pub fn quantize(x: f64, inv: f64) -> f64 {
    (x * inv).round() / inv
}

/// Rounds to `digits` significant decimal digits.
pub fn round_significant(x: f64, digits: usize) -> f64 {
    format!("{:.*e}", digits.saturating_sub(1), x)
        .parse()
        .unwrap_or(x)
}

fn gauss(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    let z: f64 = StandardNormal.sample(rng);
    sigma * z
}

fn noisy(rng: &mut ChaCha8Rng, v: &V3, sigma: f64, inv: f64) -> [f64; 3] {
    [
        quantize(v.x + gauss(rng, sigma), inv),
        quantize(v.y + gauss(rng, sigma), inv),
        quantize(v.z + gauss(rng, sigma), inv),
    ]
}

/// The IMU: accelerometer, gyro (with a constant bias) and magnetometer.
#[derive(Debug, Clone)]
pub struct ImuModel {
    noise: ImuNoise,
    /// The gyro's constant bias, rad/s (drawn uniformly within ± the configured maximum).
    pub gyr_bias: V3,
    rng: ChaCha8Rng,
}

impl ImuModel {
    /// An IMU whose bias and noise come from `rng`.
    pub fn new(noise: ImuNoise, mut rng: ChaCha8Rng) -> Self {
        let b = noise.gyr_bias_max_rad_s.abs();
        let mut draw = || {
            if b > 0.0 {
                rng.random_range(-b..=b)
            } else {
                0.0
            }
        };
        let gyr_bias = V3::new(draw(), draw(), draw());
        Self {
            noise,
            gyr_bias,
            rng,
        }
    }

    /// The sample at time `t`.
    pub fn sample(&mut self, world: &World, t: f64) -> Imu {
        let s = world.rescuer_state(t);
        let n = &self.noise;
        let mag = s.rot.transpose() * V3::from(world.earth_field_ut);
        Imu {
            t,
            acc: noisy(&mut self.rng, &s.specific_force_body, n.acc_noise_m_s2, 1e4),
            gyr: noisy(
                &mut self.rng,
                &(s.omega_body + self.gyr_bias),
                n.gyr_noise_rad_s,
                1e5,
            ),
            mag: Some(noisy(&mut self.rng, &mag, n.mag_noise_ut, 1e3)),
        }
    }
}

/// The antenna front end's output: one field vector per received transmitter pulse.
#[derive(Debug, Clone)]
pub struct PulseModel {
    config: SensorConfig,
    rng: ChaCha8Rng,
}

impl PulseModel {
    /// A pulse model drawing its noise from `rng`.
    pub fn new(config: SensorConfig, rng: ChaCha8Rng) -> Self {
        Self { config, rng }
    }

    /// Per-component standard deviation of the noise on a field of magnitude `h_norm`.
    pub fn sigma(&self, h_norm: f64) -> f64 {
        let p = &self.config.pulse;
        p.sigma_bkg_a_per_m.hypot(p.k_sen * h_norm)
    }

    /// The pulse of transmitter `i` centred at `t`, or `None` when it is below the
    /// sensitivity floor (or the receiver sits on the antenna). `src` is written when the
    /// world has several transmitters.
    pub fn measure(&mut self, world: &World, i: usize, t: f64) -> Option<Pulse> {
        let s = world.rescuer_state(t);
        let h_w = world.transmitters.get(i)?.field_at(&s.p)?;
        let norm = h_w.norm();
        if norm < self.config.detect_factor * self.config.pulse.sigma_bkg_a_per_m {
            return None;
        }
        let h_b = s.rot.transpose() * h_w;
        let sigma = self.sigma(norm);
        let sign = if self.config.sign_ambiguous && self.rng.random::<bool>() {
            -1.0
        } else {
            1.0
        };
        let mut h = [0.0; 3];
        for (k, out) in h.iter_mut().enumerate() {
            *out = round_significant(sign * (h_b[k] + gauss(&mut self.rng, sigma)), 5);
        }
        Some(Pulse {
            t,
            h,
            src: (world.transmitters.len() > 1).then_some(i as u32),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantized_values_print_short() {
        assert_eq!(
            serde_json::to_string(&quantize(9.806651234, 1e4)).unwrap(),
            "9.8067"
        );
        assert_eq!(serde_json::to_string(&quantize(-0.1, 1e5)).unwrap(), "-0.1");
        let h = round_significant(1.234567e-7, 5);
        assert_eq!(serde_json::to_string(&h).unwrap(), "1.2346e-7");
    }
}
