//! Magnetometer hard- and soft-iron calibration from a rotation in place.
//!
//! The unit's own iron distorts what the magnetometer reads: `raw = D m + b` for the field
//! `m` at the chip, with `b` the hard-iron offset and `D` a symmetric soft-iron matrix near
//! the identity. Turned through many orientations in one place (the earth field constant),
//! the readings lie on the ellipsoid `(x − b)ᵀ A (x − b) = B²` with `A = D⁻²` and `B` the
//! field's magnitude. The fit is the linear least-squares quadric
//! `xᵀ M x + 2 vᵀ x = 1` (9 unknowns, readings scaled by `B` so the normal equations stay
//! well conditioned in `f32`), accumulated sample by sample in a 9×9 normal matrix (no
//! buffer of readings), then `b = −M⁻¹ v`, `A = M B² / (1 + bᵀ M b)` and the correction
//! `S = A^{1/2}` (the symmetric root, so `S = D⁻¹` for a symmetric `D`):
//! `m = S (raw − b)` ([`MagCalibration`]).
//!
//! The field's magnitude is not observable from a rotation (a uniform scale of `D` looks
//! like a different field); the fit takes it from the caller (the configured earth field),
//! which is also what the attitude filter's magnitude gate compares with.

use crate::motion::MagCalibration;
use crate::{Mat3, Vec3};
use nalgebra::{Cholesky, SMatrix, SVector, SymmetricEigen};

/// Readings needed before a fit is attempted.
pub const MIN_SAMPLES: u32 = 50;

/// Smallest share of `B²` that the calibrated readings' spread must have along every
/// axis: a sphere covered uniformly gives 1/3, a single horizontal turn at constant tilt
/// gives ≈ 0 along the vertical. Below it the orientations do not constrain the
/// ellipsoid in some direction.
pub const MIN_SPREAD: f32 = 0.05;

/// Largest soft-iron correction accepted: eigenvalues of `S` within `[1/2, 2]`; a unit
/// outside is broken or sits next to a large piece of steel.
const MAX_SOFT_IRON_RATIO: f32 = 2.0;

/// Why a magnetometer calibration could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MagFitError {
    /// A reading or the field magnitude was NaN, infinite or (the magnitude) not positive;
    /// nothing was accumulated.
    #[error("magnetometer reading or field magnitude NaN, infinite or not positive")]
    NonFinite,
    /// Fewer than [`MIN_SAMPLES`] readings.
    #[error("too few magnetometer readings for a calibration")]
    TooFewSamples,
    /// The orientations do not span the sphere: turn the unit through more attitudes
    /// (upside down and on its sides too).
    #[error("orientations do not span the sphere: turn the unit through more attitudes")]
    PoorCoverage,
    /// The readings do not lie on an ellipsoid of plausible shape (a magnetic disturbance
    /// during the rotation, or a broken sensor).
    #[error("magnetometer readings do not fit a plausible ellipsoid")]
    NotAnEllipsoid,
}

/// A calibration with its quality figures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagFit {
    /// The calibration to apply to raw readings.
    pub calibration: MagCalibration,
    /// RMS of `|m| − B` over the readings after calibration, µT (sensor noise plus any
    /// disturbance during the rotation).
    pub residual_rms_ut: f32,
    /// Smallest spread of the calibrated readings along any axis, as a share of `B²`
    /// (1/3 for a uniformly covered sphere; see [`MIN_SPREAD`]).
    pub spread: f32,
    /// Readings used.
    pub samples: u32,
}

type Mat9 = SMatrix<f32, 9, 9>;
type Vec9 = SVector<f32, 9>;

/// The accumulator of a rotation in place: feed raw readings with [`MagCalibrator::push`],
/// then [`MagCalibrator::fit`]. 460 bytes, no buffer of readings.
#[derive(Debug, Clone)]
pub struct MagCalibrator {
    /// Field magnitude expected, µT (scale of the fit's coordinates).
    field_ut: f32,
    /// Σ φ φᵀ over the scaled readings' monomials φ.
    normal: Mat9,
    /// Σ φ.
    rhs: Vec9,
    /// Σ y of the scaled readings (their spread after calibration).
    sum: Vec3,
    /// Σ y yᵀ of the scaled readings.
    scatter: Mat3,
    /// Readings accumulated.
    count: u32,
}

/// Monomials of the quadric `xᵀ M x + 2 vᵀ x` at `y`.
fn monomials(y: &Vec3) -> Vec9 {
    Vec9::from([
        y.x * y.x,
        y.y * y.y,
        y.z * y.z,
        2.0 * y.x * y.y,
        2.0 * y.x * y.z,
        2.0 * y.y * y.z,
        2.0 * y.x,
        2.0 * y.y,
        2.0 * y.z,
    ])
}

impl MagCalibrator {
    /// An empty accumulator for an earth field of magnitude `field_ut` (µT, the configured
    /// local field). A non-finite or non-positive magnitude is refused.
    pub fn new(field_ut: f32) -> Result<Self, MagFitError> {
        if !(field_ut.is_finite() && field_ut > 0.0) {
            return Err(MagFitError::NonFinite);
        }
        Ok(Self {
            field_ut,
            normal: Mat9::zeros(),
            rhs: Vec9::zeros(),
            sum: Vec3::zeros(),
            scatter: Mat3::zeros(),
            count: 0,
        })
    }

    /// Readings accumulated so far.
    pub fn samples(&self) -> u32 {
        self.count
    }

    /// Adds one raw reading (µT, body frame). A non-finite reading is refused and not
    /// accumulated.
    pub fn push(&mut self, raw: &Vec3) -> Result<(), MagFitError> {
        if !raw.iter().all(|v| v.is_finite()) {
            return Err(MagFitError::NonFinite);
        }
        let y = raw / self.field_ut;
        let phi = monomials(&y);
        self.normal += phi * phi.transpose();
        self.rhs += phi;
        self.sum += y;
        self.scatter += y * y.transpose();
        self.count = self.count.saturating_add(1);
        Ok(())
    }

    /// The calibration from the readings so far (the accumulator is left as it is, so more
    /// readings may still be added).
    pub fn fit(&self) -> Result<MagFit, MagFitError> {
        if self.count < MIN_SAMPLES {
            return Err(MagFitError::TooFewSamples);
        }
        let p = Cholesky::new(self.normal)
            .ok_or(MagFitError::PoorCoverage)?
            .solve(&self.rhs);
        let [a, b, c, d, e, f, g, h, i]: [f32; 9] = p.into();
        if !p.iter().all(|x| x.is_finite()) {
            return Err(MagFitError::PoorCoverage);
        }
        let m = Mat3::new(a, d, e, d, b, f, e, f, c);
        let v = Vec3::new(g, h, i);
        let centre = -(m.try_inverse().ok_or(MagFitError::NotAnEllipsoid)? * v);
        let k = 1.0 + centre.dot(&(m * centre));
        if !(k.is_finite() && k > 0.0) {
            return Err(MagFitError::NotAnEllipsoid);
        }
        // In scaled units the field's magnitude is 1: A = M / k.
        let eig = SymmetricEigen::new(m / k);
        let lo = 1.0 / (MAX_SOFT_IRON_RATIO * MAX_SOFT_IRON_RATIO);
        let hi = MAX_SOFT_IRON_RATIO * MAX_SOFT_IRON_RATIO;
        if !eig
            .eigenvalues
            .iter()
            .all(|l| l.is_finite() && *l >= lo && *l <= hi)
        {
            return Err(MagFitError::NotAnEllipsoid);
        }
        let root = eig.eigenvalues.map(libm::sqrtf);
        let s = eig.eigenvectors * Mat3::from_diagonal(&root) * eig.eigenvectors.transpose();
        // Spread of the calibrated readings S (y − c): S Cov(y) Sᵀ, with Cov(y) from the
        // running sums.
        let n = self.count as f32;
        let mean = self.sum / n;
        let cov = self.scatter / n - mean * mean.transpose();
        let cal_cov = s * cov * s.transpose();
        let spread = SymmetricEigen::new(cal_cov)
            .eigenvalues
            .iter()
            .fold(f32::INFINITY, |m, l| m.min(*l));
        if !(spread.is_finite() && spread >= MIN_SPREAD) {
            return Err(MagFitError::PoorCoverage);
        }
        // Residual of the quadric: with q(y) = φᵀp − 1 = k(|S(y − c)|² − 1), Σ q² follows
        // from the accumulated sums; |m| − B ≈ B·q / (2k) near the sphere.
        let q2 = p.dot(&(self.normal * p)) - 2.0 * p.dot(&self.rhs) + n;
        let residual_rms_ut = self.field_ut * libm::sqrtf(q2.max(0.0) / n) / (2.0 * k);
        Ok(MagFit {
            calibration: MagCalibration {
                hard_iron: centre * self.field_ut,
                soft_iron: s,
            },
            residual_rms_ut,
            spread,
            samples: self.count,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rotation_from_rpy;

    /// A small deterministic generator (xorshift) with Box–Muller normals.
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

    const EARTH: [f32; 3] = [21.79, 0.0, -42.77];

    /// A unit's distortion: hard iron up to tens of µT, soft iron a few % (like the
    /// board profile's tolerances), drawn from `rng`.
    fn distortion(rng: &mut Rng) -> (Vec3, Mat3) {
        let b = Vec3::new(rng.normal(), rng.normal(), rng.normal()) * 10.0;
        let mut d = Mat3::identity();
        for i in 0..3 {
            for j in i..3 {
                let e = 0.03 * rng.normal();
                d[(i, j)] += e;
                if i != j {
                    d[(j, i)] += e;
                }
            }
        }
        (b, d)
    }

    /// Readings of a hand-held rotation in place: yaw swept through two turns while the
    /// unit is rolled and pitched through ±180° / ±80°, with `noise` µT per axis.
    fn rotate(cal: &mut MagCalibrator, b: &Vec3, d: &Mat3, noise: f32, n: usize, rng: &mut Rng) {
        let earth = Vec3::from(EARTH);
        for k in 0..n {
            let s = k as f32 / n as f32;
            let tau = 2.0 * core::f32::consts::PI;
            let rpy = Vec3::new(
                core::f32::consts::PI * libm::sinf(3.0 * tau * s),
                1.4 * libm::sinf(5.0 * tau * s + 0.3),
                2.0 * tau * s,
            );
            let r = rotation_from_rpy(&rpy);
            let m = r.transpose() * earth;
            let n3 = Vec3::new(rng.normal(), rng.normal(), rng.normal()) * noise;
            let raw = d * m + b + n3;
            assert_eq!(cal.push(&raw), Ok(()));
        }
    }

    #[test]
    fn rotation_in_place_recovers_drawn_hard_and_soft_iron() {
        let field = Vec3::from(EARTH).norm();
        let mut rng = Rng(0x5EED_0001);
        let (mut worst_hard, mut worst_soft, mut worst_heading) = (0.0f32, 0.0f32, 0.0f32);
        for unit in 0..20 {
            let (b, d) = distortion(&mut rng);
            let mut cal = MagCalibrator::new(field).unwrap();
            // 0.3 µT noise: the LSM303AGR's at 100 Hz; 20 s of turning.
            rotate(&mut cal, &b, &d, 0.3, 2000, &mut rng);
            let fit = cal.fit().unwrap();
            let c = fit.calibration;
            let hard_err = (c.hard_iron - b).norm();
            let soft_err = (c.soft_iron * d - Mat3::identity()).abs().max();
            worst_hard = worst_hard.max(hard_err);
            worst_soft = worst_soft.max(soft_err);
            assert!(hard_err < 0.2, "unit {unit}: hard-iron error {hard_err} µT");
            assert!(soft_err < 0.005, "unit {unit}: S·D − I up to {soft_err}");
            assert!(
                (fit.residual_rms_ut - 0.3).abs() < 0.1,
                "residual {} µT",
                fit.residual_rms_ut
            );
            // The figure-of-eight tumble covers the sphere less evenly than the uniform 1/3.
            assert!(fit.spread > 2.0 * MIN_SPREAD, "spread {}", fit.spread);
            // The calibrated field's heading error (what the attitude filter sees): under
            // 0.5° for any attitude.
            let earth = Vec3::from(EARTH);
            for yaw in [0.0f32, 1.0, 2.0, 3.0, 4.0, 5.0] {
                let r = rotation_from_rpy(&Vec3::new(0.3, -0.2, yaw));
                let m = r.transpose() * earth;
                let got = c.apply(&(d * m + b));
                let ang = libm::acosf((got.dot(&m) / (got.norm() * m.norm())).min(1.0));
                worst_heading = worst_heading.max(ang.to_degrees());
                assert!(ang.to_degrees() < 0.5, "unit {unit}: {}°", ang.to_degrees());
            }
        }
        std::println!(
            "20 units: worst hard-iron error {worst_hard:.3} µT, worst |S·D − I| {worst_soft:.4}, \
             worst field direction error {worst_heading:.3}°"
        );
    }

    #[test]
    fn a_flat_turn_is_refused_as_poor_coverage() {
        let field = Vec3::from(EARTH).norm();
        let mut rng = Rng(7);
        let (b, d) = distortion(&mut rng);
        let mut cal = MagCalibrator::new(field).unwrap();
        let earth = Vec3::from(EARTH);
        // Turned only about the vertical, held level: a circle, not an ellipsoid.
        for k in 0..500 {
            let r = rotation_from_rpy(&Vec3::new(0.0, 0.0, k as f32 * 0.0251));
            let n3 = Vec3::new(rng.normal(), rng.normal(), rng.normal()) * 0.3;
            cal.push(&(d * (r.transpose() * earth) + b + n3)).unwrap();
        }
        assert!(matches!(
            cal.fit(),
            Err(MagFitError::PoorCoverage | MagFitError::NotAnEllipsoid)
        ));
    }

    #[test]
    fn bad_input_is_refused_and_leaves_the_state_intact() {
        assert_eq!(
            MagCalibrator::new(f32::NAN).err(),
            Some(MagFitError::NonFinite)
        );
        assert_eq!(MagCalibrator::new(0.0).err(), Some(MagFitError::NonFinite));
        let mut cal = MagCalibrator::new(48.0).unwrap();
        assert_eq!(cal.fit(), Err(MagFitError::TooFewSamples));
        let mut rng = Rng(3);
        let (b, d) = distortion(&mut rng);
        rotate(&mut cal, &b, &d, 0.3, 400, &mut rng);
        let before = cal.fit().unwrap();
        assert_eq!(
            cal.push(&Vec3::new(f32::NAN, 0.0, 1.0)),
            Err(MagFitError::NonFinite)
        );
        assert_eq!(
            cal.push(&Vec3::new(f32::INFINITY, 0.0, 1.0)),
            Err(MagFitError::NonFinite)
        );
        assert_eq!(cal.samples(), 400);
        assert_eq!(cal.fit().unwrap(), before);
        // All readings at one point: no ellipsoid.
        let mut flat = MagCalibrator::new(48.0).unwrap();
        for _ in 0..100 {
            flat.push(&Vec3::new(20.0, 1.0, -40.0)).unwrap();
        }
        assert!(flat.fit().is_err());
    }
}
