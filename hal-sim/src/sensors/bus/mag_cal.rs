//! The magnetometer's calibration on an emulated unit: the rotation in place of the
//! board's menu procedure (`firmware::board::procedure`, "TURN IN ALL DIRECTIONS"), each
//! reading through the unit's own hard- and soft-iron ([`MagDistortion`]) with the chip's
//! noise and resolution, fitted by the firmware's [`MagCalibrator`] with the region's
//! field magnitude as its scale.
use super::unit::MagDistortion;
use crate::world::physics::{M3, V3};
use anyhow::{Result, anyhow};
use firmware::Vec3;
use firmware::calibration::mag::{MagCalibrator, MagFit};
use firmware::drivers::imu::MAG_LSB_UT;
use nalgebra::{Quaternion, UnitQuaternion};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Readings of the rotation: ≈ 30 s of turning at the magnetometer's 10 Hz.
pub const TURN_SAMPLES: usize = 300;

/// The fit of a rotation in place of the unit whose magnetometer reads through `mag`, in
/// the earth field `earth_ut` (µT, world frame), each component with white noise of σ
/// `noise_ut` (µT) and the chip's resolution ([`MAG_LSB_UT`]). The orientations are drawn
/// uniformly over all attitudes from `seed` (the rescuer turns the receiver upside down
/// and on its sides, as the display asks).
pub fn mag_calibrate(
    mag: &MagDistortion,
    earth_ut: &V3,
    noise_ut: f64,
    seed: u64,
) -> Result<MagFit> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut gauss = || -> f64 { StandardNormal.sample(&mut r) };
    let mut cal = MagCalibrator::new(earth_ut.norm() as f32)
        .map_err(|e| anyhow!("magnetometer calibration: {e}"))?;
    let lsb = f64::from(MAG_LSB_UT);
    for _ in 0..TURN_SAMPLES {
        // A uniform random rotation: a normalized 4-D Gaussian quaternion.
        let q =
            UnitQuaternion::from_quaternion(Quaternion::new(gauss(), gauss(), gauss(), gauss()));
        let body: M3 = q.to_rotation_matrix().into_inner();
        let m = mag.apply(&(body.transpose() * earth_ut));
        let raw = m.map(|v| ((v + noise_ut * gauss()) / lsb).round() * lsb);
        cal.push(&Vec3::new(raw.x as f32, raw.y as f32, raw.z as f32))
            .map_err(|e| anyhow!("magnetometer calibration: {e}"))?;
    }
    cal.fit()
        .map_err(|e| anyhow!("magnetometer calibration: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::bus::unit::Unit;
    use crate::world::earth_field_ut;
    use firmware::board::REFERENCE;

    /// The fit recovers each drawn unit's hard- and soft-iron: the corrected reading
    /// `S (raw − b)` equals the field at the chip, `S D = I`, far within the spread the
    /// units are drawn with (`UnitTolerances`), and the residual is the chip's noise.
    #[test]
    fn the_rotation_in_place_recovers_each_units_hard_and_soft_iron() {
        let tol = REFERENCE.tolerances;
        let earth = V3::from(earth_field_ut(48.0, 63.0));
        let noise = 0.3;
        let (mut worst_b, mut worst_s, mut drawn_b, mut drawn_s) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for seed in 0..20u64 {
            let unit = Unit::draw(&REFERENCE, seed);
            let fit = mag_calibrate(&unit.mag, &earth, noise, seed).unwrap();
            let c = fit.calibration;
            let b = V3::new(
                f64::from(c.hard_iron.x),
                f64::from(c.hard_iron.y),
                f64::from(c.hard_iron.z),
            );
            let s = M3::from_fn(|i, j| f64::from(c.soft_iron[(i, j)]));
            worst_b = worst_b.max((b - unit.mag.hard_iron_ut).amax());
            worst_s = worst_s.max((s * unit.mag.soft_iron - M3::identity()).amax());
            drawn_b = drawn_b.max(unit.mag.hard_iron_ut.amax());
            drawn_s = drawn_s.max((unit.mag.soft_iron - M3::identity()).amax());
            // The readings' noise and resolution (√(0.3² + 0.15²/12) ≈ 0.30 µT per axis)
            // is what is left of |m| − B.
            assert!(
                fit.residual_rms_ut < 0.5,
                "seed {seed}: residual {} µT",
                fit.residual_rms_ut
            );
        }
        println!(
            "20 units: hard iron drawn up to {drawn_b:.1} µT, fitted within {worst_b:.3} µT; \
             soft iron drawn up to {drawn_s:.4}, S·D − I within {worst_s:.4}"
        );
        // A tenth of the 1-σ spread the units are drawn with (the soft iron's error is the
        // noise's: 0.3 µT on 48 µT over 300 readings, ≈ 6e-4 per element).
        assert!(
            worst_b <= 0.1 * f64::from(tol.mag_hard_iron_ut),
            "{worst_b}"
        );
        assert!(worst_s <= 0.1 * f64::from(tol.mag_soft_iron), "{worst_s}");
        // The draws are not trivially small.
        assert!(drawn_b >= f64::from(tol.mag_hard_iron_ut));
        assert!(drawn_s >= f64::from(tol.mag_soft_iron));
    }
}
