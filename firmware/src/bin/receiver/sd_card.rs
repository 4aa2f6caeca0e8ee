//! The Feather's microSD slot on SDIO, as the session log's block device
//! ([`firmware::board::sd_log`]).
//!
//! Wiring on the Feather (schematic nets, MicroPython's `ADAFRUIT_F405_EXPRESS`): CLK PC12,
//! CMD PD2, D0–D3 PC8–PC11 (4-bit bus, the HAL's pin alternate functions), card detect
//! PB12: a switch to ground, pulled up, low with a card in. None of these is on the header.
//!
//! Blocking: `stm32f4xx-hal` 0.23's SDIO polls its FIFO and then the card's status until
//! the card is ready; a card's write can keep it busy for up to 250 ms (the SD
//! specification's write time-out); the idle loop that writes the log is the lowest
//! priority, so the tasks above it go on. After a failed transfer the sink remounts the
//! card ([`SdSink`]) over the same driver: no card re-initialisation, so a remount cures
//! a transfer error of a card that stayed powered, not a card pulled out and put back.
//! The card's power-up loop (ACMD41) has no bound: the boot marks it in the crash record,
//! so a watchdog reset there is reported and the next boot skips the card (see `mount`).

use core::cell::RefCell;
use embedded_sdmmc::{Block, BlockCount, BlockDevice, BlockIdx};
use firmware::board::sd_log::{SdError, SdLog, SdSink};
use stm32f4xx_hal::sdio::{ClockFreq, SdCard, Sdio};

/// The card on SDIO, block by block.
pub struct SdioCard {
    sdio: RefCell<Sdio<SdCard>>,
}

/// Why a transfer with the card failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SdioError {
    /// A command or data transfer failed (time-out, CRC, no card).
    #[error("SDIO transfer failed")]
    Transfer,
    /// The driver was already in use (a transfer inside a transfer).
    #[error("SDIO busy")]
    Busy,
    /// A block number beyond 32 bits.
    #[error("block number out of range")]
    Range,
}

impl SdioCard {
    fn each<B>(
        &self,
        blocks: B,
        start: BlockIdx,
        mut f: impl FnMut(&mut Sdio<SdCard>, u32, B::Item) -> Result<(), stm32f4xx_hal::sdio::Error>,
    ) -> Result<(), SdioError>
    where
        B: IntoIterator,
    {
        let mut sdio = self.sdio.try_borrow_mut().map_err(|_| SdioError::Busy)?;
        for (i, b) in blocks.into_iter().enumerate() {
            let i = u32::try_from(i).map_err(|_| SdioError::Range)?;
            let addr = start.0.checked_add(i).ok_or(SdioError::Range)?;
            f(&mut sdio, addr, b).map_err(|_| SdioError::Transfer)?;
        }
        Ok(())
    }
}

impl BlockDevice for SdioCard {
    type Error = SdioError;

    fn read(&self, blocks: &mut [Block], start_block_idx: BlockIdx) -> Result<(), Self::Error> {
        self.each(blocks.iter_mut(), start_block_idx, |sdio, addr, b| {
            sdio.read_block(addr, &mut b.contents)
        })
    }

    fn write(&self, blocks: &[Block], start_block_idx: BlockIdx) -> Result<(), Self::Error> {
        self.each(blocks.iter(), start_block_idx, |sdio, addr, b| {
            sdio.write_block(addr, &b.contents)
        })
    }

    fn num_blocks(&self) -> Result<BlockCount, Self::Error> {
        let sdio = self.sdio.try_borrow().map_err(|_| SdioError::Busy)?;
        let n = sdio.card().map_err(|_| SdioError::Transfer)?.block_count();
        Ok(BlockCount(u32::try_from(n).map_err(|_| SdioError::Range)?))
    }
}

/// Brings the card up and opens the next session file: `present` from the card-detect
/// switch; `skip` when the last boot hung in this very step (the card is then reported
/// failed without being touched).
pub fn mount(mut sdio: Sdio<SdCard>, present: bool, skip: bool, now_ms: u64) -> SdSink<SdioCard> {
    if !present {
        return SdSink::new(None);
    }
    if skip || sdio.init(ClockFreq::F24Mhz).is_err() {
        return SdSink::new(Some(Err(SdError::Card)));
    }
    let card = SdioCard {
        sdio: RefCell::new(sdio),
    };
    match SdLog::open(card, now_ms) {
        Ok(log) => SdSink::new(Some(Ok(log))),
        // A card that did not answer a transfer is mounted again from the idle loop (the
        // sink's remounts); a card without a FAT volume or a free name would not change.
        Err((SdError::Card, card)) => SdSink::mount_failed(SdError::Card, card, now_ms),
        Err((e, _)) => SdSink::new(Some(Err(e))),
    }
}
