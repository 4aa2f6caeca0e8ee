//! The session log on the microSD card: one FAT file per session, `SESS0001.LOG`,
//! `SESS0002.LOG`, … (the next number after the highest on the card), written through
//! `embedded-sdmmc` over any [`BlockDevice`] (the board: SDIO; the tests: [`RamCard`]).
//!
//! Power loss: FAT records a file's length in its directory entry, and `embedded-sdmmc`
//! writes that entry only when the file is flushed. Whatever was written after the last
//! flush is therefore invisible after a power cut, however much of it reached the card;
//! what was flushed stays. [`SdLog::poll`] flushes every [`FLUSH_INTERVAL_MS`], so at most
//! the last second of records is lost. Because the board calls `poll` between records,
//! every flushed length ends on a whole line: the file a cut leaves is a clean prefix of
//! the session.
//!
//! Writes are whole 512-byte blocks at block boundaries (one block buffered in RAM, no
//! read-modify-write); a flush writes the partial block too and keeps it buffered, so the
//! same block is written again, whole or partial, until it is full. A block rewritten in
//! place holds the old bytes as its prefix, so a cut during the rewrite still leaves the
//! flushed length's bytes intact.
//!
//! Errors: the first failed write or flush puts the log in a failed state; every byte
//! given to it from then on is counted as lost (and the `fmt::Write` calls fail, so the
//! session-log [`Recorder`](crate::session_log::Recorder) counts the records). The board
//! shows the failure as an SD fault; [`SdSink`] remounts the card every
//! [`REMOUNT_INTERVAL_MS`] ([`SdLog::into_card`], then [`SdLog::open`]: a new session
//! file, which the board log starts with a header), [`REMOUNT_TRIES`] times per failure.

use core::cell::{Cell, RefCell};
use core::ops::ControlFlow;
use embedded_sdmmc::{
    Block, BlockCount, BlockDevice, BlockIdx, Mode, RawDirectory, RawFile, RawVolume,
    ShortFileName, TimeSource, Timestamp, VolumeIdx, VolumeManager,
};

/// Longest time between two flushes, ms: half the one second the log may lose, so that a
/// flush delayed by a slow card write or a long main-loop step still keeps within it.
pub const FLUSH_INTERVAL_MS: u64 = 500;
/// Base name of the session files (8.3 names: four letters, four digits).
pub const FILE_PREFIX: &str = "SESS";
/// Extension of the session files.
pub const FILE_EXT: &str = "LOG";
/// Highest session number (four digits).
pub const MAX_SESSION: u16 = 9999;
/// Time between a failure and a remount, and between two remounts that fail, ms (a card
/// reseated or a glitch passed; long enough that a dead card costs little).
pub const REMOUNT_INTERVAL_MS: u64 = 5_000;
/// Remounts tried after a failure before the card is left alone until the next boot.
pub const REMOUNT_TRIES: u8 = 5;

/// Why the SD log is not writing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SdError {
    /// The card did not answer (absent, not initialised, a transfer failed).
    #[error("SD card not answering")]
    Card,
    /// No FAT volume in the card's first partition.
    #[error("no FAT volume on the SD card")]
    Volume,
    /// Session numbers up to the highest one are used.
    #[error("all session file numbers used")]
    Numbers,
    /// The card is full.
    #[error("SD card full")]
    Full,
    /// Another file-system error (a corrupted directory, a library limit).
    #[error("SD file system error")]
    FileSystem,
    /// An earlier error stopped the log; it must be reopened.
    #[error("SD log stopped by an earlier error")]
    Stopped,
}

impl<E: core::error::Error> From<embedded_sdmmc::Error<E>> for SdError {
    fn from(e: embedded_sdmmc::Error<E>) -> Self {
        use embedded_sdmmc::Error as E;
        match e {
            E::DeviceError(_) => SdError::Card,
            E::FormatError(_) | E::NoSuchVolume | E::Unsupported => SdError::Volume,
            E::DiskFull | E::NotEnoughSpace => SdError::Full,
            _ => SdError::FileSystem,
        }
    }
}

/// The files' time stamp: the board has no set clock, so every file carries this fixed
/// date (2026-01-01 00:00:00); the session number orders the files.
#[derive(Debug, Clone, Copy, Default)]
pub struct FixedTime;

impl TimeSource for FixedTime {
    fn get_timestamp(&self) -> Timestamp {
        Timestamp {
            year_since_1970: 56,
            zero_indexed_month: 0,
            zero_indexed_day: 0,
            hours: 0,
            minutes: 0,
            seconds: 0,
        }
    }
}

/// The 8.3 name of session `n`, e.g. `SESS0042.LOG`.
pub fn file_name(n: u16) -> [u8; 12] {
    let mut name = *b"SESS0000.LOG";
    let v = n.min(MAX_SESSION);
    let digits = [v / 1000, v / 100 % 10, v / 10 % 10, v % 10];
    for (c, d) in name.iter_mut().skip(4).zip(digits) {
        // d < 10: the cast cannot truncate.
        *c = b'0' + d as u8;
    }
    name
}

/// The session number of a directory entry's name, if it is a session file.
pub fn session_number(name: &ShortFileName) -> Option<u16> {
    let (head, digits) = name.base_name().split_at_checked(4)?;
    if name.extension() != FILE_EXT.as_bytes() || head != FILE_PREFIX.as_bytes() {
        return None;
    }
    if digits.len() != 4 {
        return None;
    }
    digits.iter().try_fold(0u16, |n, &c| {
        c.is_ascii_digit().then(|| n * 10 + u16::from(c - b'0'))
    })
}

/// What the SD log did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SdStats {
    /// Bytes accepted (buffered or on the card).
    pub bytes: u64,
    /// Bytes safely on the card: the file's length at the last flush.
    pub flushed_bytes: u64,
    /// Flushes done.
    pub flushes: u32,
    /// Failed writes or flushes (the first one stops the log).
    pub errors: u32,
    /// Bytes refused after the log stopped, and bytes buffered when it stopped.
    pub lost_bytes: u64,
}

/// A session file open on the card, buffered by one block.
pub struct SdLog<D: BlockDevice> {
    mgr: VolumeManager<D, FixedTime, 1, 1, 1>,
    volume: RawVolume,
    dir: RawDirectory,
    file: RawFile,
    number: u16,
    /// The file's bytes from `block_start` on (a partial last block).
    buf: [u8; Block::LEN],
    len: usize,
    /// File offset of `buf[0]`, a multiple of the block length.
    block_start: u32,
    /// Bytes given since the last flush.
    unflushed: bool,
    last_flush_ms: u64,
    failed: Option<SdError>,
    stats: SdStats,
}

impl<D: BlockDevice> SdLog<D> {
    /// Mounts the card's first FAT volume and creates the next session file in its root
    /// directory. On error the card is handed back (to retry later).
    pub fn open(card: D, now_ms: u64) -> Result<Self, (SdError, D)> {
        let mgr = VolumeManager::new_with_limits(card, FixedTime, 0);
        match Self::create(&mgr) {
            Ok((volume, dir, file, number)) => Ok(Self {
                mgr,
                volume,
                dir,
                file,
                number,
                buf: [0; Block::LEN],
                len: 0,
                block_start: 0,
                unflushed: false,
                last_flush_ms: now_ms,
                failed: None,
                stats: SdStats::default(),
            }),
            Err(e) => Err((e, mgr.free().0)),
        }
    }

    fn create(
        mgr: &VolumeManager<D, FixedTime, 1, 1, 1>,
    ) -> Result<(RawVolume, RawDirectory, RawFile, u16), SdError> {
        let volume = mgr.open_raw_volume(VolumeIdx(0))?;
        let dir = mgr.open_root_dir(volume)?;
        let mut highest = 0u16;
        mgr.iterate_dir(dir, |entry| {
            if let Some(n) = session_number(&entry.name) {
                highest = highest.max(n);
            }
            ControlFlow::Continue(())
        })?;
        if highest >= MAX_SESSION {
            return Err(SdError::Numbers);
        }
        let number = highest + 1;
        let name = file_name(number);
        // The name is ASCII by construction.
        let name = core::str::from_utf8(&name).map_err(|_| SdError::FileSystem)?;
        let file = mgr.open_file_in_dir(dir, name, Mode::ReadWriteCreate)?;
        Ok((volume, dir, file, number))
    }

    /// The session number (the file is [`file_name`] of it).
    pub fn number(&self) -> u16 {
        self.number
    }

    /// Runs `f` on the card (its status, the emulated card's controls).
    pub fn card<R>(&self, f: impl FnOnce(&mut D) -> R) -> R {
        self.mgr.device(f)
    }

    /// What the log did so far.
    pub fn stats(&self) -> SdStats {
        self.stats
    }

    /// The error that stopped the log, if any.
    pub fn failure(&self) -> Option<SdError> {
        self.failed
    }

    fn fail(&mut self, e: SdError) -> SdError {
        self.stats.errors = self.stats.errors.saturating_add(1);
        if self.failed.is_none() {
            self.failed = Some(e);
            // What was not flushed is lost with the file's length.
            self.stats.lost_bytes += self.stats.bytes - self.stats.flushed_bytes;
        }
        e
    }

    /// Writes `buf[..len]` at `block_start` (whole block: no read of the old block).
    fn write_buffer(&mut self) -> Result<(), SdError> {
        self.mgr.file_seek_from_start(self.file, self.block_start)?;
        let bytes = self.buf.get(..self.len).ok_or(SdError::FileSystem)?;
        self.mgr.write(self.file, bytes)?;
        Ok(())
    }

    /// Appends `bytes` to the session file (through the block buffer).
    pub fn write(&mut self, mut bytes: &[u8]) -> Result<(), SdError> {
        if self.failed.is_some() {
            self.stats.lost_bytes += bytes.len() as u64;
            return Err(SdError::Stopped);
        }
        self.stats.bytes += bytes.len() as u64;
        self.unflushed |= !bytes.is_empty();
        while !bytes.is_empty() {
            let n = bytes.len().min(Block::LEN.saturating_sub(self.len));
            let (now, later) = bytes.split_at(n);
            if let Some(dst) = self.buf.get_mut(self.len..self.len + n) {
                dst.copy_from_slice(now);
            }
            self.len += n;
            bytes = later;
            if self.len == Block::LEN {
                if let Err(e) = self.write_buffer() {
                    // The bytes still to come are lost too.
                    self.stats.lost_bytes += bytes.len() as u64;
                    return Err(self.fail(e));
                }
                self.block_start += Block::LEN_U32;
                self.len = 0;
            }
        }
        Ok(())
    }

    /// Writes the buffered bytes and the file's length to the card, now.
    pub fn flush(&mut self, now_ms: u64) -> Result<(), SdError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        self.last_flush_ms = now_ms;
        if !self.unflushed {
            return Ok(());
        }
        let r = if self.len > 0 {
            self.write_buffer()
        } else {
            Ok(())
        }
        .and_then(|()| Ok(self.mgr.flush_file(self.file)?));
        match r {
            Ok(()) => {
                self.unflushed = false;
                self.stats.flushes += 1;
                self.stats.flushed_bytes = self.stats.bytes;
                Ok(())
            }
            Err(e) => Err(self.fail(e)),
        }
    }

    /// Flushes when [`FLUSH_INTERVAL_MS`] has passed since the last flush; call between
    /// records (then every flushed length ends on a whole line). True if it flushed.
    pub fn poll(&mut self, now_ms: u64) -> Result<bool, SdError> {
        if self.failed.is_none() && now_ms.saturating_sub(self.last_flush_ms) >= FLUSH_INTERVAL_MS {
            self.flush(now_ms).map(|()| true)
        } else {
            self.failed.map_or(Ok(false), Err)
        }
    }

    /// Flushes and closes the file and the volume, and hands the card back (to reopen it
    /// or to read it). The flush's error, if any, comes with the card.
    pub fn into_card(mut self, now_ms: u64) -> (D, Result<(), SdError>) {
        let r = self.flush(now_ms);
        // Close errors change nothing for the caller: the handles go with the manager.
        let closed = self
            .mgr
            .close_file(self.file)
            .and_then(|()| self.mgr.close_dir(self.dir))
            .and_then(|()| self.mgr.close_volume(self.volume));
        let r = r.and(closed.map_err(SdError::from));
        (self.mgr.free().0, r)
    }
}

impl<D: BlockDevice> core::fmt::Write for SdLog<D> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        self.write(s.as_bytes()).map_err(|_| core::fmt::Error)
    }
}

/// What the SD log is doing, as the board shows and logs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SdState {
    /// Writing session file number .0.
    Logging(u16),
    /// No card in the slot (card detect): nothing is written, by the user's choice.
    NoCard,
    /// The card is there but not writing: at boot (mount, no FAT volume, no free name) or
    /// since a write failed.
    Failed(SdError),
}

impl SdState {
    /// A short word for the display and the log (`None` while logging).
    pub fn fault_label(self) -> Option<&'static str> {
        match self {
            SdState::Logging(_) => None,
            SdState::NoCard => Some("NO SD"),
            SdState::Failed(_) => Some("SD ERR"),
        }
    }
}

/// The SD side of the board's session log: the open session file, or why there is none.
/// As a `fmt::Write` it fails once the card has failed (so every record lost is counted
/// by the recorder) and takes records silently when no card is inserted (the state says
/// so on the display). A failed card is remounted into a new session file
/// ([`SdSink::poll`]).
pub struct SdSink<D: BlockDevice> {
    log: Option<SdLog<D>>,
    /// The card of a failed log or mount, kept for the next remount.
    card: Option<D>,
    state: SdState,
    /// When the next remount is due, while one is.
    retry_at_ms: Option<u64>,
    tries_left: u8,
    remounts: u32,
    /// Bytes the logs before the last remount lost.
    lost_before: u64,
}

impl<D: BlockDevice> SdSink<D> {
    /// The sink after the boot's mount attempt: `None` when no card is inserted.
    pub fn new(mounted: Option<Result<SdLog<D>, SdError>>) -> Self {
        let mut sink = Self {
            log: None,
            card: None,
            state: SdState::NoCard,
            retry_at_ms: None,
            tries_left: 0,
            remounts: 0,
            lost_before: 0,
        };
        match mounted {
            None => {}
            Some(Ok(log)) => {
                sink.state = SdState::Logging(log.number());
                sink.log = Some(log);
            }
            Some(Err(e)) => sink.state = SdState::Failed(e),
        }
        sink
    }

    /// The sink after a failed boot mount that handed the card back: remounts are tried
    /// from `now_ms` + [`REMOUNT_INTERVAL_MS`] on.
    pub fn mount_failed(e: SdError, card: D, now_ms: u64) -> Self {
        let mut sink = Self::new(Some(Err(e)));
        sink.card = Some(card);
        sink.schedule_remounts(now_ms);
        sink
    }

    /// The current state.
    pub fn state(&self) -> SdState {
        self.state
    }

    /// The open log's counts (none without a log); `lost_bytes` includes what the logs
    /// before a remount lost.
    pub fn stats(&self) -> Option<SdStats> {
        self.log.as_ref().map(|l| SdStats {
            lost_bytes: l.stats().lost_bytes + self.lost_before,
            ..l.stats()
        })
    }

    /// Remounts that gave a new session file since boot.
    pub fn remounts(&self) -> u32 {
        self.remounts
    }

    /// Runs `f` on the open log's card (the emulated card's controls).
    pub fn card<R>(&self, f: impl FnOnce(&mut D) -> R) -> Option<R> {
        self.log.as_ref().map(|l| l.card(f))
    }

    fn schedule_remounts(&mut self, now_ms: u64) {
        self.tries_left = REMOUNT_TRIES;
        self.retry_at_ms = Some(now_ms.saturating_add(REMOUNT_INTERVAL_MS));
    }

    /// Flushes when due ([`SdLog::poll`]); after a failure, remounts the card when due
    /// (a new session file: the state becomes `Logging` with its number). Returns the new
    /// state when it changed.
    pub fn poll(&mut self, now_ms: u64) -> Option<SdState> {
        if let Some(log) = self.log.as_mut()
            && let Err(e) = log.poll(now_ms)
            && self.state != SdState::Failed(e)
        {
            self.state = SdState::Failed(e);
            self.schedule_remounts(now_ms);
            return Some(self.state);
        }
        match self.retry_at_ms {
            Some(at) if now_ms >= at => self.remount(now_ms),
            _ => None,
        }
    }

    fn remount(&mut self, now_ms: u64) -> Option<SdState> {
        let card = match self.log.take() {
            Some(log) => {
                self.lost_before += log.stats().lost_bytes;
                // The failed log's flush fails; its handles close with it.
                log.into_card(now_ms).0
            }
            None => self.card.take()?,
        };
        match SdLog::open(card, now_ms) {
            Ok(log) => {
                self.state = SdState::Logging(log.number());
                self.log = Some(log);
                self.retry_at_ms = None;
                self.remounts += 1;
                Some(self.state)
            }
            Err((e, card)) => {
                self.card = Some(card);
                self.tries_left = self.tries_left.saturating_sub(1);
                self.retry_at_ms =
                    (self.tries_left > 0).then(|| now_ms.saturating_add(REMOUNT_INTERVAL_MS));
                let changed = self.state != SdState::Failed(e);
                self.state = SdState::Failed(e);
                changed.then_some(self.state)
            }
        }
    }
}

impl<D: BlockDevice> core::fmt::Write for SdSink<D> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        match (self.log.as_mut(), self.state) {
            (Some(log), _) => log.write_str(s),
            (None, SdState::NoCard) => Ok(()),
            (None, _) => Err(core::fmt::Error),
        }
    }
}

/// Why the [`RamCard`] refused a transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RamCardError {
    /// The block range is outside the card.
    #[error("block out of range")]
    Range,
    /// The card was told to fail (an emulated card error).
    #[error("emulated card error")]
    Failed,
    /// The emulated supply is off.
    #[error("emulated card without power")]
    PowerOff,
}

/// An SD card emulated in RAM for host tests and the simulator: an image of whole blocks
/// that can lose power (from a chosen block write on nothing reaches the image: that write
/// and every later transfer fail, as for a board whose supply went, card and MCU
/// together) or fail (transfers return an error, the image kept).
pub struct RamCard<'a> {
    image: RefCell<&'a mut [u8]>,
    /// Blocks written so far (dropped ones included).
    writes: Cell<u64>,
    /// The supply goes at this count of written blocks.
    power_off_at: Cell<Option<u64>>,
    /// Transfers fail from this count of written blocks on.
    fail_at: Cell<Option<u64>>,
}

impl<'a> RamCard<'a> {
    /// A card holding `image` (its length a multiple of 512 bytes; a trailing part block is
    /// not used).
    pub fn new(image: &'a mut [u8]) -> Self {
        Self {
            image: RefCell::new(image),
            writes: Cell::new(0),
            power_off_at: Cell::new(None),
            fail_at: Cell::new(None),
        }
    }

    /// Blocks written so far.
    pub fn writes(&self) -> u64 {
        self.writes.get()
    }

    /// Cuts the supply at the `n`-th block write (0-based): that block and everything
    /// after it never reach the image.
    pub fn power_off_at(&self, n: u64) {
        self.power_off_at.set(Some(n));
    }

    /// Fails every transfer once `n` blocks have been written.
    pub fn fail_at(&self, n: u64) {
        self.fail_at.set(Some(n));
    }

    /// Ends a [`RamCard::fail_at`] failure (the card reseated, the glitch passed).
    pub fn repair(&self) {
        self.fail_at.set(None);
    }

    fn range(
        &self,
        start: BlockIdx,
        count: usize,
    ) -> Result<core::ops::Range<usize>, RamCardError> {
        let first = usize::try_from(start.0).map_err(|_| RamCardError::Range)? * Block::LEN;
        let end = first + count * Block::LEN;
        if end > self.image.borrow().len() {
            return Err(RamCardError::Range);
        }
        Ok(first..end)
    }

    fn check(&self) -> Result<(), RamCardError> {
        let n = self.writes.get();
        if self.power_off_at.get().is_some_and(|off| n >= off) {
            Err(RamCardError::PowerOff)
        } else if self.fail_at.get().is_some_and(|f| n >= f) {
            Err(RamCardError::Failed)
        } else {
            Ok(())
        }
    }
}

impl BlockDevice for RamCard<'_> {
    type Error = RamCardError;

    fn read(&self, blocks: &mut [Block], start_block_idx: BlockIdx) -> Result<(), Self::Error> {
        self.check()?;
        let r = self.range(start_block_idx, blocks.len())?;
        let image = self.image.borrow();
        let src = image.get(r).ok_or(RamCardError::Range)?;
        for (b, src) in blocks.iter_mut().zip(src.chunks_exact(Block::LEN)) {
            b.contents.copy_from_slice(src);
        }
        Ok(())
    }

    fn write(&self, blocks: &[Block], start_block_idx: BlockIdx) -> Result<(), Self::Error> {
        self.check()?;
        let r = self.range(start_block_idx, blocks.len())?;
        let mut image = self.image.borrow_mut();
        let dst = image.get_mut(r).ok_or(RamCardError::Range)?;
        for (b, dst) in blocks.iter().zip(dst.chunks_exact_mut(Block::LEN)) {
            // A multi-block write cut part-way keeps the blocks before the cut.
            self.check()?;
            self.writes.set(self.writes.get() + 1);
            dst.copy_from_slice(&b.contents);
        }
        Ok(())
    }

    fn num_blocks(&self) -> Result<BlockCount, Self::Error> {
        let n = self.image.borrow().len() / Block::LEN;
        Ok(BlockCount(
            u32::try_from(n).map_err(|_| RamCardError::Range)?,
        ))
    }
}

#[cfg(test)]
#[path = "sd_log_tests.rs"]
mod tests;
