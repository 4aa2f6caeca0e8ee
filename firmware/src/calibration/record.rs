//! The calibration record a unit keeps in flash: what its bench and field calibrations
//! found, versioned and CRC-protected, so a unit that boots with a missing or corrupt
//! record falls back to the board profile's nominal values instead of bad ones.
//!
//! Layout (little-endian, [`RECORD_LEN`] bytes):
//!
//! | bytes | content |
//! |---|---|
//! | 0–3 | magic [`RECORD_MAGIC`] |
//! | 4–5 | layout version [`RECORD_VERSION`] |
//! | 6–7 | flags: bit 0 antenna, bit 1 magnetometer, bit 2 step length present |
//! | 8–67 | antenna: 15 `f32` — gain ×3 (A/m per V), offset ×3 (V), phase ×3 (rad), low-range ratio ×3, low-range phase ×3 (rad) |
//! | 68–79 | magnetometer hard iron ×3 (µT) |
//! | 80–115 | magnetometer soft iron, 3×3 row-major |
//! | 116–119 | step length (m) |
//! | 120–123 | reserved, 0 |
//! | 124–127 | CRC-32 (IEEE 802.3, reflected 0xEDB88320, init and final xor 0xFFFFFFFF) of bytes 0–123 |
//!
//! Absent parts are written as zeros. A new layout gets a new version; a reader refuses
//! versions it does not know.

use crate::frontend::Calibration;
use crate::motion::MagCalibration;
use crate::{Mat3, Vec3};

/// Bytes of an encoded record.
pub const RECORD_LEN: usize = 128;
/// First four bytes of a record ("ARCR": avalanche receiver calibration record).
pub const RECORD_MAGIC: [u8; 4] = *b"ARCR";
/// Layout version written by this firmware.
pub const RECORD_VERSION: u16 = 1;

const FLAG_ANTENNA: u16 = 1;
const FLAG_MAG: u16 = 1 << 1;
const FLAG_STEP: u16 = 1 << 2;
const CRC_AT: usize = RECORD_LEN - 4;

/// Why stored bytes were not accepted as a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// Fewer than [`RECORD_LEN`] bytes.
    #[error("calibration record too short")]
    Length,
    /// Every byte is 0xFF: erased flash, the unit was never calibrated.
    #[error("no calibration record (erased flash)")]
    Erased,
    /// Not a calibration record.
    #[error("not a calibration record")]
    Magic,
    /// A layout version this firmware does not read.
    #[error("calibration record layout version {0} not supported")]
    Version(u16),
    /// The CRC does not match: the record is corrupt.
    #[error("calibration record CRC mismatch")]
    Crc,
    /// A stored value is not a valid calibration (non-finite, zero gain, singular matrix,
    /// non-positive step length), or an unknown flag is set.
    #[error("calibration record holds an invalid value")]
    Invalid,
}

/// What a unit knows about itself beyond the board profile. `None`: not calibrated yet
/// (the profile's nominal values or the factory default apply).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationRecord {
    /// The antenna's per-coil calibration from the bench.
    pub antenna: Option<Calibration>,
    /// The magnetometer's hard- and soft-iron calibration from a rotation in place.
    pub mag: Option<MagCalibration>,
    /// The user's step length from the calibration walk, m.
    pub step_length_m: Option<f32>,
}

/// CRC-32 (IEEE 802.3) of `bytes`, bitwise (no table: it runs once at boot and once per
/// save).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Sequential little-endian writer into a record buffer.
struct Writer<'a> {
    buf: &'a mut [u8; RECORD_LEN],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        if let Some(dst) = self.buf.get_mut(self.at..self.at + b.len()) {
            dst.copy_from_slice(b);
        }
        self.at += b.len();
    }
    fn f32s(&mut self, xs: &[f32]) {
        for x in xs {
            self.bytes(&x.to_le_bytes());
        }
    }
}

/// Sequential little-endian reader of a record buffer.
struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.buf.get(self.at..self.at + N) {
            out.copy_from_slice(src);
        }
        self.at += N;
        out
    }
    fn f32s<const N: usize>(&mut self) -> [f32; N] {
        let mut out = [0.0f32; N];
        for x in out.iter_mut() {
            *x = f32::from_le_bytes(self.take());
        }
        out
    }
}

impl CalibrationRecord {
    /// A record with nothing calibrated.
    pub const EMPTY: CalibrationRecord = CalibrationRecord {
        antenna: None,
        mag: None,
        step_length_m: None,
    };

    /// The antenna calibration to use: the record's, or `nominal` (the board profile's)
    /// when the unit has not been on the bench.
    pub fn antenna_or(&self, nominal: &Calibration) -> Calibration {
        self.antenna.unwrap_or(*nominal)
    }

    /// The bytes to store.
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut buf = [0u8; RECORD_LEN];
        let flags = self.antenna.map_or(0, |_| FLAG_ANTENNA)
            | self.mag.map_or(0, |_| FLAG_MAG)
            | self.step_length_m.map_or(0, |_| FLAG_STEP);
        let mut w = Writer {
            buf: &mut buf,
            at: 0,
        };
        w.bytes(&RECORD_MAGIC);
        w.bytes(&RECORD_VERSION.to_le_bytes());
        w.bytes(&flags.to_le_bytes());
        let a = self.antenna.unwrap_or(Calibration {
            gain_a_per_m_per_v: [0.0; 3],
            offset_v: [0.0; 3],
            phase_rad: [0.0; 3],
            low_range_ratio: [0.0; 3],
            low_range_phase_rad: [0.0; 3],
        });
        w.f32s(&a.gain_a_per_m_per_v);
        w.f32s(&a.offset_v);
        w.f32s(&a.phase_rad);
        w.f32s(&a.low_range_ratio);
        w.f32s(&a.low_range_phase_rad);
        let (hard, soft) = self.mag.map_or((Vec3::zeros(), Mat3::zeros()), |m| {
            (m.hard_iron, m.soft_iron)
        });
        w.f32s(hard.as_slice());
        // nalgebra stores column-major: the transpose's storage is the row-major order.
        w.f32s(soft.transpose().as_slice());
        w.f32s(&[self.step_length_m.unwrap_or(0.0)]);
        let crc = crc32(buf.get(..CRC_AT).unwrap_or(&[]));
        if let Some(dst) = buf.get_mut(CRC_AT..) {
            dst.copy_from_slice(&crc.to_le_bytes());
        }
        buf
    }

    /// The record stored in `bytes` (at least [`RECORD_LEN`] of them; more are ignored).
    pub fn decode(bytes: &[u8]) -> Result<Self, RecordError> {
        let bytes = bytes.get(..RECORD_LEN).ok_or(RecordError::Length)?;
        if bytes.iter().all(|b| *b == 0xFF) {
            return Err(RecordError::Erased);
        }
        let mut r = Reader { buf: bytes, at: 0 };
        if r.take::<4>() != RECORD_MAGIC {
            return Err(RecordError::Magic);
        }
        let version = u16::from_le_bytes(r.take());
        if version != RECORD_VERSION {
            return Err(RecordError::Version(version));
        }
        let stored = bytes
            .get(CRC_AT..)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(u32::from_le_bytes);
        if stored != Some(crc32(bytes.get(..CRC_AT).unwrap_or(&[]))) {
            return Err(RecordError::Crc);
        }
        let flags = u16::from_le_bytes(r.take());
        if flags & !(FLAG_ANTENNA | FLAG_MAG | FLAG_STEP) != 0 {
            return Err(RecordError::Invalid);
        }
        let antenna = Calibration {
            gain_a_per_m_per_v: r.f32s(),
            offset_v: r.f32s(),
            phase_rad: r.f32s(),
            low_range_ratio: r.f32s(),
            low_range_phase_rad: r.f32s(),
        };
        let hard: [f32; 3] = r.f32s();
        let soft: [f32; 9] = r.f32s();
        let [step]: [f32; 1] = r.f32s();
        let mag = MagCalibration {
            hard_iron: Vec3::from(hard),
            soft_iron: Mat3::from_row_slice(&soft),
        };
        let mag_ok = hard.iter().chain(soft.iter()).all(|x| x.is_finite())
            && mag.soft_iron.determinant().abs() > 1e-6;
        let record = CalibrationRecord {
            antenna: (flags & FLAG_ANTENNA != 0).then_some(antenna),
            mag: (flags & FLAG_MAG != 0).then_some(mag),
            step_length_m: (flags & FLAG_STEP != 0).then_some(step),
        };
        let valid = record.antenna.is_none_or(|a| a.is_valid())
            && (record.mag.is_none() || mag_ok)
            && record
                .step_length_m
                .is_none_or(|s| s.is_finite() && s > 0.0);
        if valid {
            Ok(record)
        } else {
            Err(RecordError::Invalid)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::REFERENCE;

    fn full() -> CalibrationRecord {
        let mut a = REFERENCE.analog.nominal;
        a.gain_a_per_m_per_v = [4.1e-3, -3.9e-3, 4.05e-3];
        a.phase_rad = [0.0, 0.031, -0.052];
        a.offset_v = [1e-3, -2e-4, 5e-4];
        a.low_range_ratio = [63.1, 64.9, 64.2];
        CalibrationRecord {
            antenna: Some(a),
            mag: Some(MagCalibration {
                hard_iron: Vec3::new(12.5, -3.0, 7.25),
                soft_iron: Mat3::new(1.02, 0.01, -0.03, 0.01, 0.97, 0.02, -0.03, 0.02, 1.01),
            }),
            step_length_m: Some(0.71),
        }
    }

    #[test]
    fn crc32_matches_the_standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn records_round_trip_and_absent_parts_stay_absent() {
        for rec in [
            full(),
            CalibrationRecord::EMPTY,
            CalibrationRecord {
                mag: None,
                ..full()
            },
            CalibrationRecord {
                antenna: None,
                step_length_m: None,
                ..full()
            },
        ] {
            let bytes = rec.encode();
            assert_eq!(CalibrationRecord::decode(&bytes), Ok(rec));
        }
        let nominal = REFERENCE.analog.nominal;
        assert_eq!(CalibrationRecord::EMPTY.antenna_or(&nominal), nominal);
        assert_eq!(full().antenna_or(&nominal), full().antenna.unwrap());
    }

    #[test]
    fn corrupt_foreign_and_erased_records_are_refused() {
        let bytes = full().encode();
        // Any single flipped bit is caught (by the CRC, or earlier by magic/version).
        for i in 0..RECORD_LEN {
            for bit in 0..8 {
                let mut b = bytes;
                b[i] ^= 1 << bit;
                assert!(CalibrationRecord::decode(&b).is_err(), "byte {i} bit {bit}");
            }
        }
        assert_eq!(
            CalibrationRecord::decode(&[0xFF; RECORD_LEN]),
            Err(RecordError::Erased)
        );
        assert_eq!(
            CalibrationRecord::decode(&bytes[..100]),
            Err(RecordError::Length)
        );
        let mut other = bytes;
        other[4] = 2;
        assert_eq!(
            CalibrationRecord::decode(&other),
            Err(RecordError::Version(2))
        );
        // A well-formed record holding a NaN gain is still refused.
        let mut bad = full();
        if let Some(a) = bad.antenna.as_mut() {
            a.gain_a_per_m_per_v[1] = f32::NAN;
        }
        assert_eq!(
            CalibrationRecord::decode(&bad.encode()),
            Err(RecordError::Invalid)
        );
        let mut zero_step = full();
        zero_step.step_length_m = Some(0.0);
        assert_eq!(
            CalibrationRecord::decode(&zero_step.encode()),
            Err(RecordError::Invalid)
        );
    }
}
