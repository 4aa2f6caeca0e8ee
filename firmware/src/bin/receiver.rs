//! Board binary of the receiver (reference board: STM32F405RG on the Adafruit Feather
//! STM32F405 Express, 12 MHz crystal). Flash and run with `cargo board-run` (probe-rs);
//! logs arrive over RTT (defmt), the session log goes to the microSD card (one file per
//! session; over USART3 instead when no card logs).
//!
//! The application itself is [`firmware::app::Receiver`] — the very type `hal-sim`
//! drives on the PC; this file only binds it to the hardware:
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
//! | settings (append-only slots, [`firmware::board::settings_store`]), written by the idle loop when the menu closes with a change | flash sector 11 | – |
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
//! ([`firmware::board::i2c_bus`]). A dead or failing ADC, a stuck bus or a failing IMU
//! shows on the display as a fault over the status word (never as "NO SIGNAL") and is
//! logged; the battery gauge and the low-battery warning sit in the bottom-left corner
//! ([`firmware::board::health`]). SPI transfers are clocked by the MCU (master) and
//! cannot wait on the ADC; a silent ADC shows as failed frames and a DRDY stall
//! (`firmware::timebase`).
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

#[path = "receiver/sd_card.rs"]
mod sd_card;

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, Ordering};
use cortex_m::peripheral::{DWT, SCB};
use defmt_rtt as _;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::spi::ExclusiveDevice;
use firmware::app::{AppConfig, AppError, DisplayModel, Receiver};
use firmware::board::board_log::BoardLog;
use firmware::board::controls::{Closed, Controls, Response};
use firmware::board::crash::{self, CrashKind, CrashRecord, LastReset};
use firmware::board::gain;
use firmware::board::health::{self, Battery, Fault, SensorHealth};
use firmware::board::i2c_bus::{self, ClearError, Cleared, Guarded, Recoverable};
use firmware::board::log_item::{LogItem, Overruns};
use firmware::board::schedule::{
    self, IMU_QUEUE, LOG_QUEUE, PRIO_DISPLAY, PRIO_DRDY, PRIO_IMU, PRIO_PROCESS,
};
use firmware::board::sd_log::SdState;
use firmware::board::settings::Settings;
use firmware::board::settings_store::{self, BOARD_AREA};
use firmware::board::sound;
use firmware::board::view::{self, View};
use firmware::board::watchdog::{MonotonicMs, ProgressWatch, TickMisses, Verdict, Work};
use firmware::board::{self, BoardProfile, pins};
use firmware::drivers::ads131m04::Ads131m04;
use firmware::drivers::imu::{Imu, ImuReading};
use firmware::frontend::{Frontend, IfRange, PulseMeasurement, RangeChange};
use firmware::motion::MagCalibration;
use firmware::timebase::{ClockEvent, Instant, SampleClock, pulse_centre_us};
use firmware::victims::MarkButton;
use heapless::spsc::{Consumer, Producer, Queue};
use rtic::Mutex;
use ssd1306::{I2CDisplayInterface, Ssd1306, prelude::*};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::adc::config::{AdcConfig, SampleTime};
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::gpio::{
    Edge, ExtiPin, Input, OpenDrain, Output, PA3, PB6, PB7, PC1, PC2, PC3, PC6, PC7,
};
use stm32f4xx_hal::i2c::I2c;
use stm32f4xx_hal::rcc::Rcc;
use stm32f4xx_hal::timer::{CounterHz, PwmChannel, PwmHzManager};
use stm32f4xx_hal::watchdog::IndependentWatchdog;
use stm32f4xx_hal::{pac, prelude::*, rcc::Config, spi};

/// The board this binary runs on: analog chain, ADC, IMU mounting and rates, defaults.
const PROFILE: BoardProfile = board::REFERENCE;
/// Longest time (µs) the screen goes without a redraw when no pulse redraws it.
const REDRAW_MAX_US: u64 = 1_000_000;
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

/// One simultaneous sample of the three coils.
#[derive(Clone, Copy)]
struct Sample {
    volts: [f32; 3],
    clipped: bool,
}

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

type AdcSpi = ExclusiveDevice<
    spi::Spi<pac::SPI2>,
    stm32f4xx_hal::gpio::PB9<stm32f4xx_hal::gpio::Output>,
    embedded_hal_bus::spi::NoDelay,
>;

/// The ADC and its DRDY pin: read by the DRDY task, re-armed and re-ranged by the
/// processing task under the lock.
pub struct Sampler {
    adc: Ads131m04<AdcSpi, DrdyAsserted>,
    drdy: PC7<Input>,
}

/// One IMU tick's result, stamped with the samples queued before it.
pub struct ImuRecord {
    /// ADC samples queued when the IMU was read (the processing task takes the record
    /// after those samples: time order).
    queued: u32,
    /// The reading (`None`: no IMU up; `Some(Err)`: the read failed).
    reading: Option<Result<ImuReading, ()>>,
}

/// ADC samples taken (DRDY edges), queued, dropped (queue full), failed frames.
static SAMPLES: AtomicU32 = AtomicU32::new(0);
static QUEUED: AtomicU32 = AtomicU32::new(0);
static DROPPED: AtomicU32 = AtomicU32::new(0);
static FRAME_ERRORS: AtomicU32 = AtomicU32::new(0);
/// IMU ticks missed (TIM2 released again before its last release ran) and IMU records
/// lost to a full queue.
static MISSED_TICKS: AtomicU32 = AtomicU32::new(0);
/// ADC samples lost while the flash stalled every task (a settings save), from the
/// cycle counter: the processing task moves its clock on by them and logs an overrun.
static FLASH_LOST: AtomicU32 = AtomicU32::new(0);
static IMU_OVERRUNS: AtomicU32 = AtomicU32::new(0);
/// Progress of the processing task (queue drained; IMU records handled), for the feeder.
static DRAINS: AtomicU32 = AtomicU32::new(0);
static TICKS: AtomicU32 = AtomicU32::new(0);
/// The display after its last write; set when a bus clear asks for a re-init.
static SCREEN_OK: AtomicBool = AtomicBool::new(false);
static SCREEN_REINIT: AtomicBool = AtomicBool::new(false);
/// The SD card's state for the display: 0 logging, 1 no card, 2 failed.
static SD_MARK: AtomicU8 = AtomicU8::new(0);

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

/// Busy-wait delay from the core clock, for the bus clear (SysTick is the init delay's).
struct CycleDelay;

impl DelayNs for CycleDelay {
    fn delay_ns(&mut self, ns: u32) {
        let cycles = u64::from(ns) * u64::from(SYSCLK_HZ / 1_000_000) / 1000 + 1;
        cortex_m::asm::delay(u32::try_from(cycles).unwrap_or(u32::MAX));
    }
}

/// Whether PB6 (SCL) and PB7 (SDA) both read high. The input data register samples the
/// pins in every mode, the I2C alternate function included.
fn i2c_lines_high() -> bool {
    // SAFETY: a read of GPIOB's input data register, which has no side effect and is
    // never written.
    let idr = unsafe { (*pac::GPIOB::ptr()).idr().read().bits() };
    idr & (1 << 6) != 0 && idr & (1 << 7) != 0
}

/// Clears the bus on its two pins as open-drain GPIOs.
fn clear_pins(
    scl: &mut PB6<Output<OpenDrain>>,
    sda: &mut PB7<Output<OpenDrain>>,
) -> Result<Cleared, ClearError> {
    i2c_bus::clear_bus(scl, sda, &mut CycleDelay)
}

/// I2C1 that can be taken apart for a bus clear and rebuilt.
struct BoardI2c {
    /// `None` only if a clear could not get the pins back (then every transfer fails).
    i2c: Option<I2c<pac::I2C1>>,
    rcc: Rcc,
}

impl embedded_hal::i2c::ErrorType for BoardI2c {
    type Error = stm32f4xx_hal::i2c::Error;
}

impl embedded_hal::i2c::I2c for BoardI2c {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), Self::Error> {
        match self.i2c.as_mut() {
            Some(i2c) => embedded_hal::i2c::I2c::transaction(i2c, address, operations),
            None => Err(stm32f4xx_hal::i2c::Error::Bus),
        }
    }
}

impl Recoverable for BoardI2c {
    fn lines_idle(&mut self) -> bool {
        self.i2c.is_some() && i2c_lines_high()
    }

    fn clear_and_reinit(&mut self) -> Result<Cleared, ClearError> {
        let Some(i2c) = self.i2c.take() else {
            return Err(ClearError::Pin);
        };
        let (per, (scl, sda)) = i2c.release();
        let (Ok(mut scl), Ok(mut sda)) = (
            PB6::<Output<OpenDrain>>::try_from(scl),
            PB7::<Output<OpenDrain>>::try_from(sda),
        ) else {
            return Err(ClearError::Pin);
        };
        let r = clear_pins(&mut scl, &mut sda);
        self.i2c = Some(I2c::new(per, (scl, sda), I2C_HZ.Hz(), &mut self.rcc));
        r
    }
}

/// The shared I2C bus (IMU, magnetometer, display), used only through [`with_bus`].
struct BusCell(UnsafeCell<MaybeUninit<Guarded<BoardI2c>>>);

// SAFETY: every access goes through `with_bus`, which masks every task that uses the bus
// (priority ≤ the IMU tick's) for its duration: one user at a time.
unsafe impl Sync for BusCell {}

static BUS: BusCell = BusCell(UnsafeCell::new(MaybeUninit::uninit()));
/// Set once the bus is in place (before any task runs).
static BUS_READY: AtomicBool = AtomicBool::new(false);

/// BASEPRI value of the bus's ceiling (the IMU tick's priority), as RTIC computes it.
const BUS_CEILING: u8 = ((1 << pac::NVIC_PRIO_BITS) - PRIO_IMU) << (8 - pac::NVIC_PRIO_BITS);

/// Runs `f` on the bus with the tasks that use it masked (the priority-ceiling lock
/// RTIC uses for its resources, by hand: the drivers own a handle, not a borrow). The
/// DRDY interrupt (above the ceiling) still runs. `None` before the bus is in place.
fn with_bus<R>(f: impl FnOnce(&mut Guarded<BoardI2c>) -> R) -> Option<R> {
    if !BUS_READY.load(Ordering::Acquire) {
        return None;
    }
    let old = cortex_m::register::basepri::read();
    // Raising BASEPRI only masks more; it is restored below.
    cortex_m::register::basepri_max::write(BUS_CEILING);
    // SAFETY: BUS_READY says the bus was written; every task that reaches this line runs
    // at or below the ceiling, so no other access can preempt this one, and `f` does not
    // call `with_bus` (the drivers below it know nothing of it).
    let r = f(unsafe { &mut *(*BUS.0.get()).as_mut_ptr() });
    // SAFETY: restores the value read above.
    unsafe { cortex_m::register::basepri::write(old) };
    Some(r)
}

/// A driver's handle on the shared bus: each transaction under [`with_bus`].
#[derive(Clone, Copy)]
pub struct BusHandle;

impl embedded_hal::i2c::ErrorType for BusHandle {
    type Error = i2c_bus::GuardError<stm32f4xx_hal::i2c::Error>;
}

impl embedded_hal::i2c::I2c for BusHandle {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), Self::Error> {
        with_bus(|b| embedded_hal::i2c::I2c::transaction(b, address, operations)).unwrap_or(Err(
            i2c_bus::GuardError::Bus(stm32f4xx_hal::i2c::Error::Bus),
        ))
    }
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

/// Reacts to the sample clock's verdict: a stalled ADC's DRDY is re-armed by reading one
/// frame (it stays low until the frame is read, so no further edge would come).
fn watch_adc(event: ClockEvent, sampler: &mut impl Mutex<T = Sampler>) -> ClockEvent {
    match event {
        ClockEvent::Running => {}
        ClockEvent::Resumed => defmt::info!("antenna ADC delivering again"),
        ClockEvent::Stalled { rearm: false } => {}
        ClockEvent::Stalled { rearm: true } => {
            defmt::warn!("antenna ADC stalled: re-arming DRDY");
            sampler.lock(|s| {
                let _frame = s.adc.read_frame();
                s.drdy.clear_interrupt_pending_bit();
            });
        }
    }
    event
}

/// Writes a change of analog setting (gain ranging, [`firmware::board::gain`]) to the
/// hardware: the coils' PGA gain in one register write (under the DRDY task's lock), then
/// the IF range switch; after a failed gain write the switch stays at `from`. True when
/// the PGA took the new gain.
fn write_range(
    pin: &mut PC3<Output>,
    change: &RangeChange,
    sampler: &mut impl Mutex<T = Sampler>,
) -> bool {
    let gain_ok = sampler.lock(|s| s.adc.set_coil_gains(change.to.gain).is_ok());
    let r = if gain_ok { change.to } else { change.from };
    match r.if_range {
        IfRange::High => pin.set_low(),
        IfRange::Low => pin.set_high(),
    }
    gain_ok
}

/// Board time for the session log's records, s.
fn log_t(clock: &SampleClock) -> f64 {
    clock.now().secs_f64()
}

/// The SD card's word for the display (published by the idle loop).
fn sd_label() -> Option<&'static str> {
    match SD_MARK.load(Ordering::Relaxed) {
        0 => None,
        1 => SdState::NoCard.fault_label(),
        _ => Some("SD ERR"),
    }
}

/// Clears `screen` and draws `view` with the health overlay (a sensor fault over the
/// status word, the battery gauge, the SD mark); false if the display did not take it.
fn show(screen: &mut Screen, view: &View) -> bool {
    screen.clear(BinaryColor::Off).ok();
    view::draw(view, sd_label(), screen).is_ok() && screen.flush().is_ok()
}

/// What the IMU tick task owns.
pub struct Tick {
    timer: CounterHz<pac::TIM2>,
    imu: Option<Imu<BusHandle>>,
    records: Producer<'static, ImuRecord>,
    /// Lost releases, from the cycle counter.
    misses: TickMisses,
}

/// What the processing task owns.
pub struct Proc {
    samples: Consumer<'static, Sample>,
    records: Consumer<'static, ImuRecord>,
    log: Producer<'static, LogItem>,
    frontend: &'static mut Frontend,
    receiver: &'static mut Receiver,
    rate: f32,
    clock: SampleClock,
    taken: u32,
    last_imu_t: Option<Instant>,
    drawn: Option<Instant>,
    shown: DisplayModel,
    sensors: SensorHealth,
    fault: Option<Fault>,
    battery: Battery,
    mcu_adc: Adc<pac::ADC1>,
    vbat_pin: PA3<stm32f4xx_hal::gpio::Analog>,
    vdda_v: f32,
    fault_led: PC1<Output>,
    if_range: PC3<Output>,
    mark: MarkButton<PC6<Input>>,
    sound_pin: PC2<Input>,
    /// The buttons, the menu, its procedures and the tone (`board::controls`).
    controls: Controls,
    /// The tone playing and its duty.
    playing: Option<(u32, u16)>,
    buzz_timer: PwmHzManager<pac::TIM4>,
    buzzer: PwmChannel<pac::TIM4, 2>,
    mag_cal: Option<MagCalibration>,
    ms_clock: MonotonicMs,
    window_ticks: u32,
    window_samples: u32,
    window_errors: u32,
    bus_stats: i2c_bus::BusStats,
    /// Overruns counted so far, by kind, and what was last logged.
    reported: Overruns,
    log_overruns: u32,
    /// Settings to store (the idle loop writes the flash).
    saves: Producer<'static, Settings>,
}

/// What the display task owns.
pub struct Display {
    screen: Screen,
}

/// What the idle loop owns: the session log's writer and the watchdog's feeder.
pub struct Writer {
    log: &'static mut BoardLog<sd_card::SdioCard, stm32f4xx_hal::serial::Tx<pac::USART3>>,
    items: Consumer<'static, LogItem>,
    iwdg: IndependentWatchdog,
    ms_clock: MonotonicMs,
    watch: ProgressWatch,
    starving: bool,
    progress: [u32; 2],
    last_t: f64,
    /// The UART while the card logs (attached when the card fails).
    spare_uart: Option<stm32f4xx_hal::serial::Tx<pac::USART3>>,
    /// The flash (settings saves) and the settings to store.
    flash: LockedFlash,
    saves: Consumer<'static, Settings>,
    /// The ADC's sample rate, Hz (samples lost to a flash stall).
    adc_rate_hz: f32,
}

impl Proc {
    /// Queues a session-log record; a full queue loses it (counted, logged later).
    fn log(&mut self, item: LogItem) {
        if self.log.enqueue(item).is_err() {
            self.log_overruns = self.log_overruns.wrapping_add(1);
        }
    }

    /// An event record now.
    fn event(&mut self, kind: &'static str, why: Option<&'static str>, count: Option<i64>) {
        let t = log_t(&self.clock);
        self.log(LogItem::Event {
            t,
            kind,
            why,
            count,
        });
    }

    /// Hands the display the newest model.
    fn redraw(&mut self, view: &mut impl Mutex<T = Option<View>>) {
        self.drawn = Some(self.clock.now());
        let v = View {
            model: self.shown,
            fault: self.fault,
            battery: self.battery.state(),
            menu: self.controls.open_menu(),
            procedure: self
                .controls
                .procedure(self.receiver.motion().total_steps()),
            outcome: self.controls.outcome(),
        };
        view.lock(|slot| *slot = Some(v));
        rtic::pend(pac::Interrupt::USART2);
    }

    /// One ADC sample through the front end; a finished pulse through the estimator.
    fn on_sample(
        &mut self,
        sample: Sample,
        sampler: &mut impl Mutex<T = Sampler>,
        view: &mut impl Mutex<T = Option<View>>,
    ) {
        self.taken = self.taken.wrapping_add(1);
        match self.frontend.push(sample.volts, sample.clipped) {
            Ok(Some(pulse)) => {
                // The DSP counts only the samples it saw: stalls are added back.
                let t_pulse = Instant::from_micros(
                    pulse_centre_us(pulse.start_sample, pulse.duration_s, self.rate)
                        + self.clock.offset_us(),
                );
                // Logged before it is processed: a fault in the estimator loses no record.
                self.log(LogItem::Pulse {
                    t: t_pulse.secs_f64(),
                    m: pulse.measurement,
                    src: pulse.src,
                });
                let model = match pulse.measurement {
                    PulseMeasurement::Field(h) => {
                        self.receiver.on_pulse(t_pulse, &h, pulse.src).ok()
                    }
                    // Overlap, clipping, truncation: held out of the estimators.
                    _ => Some(self.receiver.on_withheld(t_pulse)),
                };
                if let Some(model) = model {
                    self.shown = model;
                    self.redraw(view);
                }
            }
            Ok(None) => {}
            Err(_) => defmt::warn!("front end refused a sample"),
        }
        // A change of gain: to the hardware, then to the log (the replay's `gain` event).
        let (queued, offset_us) = (self.samples.len(), self.clock.offset_us());
        let pin = &mut self.if_range;
        if let Some(e) = gain::apply_change(self.frontend, queued, self.rate, offset_us, |c| {
            write_range(pin, c, sampler)
        }) {
            let c = e.change;
            if e.applied {
                defmt::info!("range {} -> {} ({})", c.from, c.to, c.reason);
            } else {
                defmt::warn!("PGA write failed: staying at {}", c.from);
            }
            self.log(LogItem::Gain(e));
        }
    }

    /// One 100 Hz tick: the clock, health, battery, buttons, tones and the IMU sample.
    fn on_tick(
        &mut self,
        record: ImuRecord,
        sampler: &mut impl Mutex<T = Sampler>,
        view: &mut impl Mutex<T = Option<View>>,
    ) {
        self.sensors
            .adc_tick(watch_adc(self.clock.tick(self.taken), sampler));
        self.window_ticks += 1;
        if self.window_ticks >= IMU_HZ as u32 {
            self.window_ticks = 0;
            self.second();
        }
        // The buttons (the mark button debounced over 3 ticks by its own poll).
        let now_ms = self.ms_clock.now_ms(DWT::cycle_count());
        let steps = self.receiver.motion().total_steps();
        let low = self.sound_pin.is_low();
        let sound = self.controls.sound_button(low, now_ms, steps);
        let mut redraw = self.respond(sound);
        if self.mark.poll() {
            let r = self.controls.mark_button(steps);
            redraw |= self.respond(r);
        }
        let t = self.clock.now();
        // A fault shows at once and is logged when it comes and goes.
        let (stuck, stats) = with_bus(|b| (b.stuck(), b.stats())).unwrap_or_default();
        self.sensors.bus_stuck(stuck);
        if stats != self.bus_stats {
            defmt::warn!(
                "I2C bus: {=u32} errors, {=u32} stuck, {=u32} cleared, {=u32} clears failed",
                stats.errors,
                stats.stuck,
                stats.recoveries,
                stats.failed_recoveries
            );
            self.bus_stats = stats;
        }
        self.sensors.imu_up(record.reading.is_some());
        let now_fault = self.sensors.fault();
        if now_fault != self.fault {
            match now_fault {
                Some(f) => defmt::error!("sensor fault: {=str}", f.label()),
                None => defmt::info!("sensor fault cleared"),
            }
            self.event(
                "fault",
                Some(now_fault.map_or("cleared", Fault::label)),
                None,
            );
            self.fault = now_fault;
            redraw = true;
        }
        let screen_ok = SCREEN_OK.load(Ordering::Relaxed);
        let led = self.fault.is_some() || !screen_ok || sd_label().is_some();
        self.fault_led.set_state(led.into());
        // Pulses redraw the screen; without them it is redrawn at least every
        // REDRAW_MAX_US, so that "NO SIGNAL" and the arrow to a silent victim show.
        if redraw
            || self
                .drawn
                .is_none_or(|d| t.micros().saturating_sub(d.micros()) >= REDRAW_MAX_US)
        {
            self.shown = self.receiver.display_model();
            self.redraw(view);
        }
        self.tone();
        // A short hole in the ADC's samples holds the clock: skip that tick's sample.
        if let Some(reading) = record
            .reading
            .filter(|_| self.last_imu_t.is_none_or(|l| t > l))
        {
            self.last_imu_t = Some(t);
            match reading {
                Ok(r) => {
                    // The calibration fits the raw readings.
                    self.controls.on_mag(&r.mag);
                    let mag = self.mag_cal.map_or(r.mag, |c| c.apply(&r.mag));
                    self.log(LogItem::Imu {
                        t: t.secs_f64(),
                        acc: r.acc,
                        gyr: r.gyr,
                        mag,
                    });
                    if self.receiver.on_imu(t, &r.acc, &r.gyr, Some(&mag)).is_err() {
                        defmt::warn!("IMU sample refused");
                    }
                    self.sensors.imu_read(true);
                }
                Err(()) => {
                    defmt::warn!("IMU read failed");
                    self.event("read_error", Some("imu"), None);
                    self.sensors.imu_read(false);
                }
            }
        }
        self.overruns();
        TICKS.fetch_add(1, Ordering::Relaxed);
    }

    /// Once a second: the ADC's health window and the battery.
    fn second(&mut self) {
        let (n, e) = (
            SAMPLES.load(Ordering::Relaxed),
            FRAME_ERRORS.load(Ordering::Relaxed),
        );
        let failed = e.wrapping_sub(self.window_errors);
        self.sensors
            .adc_window(n.wrapping_sub(self.window_samples), failed);
        if failed > 0 {
            self.event("read_error", Some("adc"), Some(i64::from(failed)));
        }
        (self.window_samples, self.window_errors) = (n, e);
        let raw = self.mcu_adc.convert(&self.vbat_pin, SampleTime::Cycles_480);
        let was_low = self.battery.state().is_some_and(|b| b.low);
        let volts = health::battery_volts(raw, self.vdda_v, pins::BATTERY_DIVIDER);
        if let Some(b) = self.battery.update(volts).filter(|b| b.low != was_low) {
            if b.low {
                defmt::warn!("battery low: {=f32} V", b.volts);
            } else {
                defmt::info!("battery no longer low: {=f32} V", b.volts);
            }
        }
    }

    /// Carries out what the buttons asked for (`board::controls`): log records, a victim
    /// marked, the closed menu's settings applied and stored. True when the screen
    /// changed.
    fn respond(&mut self, r: Response) -> bool {
        if let Some(muted) = r.muted {
            defmt::info!("sound {=str}", if muted { "off" } else { "on" });
        }
        if let Some((what, result, value)) = r.calibration {
            defmt::info!("{=str}: {=str}", what, result);
            self.calibration_event(what, result, value);
        }
        if r.mark_victim {
            self.event("mark", None, None);
            match self.receiver.mark() {
                Ok(n) => defmt::info!("victim {=u8} marked", n),
                Err(_) => defmt::info!("mark: no victim to mark"),
            }
            self.shown = self.receiver.display_model();
        }
        if let Some(c) = r.closed {
            self.close_menu(c);
        }
        r.redraw || r.mark_victim
    }

    /// A `calibration` event: which procedure, what happened, its value.
    fn calibration_event(&mut self, what: &'static str, result: &'static str, value: Option<f32>) {
        let t = log_t(&self.clock);
        self.log(LogItem::Calibration {
            t,
            what,
            result,
            value,
        });
    }

    /// The receiver rebuilt in place for `s` (a new search): mode, earth field, step
    /// length; the log starts a new segment with the new earth field.
    fn rebuild_receiver(&mut self, s: &Settings) {
        let step = s
            .calibration
            .step_length_m
            .or(PROFILE.defaults.step_length_m);
        let mut cfg = PROFILE.app_config(s.earth_field(), step);
        cfg.mode = s.mode.app();
        match rebuild(self.receiver, cfg) {
            Ok(()) => {
                self.controls.rebuilt(s);
                self.last_imu_t = None;
                self.shown = self.receiver.display_model();
                self.log(LogItem::Header {
                    imu_hz: PROFILE.imu.rate_hz,
                    earth_ut: s.earth_field(),
                });
                defmt::info!("receiver rebuilt: mode {=str}", s.mode.word());
            }
            Err(e) => defmt::error!("new settings refused by the receiver: {}", e),
        }
    }

    /// The menu closed with changed settings: they apply from now on (a new mode, region
    /// or step length rebuilds the receiver: a new search), are logged and go to the idle
    /// loop to be stored in flash (it stalls every task while it writes).
    fn close_menu(&mut self, c: Closed) {
        let s = c.settings;
        self.mag_cal = s.calibration.mag;
        if c.rebuild {
            self.rebuild_receiver(&s);
        }
        let why = if self.saves.enqueue(s).is_ok() {
            defmt::info!("settings changed (volume {=u8}); saving", s.volume);
            "menu"
        } else {
            defmt::warn!("settings changed; not stored (saves pending)");
            "menu_not_saved"
        };
        self.event("settings", Some(why), Some(i64::from(s.volume)));
    }

    /// The tone of the moment (10 ms edges at the tick) at its volume.
    fn tone(&mut self) {
        let now_ms = self.ms_clock.now_ms(DWT::cycle_count());
        let play = self
            .controls
            .tone(&self.shown, self.fault, now_ms)
            .map(|(hz, volume)| (hz, sound::duty(self.buzzer.get_max_duty(), volume)));
        if play != self.playing {
            match play {
                Some((hz, duty)) => {
                    self.buzz_timer.set_period(hz.Hz());
                    self.buzzer.set_duty(duty);
                }
                None => self.buzzer.set_duty(0),
            }
            self.playing = play;
        }
    }

    /// Logs each kind of overrun whose count grew: samples dropped (queue full), IMU
    /// ticks missed, IMU records lost (queue full), log records lost (queue full; logged
    /// once the queue has room again), samples lost while the flash stalled (a settings
    /// save: the clock moves on by them).
    fn overruns(&mut self) {
        // In the order of `log_item::OVERRUN_KINDS`.
        let now = [
            DROPPED.load(Ordering::Relaxed),
            MISSED_TICKS.load(Ordering::Relaxed),
            IMU_OVERRUNS.load(Ordering::Relaxed),
            self.log_overruns,
            FLASH_LOST.load(Ordering::Relaxed),
        ];
        for (why, new) in self.reported.report(now) {
            if why == "flash" {
                self.clock.skip(new);
            }
            defmt::warn!("overrun {=str}: {=u32}", why, new);
            self.event("overrun", Some(why), Some(i64::from(new)));
        }
    }
}

impl Writer {
    /// One pass of the idle loop: the queued records to the log, the card's flush, the
    /// watchdog.
    fn pass(&mut self) {
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
        let mark = match self.log.sd_state() {
            SdState::Logging(_) => 0,
            SdState::NoCard => 1,
            SdState::Failed(_) => 2,
        };
        // The card failed: the stream takes over (its `log_error` event included).
        if mark != 0
            && let Some(uart) = self.spare_uart.take()
        {
            self.spare_uart = self.log.attach_uart(uart);
            defmt::warn!("session log: UART stream on");
        }
        SD_MARK.store(mark, Ordering::Relaxed);
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
        let read0 = SAMPLES.load(Ordering::Relaxed);
        set_watchdog_period(&mut self.iwdg, SAVE_IWDG_MS);
        let t0 = self.ms_clock.now_ms(DWT::cycle_count());
        let r = settings_store::save(&mut self.flash.unlocked(), BOARD_AREA, s);
        let t1 = self.ms_clock.now_ms(DWT::cycle_count());
        set_watchdog_period(&mut self.iwdg, IWDG_PERIOD_MS);
        for work in Work::ALL {
            self.watch.progress(work, t1);
        }
        let stall_ms = t1.saturating_sub(t0);
        let read = SAMPLES.load(Ordering::Relaxed).wrapping_sub(read0);
        let lost = settings_store::samples_lost(stall_ms, self.adc_rate_hz, read);
        FLASH_LOST.fetch_add(lost, Ordering::Relaxed);
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
            DRAINS.load(Ordering::Relaxed),
            TICKS.load(Ordering::Relaxed),
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

/// Builds a new receiver for `cfg` in the place of `receiver` (≈ 88 KB: never on the
/// stack); the old one is left as it was when `cfg` is refused.
fn rebuild(receiver: &mut Receiver, cfg: AppConfig) -> Result<(), AppError> {
    // SAFETY: `MaybeUninit<Receiver>` has `Receiver`'s layout, the pointer comes from a
    // unique reference and is used only for this call, and `emplace` leaves a valid
    // receiver behind (it checks `cfg` before it writes). The old receiver is forgotten,
    // not dropped (as `ptr::write` does): it owns no heap and no device, only inline
    // `heapless` buffers of plain data, so nothing leaks.
    let slot = unsafe { &mut *core::ptr::from_mut(receiver).cast::<MaybeUninit<Receiver>>() };
    Receiver::emplace(slot, cfg).map(|_| ())
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
        let spi_bus = dp.SPI2.spi(
            (Some(gpiob.pb13), Some(gpiob.pb14), Some(gpiob.pb15)),
            mode,
            8.MHz(),
            &mut rcc,
        );
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
        // The bus owns the clock controller from here (it rebuilds I2C1 after a clear).
        // SAFETY: the only write of BUS, before BUS_READY lets anything use it; no task runs
        // during init.
        unsafe {
            (*BUS.0.get()).write(Guarded::new(BoardI2c {
                i2c: Some(i2c),
                rcc,
            }))
        };
        BUS_READY.store(true, Ordering::Release);
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
        SCREEN_OK.store(screen_ok, Ordering::Relaxed);
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
                    samples: samples_out,
                    records: records_out,
                    log: log_in,
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
                    mcu_adc,
                    vbat_pin,
                    vdda_v,
                    fault_led,
                    if_range,
                    mark,
                    sound_pin,
                    controls: Controls::new(settings, SOUND_ON),
                    playing: None,
                    buzz_timer,
                    buzzer,
                    mag_cal,
                    ms_clock,
                    window_ticks: 0,
                    window_samples: SAMPLES.load(Ordering::Relaxed),
                    window_errors: FRAME_ERRORS.load(Ordering::Relaxed),
                    bus_stats,
                    reported: Overruns::new(),
                    log_overruns: 0,
                    saves: saves_in,
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
            SAMPLES.fetch_add(1, Ordering::Relaxed);
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
                    FRAME_ERRORS.fetch_add(1, Ordering::Relaxed);
                    Sample {
                        volts: [0.0; 3],
                        clipped: true,
                    }
                }
            }
        });
        if cx.local.samples_in.enqueue(sample).is_ok() {
            QUEUED.fetch_add(1, Ordering::Relaxed);
        } else {
            DROPPED.fetch_add(1, Ordering::Relaxed);
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
            MISSED_TICKS.fetch_add(missed, Ordering::Relaxed);
        }
        // A bus clear may have reset the devices or left them half-configured.
        if with_bus(|b| b.take_reinit()).unwrap_or(false) {
            tick.imu = imu_up(&mut CycleDelay);
            SCREEN_REINIT.store(true, Ordering::Relaxed);
            defmt::warn!(
                "I2C devices re-initialised (IMU {=bool})",
                tick.imu.is_some()
            );
        }
        let record = ImuRecord {
            queued: QUEUED.load(Ordering::Relaxed),
            reading: tick.imu.as_mut().map(|imu| imu.read().map_err(|_| ())),
        };
        if tick.records.enqueue(record).is_err() {
            IMU_OVERRUNS.fetch_add(1, Ordering::Relaxed);
        }
        rtic::pend(pac::Interrupt::USART1);
    }

    /// DSP, estimator, guidance, health and tones: samples and IMU records in time order.
    #[task(binds = USART1, priority = 2, shared = [sampler, view], local = [work])]
    fn process(cx: process::Context) {
        let w = cx.local.work;
        let (mut sampler, mut view) = (cx.shared.sampler, cx.shared.view);
        loop {
            // An IMU record once the samples queued before it are taken (or none wait).
            let waiting = w.samples.ready();
            let due = w
                .records
                .peek()
                .is_some_and(|r| schedule::imu_record_due(w.taken, r.queued, waiting));
            if due {
                if let Some(r) = w.records.dequeue() {
                    w.on_tick(r, &mut sampler, &mut view);
                }
            } else if let Some(s) = w.samples.dequeue() {
                w.on_sample(s, &mut sampler, &mut view);
            } else {
                break;
            }
        }
        DRAINS.fetch_add(1, Ordering::Relaxed);
    }

    /// Draws the newest model and flushes it (each I2C write under the bus lock).
    #[task(binds = USART2, priority = 1, shared = [view], local = [display])]
    fn show_view(mut cx: show_view::Context) {
        let screen = &mut cx.local.display.screen;
        if SCREEN_REINIT.swap(false, Ordering::Relaxed) {
            SCREEN_OK.store(screen.init().is_ok(), Ordering::Relaxed);
        }
        if let Some(v) = cx.shared.view.lock(Option::take) {
            let ok = show(screen, &v);
            if !ok {
                defmt::warn!("display write failed");
            }
            SCREEN_OK.store(ok, Ordering::Relaxed);
        }
    }
}

// The priorities above are the schedule model's (`firmware::board::schedule`).
const _: () = assert!(PRIO_DRDY == 4 && PRIO_IMU == 3 && PRIO_PROCESS == 2 && PRIO_DISPLAY == 1);
