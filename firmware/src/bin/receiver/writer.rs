//! The idle loop: the session log's writer (records to the card or the UART, the card's
//! flushes, the UART taking over from a failed card), the settings saves to flash and the
//! watchdog's feeder.

use super::{COUNTERS, IWDG_PERIOD_MS, SAVE_IWDG_MS, SYSCLK_HZ, sd_card, store_crash};
use core::sync::atomic::Ordering;
use cortex_m::peripheral::DWT;
use firmware::board::board_log::BoardLog;
use firmware::board::crash::{CrashKind, CrashRecord};
use firmware::board::log_item::LogItem;
use firmware::board::sd_log::SdState;
use firmware::board::settings::Settings;
use firmware::board::settings_store::{self, BOARD_AREA};
use firmware::board::watchdog::{MonotonicMs, ProgressWatch, Verdict, Work};
use heapless::spsc::Consumer;
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::watchdog::IndependentWatchdog;

/// What the idle loop owns: the session log's writer and the watchdog's feeder.
pub struct Writer {
    pub log: &'static mut BoardLog<sd_card::SdioCard, stm32f4xx_hal::serial::Tx<pac::USART3>>,
    pub items: Consumer<'static, LogItem>,
    pub iwdg: IndependentWatchdog,
    pub ms_clock: MonotonicMs,
    pub watch: ProgressWatch,
    pub starving: bool,
    pub progress: [u32; 2],
    pub last_t: f64,
    /// The UART while the card logs (attached when the card fails).
    pub spare_uart: Option<stm32f4xx_hal::serial::Tx<pac::USART3>>,
    /// The flash (settings saves) and the settings to store.
    pub flash: LockedFlash,
    pub saves: Consumer<'static, Settings>,
    /// The ADC's sample rate, Hz (samples lost to a flash stall).
    pub adc_rate_hz: f32,
}

impl Writer {
    /// One pass of the idle loop: the queued records to the log, the card's flush, the
    /// watchdog.
    pub fn pass(&mut self) {
        while let Some(item) = self.items.dequeue() {
            if let Some(t) = self.log.write_item(&item) {
                self.last_t = t;
            }
            self.supervise();
        }
        if let Some(s) = self.saves.dequeue() {
            self.save_settings(&s);
        }
        let now = self.ms_clock.now_ms(DWT::cycle_count());
        // The SD card: flushed when due; a failure shows and is reported.
        let (sd_changed, errors) = self.log.tick(self.last_t, now);
        if let Some(state) = sd_changed {
            defmt::error!("SD card: {}", state);
        }
        if let Some(e) = errors {
            defmt::warn!("session log errors: {}", e);
        }
        let state = self.log.sd_state();
        // The card failed: the stream takes over (its `log_error` event included).
        if !matches!(state, SdState::Logging(_))
            && let Some(uart) = self.spare_uart.take()
        {
            self.spare_uart = self.log.attach_uart(uart);
            defmt::warn!("session log: UART stream on");
        }
        COUNTERS.set_sd(&state);
        self.supervise();
    }

    /// Stores `s` in flash (`board::settings_store`: the next free slot of sector 11,
    /// read back). The flash stalls instruction fetch while it programs (144 bytes,
    /// ≈ 2 ms) and, once every 910 saves, while it erases the sector (up to 4 s): every
    /// task and interrupt stalls with it. So the watchdog's period is raised around the
    /// write, the progress stamps restart after it, and the ADC samples it cost (the
    /// samples its time should have brought minus those the DRDY task read) go to the
    /// processing task, which moves its clock on by them and logs an `overrun`. The
    /// outcome is a `settings` event.
    fn save_settings(&mut self, s: &Settings) {
        let read0 = COUNTERS.samples.load(Ordering::Relaxed);
        set_watchdog_period(&mut self.iwdg, SAVE_IWDG_MS);
        let t0 = self.ms_clock.now_ms(DWT::cycle_count());
        let r = settings_store::save(&mut self.flash.unlocked(), BOARD_AREA, s);
        let t1 = self.ms_clock.now_ms(DWT::cycle_count());
        set_watchdog_period(&mut self.iwdg, IWDG_PERIOD_MS);
        for work in Work::ALL {
            self.watch.progress(work, t1);
        }
        let stall_ms = t1.saturating_sub(t0);
        let read = COUNTERS.samples.load(Ordering::Relaxed).wrapping_sub(read0);
        let lost = settings_store::samples_lost(stall_ms, self.adc_rate_hz, read);
        COUNTERS.flash_lost.fetch_add(lost, Ordering::Relaxed);
        match &r {
            Ok(saved) => defmt::info!("settings saved: {} in {=u64} ms", saved, stall_ms),
            Err(e) => defmt::error!("settings not saved: {}", e),
        }
        self.log.settings_saved(self.last_t, &r, stall_ms);
    }

    /// Feeds the watchdog while the processing task progresses.
    fn supervise(&mut self) {
        let now = self.ms_clock.now_ms(DWT::cycle_count());
        let progress = [
            COUNTERS.drains.load(Ordering::Relaxed),
            COUNTERS.ticks.load(Ordering::Relaxed),
        ];
        for ((p, last), work) in progress.iter().zip(self.progress.iter_mut()).zip(Work::ALL) {
            if p != last {
                *last = *p;
                self.watch.progress(work, now);
            }
        }
        match self.watch.verdict(now) {
            Verdict::Feed => self.iwdg.feed(),
            Verdict::Stalled { work, for_ms } => {
                // Stop feeding: the IWDG resets within its period. Record why first.
                if !self.starving {
                    self.starving = true;
                    store_crash(&CrashRecord::new(
                        CrashKind::Starved,
                        format_args!("{} for {} ms", work.name(), for_ms),
                    ));
                    defmt::error!("watchdog starved: {=str}", work.name());
                }
            }
        }
    }
}

/// Sets the independent watchdog's period and feeds it. The IWDG takes a new reload value
/// only once its last update is done (SR.PVU/RVU clear after a few LSI cycles, RM0090):
/// waited for before and after, at most 50 ms each.
fn set_watchdog_period(iwdg: &mut IndependentWatchdog, ms: u32) {
    let updating = || {
        // SAFETY: a read of the IWDG's status register, which has no side effect.
        unsafe { (*pac::IWDG::ptr()).sr().read().bits() & 0b11 != 0 }
    };
    let wait = || {
        let start = DWT::cycle_count();
        while updating() && DWT::cycle_count().wrapping_sub(start) < 50 * (SYSCLK_HZ / 1000) {}
    };
    wait();
    iwdg.start(ms.millis());
    wait();
    iwdg.feed();
}
