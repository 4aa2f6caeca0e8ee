//! A built unit: one simulated board's actual parameters, drawn about the board profile's
//! nominal values with its tolerances ([`firmware::board::UnitTolerances`], 1 σ, see
//! `docs/decisions/unit-tolerances.md`), so that every bus-level result carries the
//! calibration error of a real unit.
//!
//! The emulated chips use the unit's actual parameters; the firmware is handed what a
//! real unit would hold: the profile's nominal calibration (an uncalibrated unit) or the
//! result of a calibration procedure run on the emulated chips — never these values.
use super::if_signal::AnalogChain;
use crate::world::physics::{M3, V3};
use firmware::board::BoardProfile;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The magnetometer's distortion by the unit's own iron: a reading is
/// `raw = soft_iron · m + hard_iron` for the field `m` at the chip (body frame, µT).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagDistortion {
    /// Hard-iron offset (permanently magnetised parts near the chip), µT, body frame.
    pub hard_iron_ut: V3,
    /// Soft-iron matrix `I + E`, `E` symmetric (induced magnetisation of nearby steel).
    pub soft_iron: M3,
}

impl MagDistortion {
    /// No distortion.
    pub fn none() -> Self {
        Self {
            hard_iron_ut: V3::zeros(),
            soft_iron: M3::identity(),
        }
    }

    /// The reading of the field `m` (µT, body frame).
    pub fn apply(&self, m: &V3) -> V3 {
        self.soft_iron * m + self.hard_iron_ut
    }
}

/// One simulated unit's actual parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unit {
    /// The antenna's analog chain (gain, phase, offset, IF range switch per coil).
    pub chain: AnalogChain,
    /// The magnetometer's hard- and soft-iron distortion.
    pub mag: MagDistortion,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

impl Unit {
    /// A unit built exactly to the profile's nominal values (no tolerances): for tests that
    /// isolate something else.
    pub fn nominal(profile: &BoardProfile) -> Self {
        Self {
            chain: AnalogChain::from_calibration(&profile.analog.nominal),
            mag: MagDistortion::none(),
        }
    }

    /// The unit drawn from `seed`: every parameter is the nominal value plus a normal
    /// deviate of the profile's 1-σ tolerance (relative for gains and ratios).
    pub fn draw(profile: &BoardProfile, seed: u64) -> Self {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        let tol = &profile.tolerances;
        let mut unit = Self::nominal(profile);
        let c = &mut unit.chain;
        let rel = |r: &mut ChaCha8Rng, sigma: f32| 1.0 + f64::from(sigma) * gauss(r);
        let abs = |r: &mut ChaCha8Rng, sigma: f32| f64::from(sigma) * gauss(r);
        for i in 0..3 {
            c.gain_a_per_m_per_v[i] *= rel(&mut r, tol.coil_gain_rel);
            c.phase_rad[i] += abs(&mut r, tol.coil_phase_rad);
            c.offset_v[i] += abs(&mut r, tol.adc_offset_v);
            c.low_range_ratio[i] *= rel(&mut r, tol.low_range_ratio_rel);
            c.low_range_phase_rad[i] += abs(&mut r, tol.low_range_phase_rad);
        }
        let hard = V3::from_fn(|_, _| abs(&mut r, tol.mag_hard_iron_ut));
        let mut soft = M3::identity();
        for i in 0..3 {
            for j in i..3 {
                let e = abs(&mut r, tol.mag_soft_iron);
                soft[(i, j)] += e;
                if i != j {
                    soft[(j, i)] += e;
                }
            }
        }
        unit.mag = MagDistortion {
            hard_iron_ut: hard,
            soft_iron: soft,
        };
        unit
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::board::REFERENCE;

    #[test]
    fn drawn_units_spread_about_the_nominal_by_the_tolerances() {
        let p = REFERENCE;
        let nominal = Unit::nominal(&p);
        let n = 400;
        let (mut gain2, mut phase2, mut off2, mut hard2, mut soft2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut sign_kept = true;
        for seed in 0..n {
            let u = Unit::draw(&p, seed);
            assert_eq!(u, Unit::draw(&p, seed), "seeded");
            for i in 0..3 {
                let g0 = nominal.chain.gain_a_per_m_per_v[i];
                let g = u.chain.gain_a_per_m_per_v[i];
                sign_kept &= g.signum() == g0.signum();
                gain2 += (g / g0 - 1.0).powi(2);
                phase2 += (u.chain.phase_rad[i] - nominal.chain.phase_rad[i]).powi(2);
                off2 += (u.chain.offset_v[i] - nominal.chain.offset_v[i]).powi(2);
                hard2 += u.mag.hard_iron_ut[i].powi(2);
                soft2 += (u.mag.soft_iron[(i, i)] - 1.0).powi(2);
            }
            assert_eq!(u.mag.soft_iron, u.mag.soft_iron.transpose());
        }
        let rms = |s: f64| (s / (3 * n) as f64).sqrt();
        let t = &p.tolerances;
        // 1200 draws each: the sample σ is within ±10 % of the tolerance.
        for (got, want) in [
            (rms(gain2), f64::from(t.coil_gain_rel)),
            (rms(phase2), f64::from(t.coil_phase_rad)),
            (rms(off2), f64::from(t.adc_offset_v)),
            (rms(hard2), f64::from(t.mag_hard_iron_ut)),
            (rms(soft2), f64::from(t.mag_soft_iron)),
        ] {
            assert!((got / want - 1.0).abs() < 0.1, "σ {got} vs {want}");
        }
        assert!(sign_kept, "a 3 % spread never flips a coil");
        assert_ne!(Unit::draw(&p, 1), Unit::draw(&p, 2));
    }
}
