//! The settings in flash, safe against a power cut at any moment: an append-only log of
//! [`Settings`] blocks in one erase unit (on the board: sector 11, 128 KB, 910 slots of
//! [`SETTINGS_LEN`] bytes), over any [`NorFlash`] (embedded-storage: the HAL's flash on the
//! board, an emulation in the tests).
//!
//! - **Save** writes the block to the first erased slot after the used ones, reads it back
//!   and compares (a slot that does not read back is skipped, the next one tried). Only
//!   when every slot is used is the area erased first: one erase per 910 saves, so the
//!   erase's stall (up to 2–4 s on the STM32F405, instruction fetch stopped; see
//!   docs/board.md) is rare, and a save is usually a 144-byte program (≈ 2 ms).
//! - **Load** scans the used slots from the start (they form a prefix: the writer never
//!   leaves an erased slot behind it) and takes the newest block that decodes (magic,
//!   version, CRC-32, ranges: [`Settings::decode`]).
//!
//! What a cut leaves: during a program, a torn newest slot that fails its CRC, so the
//! previous settings load; during the erase (or between the erase and the program), an
//! area partly erased, partly old or garbage: the old settings (an old block the scan
//! still reaches) or the defaults (the scan stops at an erased first slot). Never garbage:
//! a block is taken only when its CRC matches. Old blocks an interrupted erase left after
//! the first erased slot would later be taken for newer ones, so a save that finds any
//! slot after the used ones not erased erases first. `cargo test -p firmware
//! board::settings_store` cuts the power at every byte written and every erase step.

use crate::board::settings::{SETTINGS_ADDR, SETTINGS_LEN, Settings, SettingsError};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

/// Start of the STM32F405's flash in the address map: offset 0 of its flash driver.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// The board's settings area: flash sector 11 (128 KB; `memory.x` keeps the program out).
pub const BOARD_AREA: Area = Area {
    offset: SETTINGS_ADDR - FLASH_BASE,
    len: 128 * 1024,
};

/// Where the settings live in a flash: `len` bytes from `offset` (offsets as the flash
/// driver counts them; on the board from the start of the flash, 0x0800_0000).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Area {
    /// First byte of the area (a multiple of the flash's erase size).
    pub offset: u32,
    /// Bytes of the area (a multiple of the erase size, at least one block).
    pub len: u32,
}

impl Area {
    /// Whole blocks the area holds.
    pub fn slots(&self) -> u32 {
        self.len / SETTINGS_LEN as u32
    }

    fn slot_offset(&self, k: u32) -> u32 {
        self.offset + k * SETTINGS_LEN as u32
    }
}

/// Why the store could not read or save.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The area is not aligned to the flash's erase, write or read sizes, is smaller than
    /// one block or lies beyond the flash.
    #[error("settings area not aligned to the flash or beyond it")]
    Layout,
    /// The flash refused a read.
    #[error("flash read failed")]
    Read,
    /// The flash refused the erase.
    #[error("flash erase failed")]
    Erase,
    /// The flash refused a write.
    #[error("flash write failed")]
    Write,
    /// No slot read back what was written (after the erase too).
    #[error("settings read back differ from those written")]
    Verify,
}

impl StoreError {
    /// The session log's word for it.
    pub fn word(self) -> &'static str {
        match self {
            StoreError::Layout => "layout",
            StoreError::Read => "read",
            StoreError::Erase => "erase",
            StoreError::Write => "write",
            StoreError::Verify => "verify",
        }
    }
}

/// What [`load`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loaded {
    /// The newest stored settings, or the defaults.
    pub settings: Settings,
    /// Why the defaults apply (`None`: stored settings were read). `Erased`: nothing saved
    /// (or the area erased since).
    pub defaults_because: Option<LoadError>,
    /// The slot the settings came from.
    pub slot: Option<u32>,
    /// Slots in use (written, valid or not).
    pub used: u32,
    /// Used slots after the newest valid one that do not decode (a save the power cut;
    /// the settings before it load).
    pub torn: u32,
}

/// Why [`load`] gave the defaults.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoadError {
    /// The area could not be read.
    #[error("{0}")]
    Store(StoreError),
    /// No used slot decodes; the newest one's reason (`Erased` when none is used).
    #[error("{0}")]
    Settings(SettingsError),
}

/// What [`save`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Saved {
    /// The slot now holding the settings.
    pub slot: u32,
    /// Whether the area was erased first (the long stall).
    pub erased: bool,
    /// Slots skipped because they did not read back.
    pub skipped: u32,
    /// The settings were stored already: nothing written.
    pub unchanged: bool,
}

/// The layout's checks: alignment to the flash's sizes, room for a block, within the
/// flash.
fn check<F: ReadNorFlash>(
    flash: &F,
    area: Area,
    erase: usize,
    write: usize,
) -> Result<(), StoreError> {
    let (off, len) = (area.offset as usize, area.len as usize);
    let aligned = |n: usize, to: usize| to != 0 && n.is_multiple_of(to);
    let ok = aligned(off, erase)
        && aligned(len, erase)
        && aligned(SETTINGS_LEN, write)
        && aligned(SETTINGS_LEN, F::READ_SIZE)
        && len >= SETTINGS_LEN
        && off
            .checked_add(len)
            .is_some_and(|end| end <= flash.capacity());
    if ok { Ok(()) } else { Err(StoreError::Layout) }
}

/// The area's used slots: the newest that decodes, how many are used (the prefix of
/// slots not fully erased), the newest used slot's error when none decodes, and whether
/// any slot after the used ones is not erased (an erase the power cut short).
struct Scan {
    newest: Option<(u32, Settings)>,
    used: u32,
    last_error: Option<SettingsError>,
    dirty: bool,
}

fn scan<F: ReadNorFlash>(flash: &mut F, area: Area) -> Result<Scan, StoreError> {
    let mut s = Scan {
        newest: None,
        used: 0,
        last_error: None,
        dirty: false,
    };
    let mut block = [0u8; SETTINGS_LEN];
    let mut ended = false;
    for k in 0..area.slots() {
        flash
            .read(area.slot_offset(k), &mut block)
            .map_err(|_| StoreError::Read)?;
        let decoded = Settings::decode(&block);
        if ended {
            s.dirty |= decoded != Err(SettingsError::Erased);
            continue;
        }
        match decoded {
            // The first erased slot ends the used ones.
            Err(SettingsError::Erased) => {
                ended = true;
                continue;
            }
            Ok(settings) => {
                s.newest = Some((k, settings));
                s.last_error = None;
            }
            Err(e) => s.last_error = Some(e),
        }
        s.used = k + 1;
    }
    Ok(s)
}

/// The newest stored settings in `area`, or the defaults with the reason. Never fails:
/// a flash that cannot be read gives the defaults too.
pub fn load<F: ReadNorFlash>(flash: &mut F, area: Area) -> Loaded {
    let defaults = |e| Loaded {
        settings: Settings::DEFAULT,
        defaults_because: Some(e),
        slot: None,
        used: 0,
        torn: 0,
    };
    if let Err(e) = check(flash, area, 1, 1) {
        return defaults(LoadError::Store(e));
    }
    match scan(flash, area) {
        Err(e) => defaults(LoadError::Store(e)),
        Ok(Scan {
            newest: Some((k, settings)),
            used,
            ..
        }) => Loaded {
            settings,
            defaults_because: None,
            slot: Some(k),
            used,
            torn: used - k - 1,
        },
        Ok(Scan {
            newest: None,
            used,
            last_error,
            ..
        }) => Loaded {
            used,
            torn: used,
            ..defaults(LoadError::Settings(
                last_error.unwrap_or(SettingsError::Erased),
            ))
        },
    }
}

/// Stores `settings` in `area` (see the module doc): the next erased slot, read back and
/// compared; the area erased first when no slot is left. Settings equal to the newest
/// stored ones are not written again.
pub fn save<F: NorFlash>(
    flash: &mut F,
    area: Area,
    settings: &Settings,
) -> Result<Saved, StoreError> {
    check(flash, area, F::ERASE_SIZE, F::WRITE_SIZE)?;
    let block = settings.encode();
    let found = scan(flash, area)?;
    if let Some((slot, s)) = found.newest
        && s == *settings
        && slot + 1 == found.used
    {
        return Ok(Saved {
            slot,
            erased: false,
            skipped: 0,
            unchanged: true,
        });
    }
    // Old blocks left after the used slots (an erase cut short) would be taken for newer
    // ones once the slots before them are used again: erase first.
    let mut saved = Saved {
        slot: if found.dirty {
            area.slots()
        } else {
            found.used
        },
        erased: false,
        skipped: 0,
        unchanged: false,
    };
    let mut back = [0u8; SETTINGS_LEN];
    // Every slot at most once, plus the whole area again after the erase.
    for _ in 0..2 * area.slots() + 1 {
        if saved.slot >= area.slots() {
            if saved.erased {
                break;
            }
            flash
                .erase(area.offset, area.offset + area.len)
                .map_err(|_| StoreError::Erase)?;
            saved.erased = true;
            saved.slot = 0;
        }
        let at = area.slot_offset(saved.slot);
        flash.write(at, &block).map_err(|_| StoreError::Write)?;
        flash.read(at, &mut back).map_err(|_| StoreError::Read)?;
        if back == block {
            return Ok(saved);
        }
        // A slot that does not hold what was written (a weak cell): it stays used, and
        // fails its CRC at the next load; the next slot is tried.
        saved.skipped += 1;
        saved.slot += 1;
    }
    Err(StoreError::Verify)
}

/// ADC samples a save cost: those its `stall_ms` should have brought at `rate_hz` minus
/// the `read` ones the DRDY task got meanwhile; a difference of up to 2 is the counts'
/// own ±1 at each end, not a loss (0 then).
pub fn samples_lost(stall_ms: u64, rate_hz: f32, read: u32) -> u32 {
    let due = (stall_ms as f32 * rate_hz / 1000.0) as u32;
    let lost = due.saturating_sub(read);
    if lost > 2 { lost } else { 0 }
}

#[cfg(test)]
#[path = "settings_store_tests.rs"]
mod tests;
