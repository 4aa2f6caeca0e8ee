//! Per-axis calibration from ADC volts to field strength in A/m.

/// Per-coil calibration of the analog chain, mapping each channel's demodulated IF
/// amplitude (V at the ADC input, whatever the PGA setting) to the field component along
/// that coil's axis (A/m, body frame).
///
/// A unit's values come from its bench calibration; before it, from the board profile's
/// nominal values ([`crate::board::AnalogProfile::nominal`]). A negative gain flips a coil
/// wound (or wired) the other way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Field per IF amplitude in the IF amplifier's high (sensitive) range, A/m per V, for
    /// coils x, y, z.
    pub gain_a_per_m_per_v: [f32; 3],
    /// DC offset of each ADC channel (V), subtracted before mixing. Over a whole number of
    /// IF cycles the mixer already rejects DC; removing it keeps the saturation margin
    /// and the off-nominal configurations honest.
    pub offset_v: [f32; 3],
    /// Phase lag of each channel's analog chain at the IF in the high range (rad), removed
    /// from the demodulated phasors so the three coils are compared in phase.
    pub phase_rad: [f32; 3],
    /// How many times more field per volt the IF amplifier's low range gives than its high
    /// range, per coil (nominally the switch's attenuation, see
    /// [`crate::board::AnalogProfile`]).
    pub low_range_ratio: [f32; 3],
    /// Extra phase lag of each channel in the low range (rad).
    pub low_range_phase_rad: [f32; 3],
}

impl Default for Calibration {
    /// Unit gain (1 A/m per V), no offset, no phase error, both ranges alike: for tests of
    /// the DSP alone; a board uses its profile's or its bench calibration.
    fn default() -> Self {
        Calibration {
            gain_a_per_m_per_v: [1.0; 3],
            offset_v: [0.0; 3],
            phase_rad: [0.0; 3],
            low_range_ratio: [1.0; 3],
            low_range_phase_rad: [0.0; 3],
        }
    }
}

impl Calibration {
    /// Whether every value is finite, every gain non-zero and every range ratio positive.
    pub fn is_valid(&self) -> bool {
        let finite = |a: &[f32; 3]| a.iter().all(|x| x.is_finite());
        self.gain_a_per_m_per_v
            .iter()
            .all(|g| g.is_finite() && *g != 0.0)
            && finite(&self.offset_v)
            && finite(&self.phase_rad)
            && self
                .low_range_ratio
                .iter()
                .all(|r| r.is_finite() && *r > 0.0)
            && finite(&self.low_range_phase_rad)
    }
}
