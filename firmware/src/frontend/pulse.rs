//! What the front end reports for each received pulse.

use super::C32;
use crate::Vec3;

/// The outcome of one pulse: a field vector, or why none is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PulseMeasurement {
    /// The field strength vector in the body frame (A/m). Relative signs of the three
    /// components are measured; the overall sign is not (it is normalised so that the
    /// largest component is positive).
    Field(Vec3),
    /// The pulse does not fit a single carrier with a constant envelope and a common
    /// phase on the three coils: most likely two transmitters overlapping. No vector is
    /// given rather than a wrong one.
    Overlap,
    /// At least one coil clipped during the pulse: the amplitudes are not trustworthy.
    Saturated,
    /// The pulse (or a continuous interferer) outlasted the front end's buffer.
    Truncated,
}

/// One detected pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    /// Time of the pulse centre, seconds since the first sample (f32: 0.25 ms
    /// resolution after an hour).
    pub t_s: f32,
    /// Index of the pulse's first sample since the first sample.
    pub start_sample: u64,
    /// Pulse duration (s), as found by the edge estimate.
    pub duration_s: f32,
    /// Carrier offset from the nominal IF (Hz); positive = carrier above nominal.
    pub carrier_offset_hz: f32,
    /// Standard deviation of each field component due to the noise floor (A/m).
    pub sigma_a_per_m: f32,
    /// Energy left after fitting one carrier with a constant envelope, minus the noise
    /// expected, as a fraction of the fitted signal energy (≈0 for a clean pulse).
    pub residual_fraction: f32,
    /// Energy in quadrature to the common phase of the coils as a fraction of the
    /// in-phase energy (≈0 for one transmitter).
    pub quadrature_fraction: f32,
    /// The three coils' calibrated complex amplitudes (A/m) rotated onto their common
    /// phase, with the sign of the reported vector: the real parts are the field vector,
    /// the imaginary parts what is in quadrature (a channel's phase error shows there).
    /// Given for overlapped and saturated pulses too (the bench calibration reads it);
    /// zero for truncated ones.
    pub amplitude: [C32; 3],
    /// Transmitter the pulse was attributed to by its period and carrier, if any.
    pub src: Option<u8>,
    /// The field vector or the reason it is withheld.
    pub measurement: PulseMeasurement,
}

impl Pulse {
    /// The field vector, when the pulse gave one.
    pub fn field(&self) -> Option<Vec3> {
        match self.measurement {
            PulseMeasurement::Field(h) => Some(h),
            _ => None,
        }
    }
}
