//! The record a panic (or a starved watchdog) leaves in no-init RAM for the next boot.
//!
//! The board's panic handler formats the panic's location and message into a
//! [`CrashRecord`], writes it to a `static` in the `.uninit` section (which the runtime
//! neither zeroes nor initialises, so it survives a system reset but not a power cycle),
//! and resets the MCU. The next boot reads the record, reports it ([`LastReset`]: logged
//! and drawn on the display by [`draw_last_reset`]) and clears it, so it is shown once.
//!
//! # Format (`repr(C)`, 136 bytes, little-endian words)
//! | offset | field | content |
//! |---|---|---|
//! | 0 | `magic` | [`MAGIC`] (`"CRSH"`), written last |
//! | 4 | `kind` | 1 = panic, 2 = watchdog starved (work stalled) |
//! | 8 | `len` | message length in bytes, ≤ [`MESSAGE_LEN`] |
//! | 12 | `message` | UTF-8, truncated on a character boundary, rest zero |
//! | 132 | `crc` | CRC-32 (IEEE 802.3) of the bytes of `kind`, `len` and `message[..len]` |
//!
//! RAM after power-on holds arbitrary bits: a record counts only if the magic, the kind,
//! the length, the CRC and the UTF-8 all check, so noise passes with a probability of
//! about 2⁻⁶⁴.

use core::fmt;

use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};

/// Marks a written record (`"CRSH"` as a little-endian word).
pub const MAGIC: u32 = u32::from_le_bytes(*b"CRSH");
/// Room for the message, bytes.
pub const MESSAGE_LEN: usize = 120;

/// Why the record was written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrashKind {
    /// A panic (location and message).
    Panic = 1,
    /// The watchdog was no longer fed because a piece of work stalled (its name).
    Starved = 2,
}

/// The no-init RAM record (see the module doc for the layout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct CrashRecord {
    magic: u32,
    kind: u32,
    len: u32,
    message: [u8; MESSAGE_LEN],
    crc: u32,
}

impl CrashRecord {
    /// A record that holds nothing (what the next boot writes after reading one).
    pub const CLEARED: CrashRecord = CrashRecord {
        magic: 0,
        kind: 0,
        len: 0,
        message: [0; MESSAGE_LEN],
        crc: 0,
    };

    /// A valid record of `kind` with the formatted message, truncated to
    /// [`MESSAGE_LEN`] bytes on a character boundary. Never fails, never panics.
    pub fn new(kind: CrashKind, message: fmt::Arguments<'_>) -> CrashRecord {
        let mut w = Truncating {
            buf: [0; MESSAGE_LEN],
            len: 0,
            full: false,
        };
        // `Truncating` never returns an error; a formatting error of a `Display`
        // implementation only ends the message early.
        let _ = fmt::write(&mut w, message);
        let kind = kind as u32;
        let len = w.len as u32;
        CrashRecord {
            magic: MAGIC,
            kind,
            len,
            message: w.buf,
            crc: record_crc(kind, len, &w.buf),
        }
    }

    /// The kind and message, if this is a valid record.
    pub fn decode(&self) -> Option<(CrashKind, &str)> {
        if self.magic != MAGIC {
            return None;
        }
        let kind = match self.kind {
            1 => CrashKind::Panic,
            2 => CrashKind::Starved,
            _ => return None,
        };
        let text = self.message.get(..self.len as usize)?;
        if record_crc(self.kind, self.len, &self.message) != self.crc {
            return None;
        }
        core::str::from_utf8(text).ok().map(|m| (kind, m))
    }
}

fn record_crc(kind: u32, len: u32, message: &[u8; MESSAGE_LEN]) -> u32 {
    let text = message.get(..len as usize).unwrap_or(&[]);
    let mut c = Crc32::new();
    c.update(&kind.to_le_bytes());
    c.update(&len.to_le_bytes());
    c.update(text);
    c.finish()
}

/// A `fmt::Write` into a fixed buffer that keeps what fits (whole characters).
struct Truncating {
    buf: [u8; MESSAGE_LEN],
    len: usize,
    /// A character did not fit: everything after it is dropped too (a message with a
    /// hole in it would mislead).
    full: bool,
}

impl fmt::Write for Truncating {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for ch in s.chars() {
            let mut b = [0u8; 4];
            let e = ch.encode_utf8(&mut b).as_bytes();
            let Some(dst) = self
                .buf
                .get_mut(self.len..self.len + e.len())
                .filter(|_| !self.full)
            else {
                self.full = true;
                return Ok(());
            };
            dst.copy_from_slice(e);
            self.len += e.len();
        }
        Ok(())
    }
}

/// CRC-32 (IEEE 802.3: reflected, polynomial 0xEDB88320, initial and final XOR all ones),
/// bitwise: a record is checked once per boot, so a table would only cost flash.
#[derive(Debug, Clone, Copy)]
pub struct Crc32(u32);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// A CRC over no bytes yet.
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    /// Adds `bytes`.
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u32::from(b);
            for _ in 0..8 {
                let lsb = self.0 & 1;
                self.0 = (self.0 >> 1) ^ (0xEDB8_8320 & 0u32.wrapping_sub(lsb));
            }
        }
    }

    /// The CRC of the bytes added.
    pub fn finish(self) -> u32 {
        !self.0
    }
}

/// A source path shortened for the record: a dependency's path from the crate's own
/// directory on (`nalgebra-0.33.2/src/…` instead of the registry's absolute path), the
/// firmware's paths as they are.
pub fn short_path(file: &str) -> &str {
    match file.rfind("registry/src/") {
        Some(i) => {
            let rest = file.get(i + "registry/src/".len()..).unwrap_or(file);
            // Skip the index directory (`index.crates.io-…/`).
            rest.split_once('/')
                .map_or(rest, |(_, crate_path)| crate_path)
        }
        None => file,
    }
}

/// Why the MCU last reset, as the next boot reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LastReset<'a> {
    /// Power-on, the reset button, or a flash: nothing to report.
    Clean,
    /// A panic, with its location and message.
    Panic(&'a str),
    /// The watchdog starved because this work stalled.
    Starved(&'a str),
    /// The watchdog reset the MCU and no record was written: the main loop hung inside a
    /// call (e.g. a bus transfer that never ended).
    WatchdogHung,
}

impl<'a> LastReset<'a> {
    /// The report for a record read at boot and the watchdog-reset flag of the reset
    /// controller (`RCC_CSR.IWDGRSTF`).
    pub fn from_boot(record: &'a CrashRecord, watchdog_reset: bool) -> LastReset<'a> {
        match record.decode() {
            Some((CrashKind::Panic, m)) => LastReset::Panic(m),
            Some((CrashKind::Starved, m)) => LastReset::Starved(m),
            None if watchdog_reset => LastReset::WatchdogHung,
            None => LastReset::Clean,
        }
    }

    /// The display's title line.
    pub fn title(&self) -> &'static str {
        match self {
            LastReset::Clean => "",
            LastReset::Panic(_) => "RESET: PANIC",
            LastReset::Starved(_) | LastReset::WatchdogHung => "RESET: WATCHDOG",
        }
    }

    /// The detail under the title.
    pub fn detail(&self) -> &'a str {
        match self {
            LastReset::Clean => "",
            LastReset::Panic(m) | LastReset::Starved(m) => m,
            LastReset::WatchdogHung => "main loop hung",
        }
    }
}

/// Characters per line of [`draw_last_reset`] (6 px font on 128 px).
pub const COLUMNS: usize = 21;
/// Lines of detail under the title (10 px font on 64 px, title included: 6).
pub const DETAIL_LINES: usize = 5;

/// Splits `text` into display lines of at most `cols` characters, breaking at newlines
/// and otherwise hard (a path has no spaces to break at).
pub fn wrap(text: &str, cols: usize) -> impl Iterator<Item = &str> {
    text.split('\n').flat_map(move |line| {
        let mut rest = line;
        let mut first = true;
        core::iter::from_fn(move || {
            if rest.is_empty() && !first {
                return None;
            }
            first = false;
            let cut = rest
                .char_indices()
                .nth(cols.max(1))
                .map_or(rest.len(), |(i, _)| i);
            let (head, tail) = rest.split_at(cut);
            rest = tail;
            Some(head)
        })
    })
}

/// Draws the last reset's title and detail (as many lines as fit) on a 128×64 target.
pub fn draw_last_reset<D>(reset: &LastReset<'_>, target: &mut D) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    let style = MonoTextStyle::new(&FONT_6X10, BinaryColor::On);
    Text::with_baseline(reset.title(), Point::zero(), style, Baseline::Top).draw(target)?;
    for (i, line) in wrap(reset.detail(), COLUMNS).take(DETAIL_LINES).enumerate() {
        let y = 12 + 10 * i as i32;
        Text::with_baseline(line, Point::new(0, y), style, Baseline::Top).draw(target)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_graphics::image::GetPixel;

    #[test]
    fn crc32_matches_the_ieee_check_value() {
        let mut c = Crc32::new();
        c.update(b"123456789");
        assert_eq!(c.finish(), 0xCBF4_3926);
        assert_eq!(Crc32::new().finish(), 0);
    }

    #[test]
    fn a_record_round_trips_its_kind_and_message() {
        let r = CrashRecord::new(
            CrashKind::Panic,
            format_args!(
                "{}:{}: {}",
                "firmware/src/app.rs", 42, "index out of bounds"
            ),
        );
        assert_eq!(
            r.decode(),
            Some((
                CrashKind::Panic,
                "firmware/src/app.rs:42: index out of bounds"
            ))
        );
        let s = CrashRecord::new(CrashKind::Starved, format_args!("IMU ticks not handled"));
        assert_eq!(
            s.decode(),
            Some((CrashKind::Starved, "IMU ticks not handled"))
        );
        assert_eq!(core::mem::size_of::<CrashRecord>(), 136);
    }

    #[test]
    fn a_long_message_is_cut_on_a_character_boundary() {
        // 119 ASCII bytes, then "é" (2 bytes) would end at 121 > 120: cut before it.
        let long = "x".repeat(119);
        let r = CrashRecord::new(CrashKind::Panic, format_args!("{long}é and more"));
        let (_, m) = r.decode().unwrap();
        assert_eq!(m, long);
        let r = CrashRecord::new(CrashKind::Panic, format_args!("{}", "ü".repeat(100)));
        let (_, m) = r.decode().unwrap();
        assert_eq!(m, "ü".repeat(60));
    }

    #[test]
    fn any_damage_or_noise_is_not_a_record() {
        let good = CrashRecord::new(CrashKind::Panic, format_args!("boom"));
        assert!(good.decode().is_some());
        assert_eq!(CrashRecord::CLEARED.decode(), None);
        let mut r = good;
        r.message[1] ^= 0x01;
        assert_eq!(r.decode(), None, "flipped message bit");
        let mut r = good;
        r.len = 3;
        assert_eq!(r.decode(), None, "length changed");
        let mut r = good;
        r.len = 10_000;
        assert_eq!(r.decode(), None, "length out of range");
        let mut r = good;
        r.kind = 7;
        assert_eq!(r.decode(), None, "unknown kind");
        let mut r = good;
        r.magic ^= 1 << 31;
        assert_eq!(r.decode(), None, "magic");
        // Power-on RAM: pseudo-random bytes (seeded xorshift) never decode.
        let mut x: u32 = 0x9E37_79B9;
        for _ in 0..2000 {
            let mut bytes = [0u8; 136];
            for b in bytes.iter_mut() {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *b = x as u8;
            }
            // SAFETY (test): CrashRecord is repr(C) of integers; every bit pattern is valid.
            #[allow(unsafe_code)]
            let r: CrashRecord = unsafe { core::mem::transmute(bytes) };
            assert_eq!(r.decode(), None);
        }
        // Noise with a valid magic still fails the CRC.
        let mut bytes = [0x5Au8; 136];
        bytes[..4].copy_from_slice(&MAGIC.to_le_bytes());
        bytes[4..8].copy_from_slice(&1u32.to_le_bytes());
        bytes[8..12].copy_from_slice(&4u32.to_le_bytes());
        #[allow(unsafe_code)]
        // SAFETY (test): as above.
        let r: CrashRecord = unsafe { core::mem::transmute(bytes) };
        assert_eq!(r.decode(), None);
    }

    #[test]
    fn the_boot_report_combines_the_record_and_the_watchdog_flag() {
        let p = CrashRecord::new(CrashKind::Panic, format_args!("boom"));
        let s = CrashRecord::new(CrashKind::Starved, format_args!("IMU ticks not handled"));
        let c = CrashRecord::CLEARED;
        assert_eq!(LastReset::from_boot(&p, false), LastReset::Panic("boom"));
        assert_eq!(
            LastReset::from_boot(&s, true),
            LastReset::Starved("IMU ticks not handled")
        );
        assert_eq!(LastReset::from_boot(&c, true), LastReset::WatchdogHung);
        assert_eq!(LastReset::from_boot(&c, false), LastReset::Clean);
        assert_eq!(LastReset::WatchdogHung.title(), "RESET: WATCHDOG");
        assert_eq!(LastReset::WatchdogHung.detail(), "main loop hung");
    }

    #[test]
    fn dependency_paths_lose_the_registry_prefix() {
        assert_eq!(
            short_path(
                "/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/nalgebra-0.33.2/src/base/ops.rs"
            ),
            "nalgebra-0.33.2/src/base/ops.rs"
        );
        assert_eq!(short_path("firmware/src/app.rs"), "firmware/src/app.rs");
        assert_eq!(short_path("x/registry/src/"), "");
    }

    #[test]
    fn wrapping_breaks_at_newlines_and_at_the_column() {
        let lines: Vec<&str> = wrap("panicked at firmware/src/x.rs:1:2:\nboom", 21).collect();
        assert_eq!(lines, ["panicked at firmware/", "src/x.rs:1:2:", "boom"]);
        let lines: Vec<&str> = wrap("ééééé", 2).collect();
        assert_eq!(lines, ["éé", "éé", "é"]);
        assert_eq!(wrap("", 21).collect::<Vec<_>>(), [""]);
    }

    #[test]
    fn the_report_is_drawn_within_the_screen() {
        let mut fb = crate::display::Frame::new();
        let r = LastReset::Panic(
            "firmware/src/estimate/sog.rs:120:9: attempt to subtract with overflow and more text \
             than the screen holds, which is dropped",
        );
        draw_last_reset(&r, &mut fb).unwrap();
        let lit = |y0: i32, y1: i32| {
            (y0..y1)
                .flat_map(|y| (0..128).map(move |x| Point::new(x, y)))
                .filter(|p| fb.pixel(*p) == Some(BinaryColor::On))
                .count()
        };
        assert!(lit(0, 10) > 0, "title drawn");
        for i in 0..DETAIL_LINES as i32 {
            assert!(lit(12 + 10 * i, 22 + 10 * i) > 0, "detail line {i} drawn");
        }
    }
}
