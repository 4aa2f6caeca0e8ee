//! Board binary of the receiver (reference board: STM32F405RG on the Adafruit Feather
//! STM32F405 Express, 12 MHz crystal). Flash and run with `cargo board-run` (probe-rs);
//! logs arrive over RTT (defmt), the session log goes to the microSD card (one file per
//! session; over USART3 instead when no card logs).
//!
//! The application itself is [`firmware::app::Receiver`] — the very type `hal-sim`
//! drives on the PC — and the processing task's logic is [`firmware::board::process`]
//! (tested on the host); this file and its modules only bind them to the hardware: the
//! processing task's pins (`receiver/io.rs`), the shared I2C bus (`receiver/bus.rs`),
//! the idle loop's log writer and watchdog feeder (`receiver/writer.rs`), the microSD
//! card (`receiver/sd_card.rs`):
//!
//! | function | peripheral | MCU pins (Feather label) |
//! |---|---|---|
//! | antenna ADC ADS131M04 (SPI mode 1, 8 MHz; CLKIN 8.192 MHz from its own oscillator) | SPI2, EXTI7 | SCK PB13 (SCK), MISO PB14 (MISO), MOSI PB15 (MOSI), CS PB9 (D10), DRDY PC7 (D5) |
//! | IMU BMI160 (acc+gyr) + LSM303AGR (mag), SSD1306 128×64 display | I2C1, 400 kHz, shared | SCL PB6 (SCL), SDA PB7 (SDA) |
//! | session-log stream (spec `arva-session` v1, 921 600 Bd; optional, [`UART_LOG`]) | USART3 TX | PB10 (TX) |
//! | session log on the microSD card (FAT, `SESSnnnn.LOG`, flushed every 0.5 s) | SDIO 4-bit, card detect | PC8–PC11 (D0–D3), PC12 (CLK), PD2 (CMD), PB12 (detect; all on board) |
//! | IMU sample clock (100 Hz) | TIM2 | – |
//! | mark button (push button to ground, internal pull-up; polled at 100 Hz, debounced) | GPIO | PC6 (D6) |
//! | fault LED (the Feather's red LED): lit while a sensor fault holds or the display is down | GPIO | PC1 (D13) |
//! | buzzer (passive piezo): guidance tones ([`firmware::board::sound`]) | TIM4 CH3 PWM | PB8 (D9) |
//! | sound button (push button to ground, internal pull-up; debounced): short = mute / unmute (a chirp confirms "on"), long = the menu ([`firmware::board::controls`]) | GPIO | PC2 (D12) |
//! | settings (two sectors used in turn, [`firmware::board::settings_store`]), written by the idle loop when the menu closes with a change | flash sectors 10, 11 | – |
//! | battery voltage (the Feather's ½ divider on BAT, read once a second) | ADC1 IN3 | PA3 (on board) |
//! | supervision: independent watchdog (1 s), cycle counter (progress times) | IWDG, DWT | – |
//!
//! The full pin map, checked against the Feather's pinout by unit tests, with the pins
//! reserved for the buzzer, the second button and the battery divider, is
//! [`firmware::board::pins`].
//!
//! Supervision: the IWDG is fed only while the main loop's work progresses
//! ([`firmware::board::watchdog`]: the sample queue drained within 1 s, a timer tick
//! handled within 0.5 s; its period is 8 s while a settings save stalls the flash, and
//! the samples lost are logged); a panic stores its message in no-init RAM and resets, and a
//! starved watchdog stores the stalled work first ([`firmware::board::crash`]); the next
//! boot logs the record and shows it on the display for 3 s. The I2C bus is cleared at
//! boot (a slave may still hold SDA from a transfer the reset cut), checked before every
//! transfer and cleared and its devices re-initialised when stuck
//! ([`firmware::board::i2c_bus`]); every wait of a transfer is bounded (1 ms,
//! [`firmware::board::i2c_master`]), so a slave holding SCL mid-transfer is an error
//! and a bus clear, not a watchdog reset. A dead or failing ADC, a stuck bus or a failing IMU
//! shows on the display as a fault over the status word (never as "NO SIGNAL") and is
//! logged; the battery gauge and the low-battery warning sit in the bottom-left corner
//! ([`firmware::board::health`]). SPI transfers are clocked by the MCU (master) and
//! cannot wait on the ADC; every wait is bounded all the same (100 µs,
//! [`firmware::board::spi_master`]), so a stopped peripheral is a failed frame, not a
//! hang of the highest-priority task. A silent ADC shows as failed frames and a DRDY
//! stall (`firmware::timebase`).
//!
//! Timing: RTIC 2 tasks by priority (`firmware::board::schedule`, docs/board.md
//! "Real-time structure", docs/decisions/board-realtime.md): the ADC's DRDY interrupt
//! (EXTI9_5, priority 4) reads every sample into the sample queue (2 048 = 256 ms); the
//! IMU tick (TIM2, 3) reads the IMU over I2C into the IMU queue (32 = 320 ms), so no IMU
//! sample waits for the estimator or the display; the processing task (2) runs the DSP,
//! the estimator, guidance, health and tones, IMU records and samples in time order; the
//! display task (1) draws the newest model and flushes it in 16-byte I2C writes, each
//! under the bus lock (ceiling 3), so the IMU tick waits at most one (0.41 ms); the idle
//! loop (0) formats the session-log records, writes them to the card or the UART (the
//! card may stay busy 250 ms) and feeds the watchdog. Every overrun (sample queue full,
//! IMU tick missed, IMU queue full, log queue full) is counted and logged as an
//! `overrun` event. The ADC's sample count is the time base of everything (8 kSPS); if
//! the ADC stops delivering, the 100 Hz tick carries the clock and DRDY is re-armed every
//! 100 ms (`firmware::timebase`). Memory: the receiver state (≈ 88 KB) lives in SRAM
//! (`.uninit`, never on the stack, never moved); the ADC sample queue (32 KB) and the
//! pulse front end live in the core-coupled RAM (`.ccmram`, see `memory.x`).
#![no_std]
#![no_main]
// Narrow uses, each with its SAFETY note: the statics of the receiver, the sample queue,
// the front end, the session log, the I2C bus and the crash record (each taken once, at
// boot or in the panic handler), the bus lock's BASEPRI writes, the receiver rebuilt in
// place (`rebuild`), and read-only reads of GPIOB's input and IWDG's status registers.
#![allow(unsafe_code)]

#[path = "receiver/bus.rs"]
mod bus;
#[path = "receiver/io.rs"]
mod io;
#[path = "receiver/sd_card.rs"]
mod sd_card;
#[path = "receiver/writer.rs"]
mod writer;

use bus::{BusHandle, CycleDelay, clear_pins, with_bus};
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::{DWT, SCB};
use defmt_rtt as _;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::spi::ExclusiveDevice;
use firmware::app::Receiver;
use firmware::board::board_log::BoardLog;
use firmware::board::controls::Controls;
use firmware::board::crash::{self, CrashKind, CrashRecord, LastReset};
use firmware::board::health::{Battery, SensorHealth};
use firmware::board::i2c_bus::Cleared;
use firmware::board::log_item::{LogItem, Overruns};
use firmware::board::process::{Counters, ImuRecord, Process, Sample};
use firmware::board::schedule::{
    self, IMU_QUEUE, LOG_QUEUE, PRIO_DISPLAY, PRIO_DRDY, PRIO_IMU, PRIO_PROCESS,
};
use firmware::board::sd_log::SdState;
use firmware::board::settings::Settings;
use firmware::board::settings_store::{self, BOARD_AREA};
use firmware::board::spi_master::{self, BoundedSpi, SpiRegs};
use firmware::board::view::{self, View};
use firmware::board::watchdog::{MonotonicMs, ProgressWatch, TickMisses};
use firmware::board::{self, BoardProfile};
use firmware::drivers::ads131m04::Ads131m04;
use firmware::drivers::button::MarkButton;
use firmware::drivers::imu::Imu;
use firmware::frontend::Frontend;
use firmware::timebase::SampleClock;
use heapless::spsc::{Consumer, Producer, Queue};
use io::{Io, ProcPins};
use ssd1306::{I2CDisplayInterface, Ssd1306, prelude::*};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::adc::config::AdcConfig;
use stm32f4xx_hal::flash::LockedFlash;
use stm32f4xx_hal::gpio::{Edge, ExtiPin, Input, PC7};
use stm32f4xx_hal::i2c::I2c;
use stm32f4xx_hal::timer::CounterHz;
use stm32f4xx_hal::watchdog::IndependentWatchdog;
use stm32f4xx_hal::{pac, prelude::*, rcc::Config, spi};
use writer::Writer;

/// The board this binary runs on: analog chain, ADC, IMU mounting and rates, defaults.
const PROFILE: BoardProfile = board::REFERENCE;
/// ADC frames buffered between the DRDY interrupt and the processing task: 256 ms at
/// 8 kSPS (`board::schedule::SAMPLE_QUEUE`; the worst burst of pulses fills 875).
const QUEUE_LEN: usize = firmware::board::schedule::SAMPLE_QUEUE as usize;
/// Core clock, Hz (also the DWT cycle counter's rate).
const SYSCLK_HZ: u32 = 168_000_000;
/// The independent watchdog's period, ms: the idle loop feeds it; the longest it waits
/// is a card's busy time (250 ms) behind the tasks above it.
const IWDG_PERIOD_MS: u32 = 1000;
/// The watchdog's period while the settings are written to flash, ms: a sector erase
/// stalls instruction fetch up to 4 s (STM32F405 datasheet, 128 KB sector at ×8
/// parallelism, which the HAL's erase uses), and the LSI that clocks the IWDG may run
/// 47/32 fast (8 s nominal ≥ 5.4 s).
const SAVE_IWDG_MS: u32 = 8000;
/// Progress limits, ms, by [`Work`]: the sample queue drained within 1 s (it holds
/// 256 ms; a burst of pulses keeps it busy ≈ 0.3 s), IMU records handled within 0.5 s.
const PROGRESS_LIMIT_MS: [u64; 2] = [1000, 500];
/// How long the last reset's report stays on the display at boot, ms.
const RESET_REPORT_MS: u32 = 3000;
/// I2C1's bus clock.
const I2C_HZ: u32 = 400_000;
/// The session log streams over USART3 (921 600 Bd) when no card logs, for a host
/// attached by wire.
const UART_LOG: bool = true;
/// Crash-record text marking the SD card's bring-up: a watchdog reset there (a card that
/// never leaves power-up) is reported with it, and the next boot leaves the card alone.
const SD_INIT_MARK: &str = "SD card bring-up";
/// Guidance tones on at boot unless the stored volume is 0 (the sound button toggles
/// them for the session; the menu's SOUND item is what is stored).
const SOUND_ON: bool = true;
/// IMU sampling (and sample-clock watchdog) rate, Hz.
const IMU_HZ: f32 = PROFILE.imu.rate_hz;
/// Core cycles of one IMU tick.
const TICK_CYCLES: u32 = SYSCLK_HZ / PROFILE.imu.rate_hz as u32;

/// DRDY always reads "ready": the driver is only called from the DRDY interrupt, i.e.
/// right after the real DRDY pin (owned by the interrupt for its pending flag) fell.
struct DrdyAsserted;

impl embedded_hal::digital::ErrorType for DrdyAsserted {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::InputPin for DrdyAsserted {
    fn is_high(&mut self) -> Result<bool, Self::Error> {
        Ok(false)
    }
    fn is_low(&mut self) -> Result<bool, Self::Error> {
        Ok(true)
    }
}

/// SPI2's status and data registers and the core's cycle counter, for the bounded master.
pub struct Spi2Regs(pac::SPI2);

impl SpiRegs for Spi2Regs {
    fn sr(&mut self) -> u16 {
        self.0.sr().read().bits()
    }
    fn dr(&mut self) -> u8 {
        // 8-bit frames: the byte is DR's low half.
        self.0.dr().read().bits() as u8
    }
    fn set_dr(&mut self, value: u8) {
        // SAFETY: any byte is a valid DR write in 8-bit frame mode.
        self.0.dr().write(|w| unsafe { w.bits(u16::from(value)) });
    }
    fn rewrite_cr1(&mut self) {
        self.0.cr1().modify(|_, w| w);
    }
    fn now(&mut self) -> u32 {
        DWT::cycle_count()
    }
}

type AdcSpi = ExclusiveDevice<
    BoundedSpi<Spi2Regs>,
    stm32f4xx_hal::gpio::PB9<stm32f4xx_hal::gpio::Output>,
    embedded_hal_bus::spi::NoDelay,
>;

/// The ADC and its DRDY pin: read by the DRDY task, re-armed and re-ranged by the
/// processing task under the lock.
pub struct Sampler {
    adc: Ads131m04<AdcSpi, DrdyAsserted>,
    drdy: PC7<Input>,
}

/// Counters and flags the tasks share (samples, overruns, progress, display, SD card).
static COUNTERS: Counters = Counters::new();

/// The application state in SRAM (not zeroed by the runtime: initialized with
/// `Receiver::emplace` before use).
#[unsafe(link_section = ".uninit.RECEIVER")]
static mut RECEIVER: MaybeUninit<Receiver> = MaybeUninit::uninit();
/// The ADC sample queue in core-coupled RAM (initialized at boot before use).
#[unsafe(link_section = ".ccmram")]
static mut QUEUE: MaybeUninit<Queue<Sample, QUEUE_LEN>> = MaybeUninit::uninit();
/// The pulse front end in core-coupled RAM (initialized at boot before use).
#[unsafe(link_section = ".ccmram")]
static mut FRONTEND: MaybeUninit<Frontend> = MaybeUninit::uninit();
/// The IMU record and session-log record queues in core-coupled RAM.
#[unsafe(link_section = ".ccmram")]
static mut IMU_Q: MaybeUninit<Queue<ImuRecord, { IMU_QUEUE as usize }>> = MaybeUninit::uninit();
#[unsafe(link_section = ".ccmram")]
static mut LOG_Q: MaybeUninit<Queue<LogItem, { LOG_QUEUE as usize }>> = MaybeUninit::uninit();
/// Settings to store (processing task → idle loop): the menu closes at most every ≈ 2 s
/// (two long presses), the idle loop stores within its pass (≤ 0.3 s), so 3 places.
#[unsafe(link_section = ".ccmram")]
static mut SAVE_Q: MaybeUninit<Queue<Settings, 4>> = MaybeUninit::uninit();
/// The crash record: in `.uninit` SRAM, so a system reset keeps it (the runtime neither
/// zeroes nor initialises it); read and cleared once at boot, written by the panic
/// handler and by a starving watchdog feeder.
#[unsafe(link_section = ".uninit.CRASH")]
static mut CRASH: MaybeUninit<CrashRecord> = MaybeUninit::uninit();
/// The session log (SD card file system, its block buffer, the UART): in SRAM, not on
/// a stack (initialized at boot before use; the idle loop's afterwards).
#[unsafe(link_section = ".uninit.LOG")]
static mut LOG: MaybeUninit<BoardLog<sd_card::SdioCard, stm32f4xx_hal::serial::Tx<pac::USART3>>> =
    MaybeUninit::uninit();
/// Set by the first panic: a panic inside the panic handler resets at once.
static PANICKING: AtomicBool = AtomicBool::new(false);

/// Stores `record` in the no-init crash record.
fn store_crash(record: &CrashRecord) {
    // SAFETY: a plain volatile write of a `repr(C)` value of integers to the record's
    // static, whose only other users (boot, panic handler, feeder) run in thread mode
    // and never at the same time as this write.
    unsafe {
        core::ptr::write_volatile(
            core::ptr::addr_of_mut!(CRASH).cast::<CrashRecord>(),
            *record,
        )
    };
}

/// Reads the crash record left by the last reset and clears it (it is shown once).
fn take_crash() -> CrashRecord {
    let p = core::ptr::addr_of_mut!(CRASH).cast::<CrashRecord>();
    // SAFETY: boot, before any other user of the record runs; every bit pattern is a
    // valid `CrashRecord` (integers only), and power-on noise fails its magic and CRC.
    let record = unsafe { core::ptr::read_volatile(p) };
    // SAFETY: as for the read.
    unsafe { core::ptr::write_volatile(p, CrashRecord::CLEARED) };
    record
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    if !PANICKING.swap(true, Ordering::Relaxed) {
        let record = match info.location() {
            Some(l) => CrashRecord::new(
                CrashKind::Panic,
                format_args!(
                    "{}\n@{}:{}",
                    info.message(),
                    crash::short_path(l.file()),
                    l.line()
                ),
            ),
            None => CrashRecord::new(CrashKind::Panic, format_args!("{}", info.message())),
        };
        store_crash(&record);
        if let Some((_, m)) = record.decode() {
            defmt::error!("panic: {=str}; resetting", m);
        }
    }
    SCB::sys_reset()
}

/// A fatal error at boot: recorded like a panic, then reset.
fn fatal(what: &'static str) -> ! {
    store_crash(&CrashRecord::new(
        CrashKind::Panic,
        format_args!("boot: {what}"),
    ));
    defmt::error!("fatal: {=str}; resetting", what);
    SCB::sys_reset()
}

type Screen = Ssd1306<
    I2CInterface<BusHandle>,
    DisplaySize128x64,
    ssd1306::mode::BufferedGraphicsMode<DisplaySize128x64>,
>;

/// Brings the IMU up on the shared bus (at boot and after a bus clear).
fn imu_up(delay: &mut impl DelayNs) -> Option<Imu<BusHandle>> {
    match Imu::with_mounting(BusHandle, BusHandle, PROFILE.imu.mounting, delay) {
        Ok(imu) => Some(imu),
        Err(_) => {
            defmt::error!("IMU not answering: no dead reckoning");
            None
        }
    }
}

/// Clears `screen` and draws `view` with the health overlay (a sensor fault over the
/// status word, the battery gauge, the SD mark); false if the display did not take it.
fn show(screen: &mut Screen, view: &View) -> bool {
    screen.clear(BinaryColor::Off).ok();
    view::draw(view, COUNTERS.sd_label(), screen).is_ok() && screen.flush().is_ok()
}

/// What the IMU tick task owns.
pub struct Tick {
    timer: CounterHz<pac::TIM2>,
    imu: Option<Imu<BusHandle>>,
    records: Producer<'static, ImuRecord>,
    /// Lost releases, from the cycle counter.
    misses: TickMisses,
}

/// What the processing task owns: its logic ([`Process`]), its input queues and the
/// hardware it drives.
pub struct Proc {
    core: Process<'static>,
    samples: Consumer<'static, Sample>,
    records: Consumer<'static, ImuRecord>,
    pins: ProcPins,
}

/// What the display task owns.
pub struct Display {
    screen: Screen,
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use super::*;

    #[shared]
    struct Shared {
        sampler: Sampler,
        view: Option<View>,
    }

    #[local]
    struct Local {
        samples_in: Producer<'static, Sample>,
        tick: Tick,
        work: Proc,
        display: Display,
        writer: Writer,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut cp = cx.core;
        // Why the last reset happened: the reset controller's flags, then cleared.
        let csr = dp.RCC.csr().read();
        let watchdog_reset = csr.wdgrstf().bit_is_set();
        dp.RCC.csr().modify(|_, w| w.rmvf().set_bit());
        let crash_record = take_crash();
        let last_reset = LastReset::from_boot(&crash_record, watchdog_reset);

        let mut rcc = dp.RCC.freeze(Config::hse(12.MHz()).sysclk(SYSCLK_HZ.Hz()));
        // The watchdog first, so that a hang anywhere after this resets the board; it stops
        // while a debugger halts the core.
        let mut iwdg = IndependentWatchdog::new(dp.IWDG);
        iwdg.stop_on_debug(&dp.DBGMCU, true);
        iwdg.start(IWDG_PERIOD_MS.millis());
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
        let mut delay = cp.SYST.delay(&rcc.clocks);
        let mut syscfg = dp.SYSCFG.constrain(&mut rcc);
        let mut exti = dp.EXTI;
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
        let gpioa = dp.GPIOA.split(&mut rcc);
        // Battery: the Feather's ½ divider on PA3 (ADC1 channel 3), read once a second. The
        // HAL calibrates VDDA from the factory VREFINT value, so the reading does not assume
        // exactly 3.3 V.
        let vbat_pin = gpioa.pa3.into_analog();
        let mcu_adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
        let vdda_v = mcu_adc.reference_voltage() as f32 / 1000.0;

        match last_reset {
            LastReset::Clean => {}
            LastReset::Panic(m) => defmt::error!("last reset: panic: {=str}", m),
            LastReset::Starved(m) => defmt::error!("last reset: watchdog, stalled: {=str}", m),
            LastReset::WatchdogHung => defmt::error!("last reset: watchdog, main loop hung"),
        }

        // Session log first, so everything after it can be recorded: the microSD card (its
        // bring-up marked in the crash record, see SD_INIT_MARK) and the UART stream.
        let gpiod = dp.GPIOD.split(&mut rcc);
        // The switch is read after the SDIO set-up, so the pull-up has settled.
        let card_detect = gpiob.pb12.into_pull_up_input();
        let sdio = stm32f4xx_hal::sdio::Sdio::new(
            dp.SDIO,
            (
                gpioc.pc12, gpiod.pd2, gpioc.pc8, gpioc.pc9, gpioc.pc10, gpioc.pc11,
            ),
            &mut rcc,
        );
        let card_in = card_detect.is_low();
        let skip_sd = matches!(last_reset, LastReset::Starved(m) if m == SD_INIT_MARK);
        store_crash(&CrashRecord::new(
            CrashKind::Starved,
            format_args!("{SD_INIT_MARK}"),
        ));
        iwdg.feed();
        let sd = sd_card::mount(sdio, card_in, skip_sd, 0);
        iwdg.feed();
        // Bring-up over: clear the marker (the last reset's record was read before it).
        let _marker = take_crash();
        let Ok(uart) = dp.USART3.tx(gpiob.pb10, 921_600.bps(), &mut rcc) else {
            fatal("USART3 configuration refused");
        };
        // The UART stream only while no card logs (it takes over when the card fails): the
        // writer cannot send both beside the card's worst busy times (`board::schedule`,
        // `UART_ONLY`).
        let card_logging = matches!(sd.state(), SdState::Logging(_));
        let (stream, spare_uart) = match (UART_LOG, card_logging) {
            (false, _) => (None, None),
            (true, false) => (Some(uart), None),
            (true, true) => (None, Some(uart)),
        };
        // SAFETY: the only reference ever taken to LOG, here, once; then the idle loop's.
        let log = unsafe { &mut *core::ptr::addr_of_mut!(LOG) }.write(BoardLog::new(sd, stream));
        // The unit's settings from flash sector 11: the newest block saved (defaults, with
        // the reason, when none is readable).
        let mut flash = LockedFlash::new(dp.FLASH);
        let loaded = settings_store::load(&mut flash, BOARD_AREA);
        let (settings, settings_error) = (loaded.settings, loaded.defaults_because);
        let step_length_m = settings
            .calibration
            .step_length_m
            .or(PROFILE.defaults.step_length_m);
        let earth = settings.earth_field();
        log.header(PROFILE.imu.rate_hz, &earth, true);
        log.reset(0.0, &last_reset);
        log.settings_loaded(0.0, &loaded, step_length_m);
        if let Some(e) = settings_error {
            defmt::warn!("settings: {}; defaults apply", e);
        }
        if loaded.torn > 0 {
            defmt::warn!(
                "settings: {=u32} newer blocks torn (a save cut short)",
                loaded.torn
            );
        }
        // The logged and processed magnetometer reading is the calibrated one (the spec's
        // body-frame field), so a replay needs no calibration of its own.
        let mag_cal = settings.calibration.mag;
        match log.sd_state() {
            SdState::Logging(n) => defmt::info!("SD card: logging to session {=u16}", n),
            SdState::NoCard => defmt::warn!("SD card: none inserted, log on UART only"),
            SdState::Failed(e) => defmt::error!("SD card: {}", e),
        }

        // Antenna ADC on SPI2, mode 1.
        let mode = spi::Mode {
            polarity: spi::Polarity::IdleLow,
            phase: spi::Phase::CaptureOnSecondTransition,
        };
        // The HAL configures SPI2 (clock, mode, software NSS, enable); the bounded master
        // drives it (every wait ends after 100 µs). The pins stay in their alternate
        // function: nothing changes them once released.
        let (spi2, _pins) = dp
            .SPI2
            .spi(
                (Some(gpiob.pb13), Some(gpiob.pb14), Some(gpiob.pb15)),
                mode,
                8.MHz(),
                &mut rcc,
            )
            .release();
        let spi_bus = BoundedSpi::new(Spi2Regs(spi2), spi_master::BOARD_BUDGET_CYCLES);
        let Ok(adc_spi) = ExclusiveDevice::new_no_delay(spi_bus, gpiob.pb9.into_push_pull_output());
        let mut adc = Ads131m04::new(adc_spi, DrdyAsserted);
        let adc_ok = adc.reset(&mut delay).is_ok()
            && adc.check_id().is_ok()
            && adc.configure(&PROFILE.adc.config).is_ok();
        if !adc_ok {
            defmt::error!("antenna ADC not answering: no pulses will be received");
        }
        iwdg.feed();

        let mut imu_tick = dp.TIM2.counter_hz(&mut rcc);
        if imu_tick.start((IMU_HZ as u32).Hz()).is_err() {
            defmt::error!("IMU timer refused 100 Hz");
        }

        // Buzzer: a passive piezo on D9 (PB8), TIM4 channel 3 PWM at the tone's frequency and
        // 50 % duty; duty 0 is silence.
        let (buzz_timer, (_, _, buzz_ch, _)) = dp.TIM4.pwm_hz(2.kHz(), &mut rcc);
        let mut buzzer = buzz_ch.with(gpiob.pb8);
        buzzer.set_duty(0);
        buzzer.enable();

        // IMU and display share I2C1. A reset may have cut a transfer with a slave still
        // holding SDA: clear the bus on the bare pins before the peripheral takes them.
        let mut scl = gpiob.pb6.into_open_drain_output();
        let mut sda = gpiob.pb7.into_open_drain_output();
        match clear_pins(&mut scl, &mut sda) {
            Ok(Cleared { pulses: 0 }) => {}
            Ok(Cleared { pulses }) => {
                defmt::warn!("I2C bus held at boot: freed by {=u8} pulses", pulses)
            }
            Err(_) => defmt::error!("I2C bus stuck at boot and not freed"),
        }
        let i2c = I2c::new(dp.I2C1, (scl, sda), I2C_HZ.Hz(), &mut rcc);
        bus::install(i2c, rcc);
        let imu = imu_up(&mut delay);
        let mut sensors = SensorHealth::new();
        sensors.adc_boot(adc_ok);
        sensors.imu_up(imu.is_some());
        // The red LED tells of a fault even when the display is what failed.
        let mut fault_led = gpioc.pc1.into_push_pull_output();
        let mut screen: Screen = Ssd1306::new(
            I2CDisplayInterface::new(BusHandle),
            DisplaySize128x64,
            DisplayRotation::Rotate0,
        )
        .into_buffered_graphics_mode();
        let screen_ok = screen.init().is_ok();
        COUNTERS.screen_ok.store(screen_ok, Ordering::Relaxed);
        iwdg.feed();

        // The last reset's report, on the display for a while (the watchdog fed meanwhile).
        if last_reset != LastReset::Clean && screen_ok {
            screen.clear(BinaryColor::Off).ok();
            if crash::draw_last_reset(&last_reset, &mut screen).is_ok() && screen.flush().is_ok() {
                for _ in 0..RESET_REPORT_MS / 100 {
                    delay.delay_ms(100);
                    iwdg.feed();
                }
            }
        }

        // The application in SRAM.
        let mut cfg = PROFILE.app_config(earth, step_length_m);
        cfg.mode = settings.mode.app();
        // SAFETY: the only reference ever taken to RECEIVER, here, once, before any task
        // runs; then the processing task's alone.
        let slot = unsafe { &mut *core::ptr::addr_of_mut!(RECEIVER) };
        let Ok(receiver) = Receiver::emplace(slot, cfg) else {
            fatal("default configuration refused");
        };
        // The nominal calibration of the design until the unit's bench calibration is stored.
        let fe_cfg =
            PROFILE.frontend_config(&settings.calibration.antenna_or(&PROFILE.analog.nominal));
        let rate = fe_cfg.sample_rate_hz;
        let Ok(new_frontend) = Frontend::new(fe_cfg) else {
            fatal("front-end configuration refused");
        };
        // SAFETY: the only reference ever taken to FRONTEND, here, once; then the
        // processing task's alone.
        let frontend = unsafe { &mut *core::ptr::addr_of_mut!(FRONTEND) }.write(new_frontend);

        // The queues: samples (DRDY → processing), IMU records (tick → processing),
        // session-log records (processing → idle).
        // SAFETY: the only references ever taken to the three queues, here, once, before
        // any task runs; each end then belongs to one task.
        let (samples_in, samples_out) = unsafe { &mut *core::ptr::addr_of_mut!(QUEUE) }
            .write(Queue::new())
            .split();
        let (records_in, records_out) = unsafe { &mut *core::ptr::addr_of_mut!(IMU_Q) }
            .write(Queue::new())
            .split();
        let (log_in, log_out) = unsafe { &mut *core::ptr::addr_of_mut!(LOG_Q) }
            .write(Queue::new())
            .split();
        // SAFETY: as for the queues above: once, here; one end per task.
        let (saves_in, saves_out) = unsafe { &mut *core::ptr::addr_of_mut!(SAVE_Q) }
            .write(Queue::new())
            .split();
        // The mark button: flags the victim being guided to as found.
        let mark = MarkButton::new(gpioc.pc6.into_pull_up_input());
        // The sound button: the same debounced press, on D12.
        let sound_pin = gpioc.pc2.into_pull_up_input();
        // The IF range switch starts in the high range, the ADC at the profile's gain: the
        // DSP's starting setting (`BoardProfile::start_range`).
        let mut if_range = gpioc.pc3.into_push_pull_output();
        if_range.set_low();
        let mut drdy = gpioc.pc7.into_pull_up_input();
        drdy.make_interrupt_source(&mut syscfg);
        drdy.trigger_on_edge(&mut exti, Edge::Falling);
        drdy.enable_interrupt(&mut exti);
        imu_tick.listen(stm32f4xx_hal::timer::Event::Update);

        defmt::info!(
            "receiver running (ADC {=bool}, display {=bool})",
            adc_ok,
            screen_ok
        );
        let Ok(clock) = SampleClock::new(rate, IMU_HZ, 0) else {
            fatal("sample clock refused its rates");
        };
        let fault = sensors.fault();
        if let Some(f) = fault {
            defmt::error!("sensor fault at boot: {=str}", f.label());
        }
        let sd_fault = log.sd_state().fault_label().is_some();
        fault_led.set_state((fault.is_some() || !screen_ok || sd_fault).into());
        let ms_clock = MonotonicMs::new(SYSCLK_HZ / 1000, DWT::cycle_count());
        let mut idle_ms = MonotonicMs::new(SYSCLK_HZ / 1000, DWT::cycle_count());
        let now_ms = idle_ms.now_ms(DWT::cycle_count());
        let shown = receiver.display_model();
        let bus_stats = with_bus(|b| b.stats()).unwrap_or_default();
        (
            Shared {
                sampler: Sampler { adc, drdy },
                view: None,
            },
            Local {
                samples_in,
                tick: Tick {
                    timer: imu_tick,
                    imu,
                    records: records_in,
                    misses: TickMisses::new(TICK_CYCLES),
                },
                work: Proc {
                    core: Process {
                        profile: &PROFILE,
                        counters: &COUNTERS,
                        log: log_in,
                        saves: saves_in,
                        frontend,
                        receiver,
                        rate,
                        clock,
                        taken: 0,
                        last_imu_t: None,
                        drawn: None,
                        shown,
                        sensors,
                        fault,
                        battery: Battery::new(),
                        controls: Controls::new(settings, SOUND_ON),
                        playing: None,
                        mag_cal,
                        window_ticks: 0,
                        window_samples: COUNTERS.samples.load(Ordering::Relaxed),
                        window_errors: COUNTERS.frame_errors.load(Ordering::Relaxed),
                        bus_stats,
                        reported: Overruns::new(),
                        log_overruns: 0,
                    },
                    samples: samples_out,
                    records: records_out,
                    pins: ProcPins {
                        mcu_adc,
                        vbat_pin,
                        vdda_v,
                        fault_led,
                        if_range,
                        mark,
                        sound_pin,
                        buzz_timer,
                        buzzer,
                        ms_clock,
                    },
                },
                display: Display { screen },
                writer: Writer {
                    log,
                    items: log_out,
                    iwdg,
                    ms_clock: idle_ms,
                    watch: ProgressWatch::new(PROGRESS_LIMIT_MS, now_ms),
                    starving: false,
                    progress: [0; 2],
                    last_t: 0.0,
                    spare_uart,
                    flash,
                    saves: saves_out,
                    adc_rate_hz: rate,
                },
            },
        )
    }

    /// The log writer and the watchdog's feeder, below every task.
    #[idle(local = [writer])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            cx.local.writer.pass();
        }
    }

    /// ADC data ready: one frame into the sample queue.
    #[task(binds = EXTI9_5, priority = 4, shared = [sampler], local = [samples_in])]
    fn drdy(mut cx: drdy::Context) {
        let sample = cx.shared.sampler.lock(|s| {
            s.drdy.clear_interrupt_pending_bit();
            COUNTERS.samples.fetch_add(1, Ordering::Relaxed);
            match s.adc.read_frame() {
                Ok(frame) => {
                    let v = s.adc.to_volts(&frame);
                    Sample {
                        volts: [v[0], v[1], v[2]],
                        clipped: frame.coils_saturated(),
                    }
                }
                // A corrupted frame keeps the time base: the DSP sees a clipped zero sample.
                Err(_) => {
                    COUNTERS.frame_errors.fetch_add(1, Ordering::Relaxed);
                    Sample {
                        volts: [0.0; 3],
                        clipped: true,
                    }
                }
            }
        });
        if cx.local.samples_in.enqueue(sample).is_ok() {
            COUNTERS.queued.fetch_add(1, Ordering::Relaxed);
        } else {
            COUNTERS.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The 100 Hz tick: the IMU read into its queue, then the processing task woken.
    #[task(binds = TIM2, priority = 3, local = [tick])]
    fn imu_tick(cx: imu_tick::Context) {
        let tick = cx.local.tick;
        let _flag = tick.timer.wait();
        // Releases lost since the last tick (the timer's update came again before this ran).
        let missed = tick.misses.on_tick(DWT::cycle_count());
        if missed > 0 {
            COUNTERS.missed_ticks.fetch_add(missed, Ordering::Relaxed);
        }
        // A bus clear may have reset the devices or left them half-configured.
        if with_bus(|b| b.take_reinit()).unwrap_or(false) {
            tick.imu = imu_up(&mut CycleDelay);
            COUNTERS.screen_reinit.store(true, Ordering::Relaxed);
            defmt::warn!(
                "I2C devices re-initialised (IMU {=bool})",
                tick.imu.is_some()
            );
        }
        let record = ImuRecord {
            queued: COUNTERS.queued.load(Ordering::Relaxed),
            reading: tick.imu.as_mut().map(|imu| imu.read().map_err(|_| ())),
        };
        if tick.records.enqueue(record).is_err() {
            COUNTERS.imu_overruns.fetch_add(1, Ordering::Relaxed);
        }
        rtic::pend(pac::Interrupt::USART1);
    }

    /// DSP, estimator, guidance, health and tones: samples and IMU records in time order.
    #[task(binds = USART1, priority = 2, shared = [sampler, view], local = [work])]
    fn process(cx: process::Context) {
        let w = cx.local.work;
        let (mut sampler, mut view) = (cx.shared.sampler, cx.shared.view);
        let mut io = Io {
            pins: &mut w.pins,
            samples: &mut w.samples,
            sampler: &mut sampler,
            view: &mut view,
        };
        loop {
            // An IMU record once the samples queued before it are taken (or none wait).
            let waiting = io.samples.ready();
            let due = w
                .records
                .peek()
                .is_some_and(|r| schedule::imu_record_due(w.core.taken, r.queued, waiting));
            if due {
                if let Some(r) = w.records.dequeue() {
                    w.core.on_tick(r, &mut io);
                }
            } else if let Some(s) = io.samples.dequeue() {
                w.core.on_sample(s, &mut io);
            } else {
                break;
            }
        }
        COUNTERS.drains.fetch_add(1, Ordering::Relaxed);
    }

    /// Draws the newest model and flushes it (each I2C write under the bus lock).
    #[task(binds = USART2, priority = 1, shared = [view], local = [display])]
    fn show_view(mut cx: show_view::Context) {
        let screen = &mut cx.local.display.screen;
        if COUNTERS.screen_reinit.swap(false, Ordering::Relaxed) {
            COUNTERS
                .screen_ok
                .store(screen.init().is_ok(), Ordering::Relaxed);
        }
        if let Some(v) = cx.shared.view.lock(Option::take) {
            let ok = show(screen, &v);
            if !ok {
                defmt::warn!("display write failed");
            }
            COUNTERS.screen_ok.store(ok, Ordering::Relaxed);
        }
    }
}

// The priorities above are the schedule model's (`firmware::board::schedule`).
const _: () = assert!(PRIO_DRDY == 4 && PRIO_IMU == 3 && PRIO_PROCESS == 2 && PRIO_DISPLAY == 1);
