//! The unit's settings as stored in flash: search mode, sound volume, the region's earth
//! field and the calibration record ([`CalibrationRecord`]: antenna, magnetometer, step
//! length), in one versioned block with a CRC-32 (the calibration record's own
//! [`crc32`]).
//!
//! Layout ([`SETTINGS_LEN`] bytes, little-endian): magic `"ARST"` (0..4), version u16
//! (4..6), search mode u8 (6: 0 SOGs, 1 classic), volume u8 (7: 0 muted … [`MAX_VOLUME`]),
//! region u8 (8: index into [`REGIONS`]), 3 bytes zero (9..12), the calibration record
//! (12..140, its own magic/version/CRC), CRC-32 of bytes 0..140 (140..144).
//!
//! Reading never fails the boot: erased flash, another version or a CRC mismatch give
//! [`Settings::DEFAULT`] with the reason, which the board shows and logs.

use crate::Vec3;
use crate::calibration::record::{CalibrationRecord, RECORD_LEN, RecordError, crc32};

/// Where the blocks are stored: the start of flash sectors 10 and 11 of the STM32F405 (the
/// last two, 128 KB each, used in turn by [`super::settings_store`]; `memory.x` ends the
/// program's FLASH region before them). Erasing one takes up to 2–4 s with instruction
/// fetch stalled, longer than the 1 s watchdog period (docs/board.md).
pub const SETTINGS_ADDR: u32 = 0x080C_0000;
/// The flash sectors holding the settings.
pub const SETTINGS_SECTORS: [u8; 2] = [10, 11];
/// Bytes of the stored block.
pub const SETTINGS_LEN: usize = 144;
/// Start of a settings block.
pub const SETTINGS_MAGIC: [u8; 4] = *b"ARST";
/// The layout version this firmware writes and reads.
pub const SETTINGS_VERSION: u16 = 1;
/// Loudest volume step (0 is muted).
pub const MAX_VOLUME: u8 = 3;
const CAL_AT: usize = 12;
const CRC_AT: usize = CAL_AT + RECORD_LEN;

/// A region's local geomagnetic field in W (x magnetic north, y west, z up; µT), the
/// header's `earth_field_uT`: one value near the middle of the region's range in the IGRF-14
/// model (2026.0; the field varies by up to 5 µT across a region, see the test
/// `regions_match_the_igrf_model`). The estimator uses it for the heading's reference and
/// the magnetometer's plausibility.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Name on the display (at most 10 characters).
    pub name: &'static str,
    /// The field, µT.
    pub earth_field_ut: [f32; 3],
}

/// The regions offered in the menu; the first is the board profile's default.
pub const REGIONS: [Region; 4] = [
    Region {
        name: "ALPS",
        earth_field_ut: [21.79, 0.0, -42.77],
    },
    Region {
        name: "ROCKIES",
        earth_field_ut: [19.2, 0.0, -48.5],
    },
    Region {
        name: "NORWAY",
        earth_field_ut: [12.5, 0.0, -50.5],
    },
    Region {
        name: "NZ ALPS",
        earth_field_ut: [20.6, 0.0, 53.9],
    },
];

/// How the receiver searches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SearchMode {
    /// The SOGs estimator (the receiver's own search).
    Sog,
    /// The classic flux-line search (`crate::guidance::classic`).
    Classic,
}

impl SearchMode {
    /// The application's mode.
    pub fn app(self) -> crate::app::SearchMode {
        match self {
            SearchMode::Sog => crate::app::SearchMode::Sog,
            SearchMode::Classic => crate::app::SearchMode::Classic,
        }
    }

    /// The session log's word for it.
    pub fn word(self) -> &'static str {
        match self {
            SearchMode::Sog => "sog",
            SearchMode::Classic => "classic",
        }
    }
}

/// The unit's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Search mode.
    pub mode: SearchMode,
    /// Tone volume, 0 (muted) to [`MAX_VOLUME`].
    pub volume: u8,
    /// Index into [`REGIONS`].
    pub region: u8,
    /// The unit's calibration (antenna, magnetometer, step length).
    pub calibration: CalibrationRecord,
}

/// Why stored bytes were not taken as settings (the defaults apply).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsError {
    /// Fewer than [`SETTINGS_LEN`] bytes.
    #[error("settings block too short")]
    Length,
    /// Every byte is 0xFF: never saved.
    #[error("no settings saved (erased flash)")]
    Erased,
    /// Not a settings block.
    #[error("not a settings block")]
    Magic,
    /// A layout version this firmware does not read.
    #[error("settings layout version {0} not supported")]
    Version(u16),
    /// The CRC does not match: the block is corrupt.
    #[error("settings CRC mismatch")]
    Crc,
    /// A value out of range (mode, volume, region, padding).
    #[error("settings hold an invalid value")]
    Invalid,
    /// The calibration record inside is refused.
    #[error("settings: calibration record refused: {0}")]
    Calibration(RecordError),
}

impl Settings {
    /// Factory settings: SOGs, full volume, the first region, not calibrated.
    pub const DEFAULT: Settings = Settings {
        mode: SearchMode::Sog,
        volume: MAX_VOLUME,
        region: 0,
        calibration: CalibrationRecord::EMPTY,
    };

    /// The region's earth field (the first region if the index is out of range).
    pub fn earth_field(&self) -> Vec3 {
        let [x, y, z] = REGIONS
            .get(usize::from(self.region))
            .or(REGIONS.first())
            .map_or([0.0; 3], |r| r.earth_field_ut);
        Vec3::new(x, y, z)
    }

    /// The stored block.
    pub fn encode(&self) -> [u8; SETTINGS_LEN] {
        let [v0, v1] = SETTINGS_VERSION.to_le_bytes();
        let [m0, m1, m2, m3] = SETTINGS_MAGIC;
        let mode = match self.mode {
            SearchMode::Sog => 0,
            SearchMode::Classic => 1,
        };
        let head = [
            m0,
            m1,
            m2,
            m3,
            v0,
            v1,
            mode,
            self.volume.min(MAX_VOLUME),
            self.region,
        ];
        let mut b = [0u8; SETTINGS_LEN];
        put(&mut b, 0, &head);
        put(&mut b, CAL_AT, &self.calibration.encode());
        let crc = crc32(b.get(..CRC_AT).unwrap_or(&[]));
        put(&mut b, CRC_AT, &crc.to_le_bytes());
        b
    }

    /// Reads a stored block (the first [`SETTINGS_LEN`] bytes of `bytes`).
    pub fn decode(bytes: &[u8]) -> Result<Settings, SettingsError> {
        let b = bytes.get(..SETTINGS_LEN).ok_or(SettingsError::Length)?;
        if b.iter().all(|&x| x == 0xFF) {
            return Err(SettingsError::Erased);
        }
        let (body, crc) = b.split_at(CRC_AT);
        let (head, cal) = body.split_at(CAL_AT);
        let [m0, m1, m2, m3, v0, v1, mode, volume, region, p0, p1, p2] = head else {
            return Err(SettingsError::Length);
        };
        if [*m0, *m1, *m2, *m3] != SETTINGS_MAGIC {
            return Err(SettingsError::Magic);
        }
        let version = u16::from_le_bytes([*v0, *v1]);
        if version != SETTINGS_VERSION {
            return Err(SettingsError::Version(version));
        }
        let stored = crc
            .try_into()
            .map(u32::from_le_bytes)
            .map_err(|_| SettingsError::Length)?;
        if stored != crc32(body) {
            return Err(SettingsError::Crc);
        }
        let mode = match mode {
            0 => SearchMode::Sog,
            1 => SearchMode::Classic,
            _ => return Err(SettingsError::Invalid),
        };
        if *volume > MAX_VOLUME
            || usize::from(*region) >= REGIONS.len()
            || [*p0, *p1, *p2] != [0; 3]
        {
            return Err(SettingsError::Invalid);
        }
        // An uncalibrated unit stores the empty record; its own errors are reported.
        let calibration = CalibrationRecord::decode(cal).map_err(SettingsError::Calibration)?;
        Ok(Settings {
            mode,
            volume: *volume,
            region: *region,
            calibration,
        })
    }

    /// The settings stored in `bytes`, or the defaults with the reason they were not read.
    pub fn load(bytes: &[u8]) -> (Settings, Option<SettingsError>) {
        match Settings::decode(bytes) {
            Ok(s) => (s, None),
            Err(e) => (Settings::DEFAULT, Some(e)),
        }
    }
}

/// Copies `src` into `b` at `at` (the layout's offsets are constants within the block).
fn put(b: &mut [u8], at: usize, src: &[u8]) {
    if let Some(d) = b.get_mut(at..at + src.len()) {
        d.copy_from_slice(src);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;

    fn sample() -> Settings {
        Settings {
            mode: SearchMode::Classic,
            volume: 1,
            region: 2,
            calibration: CalibrationRecord {
                step_length_m: Some(0.71),
                ..CalibrationRecord::EMPTY
            },
        }
    }

    #[test]
    fn modes_map_to_the_application() {
        assert_eq!(SearchMode::Sog.app(), crate::app::SearchMode::Sog);
        assert_eq!(SearchMode::Classic.app(), crate::app::SearchMode::Classic);
        assert_eq!(SearchMode::Classic.word(), "classic");
    }

    #[test]
    fn settings_round_trip() {
        for s in [Settings::DEFAULT, sample()] {
            assert_eq!(Settings::decode(&s.encode()), Ok(s));
        }
        let e = sample().earth_field();
        assert_eq!(e, Vec3::new(12.5, 0.0, -50.5));
    }

    #[test]
    fn every_single_bit_flip_is_refused() {
        let good = sample().encode();
        for bit in 0..SETTINGS_LEN * 8 {
            let mut b = good;
            b[bit / 8] ^= 1 << (bit % 8);
            assert!(
                Settings::decode(&b).is_err(),
                "bit {bit} flipped went unnoticed"
            );
        }
    }

    #[test]
    fn bad_blocks_give_the_defaults_and_the_reason() {
        assert_eq!(
            Settings::load(&[0xFF; SETTINGS_LEN]),
            (Settings::DEFAULT, Some(SettingsError::Erased))
        );
        assert_eq!(
            Settings::load(&[0; 10]),
            (Settings::DEFAULT, Some(SettingsError::Length))
        );
        let mut b = sample().encode();
        b[4] = 9;
        assert_eq!(Settings::decode(&b), Err(SettingsError::Version(9)));
        // Out-of-range values with a valid CRC (a newer firmware's region, say).
        let mut s = sample();
        s.region = REGIONS.len() as u8;
        assert_eq!(Settings::decode(&s.encode()), Err(SettingsError::Invalid));
        // A volume beyond the maximum is clamped when written.
        s = sample();
        s.volume = 200;
        assert_eq!(
            Settings::decode(&s.encode()).map(|s| s.volume),
            Ok(MAX_VOLUME)
        );
    }

    #[test]
    fn the_linker_script_keeps_the_program_out_of_the_settings_sector() {
        let script = include_str!("../../../memory.x");
        let line = |name: &str| {
            script
                .lines()
                .find(|l| l.trim_start().starts_with(name))
                .unwrap_or_else(|| panic!("{name} not in memory.x"))
                .replace(' ', "")
        };
        assert!(line("FLASH ").contains("ORIGIN=0x08000000,LENGTH=768K"));
        assert!(line("SETTINGS ").contains(
            &std::format!("ORIGIN={SETTINGS_ADDR:#010X},LENGTH=256K").replace("0X", "0x")
        ));
        assert_eq!(0x0800_0000 + 768 * 1024, SETTINGS_ADDR);
        assert_eq!(SETTINGS_SECTORS, [10, 11]);
    }

    #[test]
    fn regions_are_plausible_fields() {
        // The session-log reader refuses a header field outside 15–80 µT.
        for r in REGIONS {
            let [x, y, z] = r.earth_field_ut;
            let m = (x * x + y * y + z * z).sqrt();
            assert!((40.0..65.0).contains(&m), "{}: {m} µT", r.name);
            assert!(r.name.len() <= 10);
        }
    }

    /// IGRF-14 at 2026.0, 1.5 km altitude, at places of each region where people search
    /// avalanches: (region, place, horizontal = north µT, up µT). From ppigrf 2.1.0, the
    /// script in docs/board.md ("Regions").
    const IGRF14_2026: [(&str, &str, f32, f32); 23] = [
        ("ALPS", "Chamonix", 22.44, -42.16),
        ("ALPS", "Engadin", 22.03, -42.82),
        ("ALPS", "Innsbruck", 21.57, -43.43),
        ("ALPS", "Hohe Tauern", 21.65, -43.43),
        ("ALPS", "Maritime Alps", 23.41, -41.01),
        ("ALPS", "Rax", 21.22, -44.10),
        ("ROCKIES", "Colorado Front Range", 20.97, -46.39),
        ("ROCKIES", "San Juans", 21.86, -44.61),
        ("ROCKIES", "Wasatch", 21.03, -46.12),
        ("ROCKIES", "Tetons", 19.60, -48.59),
        ("ROCKIES", "Glacier NP", 17.47, -51.44),
        ("ROCKIES", "Rogers Pass", 16.58, -52.33),
        ("NORWAY", "Hardanger", 15.11, -49.13),
        ("NORWAY", "Jotunheimen", 14.40, -49.73),
        ("NORWAY", "Sunnmore", 14.11, -49.91),
        ("NORWAY", "Trollheimen", 13.85, -50.18),
        ("NORWAY", "Lofoten", 11.47, -52.06),
        ("NORWAY", "Lyngen", 10.79, -52.80),
        ("NZ ALPS", "Aoraki", 20.60, 53.99),
        ("NZ ALPS", "Arthur's Pass", 21.09, 53.13),
        ("NZ ALPS", "Nelson Lakes", 21.75, 52.03),
        ("NZ ALPS", "Fiordland", 19.37, 55.81),
        ("NZ ALPS", "Remarkables", 19.67, 55.33),
    ];
    /// Secular variation allowance: the field drifts ≲ 0.1 µT a year in these regions, so
    /// the model's values hold to 0.5 µT until about 2030.
    const DRIFT_UT: f32 = 0.5;
    /// Largest difference between a region's value and the field anywhere in it (≈ 10 %
    /// of the field: an inclination error of ≲ 3°).
    const SPREAD_UT: f32 = 5.0;

    #[test]
    fn regions_match_the_igrf_model() {
        for r in REGIONS {
            let places: std::vec::Vec<_> = IGRF14_2026.iter().filter(|p| p.0 == r.name).collect();
            assert!(places.len() >= 5, "{}: no model places", r.name);
            let [x, y, z] = r.earth_field_ut;
            // x is magnetic north: nothing west.
            assert_eq!(y, 0.0, "{}", r.name);
            // Inside the range the model gives over the region (its box, ± drift).
            let (h_lo, h_hi, u_lo, u_hi) = places.iter().fold(
                (f32::MAX, f32::MIN, f32::MAX, f32::MIN),
                |(a, b, c, d), p| (a.min(p.2), b.max(p.2), c.min(p.3), d.max(p.3)),
            );
            assert!(
                (h_lo - DRIFT_UT..=h_hi + DRIFT_UT).contains(&x),
                "{}: north {x} µT outside the model's {h_lo}..{h_hi}",
                r.name
            );
            assert!(
                (u_lo - DRIFT_UT..=u_hi + DRIFT_UT).contains(&z),
                "{}: up {z} µT outside the model's {u_lo}..{u_hi}",
                r.name
            );
            // And close enough to every place of the region.
            for p in &places {
                let d = ((x - p.2).powi(2) + (z - p.3).powi(2)).sqrt();
                assert!(d <= SPREAD_UT, "{} at {}: {d} µT off", r.name, p.1);
            }
        }
    }

    #[test]
    fn the_model_check_fails_for_a_field_off_its_region() {
        // Norway's field given for the Alps, and a sign slip (the southern hemisphere's
        // up field in the north), each land outside the model's range.
        let inside = |name: &str, x: f32, z: f32| {
            IGRF14_2026
                .iter()
                .filter(|p| p.0 == name)
                .all(|p| ((x - p.2).powi(2) + (z - p.3).powi(2)).sqrt() <= SPREAD_UT)
        };
        assert!(inside("ALPS", 21.79, -42.77));
        assert!(!inside("ALPS", 12.5, -50.5));
        assert!(!inside("NORWAY", 12.5, 50.5));
        assert!(!inside("ROCKIES", 21.4, -42.0));
    }
}
