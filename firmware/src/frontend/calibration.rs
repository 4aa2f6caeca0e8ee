//! Per-axis calibration from ADC volts to field strength in A/m.

/// Per-coil calibration of the analog chain, mapping each channel's demodulated IF
/// amplitude (V) to the field component along that coil's axis (A/m, body frame).
///
/// Measured on the bench with a calibrated Helmholtz coil; a negative gain flips a coil
/// wound (or wired) the other way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Field per IF amplitude, A/m per V, for coils x, y, z.
    pub gain_a_per_m_per_v: [f32; 3],
    /// DC offset of each ADC channel (V), subtracted before mixing. Over a whole number of
    /// IF cycles the mixer already rejects DC; removing it keeps the saturation margin
    /// and the off-nominal configurations honest.
    pub offset_v: [f32; 3],
    /// Phase lag of each channel's analog chain at the IF (rad), removed from the
    /// demodulated phasors so the three coils are compared in phase.
    pub phase_rad: [f32; 3],
}

impl Default for Calibration {
    /// Unit gain (1 A/m per V), no offset, no phase error.
    fn default() -> Self {
        Calibration {
            gain_a_per_m_per_v: [1.0; 3],
            offset_v: [0.0; 3],
            phase_rad: [0.0; 3],
        }
    }
}

impl Calibration {
    /// Whether every value is finite and every gain non-zero.
    pub fn is_valid(&self) -> bool {
        self.gain_a_per_m_per_v
            .iter()
            .all(|g| g.is_finite() && *g != 0.0)
            && self.offset_v.iter().all(|x| x.is_finite())
            && self.phase_rad.iter().all(|x| x.is_finite())
    }
}
