//! Antenna per-coil gain and phase from the bench: pulses of a reference transmitter at
//! known poses (procedure: `docs/antenna-bench-calibration.md`).
//!
//! The pulse DSP, holding some calibration (the board profile's nominal one on a new
//! unit), reports each pulse's three complex amplitudes on their common phase
//! ([`Pulse::amplitude`](crate::frontend::Pulse::amplitude)). With the coils' true
//! field `t_k` at pose `k` known from the jig, the DSP's amplitudes are
//!
//! `a_{k,i} = u_i · t_{k,i} · z_k + noise`,
//!
//! `u_i = (g_held,i / g_i) · e^{j(φ_held,i − φ_i)}` per coil (the held calibration's error)
//! and `z_k` a unit phasor per pulse (the transmitter's free-running carrier phase and the
//! DSP's sign choice). Least squares alternates between the two (each step is closed form:
//! `z_k ∝ Σ_i conj(u_i t_{k,i}) a_{k,i}`, `u_i = Σ_k t_{k,i} conj(z_k) a_{k,i} / Σ_k t_{k,i}²`),
//! from `u = 1`. A common phase of all `u_i` (and a common sign) is not observable — the
//! transmitter's phase is unknown — and is irrelevant to the DSP, which measures the
//! coils against their common phase: coil x's phase and sign are kept as held and the
//! other two are measured relative to it.

use crate::Vec3;
use crate::frontend::{C32, Calibration};

/// Readings (pulses) one fit holds.
pub const MAX_READINGS: usize = 64;
/// Readings needed before a fit is attempted.
pub const MIN_READINGS: usize = 8;
/// Alternating least-squares rounds (from `u = 1` with errors of a few %/°, three rounds
/// already agree to `f32` precision; the rest is margin).
const ROUNDS: usize = 12;
/// Least share of the poses' field energy that each coil must see, and that each pair of
/// coils must see together (`Σ|t_i t_j|` against `Σ|t|²`), so that every gain and every
/// relative phase is measured (the procedure's diagonal poses give 1/3 each).
const MIN_SHARE: f32 = 0.05;

/// Why a bench calibration could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AntennaFitError {
    /// A reading had a non-finite value or a zero field; it was not stored.
    #[error("bench reading NaN, infinite or with a zero field")]
    NonFinite,
    /// [`MAX_READINGS`] readings are already held; the reading was not stored.
    #[error("bench readings full")]
    Full,
    /// Fewer than [`MIN_READINGS`] readings.
    #[error("too few bench readings")]
    TooFewReadings,
    /// The poses leave a coil, or a pair of coils, without enough field.
    #[error("bench poses leave a coil or a pair of coils without field")]
    PoorCoverage,
    /// The held calibration is invalid, or the fit's is (a dead coil: zero amplitude).
    #[error("invalid antenna calibration")]
    InvalidCalibration,
}

/// A bench calibration with its quality figure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AntennaFit {
    /// The held calibration with gains and high-range phases replaced by the measured ones.
    pub calibration: Calibration,
    /// RMS of the readings' misfit relative to their field (noise, pose errors).
    pub residual_rel: f32,
    /// Readings used.
    pub readings: usize,
}

/// One pulse at a known pose.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Reading {
    field: Vec3,
    amplitude: [C32; 3],
}

/// The readings of one bench session, in a fixed array (≈ 2.3 KB).
#[derive(Debug, Clone)]
pub struct AntennaCalibrator {
    held: Calibration,
    readings: [Reading; MAX_READINGS],
    len: usize,
}

impl AntennaCalibrator {
    /// A session whose pulses are measured by a DSP holding `held` (refused if invalid).
    pub fn new(held: Calibration) -> Result<Self, AntennaFitError> {
        if !held.is_valid() {
            return Err(AntennaFitError::InvalidCalibration);
        }
        Ok(Self {
            held,
            readings: [Reading {
                field: Vec3::zeros(),
                amplitude: [C32::ZERO; 3],
            }; MAX_READINGS],
            len: 0,
        })
    }

    /// Readings held.
    pub fn readings(&self) -> usize {
        self.len
    }

    /// Adds one pulse: the coils' true field at the pose (A/m, body frame, from the jig and
    /// the reference transmitter's moment) and the DSP's amplitudes for it.
    pub fn push(&mut self, field: &Vec3, amplitude: &[C32; 3]) -> Result<(), AntennaFitError> {
        if !(field.iter().all(|x| x.is_finite())
            && field.norm_squared() > 0.0
            && amplitude.iter().all(|z| z.is_finite()))
        {
            return Err(AntennaFitError::NonFinite);
        }
        let slot = self
            .readings
            .get_mut(self.len)
            .ok_or(AntennaFitError::Full)?;
        *slot = Reading {
            field: *field,
            amplitude: *amplitude,
        };
        self.len += 1;
        Ok(())
    }

    fn used(&self) -> &[Reading] {
        self.readings.get(..self.len).unwrap_or(&[])
    }

    /// The calibration from the readings so far (they are kept: more may be added).
    pub fn fit(&self) -> Result<AntennaFit, AntennaFitError> {
        let r = self.used();
        if r.len() < MIN_READINGS {
            return Err(AntennaFitError::TooFewReadings);
        }
        // Coverage: every coil, and every pair of coils, sees a share of the field.
        let total: f32 = r.iter().map(|x| x.field.norm_squared()).sum();
        let t2: Vec3 = r.iter().map(|x| x.field.component_mul(&x.field)).sum();
        let pairs: Vec3 = r
            .iter()
            .map(|x| {
                let f = x.field;
                Vec3::new(f.x * f.y, f.x * f.z, f.y * f.z).abs()
            })
            .sum();
        if !t2
            .iter()
            .chain(pairs.iter())
            .all(|s| *s >= MIN_SHARE * total)
        {
            return Err(AntennaFitError::PoorCoverage);
        }
        let t2 = components(&t2);
        let mut u = [C32::new(1.0, 0.0); 3];
        for _ in 0..ROUNDS {
            let mut acc = [C32::ZERO; 3];
            for x in r {
                let z = phase_of(&u, x).conj();
                for ((a, amp), t) in acc.iter_mut().zip(x.amplitude).zip(components(&x.field)) {
                    *a += amp.scale(t) * z;
                }
            }
            for ((ui, a), t) in u.iter_mut().zip(acc).zip(t2) {
                *ui = a.scale(1.0 / t);
            }
        }
        // Coil x's phase and sign are kept as held (see the module docs).
        let ref_rot = C32::cis(-u.first().map_or(0.0, |z| z.arg()));
        let u = u.map(|z| z * ref_rot);
        let mut residual = 0.0f32;
        for x in r {
            let z = phase_of(&u, x);
            for ((ui, amp), t) in u.iter().zip(x.amplitude).zip(components(&x.field)) {
                residual += (amp - ui.scale(t) * z).norm_sqr();
            }
        }
        let residual_rel = libm::sqrtf(residual / total);
        let mut cal = self.held;
        for (((g, ph), ui), (g_held, ph_held)) in cal
            .gain_a_per_m_per_v
            .iter_mut()
            .zip(cal.phase_rad.iter_mut())
            .zip(u)
            .zip(self.held.gain_a_per_m_per_v.iter().zip(self.held.phase_rad))
        {
            let m = ui.abs();
            if !(m.is_finite() && m > 0.0) {
                return Err(AntennaFitError::InvalidCalibration);
            }
            // u = (g_held / g) e^{j(φ_held − φ)}; a phase beyond ±90° is a coil wired the
            // other way than held: flip its gain's sign and take π off its phase.
            let (sign, arg) = if libm::fabsf(ui.arg()) > core::f32::consts::FRAC_PI_2 {
                (-1.0, ui.scale(-1.0).arg())
            } else {
                (1.0, ui.arg())
            };
            *g = sign * g_held / m;
            *ph = ph_held - arg;
        }
        if !cal.is_valid() || !residual_rel.is_finite() {
            return Err(AntennaFitError::InvalidCalibration);
        }
        Ok(AntennaFit {
            calibration: cal,
            residual_rel,
            readings: r.len(),
        })
    }
}

/// A vector's components as an array (iterated beside the per-coil arrays).
fn components(v: &Vec3) -> [f32; 3] {
    [v.x, v.y, v.z]
}

/// The reading's unit phasor `z` given the coils' factors `u`.
fn phase_of(u: &[C32; 3], x: &Reading) -> C32 {
    let mut s = C32::ZERO;
    for ((ui, amp), t) in u.iter().zip(x.amplitude).zip(components(&x.field)) {
        s += ui.scale(t).conj() * amp;
    }
    let m = s.abs();
    if m > 0.0 {
        s.scale(1.0 / m)
    } else {
        C32::new(1.0, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Rng(u64);
    impl Rng {
        fn uniform(&mut self) -> f32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            ((self.0 >> 40) as f32 + 0.5) / (1u64 << 24) as f32
        }
        fn normal(&mut self) -> f32 {
            let (u, v) = (self.uniform(), self.uniform());
            libm::sqrtf(-2.0 * libm::logf(u)) * libm::cosf(2.0 * core::f32::consts::PI * v)
        }
    }

    /// The procedure's poses: the reference field along the four body diagonals.
    const POSES: [[f32; 3]; 4] = [
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ];

    /// The DSP's amplitudes of a pulse of true field `t` for a unit whose actual chain is
    /// `truth` while the DSP holds `held`, with relative noise `noise` per component.
    fn amplitudes(
        truth: &Calibration,
        held: &Calibration,
        t: &Vec3,
        noise: f32,
        rng: &mut Rng,
    ) -> [C32; 3] {
        let z = C32::cis(2.0 * core::f32::consts::PI * rng.uniform());
        let scale = t.norm();
        [0, 1, 2].map(|i| {
            let u = C32::cis(held.phase_rad[i] - truth.phase_rad[i])
                .scale(held.gain_a_per_m_per_v[i] / truth.gain_a_per_m_per_v[i]);
            u.scale(t[i]) * z + C32::new(rng.normal(), rng.normal()).scale(noise * scale)
        })
    }

    fn drawn(held: &Calibration, rng: &mut Rng) -> Calibration {
        let mut c = *held;
        for i in 0..3 {
            c.gain_a_per_m_per_v[i] *= 1.0 + 0.03 * rng.normal();
            c.phase_rad[i] += 0.052 * rng.normal();
        }
        c
    }

    fn nominal() -> Calibration {
        crate::board::REFERENCE.analog.nominal
    }

    /// Relative phases (coil y, z against x), the observable part.
    fn rel_phase(c: &Calibration, i: usize) -> f32 {
        c.phase_rad[i] - c.phase_rad[0]
    }

    #[test]
    fn bench_poses_recover_drawn_gains_and_relative_phases() {
        let held = nominal();
        let mut rng = Rng(0xBE9C_0001);
        let h = 1.6e-3; // the reference transmitter 1 m away on its axis
        // 1 % of |t| per real component (complex noise): each coil sees t_i² = |t|²/3, so
        // over N readings a gain is measured to σ = 1 %·√3/√N and a coil's phase to the
        // same σ in rad.
        let noise = 0.01;
        let n = POSES.len() * 10;
        let sigma = noise * libm::sqrtf(3.0 / n as f32);
        let (mut sum_g2, mut sum_p2, mut count) = (0.0f32, 0.0f32, 0);
        for unit in 0..20 {
            let truth = drawn(&held, &mut rng);
            let mut cal = AntennaCalibrator::new(held).unwrap();
            for p in POSES {
                let t = Vec3::from(p).normalize() * h;
                for _ in 0..10 {
                    let a = amplitudes(&truth, &held, &t, noise, &mut rng);
                    cal.push(&t, &a).unwrap();
                }
            }
            let fit = cal.fit().unwrap();
            assert_eq!(fit.readings, n);
            let c = fit.calibration;
            for i in 0..3 {
                let g = c.gain_a_per_m_per_v[i] / truth.gain_a_per_m_per_v[i] - 1.0;
                assert!(
                    libm::fabsf(g) < 4.5 * sigma,
                    "unit {unit} coil {i}: gain error {g}"
                );
                sum_g2 += g * g;
                if i > 0 {
                    // A relative phase is the difference of two coils' errors: σ·√2.
                    let dp = rel_phase(&c, i) - rel_phase(&truth, i);
                    assert!(
                        libm::fabsf(dp) < 4.5 * sigma * core::f32::consts::SQRT_2,
                        "unit {unit} coil {i}: phase error {}°",
                        dp.to_degrees()
                    );
                    sum_p2 += dp * dp / 2.0;
                }
                count += 1;
            }
            // Residual: √6 · 1 % less the fitted degrees of freedom.
            assert!(
                fit.residual_rel > 0.015 && fit.residual_rel < 0.03,
                "residual {}",
                fit.residual_rel
            );
            assert_eq!(c.offset_v, held.offset_v);
        }
        // The errors are the noise's, neither larger nor suspiciously smaller.
        let rms_g = libm::sqrtf(sum_g2 / count as f32);
        let rms_p = libm::sqrtf(sum_p2 / (count as f32 * 2.0 / 3.0));
        for rms in [rms_g, rms_p] {
            assert!(
                rms > 0.6 * sigma && rms < 1.4 * sigma,
                "rms {rms} vs σ {sigma}"
            );
        }
    }

    #[test]
    fn noise_free_readings_are_fitted_exactly_and_a_reversed_coil_is_found() {
        let held = nominal();
        let mut truth = drawn(&held, &mut Rng(5));
        // Coil z wired the other way than the held calibration says.
        truth.gain_a_per_m_per_v[2] = -truth.gain_a_per_m_per_v[2];
        let mut rng = Rng(9);
        let mut cal = AntennaCalibrator::new(held).unwrap();
        for p in POSES.iter().cycle().take(8) {
            let t = Vec3::from(*p) * 1e-3;
            cal.push(&t, &amplitudes(&truth, &held, &t, 0.0, &mut rng))
                .unwrap();
        }
        let c = cal.fit().unwrap().calibration;
        for i in 0..3 {
            let g = c.gain_a_per_m_per_v[i] / truth.gain_a_per_m_per_v[i] - 1.0;
            assert!(libm::fabsf(g) < 1e-4, "coil {i}: {g}");
            let dp = rel_phase(&c, i) - rel_phase(&truth, i);
            assert!(libm::fabsf(dp) < 1e-4, "coil {i}: {dp}");
        }
    }

    #[test]
    fn bad_readings_and_poor_poses_are_refused() {
        let held = nominal();
        let mut cal = AntennaCalibrator::new(held).unwrap();
        let a = [C32::new(1e-3, 0.0); 3];
        assert_eq!(
            cal.push(&Vec3::new(f32::NAN, 0.0, 0.0), &a),
            Err(AntennaFitError::NonFinite)
        );
        assert_eq!(
            cal.push(&Vec3::zeros(), &a),
            Err(AntennaFitError::NonFinite)
        );
        let bad = [C32::new(f32::INFINITY, 0.0), C32::ZERO, C32::ZERO];
        assert_eq!(
            cal.push(&Vec3::new(1e-3, 0.0, 0.0), &bad),
            Err(AntennaFitError::NonFinite)
        );
        assert_eq!(cal.readings(), 0);
        assert_eq!(cal.fit(), Err(AntennaFitError::TooFewReadings));
        // Field along coil x only: y and z are never excited.
        for _ in 0..MAX_READINGS {
            cal.push(&Vec3::new(1e-3, 0.0, 0.0), &a).unwrap();
        }
        assert_eq!(
            cal.push(&Vec3::new(1e-3, 0.0, 0.0), &a),
            Err(AntennaFitError::Full)
        );
        assert_eq!(cal.fit(), Err(AntennaFitError::PoorCoverage));
        let mut invalid = held;
        invalid.gain_a_per_m_per_v[1] = 0.0;
        assert_eq!(
            AntennaCalibrator::new(invalid).err(),
            Some(AntennaFitError::InvalidCalibration)
        );
    }
}
