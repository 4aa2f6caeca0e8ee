//! Avalanche transceivers in transmit mode (ETS/EN 300 718): a magnetic dipole pulsing
//! at 457 kHz with a fixed period and on-time.
use crate::world::physics::{V3, dipole_field};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Nominal carrier frequency of the standard, Hz.
pub const CARRIER_HZ: f64 = 457_000.0;
/// Carrier tolerance of the standard, Hz.
pub const CARRIER_TOLERANCE_HZ: f64 = 80.0;
/// Shortest pulse on-time of the standard, s.
pub const MIN_ON_TIME_S: f64 = 0.070;
/// Shortest and longest pulse period of the standard (1000 ± 300 ms), s.
pub const PERIOD_RANGE_S: [f64; 2] = [0.7, 1.3];

/// The range of transmitter parameters drawn for a scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransmitterSpec {
    /// Magnetic moment magnitude range, A·m² (drawn log-uniformly). The standard's
    /// 0.5–2.23 µA/m at 10 m corresponds to about 3e-3 … 1.4e-2 A·m² measured on the
    /// dipole axis and 6e-3 … 2.8e-2 A·m² on its equator; the default 3e-3 … 3e-2 covers both.
    pub moment_range: [f64; 2],
    /// Pulse on-time range, s (the standard requires at least 70 ms).
    pub on_time_range_s: [f64; 2],
}

impl Default for TransmitterSpec {
    fn default() -> Self {
        Self {
            moment_range: [3e-3, 3e-2],
            on_time_range_s: [MIN_ON_TIME_S, 0.15],
        }
    }
}

/// One transmitter: where it is, how it is oriented and when it pulses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Transmitter {
    /// Position in W, m (z is negative below the snow surface at z = 0).
    pub position: [f64; 3],
    /// Magnetic moment in W, A·m².
    pub moment: [f64; 3],
    /// Carrier frequency, Hz.
    pub carrier_hz: f64,
    /// Pulse period, s (fixed per transmitter).
    pub period_s: f64,
    /// Pulse on-time, s.
    pub on_time_s: f64,
    /// Start time of the first pulse, s (in `[0, period_s)`).
    pub phase_s: f64,
}

impl Transmitter {
    /// Draws a transmitter of the standard at `position` with a random moment direction
    /// (uniform on the sphere), power, carrier, period, on-time and phase.
    pub fn random(rng: &mut impl Rng, spec: &TransmitterSpec, position: [f64; 3]) -> Self {
        let [lo, hi] = spec.moment_range;
        let magnitude = lo * (hi / lo).powf(rng.random::<f64>());
        let dir = random_unit(rng);
        let period_s = rng.random_range(PERIOD_RANGE_S[0]..=PERIOD_RANGE_S[1]);
        Self {
            position,
            moment: (dir * magnitude).into(),
            carrier_hz: CARRIER_HZ + rng.random_range(-CARRIER_TOLERANCE_HZ..=CARRIER_TOLERANCE_HZ),
            period_s,
            on_time_s: rng.random_range(spec.on_time_range_s[0]..=spec.on_time_range_s[1]),
            phase_s: rng.random_range(0.0..period_s),
        }
    }

    /// Whether the transmitter is emitting at time `t` (s).
    pub fn is_on(&self, t: f64) -> bool {
        let k = ((t - self.phase_s) / self.period_s).floor();
        k >= 0.0 && t - (self.phase_s + k * self.period_s) < self.on_time_s
    }

    /// Centre times (s) of the pulses that lie entirely within `[t0, t1]`.
    pub fn pulse_centres(&self, t0: f64, t1: f64) -> Vec<f64> {
        let mut out = Vec::new();
        let first = ((t0 - self.phase_s) / self.period_s).ceil().max(0.0) as u64;
        let mut k = first;
        loop {
            let start = self.phase_s + k as f64 * self.period_s;
            if start + self.on_time_s > t1 {
                break;
            }
            out.push(start + 0.5 * self.on_time_s);
            k += 1;
        }
        out
    }

    /// The field `H` in W (A/m) at `p` (m, in W); `None` within 5 cm of the antenna.
    pub fn field_at(&self, p: &V3) -> Option<V3> {
        let r = p - V3::from(self.position);
        (r.norm() >= firmware::dipole::MIN_RANGE_M as f64)
            .then(|| dipole_field(&r, &V3::from(self.moment)))
    }
}

/// A unit vector uniform on the sphere.
pub fn random_unit(rng: &mut impl Rng) -> V3 {
    let z: f64 = rng.random_range(-1.0..=1.0);
    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let s = (1.0 - z * z).max(0.0).sqrt();
    V3::new(s * a.cos(), s * a.sin(), z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn drawn_transmitters_meet_the_standard() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let spec = TransmitterSpec::default();
        for _ in 0..500 {
            let tx = Transmitter::random(&mut rng, &spec, [10.0, 0.0, -1.0]);
            assert!((tx.carrier_hz - CARRIER_HZ).abs() <= CARRIER_TOLERANCE_HZ);
            assert!(tx.on_time_s >= MIN_ON_TIME_S);
            assert!((PERIOD_RANGE_S[0]..=PERIOD_RANGE_S[1]).contains(&tx.period_s));
            let m = V3::from(tx.moment).norm();
            assert!(m >= spec.moment_range[0] * 0.999 && m <= spec.moment_range[1] * 1.001);
            let centres = tx.pulse_centres(0.0, 30.0);
            assert!(centres.len() >= 22);
            for w in centres.windows(2) {
                assert!((w[1] - w[0] - tx.period_s).abs() < 1e-9);
            }
            for &c in &centres {
                assert!(tx.is_on(c) && tx.is_on(c - 0.49 * tx.on_time_s));
                assert!(!tx.is_on(c + 0.51 * tx.on_time_s));
            }
        }
    }

    #[test]
    fn field_on_axis_is_twice_the_equator() {
        let m = 0.02;
        for &d in &[1.0, 10.0, 40.0] {
            let tx = Transmitter {
                position: [0.0, 0.0, -1.0],
                moment: [0.0, 0.0, m],
                carrier_hz: CARRIER_HZ,
                period_s: 1.0,
                on_time_s: 0.1,
                phase_s: 0.0,
            };
            let axis = tx.field_at(&V3::new(0.0, 0.0, d - 1.0)).unwrap().norm();
            let equator = tx.field_at(&V3::new(0.0, d, -1.0)).unwrap().norm();
            assert!((axis / equator - 2.0).abs() < 1e-12);
            let k = m / (4.0 * std::f64::consts::PI * d * d * d);
            assert!((equator - k).abs() < 1e-12 * k.max(1.0));
        }
    }
}
