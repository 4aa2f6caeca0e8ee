//! The settings in flash, safe against a power cut at any moment: two erase units (on the
//! board flash sectors 10 and 11, 128 KB each, [`SLOT_LEN`]-byte slots, 819 per sector)
//! used in turn, over any [`NorFlash`] (embedded-storage: the HAL's flash on the board,
//! an emulation in the tests).
//!
//! Each slot holds a [`Settings`] block, a save counter (`seq`) and a CRC-32 over both.
//! - **Load** takes the valid slot with the highest `seq` in either sector (a slot is
//!   valid when its CRC and the block's own checks pass: [`Settings::decode`]).
//! - **Save** appends `seq + 1` after the last written slot of the sector holding the
//!   newest block, reads it back and compares (a slot that does not read back is
//!   skipped). When that sector is full, the *other* sector is erased (unless it is
//!   erased already) and the block goes to its first slot: the sector with the newest
//!   block is never erased, so a cut in the erase or between the erase and the program
//!   leaves the newest block where it was. One erase per 819 saves: the erase's stall
//!   (up to 2–4 s on the STM32F405, instruction fetch stopped; docs/board.md) is rare,
//!   and a save is usually a 160-byte program (≈ 2 ms).
//!
//! What a cut leaves: during a program, a torn slot that fails its CRC, so the previous
//! settings load; during an erase, a sector of old blocks (lower `seq`), garbage and
//! erased cells beside the untouched sector with the newest block, which loads. So a load
//! after a cut gives the last saved settings or the ones being saved, never an older
//! save and never garbage (defaults only before the first save completes). `cargo test
//! -p firmware board::settings_store` cuts the power at every byte written and every
//! erase step, through sector switches.

use crate::board::settings::{SETTINGS_ADDR, SETTINGS_LEN, Settings, SettingsError};
use crate::calibration::record::crc32;
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

/// Start of the STM32F405's flash in the address map: offset 0 of its flash driver.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// Bytes of one slot: the settings block, `seq` (u32), CRC-32 of both, zero padding to a
/// 16-byte flash row (the HAL programs rows of 16 bytes).
pub const SLOT_LEN: usize = 160;
const SEQ_AT: usize = SETTINGS_LEN;
const CRC_AT: usize = SEQ_AT + 4;
const PAD_AT: usize = CRC_AT + 4;
/// The board's settings: flash sectors 10 and 11 (128 KB each; `memory.x` keeps the
/// program out).
pub const BOARD_AREA: Areas = Areas {
    sectors: [
        Area {
            offset: SETTINGS_ADDR - FLASH_BASE,
            len: 128 * 1024,
        },
        Area {
            offset: SETTINGS_ADDR - FLASH_BASE + 128 * 1024,
            len: 128 * 1024,
        },
    ],
};

/// One erase unit of the store: `len` bytes from `offset` (offsets as the flash driver
/// counts them; on the board from the start of the flash, 0x0800_0000).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Area {
    /// First byte of the area (a multiple of the flash's erase size).
    pub offset: u32,
    /// Bytes of the area (a multiple of the erase size, at least one slot).
    pub len: u32,
}

impl Area {
    /// Whole slots the area holds.
    pub fn slots(&self) -> u32 {
        self.len / SLOT_LEN as u32
    }

    fn slot_offset(&self, k: u32) -> u32 {
        self.offset + k * SLOT_LEN as u32
    }
}

/// The two erase units used in turn (never overlapping, each its own erase).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Areas {
    /// The sectors; a slot's number counts the first sector's slots first.
    pub sectors: [Area; 2],
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

/// The layout's checks: alignment to the flash's sizes, room for a slot, within the
/// flash, the two sectors apart.
fn check<F: ReadNorFlash>(
    flash: &F,
    areas: Areas,
    erase: usize,
    write: usize,
) -> Result<(), StoreError> {
    let aligned = |n: usize, to: usize| to != 0 && n.is_multiple_of(to);
    let one = |a: Area| {
        let (off, len) = (a.offset as usize, a.len as usize);
        aligned(off, erase)
            && aligned(len, erase)
            && len >= SLOT_LEN
            && off
                .checked_add(len)
                .is_some_and(|end| end <= flash.capacity())
    };
    let [a, b] = areas.sectors;
    let apart =
        a.offset.saturating_add(a.len) <= b.offset || b.offset.saturating_add(b.len) <= a.offset;
    let ok = one(a)
        && one(b)
        && apart
        && a.slots() == b.slots()
        && aligned(SLOT_LEN, write)
        && aligned(SLOT_LEN, F::READ_SIZE);
    if ok { Ok(()) } else { Err(StoreError::Layout) }
}

/// The slot holding `block` as save number `seq`.
fn encode_slot(seq: u32, block: &[u8; SETTINGS_LEN]) -> [u8; SLOT_LEN] {
    let mut slot = [0u8; SLOT_LEN];
    slot[..SETTINGS_LEN].copy_from_slice(block);
    slot[SEQ_AT..CRC_AT].copy_from_slice(&seq.to_le_bytes());
    let crc = crc32(&slot[..CRC_AT]);
    slot[CRC_AT..PAD_AT].copy_from_slice(&crc.to_le_bytes());
    slot
}

/// A slot's save number and settings, or why it is not taken.
fn decode_slot(slot: &[u8; SLOT_LEN]) -> Result<(u32, Settings), SettingsError> {
    if slot.iter().all(|&b| b == 0xFF) {
        return Err(SettingsError::Erased);
    }
    let word = |at: usize| {
        slot.get(at..at + 4)
            .and_then(|w| w.try_into().ok())
            .map(u32::from_le_bytes)
    };
    let (Some(seq), Some(crc)) = (word(SEQ_AT), word(CRC_AT)) else {
        return Err(SettingsError::Length);
    };
    // A block of 0xFF beside written bytes is garbage, not an erased slot.
    let settings = Settings::decode(&slot[..SETTINGS_LEN]).map_err(|e| match e {
        SettingsError::Erased => SettingsError::Crc,
        e => e,
    })?;
    if crc != crc32(&slot[..CRC_AT]) || slot[PAD_AT..].iter().any(|&b| b != 0) {
        return Err(SettingsError::Crc);
    }
    Ok((seq, settings))
}

/// One sector's slots: its newest valid block (`seq`, slot, settings), how many slots
/// are written (up to the last one not erased), the last written slot's error when it
/// is not valid.
#[derive(Debug, Clone, Copy)]
struct SectorScan {
    newest: Option<(u32, u32, Settings)>,
    used: u32,
    last_error: Option<SettingsError>,
}

fn scan_sector<F: ReadNorFlash>(flash: &mut F, area: Area) -> Result<SectorScan, StoreError> {
    let mut s = SectorScan {
        newest: None,
        used: 0,
        last_error: None,
    };
    let mut slot = [0u8; SLOT_LEN];
    for k in 0..area.slots() {
        flash
            .read(area.slot_offset(k), &mut slot)
            .map_err(|_| StoreError::Read)?;
        match decode_slot(&slot) {
            Err(SettingsError::Erased) => continue,
            Ok((seq, settings)) => {
                // A later slot with the same `seq` is a retry after a failed read-back.
                if s.newest.is_none_or(|(n, _, _)| seq >= n) {
                    s.newest = Some((seq, k, settings));
                }
                s.last_error = None;
            }
            Err(e) => s.last_error = Some(e),
        }
        s.used = k + 1;
    }
    Ok(s)
}

/// Element `i` (0 or 1; 1 for anything else) of a pair.
fn of<T: Copy>(pair: [T; 2], i: usize) -> T {
    let [a, b] = pair;
    if i == 0 { a } else { b }
}

/// Both sectors, and which one holds the newest block (the first when none does).
struct Scan {
    sectors: [SectorScan; 2],
    active: usize,
}

fn scan<F: ReadNorFlash>(flash: &mut F, areas: Areas) -> Result<Scan, StoreError> {
    let sectors = [
        scan_sector(flash, areas.sectors[0])?,
        scan_sector(flash, areas.sectors[1])?,
    ];
    let seq = |s: &SectorScan| s.newest.map(|(n, _, _)| n);
    let active = usize::from(seq(&sectors[1]) > seq(&sectors[0]));
    Ok(Scan { sectors, active })
}

/// The newest stored settings, or the defaults with the reason. Never fails: a flash that
/// cannot be read gives the defaults too.
pub fn load<F: ReadNorFlash>(flash: &mut F, areas: Areas) -> Loaded {
    let defaults = |e| Loaded {
        settings: Settings::DEFAULT,
        defaults_because: Some(e),
        slot: None,
        used: 0,
        torn: 0,
    };
    if let Err(e) = check(flash, areas, 1, 1) {
        return defaults(LoadError::Store(e));
    }
    let found = match scan(flash, areas) {
        Err(e) => return defaults(LoadError::Store(e)),
        Ok(found) => found,
    };
    let s = of(found.sectors, found.active);
    match s.newest {
        Some((_, k, settings)) => Loaded {
            settings,
            defaults_because: None,
            slot: Some(found.active as u32 * areas.sectors[0].slots() + k),
            used: s.used,
            torn: s.used - k - 1,
        },
        None => {
            let last_error = found.sectors[1].last_error.or(found.sectors[0].last_error);
            Loaded {
                used: s.used,
                torn: found.sectors[0].used + found.sectors[1].used,
                ..defaults(LoadError::Settings(
                    last_error.unwrap_or(SettingsError::Erased),
                ))
            }
        }
    }
}

/// Stores `settings` (see the module doc): appended after the newest block's sector's
/// written slots, read back and compared; when that sector is full, the other one is
/// erased and takes it. Settings equal to the newest stored ones are not written again.
pub fn save<F: NorFlash>(
    flash: &mut F,
    areas: Areas,
    settings: &Settings,
) -> Result<Saved, StoreError> {
    check(flash, areas, F::ERASE_SIZE, F::WRITE_SIZE)?;
    let found = scan(flash, areas)?;
    let per = areas.sectors[0].slots();
    let active = of(found.sectors, found.active);
    if let Some((_, k, s)) = active.newest
        && s == *settings
        && k + 1 == active.used
    {
        return Ok(Saved {
            slot: found.active as u32 * per + k,
            erased: false,
            skipped: 0,
            unchanged: true,
        });
    }
    let seq = active.newest.map_or(0, |(n, _, _)| n.wrapping_add(1));
    let slot = encode_slot(seq, &settings.encode());
    let mut sector = found.active;
    let mut k = active.used;
    let mut saved = Saved {
        slot: 0,
        erased: false,
        skipped: 0,
        unchanged: false,
    };
    let mut back = [0u8; SLOT_LEN];
    // Every slot of the sector at most once, plus the other sector after its erase.
    for _ in 0..2 * per + 1 {
        if k >= per {
            if sector != found.active {
                break;
            }
            // Never erase the sector with the newest block: the other one takes over.
            sector = 1 - found.active;
            if of(found.sectors, sector).used > 0 {
                let a = of(areas.sectors, sector);
                flash
                    .erase(a.offset, a.offset + a.len)
                    .map_err(|_| StoreError::Erase)?;
                saved.erased = true;
            }
            k = 0;
        }
        let at = of(areas.sectors, sector).slot_offset(k);
        flash.write(at, &slot).map_err(|_| StoreError::Write)?;
        flash.read(at, &mut back).map_err(|_| StoreError::Read)?;
        if back == slot {
            saved.slot = sector as u32 * per + k;
            return Ok(saved);
        }
        // A slot that does not hold what was written (a weak cell): it fails its CRC at
        // the next load; the next slot is tried.
        saved.skipped += 1;
        k += 1;
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
