//! The settings store against an emulated NOR flash whose power can be cut at any byte
//! programmed and at any step of an erase: after the cut (a reboot: the same memory, a
//! fresh driver) the settings read are the last saved ones or the ones being saved, never
//! an older save, the defaults or garbage, and the next saves work.

use super::*;
use crate::board::settings::{MAX_VOLUME, REGIONS, SearchMode};
use crate::calibration::record::CalibrationRecord;
use embedded_storage::nor_flash::{ErrorType, NorFlashError, NorFlashErrorKind};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
extern crate std;
use std::vec;
use std::vec::Vec;

/// Erase unit of the emulation (small, so that a test wraps the area often).
const ERASE: usize = 2048;
/// Bytes an erase step clears (the emulated erase runs in 32 steps).
const ERASE_STEP: usize = 64;

/// NOR flash: erase sets whole units to 0xFF, a write can only clear bits (new = old AND
/// data). `budget`: operations (bytes programmed, erase steps) left before the power is
/// cut; the cut operation is left half done (a programmed byte with some of its bits
/// cleared, an erase step with random bits set), and everything after it fails.
struct SimFlash<'a> {
    mem: &'a mut [u8],
    budget: Option<usize>,
    dead: bool,
    rng: SmallRng,
    ops: usize,
    erases: usize,
    /// Byte offsets whose cells are weak: a write leaves them at 0xFF.
    weak: Vec<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Cut;

impl NorFlashError for Cut {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::Other
    }
}

impl<'a> SimFlash<'a> {
    fn new(mem: &'a mut [u8], budget: Option<usize>, seed: u64) -> Self {
        Self {
            mem,
            budget,
            dead: false,
            rng: SmallRng::seed_from_u64(seed),
            ops: 0,
            erases: 0,
            weak: Vec::new(),
        }
    }

    /// One operation: false when the power is cut at it (then it is half done by the
    /// caller).
    fn op(&mut self) -> bool {
        self.ops += 1;
        match self.budget.as_mut() {
            Some(0) => {
                self.dead = true;
                false
            }
            Some(n) => {
                *n -= 1;
                true
            }
            None => true,
        }
    }
}

impl ErrorType for SimFlash<'_> {
    type Error = Cut;
}

impl ReadNorFlash for SimFlash<'_> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Cut> {
        let at = offset as usize;
        match self.mem.get(at..at + bytes.len()) {
            Some(src) if !self.dead => {
                bytes.copy_from_slice(src);
                Ok(())
            }
            _ => Err(Cut),
        }
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for SimFlash<'_> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = ERASE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Cut> {
        let (from, to) = (from as usize, to as usize);
        assert!(from.is_multiple_of(ERASE) && to.is_multiple_of(ERASE) && to <= self.mem.len());
        if self.dead {
            return Err(Cut);
        }
        self.erases += 1;
        for at in (from..to).step_by(ERASE_STEP) {
            if !self.op() {
                // Cut inside this step: its cells end anywhere between old and erased.
                for b in &mut self.mem[at..at + ERASE_STEP] {
                    *b |= self.rng.random::<u8>();
                }
                return Err(Cut);
            }
            self.mem[at..at + ERASE_STEP].fill(0xFF);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Cut> {
        let at = offset as usize;
        assert!(at.is_multiple_of(4) && bytes.len().is_multiple_of(4));
        assert!(at + bytes.len() <= self.mem.len());
        if self.dead {
            return Err(Cut);
        }
        for (i, &b) in bytes.iter().enumerate() {
            if !self.op() {
                // Some of the bits to clear were cleared.
                self.mem[at + i] &= b | self.rng.random::<u8>();
                return Err(Cut);
            }
            if !self.weak.contains(&(at + i)) {
                self.mem[at + i] &= b;
            }
        }
        Ok(())
    }
}

/// The store: two erase units after one unit of something else (the program, say), and
/// one unit after them.
const AREA: Areas = Areas {
    sectors: [
        Area {
            offset: ERASE as u32,
            len: ERASE as u32,
        },
        Area {
            offset: 2 * ERASE as u32,
            len: ERASE as u32,
        },
    ],
};
const FLASH_LEN: usize = 4 * ERASE;
/// Slots per sector in the tests.
const PER: u32 = (ERASE / SLOT_LEN) as u32;

fn settings(n: u32) -> Settings {
    Settings {
        mode: if n.is_multiple_of(2) {
            SearchMode::Sog
        } else {
            SearchMode::Classic
        },
        volume: (n % u32::from(MAX_VOLUME + 1)) as u8,
        region: (n % REGIONS.len() as u32) as u8,
        calibration: CalibrationRecord {
            step_length_m: Some(0.5 + n as f32 * 1e-3),
            ..CalibrationRecord::EMPTY
        },
    }
}

fn erased() -> Vec<u8> {
    vec![0xFF; FLASH_LEN]
}

#[test]
fn saves_load_newest_first_and_erase_once_per_full_sector() {
    let mut mem = erased();
    let mut f = SimFlash::new(&mut mem, None, 1);
    let first = load(&mut f, AREA);
    assert_eq!(first.settings, Settings::DEFAULT);
    assert_eq!(
        first.defaults_because,
        Some(LoadError::Settings(SettingsError::Erased))
    );
    assert_eq!(PER, 12);
    let saves = 4 * PER + 5;
    for n in 0..saves {
        let s = settings(n);
        let saved = save(&mut f, AREA, &s).expect("save");
        // Sector 0, then sector 1 (erased already), then back to sector 0 (erased first).
        let slot = (n / PER % 2) * PER + n % PER;
        assert_eq!(saved.slot, slot, "save {n}");
        assert_eq!(saved.erased, n >= 2 * PER && n % PER == 0, "save {n}");
        let l = load(&mut f, AREA);
        assert_eq!((l.settings, l.slot, l.torn), (s, Some(slot), 0));
    }
    assert_eq!(f.erases, 3);
    // The same settings again: nothing written.
    let ops = f.ops;
    let again = save(&mut f, AREA, &settings(saves - 1)).expect("save");
    assert!(again.unchanged);
    assert_eq!(f.ops, ops);
    // The bytes outside the store are untouched.
    assert!(
        mem[..ERASE]
            .iter()
            .chain(&mem[3 * ERASE..])
            .all(|&b| b == 0xFF)
    );
}

/// Cuts the power at every operation of one save (from a flash holding `old` as its
/// newest settings, `prefill` saves in) and reboots: what loads is `old`, the new
/// settings or (only when `may_default`) the defaults; a save after the reboot works.
/// Returns how often each outcome was seen: (old, new, defaults).
fn cut_everywhere(prefill: u32, may_default: bool, seed: u64) -> (usize, usize, usize) {
    let mut base = erased();
    {
        let mut f = SimFlash::new(&mut base, None, seed);
        for n in 0..prefill {
            save(&mut f, AREA, &settings(n)).expect("prefill");
        }
    }
    let old = if prefill == 0 {
        Settings::DEFAULT
    } else {
        settings(prefill - 1)
    };
    let new = settings(1000);
    // How many operations the uncut save takes.
    let total = {
        let mut mem = base.clone();
        let mut f = SimFlash::new(&mut mem, None, seed);
        save(&mut f, AREA, &new).expect("uncut save");
        f.ops
    };
    let mut seen = (0, 0, 0);
    for cut in 0..=total {
        let mut mem = base.clone();
        let r = save(
            &mut SimFlash::new(&mut mem, Some(cut), seed ^ cut as u64),
            AREA,
            &new,
        );
        assert_eq!(r.is_ok(), cut == total, "cut at {cut} of {total}");
        // Reboot.
        let mut f = SimFlash::new(&mut mem, None, seed);
        let got = load(&mut f, AREA).settings;
        if got == old {
            seen.0 += 1;
        } else if got == new {
            seen.1 += 1;
        } else if got == Settings::DEFAULT && may_default {
            seen.2 += 1;
        } else {
            panic!("cut at {cut} of {total}: loaded {got:?}");
        }
        // Saves after the reboot, through two sector switches: each is the one that loads
        // (none of the leftovers).
        for n in 2000..2000 + 2 * PER + 2 {
            save(&mut f, AREA, &settings(n)).expect("save after the reboot");
            assert_eq!(
                load(&mut f, AREA).settings,
                settings(n),
                "cut at {cut}, save {n}"
            );
        }
    }
    seen
}

#[test]
fn a_cut_while_programming_keeps_the_old_settings() {
    for seed in 0..4 {
        // First save on an erased store: "old" is the defaults; every cut but the last
        // loads them.
        assert_eq!(
            cut_everywhere(0, true, seed),
            (SLOT_LEN, 1, 0),
            "seed {seed}"
        );
        // A save into a half-used sector, and the first save into the second (erased)
        // sector.
        for prefill in [5, PER] {
            assert_eq!(
                cut_everywhere(prefill, false, seed),
                (SLOT_LEN, 1, 0),
                "seed {seed}"
            );
        }
    }
}

#[test]
fn a_cut_in_an_erase_keeps_the_last_save_and_never_brings_back_an_older_one() {
    for seed in 0..4 {
        // The active sector is full and the other holds older saves: the save erases the
        // other (32 steps) and programs its first slot. Every cut in the erase, between
        // the erase and the program, or in the program loads the last save; the older
        // blocks the cut erase leaves are never taken (and the defaults never load).
        for prefill in [2 * PER, 3 * PER] {
            let (old, new, def) = cut_everywhere(prefill, false, seed);
            assert_eq!(
                (old, new, def),
                (ERASE / ERASE_STEP + SLOT_LEN, 1, 0),
                "seed {seed}"
            );
        }
    }
}

#[test]
fn random_cuts_through_many_switches_never_lose_or_rewind() {
    for seed in 0..6u64 {
        let mut rng = SmallRng::seed_from_u64(seed);
        let mut mem = erased();
        let mut last = Settings::DEFAULT;
        let mut cuts = 0;
        for n in 0..10 * PER {
            let new = settings(n);
            let budget = rng
                .random_bool(0.3)
                .then(|| rng.random_range(0..ERASE / ERASE_STEP + SLOT_LEN));
            let r = save(
                &mut SimFlash::new(&mut mem, budget, seed ^ u64::from(n)),
                AREA,
                &new,
            );
            let got = load(&mut SimFlash::new(&mut mem, None, seed), AREA).settings;
            if r.is_ok() {
                assert_eq!(got, new, "seed {seed}, save {n}");
            } else {
                cuts += 1;
                assert!(got == last || got == new, "seed {seed}, save {n}: {got:?}");
            }
            last = got;
        }
        assert!(cuts > PER, "seed {seed}: {cuts} cuts");
    }
}

#[test]
fn a_torn_block_in_the_middle_is_skipped_and_reported() {
    let mut mem = erased();
    {
        let mut f = SimFlash::new(&mut mem, None, 3);
        save(&mut f, AREA, &settings(1)).expect("save");
    }
    {
        // Cut half-way through the second block.
        let mut f = SimFlash::new(&mut mem, Some(70), 3);
        assert_eq!(save(&mut f, AREA, &settings(2)), Err(StoreError::Write));
    }
    let mut f = SimFlash::new(&mut mem, None, 3);
    let l = load(&mut f, AREA);
    assert_eq!(
        (l.settings, l.slot, l.used, l.torn),
        (settings(1), Some(0), 2, 1)
    );
    // The next save goes after the torn slot and is the one that loads.
    let s = save(&mut f, AREA, &settings(3)).expect("save");
    assert_eq!((s.slot, s.erased), (2, false));
    let l = load(&mut f, AREA);
    assert_eq!((l.settings, l.slot, l.torn), (settings(3), Some(2), 0));
}

#[test]
fn a_slot_that_does_not_read_back_is_skipped() {
    let mut mem = erased();
    let mut f = SimFlash::new(&mut mem, None, 4);
    // A weak cell inside the first slot's CRC.
    f.weak.push(ERASE + SLOT_LEN - 10);
    let s = save(&mut f, AREA, &settings(7)).expect("save");
    assert_eq!((s.slot, s.skipped), (1, 1));
    let l = load(&mut f, AREA);
    assert_eq!((l.settings, l.slot), (settings(7), Some(1)));
}

#[test]
fn a_bad_area_is_refused_and_load_falls_back() {
    let mut mem = erased();
    let mut f = SimFlash::new(&mut mem, None, 5);
    let unit = |offset: u32, len: u32| Area { offset, len };
    let e = ERASE as u32;
    for sectors in [
        [unit(100, e), unit(2 * e, e)],
        [unit(0, 100), unit(2 * e, e)],
        [unit(e, e), unit(3 * e, 2 * e)],
        [unit(e, 2 * e), unit(2 * e, e)],
        [unit(e, e), unit(2 * e, 2 * e)],
    ] {
        assert_eq!(
            save(&mut f, Areas { sectors }, &settings(1)),
            Err(StoreError::Layout),
            "{sectors:?}"
        );
    }
    let beyond = Areas {
        sectors: [unit(e, e), unit(FLASH_LEN as u32, e)],
    };
    let l = load(&mut f, beyond);
    assert_eq!(
        (l.settings, l.defaults_because),
        (
            Settings::DEFAULT,
            Some(LoadError::Store(StoreError::Layout))
        )
    );
    // A flash that cannot be read gives the defaults too.
    f.dead = true;
    assert_eq!(
        load(&mut f, AREA).defaults_because,
        Some(LoadError::Store(StoreError::Read))
    );
}

#[test]
fn random_garbage_in_the_area_never_loads_as_settings() {
    let mut rng = SmallRng::seed_from_u64(6);
    for _ in 0..200 {
        let mut mem = erased();
        // Random bytes over a random part of the area (an erase cut short, noise).
        let n = rng.random_range(1..2 * ERASE);
        for b in &mut mem[ERASE..ERASE + n] {
            *b = rng.random();
        }
        let mut f = SimFlash::new(&mut mem, None, 6);
        let l = load(&mut f, AREA);
        assert_eq!(l.settings, Settings::DEFAULT);
        save(&mut f, AREA, &settings(9)).expect("save over garbage");
        assert_eq!(load(&mut f, AREA).settings, settings(9));
    }
}

#[test]
fn the_board_store_is_sectors_10_and_11() {
    assert_eq!(
        BOARD_AREA.sectors[0],
        Area {
            offset: 0xC_0000,
            len: 128 * 1024
        }
    );
    assert_eq!(
        BOARD_AREA.sectors[1],
        Area {
            offset: 0xE_0000,
            len: 128 * 1024
        }
    );
    assert_eq!(BOARD_AREA.sectors[0].slots(), 819);
    // Slots stay aligned to the flash's 16-byte rows and 4-byte words.
    assert!(SLOT_LEN.is_multiple_of(16));
}

#[test]
fn a_stalled_save_counts_the_samples_it_cost() {
    // A 2 ms program with the DRDY task stalled throughout: 16 samples at 8 kSPS.
    assert_eq!(samples_lost(2, 8000.0, 0), 16);
    // The same time with every sample read (the interrupt ran from the cache): none.
    assert_eq!(samples_lost(2, 8000.0, 15), 0);
    // A 1.8 s erase: 14 400 due, 3 read around it.
    assert_eq!(samples_lost(1800, 8000.0, 3), 14_397);
    assert_eq!(samples_lost(0, 8000.0, 0), 0);
}
