//! Board binary of the receiver (reference board: STM32F405RG on the Adafruit Feather
//! STM32F405 Express, 12 MHz crystal). Flash and run with `cargo board-run` (probe-rs);
//! logs arrive over RTT (defmt), the session log goes to the microSD card (one file per
//! session) and over USART3.
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
//! | sound button (push button to ground, internal pull-up; debounced): mute / unmute, a chirp confirms "on" | GPIO | PC2 (D12) |
//! | battery voltage (the Feather's ½ divider on BAT, read once a second) | ADC1 IN3 | PA3 (on board) |
//! | supervision: independent watchdog (1 s), cycle counter (progress times) | IWDG, DWT | – |
//!
//! The full pin map, checked against the Feather's pinout by unit tests, with the pins
//! reserved for the buzzer, the second button and the battery divider, is
//! [`firmware::board::pins`].
//!
//! Supervision: the IWDG is fed only while the main loop's work progresses
//! ([`firmware::board::watchdog`]: the sample queue drained within 1 s, a timer tick
//! handled within 0.5 s); a panic stores its message in no-init RAM and resets, and a
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
//! Timing: every ADC sample is read in the DRDY interrupt (EXTI9_5, highest priority)
//! into a lock-free queue, so no sample is lost while the main loop runs the estimator
//! (≤ 8.4 M instructions per pulse, see `hal-sim/reports/budget.md`) or flushes the
//! display. The ADC's sample count is the time base of everything (8 kSPS), so the
//! pulse times of the front end and the IMU times share one clock; if the ADC stops
//! delivering (a DRDY edge lost), the 100 Hz timer carries the clock and DRDY is re-armed
//! every 100 ms (`firmware::timebase`), so dead reckoning and the display go on. Each record is
//! written to the session log *before* the application processes it, so a fault in the
//! estimator never loses recorded data. Memory: the receiver state (≈ 88 KB: four victims'
//! SOGs mixtures, see `firmware::victims`) lives in SRAM (`.uninit`, never on the stack,
//! never moved); the ADC sample queue (32 KB) and the pulse front end live in the
//! core-coupled RAM (`.ccmram`, see `memory.x`), which the DMA-free design never needs
//! to reach from a bus master.
#![no_std]
#![no_main]
// Narrow uses, each with its SAFETY note: the statics of the receiver, the sample queue,
// the front end and the crash record (each taken once, in `main` or the panic handler),
// and read-only reads of GPIOB's input register.
#![allow(unsafe_code)]

#[path = "receiver/sd_card.rs"]
mod sd_card;

use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::{DWT, SCB};
use cortex_m_rt::entry;
use defmt_rtt as _;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::i2c::RefCellDevice;
use embedded_hal_bus::spi::ExclusiveDevice;
use firmware::app::Receiver;
use firmware::board::board_log::BoardLog;
use firmware::board::crash::{self, CrashKind, CrashRecord, LastReset};
use firmware::board::health::{self, Battery, BatteryState, Fault, SensorHealth};
use firmware::board::i2c_bus::{self, ClearError, Cleared, Guarded, Recoverable};
use firmware::board::sd_log::SdState;
use firmware::board::settings::{self, Settings};
use firmware::board::sound::{self, SoundInput};
use firmware::board::watchdog::{MonotonicMs, ProgressWatch, Verdict, Work};
use firmware::board::{self, BoardProfile, pins};
use firmware::display;
use firmware::drivers::ads131m04::Ads131m04;
use firmware::drivers::imu::Imu;
use firmware::frontend::{Frontend, IfRange, PulseMeasurement, RangeChange};
use firmware::session_log::Detail;
use firmware::timebase::{ClockEvent, Instant, SampleClock, pulse_centre_us};
use firmware::victims::MarkButton;
use heapless::spsc::{Consumer, Producer, Queue};
use ssd1306::{I2CDisplayInterface, Ssd1306, prelude::*};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::adc::config::{AdcConfig, SampleTime};
use stm32f4xx_hal::gpio::{Edge, ExtiPin, Input, OpenDrain, Output, PB6, PB7, PC3, PC7};
use stm32f4xx_hal::i2c::I2c;
use stm32f4xx_hal::rcc::Rcc;
use stm32f4xx_hal::watchdog::IndependentWatchdog;
use stm32f4xx_hal::{interrupt, pac, prelude::*, rcc::Config, spi};

/// The board this binary runs on: analog chain, ADC, IMU mounting and rates, defaults.
const PROFILE: BoardProfile = board::REFERENCE;
/// Longest time (µs) the screen goes without a redraw when no pulse redraws it.
const REDRAW_MAX_US: u64 = 1_000_000;
/// ADC frames buffered between the DRDY interrupt and the main loop: 250 ms at 8 kSPS,
/// room for the worst estimator step plus a display flush.
const QUEUE_LEN: usize = 2048;
/// Core clock, Hz (also the DWT cycle counter's rate).
const SYSCLK_HZ: u32 = 168_000_000;
/// The independent watchdog's period, ms: the longest the main loop blocks is an
/// estimator step (≈ 50 ms) plus a display flush (≈ 25 ms).
const IWDG_PERIOD_MS: u32 = 1000;
/// Progress limits, ms, by [`Work`]: the queue holds 250 ms of samples, so draining it
/// within 1 s leaves the worst estimator step four times over; the 100 Hz tick within
/// 0.5 s (50 ticks).
const PROGRESS_LIMIT_MS: [u64; 2] = [1000, 500];
/// How long the last reset's report stays on the display at boot, ms.
const RESET_REPORT_MS: u32 = 3000;
/// I2C1's bus clock.
const I2C_HZ: u32 = 400_000;
/// The session log also streams over USART3 (921 600 Bd), for a host attached by wire.
const UART_LOG: bool = true;
/// Crash-record text marking the SD card's bring-up: a watchdog reset there (a card that
/// never leaves power-up) is reported with it, and the next boot leaves the card alone.
const SD_INIT_MARK: &str = "SD card bring-up";
/// Guidance tones on at boot (the sound button toggles them; not stored until settings
/// live in flash).
const SOUND_ON: bool = true;

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

/// What the DRDY interrupt owns.
struct Sampler {
    adc: Ads131m04<AdcSpi, DrdyAsserted>,
    drdy: PC7<Input>,
    queue: Producer<'static, Sample>,
}

static SAMPLER: Mutex<RefCell<Option<Sampler>>> = Mutex::new(RefCell::new(None));
/// ADC samples taken (the time base) and samples dropped (queue full or bus error).
static SAMPLES: AtomicU32 = AtomicU32::new(0);
static DROPPED: AtomicU32 = AtomicU32::new(0);
/// ADC frames that failed (CRC or bus error), for the health monitor.
static FRAME_ERRORS: AtomicU32 = AtomicU32::new(0);

/// The application state in SRAM (not zeroed by the runtime: initialized with
/// `Receiver::emplace` before use).
#[unsafe(link_section = ".uninit.RECEIVER")]
static mut RECEIVER: MaybeUninit<Receiver> = MaybeUninit::uninit();
/// The ADC sample queue in core-coupled RAM (initialized in `main` before use).
#[unsafe(link_section = ".ccmram")]
static mut QUEUE: MaybeUninit<Queue<Sample, QUEUE_LEN>> = MaybeUninit::uninit();
/// The pulse front end in core-coupled RAM (initialized in `main` before use).
#[unsafe(link_section = ".ccmram")]
static mut FRONTEND: MaybeUninit<Frontend> = MaybeUninit::uninit();
/// The crash record: in `.uninit` SRAM, so a system reset keeps it (the runtime neither
/// zeroes nor initialises it); read and cleared once at boot, written by the panic
/// handler and by a starving watchdog feeder.
#[unsafe(link_section = ".uninit.CRASH")]
static mut CRASH: MaybeUninit<CrashRecord> = MaybeUninit::uninit();
/// The session log (SD card file system, its block buffer, the UART): in SRAM, not on
/// main's stack (initialized in `main` before use).
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

type Bus = RefCell<Guarded<BoardI2c>>;
type Screen<'a> = Ssd1306<
    I2CInterface<RefCellDevice<'a, Guarded<BoardI2c>>>,
    DisplaySize128x64,
    ssd1306::mode::BufferedGraphicsMode<DisplaySize128x64>,
>;

/// Brings the IMU up on the shared bus (at boot and after a bus clear).
fn imu_up<'a>(
    bus: &'a Bus,
    delay: &mut impl DelayNs,
) -> Option<Imu<RefCellDevice<'a, Guarded<BoardI2c>>>> {
    match Imu::with_mounting(
        RefCellDevice::new(bus),
        RefCellDevice::new(bus),
        PROFILE.imu.mounting,
        delay,
    ) {
        Ok(imu) => Some(imu),
        Err(_) => {
            defmt::error!("IMU not answering: no dead reckoning");
            None
        }
    }
}

#[interrupt]
fn EXTI9_5() {
    cortex_m::interrupt::free(|cs| {
        let mut guard = SAMPLER.borrow(cs).borrow_mut();
        let Some(s) = guard.as_mut() else { return };
        s.drdy.clear_interrupt_pending_bit();
        SAMPLES.fetch_add(1, Ordering::Relaxed);
        let sample = match s.adc.read_frame() {
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
        };
        if s.queue.enqueue(sample).is_err() {
            DROPPED.fetch_add(1, Ordering::Relaxed);
        }
    });
}

/// IMU sampling (and sample-clock watchdog) rate, Hz.
const IMU_HZ: f32 = PROFILE.imu.rate_hz;

/// Reacts to the sample clock's verdict: a stalled ADC's DRDY is re-armed by reading one
/// frame (it stays low until the frame is read, so no further edge would come).
fn watch_adc(event: ClockEvent) -> ClockEvent {
    match event {
        ClockEvent::Running => {}
        ClockEvent::Resumed => defmt::info!("antenna ADC delivering again"),
        ClockEvent::Stalled { rearm: false } => {}
        ClockEvent::Stalled { rearm: true } => {
            defmt::warn!("antenna ADC stalled: re-arming DRDY");
            cortex_m::interrupt::free(|cs| {
                if let Some(s) = SAMPLER.borrow(cs).borrow_mut().as_mut() {
                    let _ = s.adc.read_frame();
                    s.drdy.clear_interrupt_pending_bit();
                }
            });
        }
    }
    event
}

/// Applies the DSP's change of analog setting (gain ranging): the coils' PGA gain in one
/// register write (inside the DRDY handler's critical section) and the IF range switch.
/// Samples already queued were taken in the old setting: the DSP discards them with the
/// switch's settling. A failed gain write puts the switch and the DSP back on `from`.
fn apply_range(frontend: &mut Frontend, pin: &mut PC3<Output>, change: RangeChange, queued: usize) {
    let set_pin = |pin: &mut PC3<Output>, r: IfRange| match r {
        IfRange::High => pin.set_low(),
        IfRange::Low => pin.set_high(),
    };
    let gain_ok = cortex_m::interrupt::free(|cs| {
        SAMPLER
            .borrow(cs)
            .borrow_mut()
            .as_mut()
            .is_some_and(|s| s.adc.set_coil_gains(change.to.gain).is_ok())
    });
    if gain_ok {
        set_pin(pin, change.to.if_range);
        frontend.extend_settle(queued);
        defmt::info!("range {} -> {} ({})", change.from, change.to, change.reason);
    } else {
        set_pin(pin, change.from.if_range);
        if frontend.set_range(change.from).is_err() {
            defmt::error!("front end refused its own setting");
        }
        frontend.extend_settle(queued);
        defmt::warn!("PGA write failed: staying at {}", change.from);
    }
}

/// Board time for the session log's records, s.
fn log_t(clock: &SampleClock) -> f64 {
    clock.now().secs_f64()
}

/// Clears `screen` and draws `model` with the health overlay (a sensor fault over the
/// status word, the battery gauge) on it; false if the display did not take it.
fn show(
    screen: &mut Screen<'_>,
    model: &firmware::app::DisplayModel,
    fault: Option<Fault>,
    battery: Option<BatteryState>,
    sd: SdState,
) -> bool {
    screen.clear(BinaryColor::Off).ok();
    display::draw(model, screen).is_ok()
        && health::draw_overlay(fault, battery, screen).is_ok()
        && health::draw_sd_mark(sd.fault_label(), screen).is_ok()
        && screen.flush().is_ok()
}

#[entry]
fn main() -> ! {
    let (Some(dp), Some(mut cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        fatal("peripherals taken twice");
    };
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
    let mut mcu_adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
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
    // SAFETY: the only reference ever taken to LOG, here, once; no interrupt uses it.
    let log = unsafe { &mut *core::ptr::addr_of_mut!(LOG) }
        .write(BoardLog::new(sd, UART_LOG.then_some(uart)));
    // The unit's settings from flash sector 11 (defaults, with the reason, when erased or
    // corrupt).
    // SAFETY: SETTINGS_LEN bytes of memory-mapped flash inside the reserved sector
    // (memory.x), always readable; nothing writes flash while this boot reads it.
    let stored = unsafe {
        core::slice::from_raw_parts(settings::SETTINGS_ADDR as *const u8, settings::SETTINGS_LEN)
    };
    let (settings, settings_error) = Settings::load(stored);
    let step_length_m = settings
        .calibration
        .step_length_m
        .or(PROFILE.defaults.step_length_m);
    let earth = settings.earth_field();
    log.header(PROFILE.imu.rate_hz, &earth, true);
    log.reset(0.0, &last_reset);
    let region = settings::REGIONS
        .get(usize::from(settings.region))
        .map_or("?", |r| r.name);
    log.event(
        0.0,
        "settings",
        Some(if settings_error.is_some() {
            "defaults"
        } else {
            "stored"
        }),
        &[
            // "none": not calibrated (the step detector's default length applies).
            (
                "step_length_m",
                step_length_m.map_or(Detail::Text("none"), Detail::Num),
            ),
            ("mode", Detail::Text("sog")),
            ("volume", Detail::Int(i64::from(settings.volume))),
            ("region", Detail::Text(region)),
            (
                "antenna_cal",
                Detail::Flag(settings.calibration.antenna.is_some()),
            ),
            ("mag_cal", Detail::Flag(settings.calibration.mag.is_some())),
        ],
    );
    if let Some(e) = settings_error {
        defmt::warn!("settings: {}; defaults apply", e);
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
    let (mut buzz_timer, (_, _, buzz_ch, _)) = dp.TIM4.pwm_hz(2.kHz(), &mut rcc);
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
    let bus: Bus = RefCell::new(Guarded::new(BoardI2c {
        i2c: Some(i2c),
        rcc,
    }));
    let mut imu = imu_up(&bus, &mut delay);
    let mut sensors = SensorHealth::new();
    sensors.adc_boot(adc_ok);
    sensors.imu_up(imu.is_some());
    let mut battery = Battery::new();
    // The red LED tells of a fault even when the display is what failed.
    let mut fault_led = gpioc.pc1.into_push_pull_output();
    let mut screen: Screen<'_> = Ssd1306::new(
        I2CDisplayInterface::new(RefCellDevice::new(&bus)),
        DisplaySize128x64,
        DisplayRotation::Rotate0,
    )
    .into_buffered_graphics_mode();
    let mut screen_ok = screen.init().is_ok();
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
    let cfg = PROFILE.app_config(earth, step_length_m);
    // SAFETY: the only reference ever taken to RECEIVER, here, once, before any interrupt
    // that could run is enabled; no interrupt touches it.
    let slot = unsafe { &mut *core::ptr::addr_of_mut!(RECEIVER) };
    let Ok(receiver) = Receiver::emplace(slot, cfg) else {
        fatal("default configuration refused");
    };
    // The nominal calibration of the design until the unit's bench calibration is stored.
    let fe_cfg = PROFILE.frontend_config(&settings.calibration.antenna_or(&PROFILE.analog.nominal));
    let rate = fe_cfg.sample_rate_hz;
    let Ok(new_frontend) = Frontend::new(fe_cfg) else {
        fatal("front-end configuration refused");
    };
    // SAFETY: the only reference ever taken to FRONTEND, here, once; no interrupt uses it.
    let frontend = unsafe { &mut *core::ptr::addr_of_mut!(FRONTEND) }.write(new_frontend);

    // ADC samples flow through the queue from the DRDY interrupt.
    // SAFETY: the only reference ever taken to QUEUE, here, once, before the DRDY
    // interrupt (its producer's only user) is unmasked.
    let queue = unsafe { &mut *core::ptr::addr_of_mut!(QUEUE) }.write(Queue::new());
    let (producer, mut consumer): (Producer<'static, Sample>, Consumer<'static, Sample>) =
        queue.split();
    // The mark button: flags the victim being guided to as found.
    let mut mark = MarkButton::new(gpioc.pc6.into_pull_up_input());
    // The sound button: the same debounced press, on D12.
    let mut sound_button = MarkButton::new(gpioc.pc2.into_pull_up_input());
    // Volume steps are not wired to the buzzer yet (50 % duty): 0 mutes.
    let mut muted = !SOUND_ON || settings.volume == 0;
    let mut chirp_until_ms = 0u64;
    // The IF range switch starts in the high range, the ADC at the profile's gain: the
    // DSP's starting setting (`BoardProfile::start_range`).
    let mut if_range = gpioc.pc3.into_push_pull_output();
    if_range.set_low();
    let mut drdy = gpioc.pc7.into_pull_up_input();
    drdy.make_interrupt_source(&mut syscfg);
    drdy.trigger_on_edge(&mut exti, Edge::Falling);
    drdy.enable_interrupt(&mut exti);
    cortex_m::interrupt::free(|cs| {
        SAMPLER.borrow(cs).replace(Some(Sampler {
            adc,
            drdy,
            queue: producer,
        }));
    });
    // SAFETY: the handler and its state are in place; unmasking cannot break a critical section.
    unsafe { cortex_m::peripheral::NVIC::unmask(pac::Interrupt::EXTI9_5) };

    defmt::info!(
        "receiver running (ADC {=bool}, display {=bool})",
        adc_ok,
        screen_ok
    );

    let mut taken: u32 = 0;
    // Board time: samples taken through the front end, kept running by the IMU timer if
    // the ADC stalls (see `firmware::timebase`).
    let Ok(mut clock) = SampleClock::new(rate, IMU_HZ, taken) else {
        fatal("sample clock refused its rates");
    };
    let mut last_imu_t: Option<Instant> = None;
    // Board time of the last redraw.
    let mut drawn: Option<Instant> = None;
    // Progress of the main loop's work, on the cycle counter's clock.
    let mut ms_clock = MonotonicMs::new(SYSCLK_HZ / 1000, DWT::cycle_count());
    let mut watch = ProgressWatch::new(PROGRESS_LIMIT_MS, ms_clock.now_ms(DWT::cycle_count()));
    let mut starving = false;
    let mut bus_stats = bus.borrow().stats();
    let mut fault = sensors.fault();
    if let Some(f) = fault {
        defmt::error!("sensor fault at boot: {=str}", f.label());
    }
    let sd_fault = log.sd_state().fault_label().is_some();
    fault_led.set_state((fault.is_some() || !screen_ok || sd_fault).into());
    // Ticks since the last one-second health window, and the counters at its start.
    let mut window_ticks = 0u32;
    let mut window_samples = SAMPLES.load(Ordering::Relaxed);
    let mut window_errors = FRAME_ERRORS.load(Ordering::Relaxed);
    // What the screen shows last (the tones follow it) and the tone playing.
    let mut shown = receiver.display_model();
    let mut playing: Option<u32> = None;
    loop {
        while let Some(sample) = consumer.dequeue() {
            taken = taken.wrapping_add(1);
            match frontend.push(sample.volts, sample.clipped) {
                Ok(Some(pulse)) => {
                    // The DSP counts only the samples it saw: stalls are added back.
                    let t_pulse = Instant::from_micros(
                        pulse_centre_us(pulse.start_sample, pulse.duration_s, rate)
                            + clock.offset_us(),
                    );
                    log.pulse(t_pulse.secs_f64(), &pulse.measurement, pulse.src);
                    let model = match pulse.measurement {
                        PulseMeasurement::Field(h) => {
                            receiver.on_pulse(t_pulse, &h, pulse.src).ok()
                        }
                        // Overlap, clipping, truncation: held out of the estimators.
                        _ => Some(receiver.on_withheld(t_pulse)),
                    };
                    if let Some(model) = model {
                        shown = model;
                    }
                    if let Some(model) = model.filter(|_| screen_ok) {
                        drawn = Some(clock.now());
                        if !show(&mut screen, &model, fault, battery.state(), log.sd_state()) {
                            defmt::warn!("display write failed");
                        }
                    }
                }
                Ok(None) => {}
                Err(_) => defmt::warn!("front end refused a sample"),
            }
            if let Some(change) = frontend.take_range_change() {
                apply_range(frontend, &mut if_range, change, consumer.len());
            }
        }
        watch.progress(Work::Samples, ms_clock.now_ms(DWT::cycle_count()));
        if imu_tick.wait().is_ok() {
            watch.progress(Work::Ticks, ms_clock.now_ms(DWT::cycle_count()));
            sensors.adc_tick(watch_adc(clock.tick(taken)));
            window_ticks += 1;
            if window_ticks >= IMU_HZ as u32 {
                window_ticks = 0;
                let (n, e) = (
                    SAMPLES.load(Ordering::Relaxed),
                    FRAME_ERRORS.load(Ordering::Relaxed),
                );
                let failed = e.wrapping_sub(window_errors);
                sensors.adc_window(n.wrapping_sub(window_samples), failed);
                if failed > 0 {
                    let count = Detail::Int(i64::from(failed));
                    log.event(
                        log_t(&clock),
                        "read_error",
                        Some("adc"),
                        &[("count", count)],
                    );
                }
                (window_samples, window_errors) = (n, e);
                let raw = mcu_adc.convert(&vbat_pin, SampleTime::Cycles_480);
                let was_low = battery.state().is_some_and(|b| b.low);
                let volts = health::battery_volts(raw, vdda_v, pins::BATTERY_DIVIDER);
                if let Some(b) = battery.update(volts).filter(|b| b.low != was_low) {
                    if b.low {
                        defmt::warn!("battery low: {=f32} V", b.volts);
                    } else {
                        defmt::info!("battery no longer low: {=f32} V", b.volts);
                    }
                }
            }
            // The mark button, polled at the IMU tick (debounced over 3 ticks).
            let mut redraw = false;
            if mark.poll() {
                log.event(log_t(&clock), "mark", None, &[]);
                match receiver.mark() {
                    Ok(n) => defmt::info!("victim {=u8} marked", n),
                    Err(_) => defmt::info!("mark: no victim to mark"),
                }
                redraw = true;
            }
            let t = clock.now();
            // A fault shows at once and is logged when it comes and goes.
            sensors.bus_stuck(bus.borrow().stuck());
            let now_fault = sensors.fault();
            if now_fault != fault {
                match now_fault {
                    Some(f) => defmt::error!("sensor fault: {=str}", f.label()),
                    None => defmt::info!("sensor fault cleared"),
                }
                let why = now_fault.map_or("cleared", Fault::label);
                log.event(log_t(&clock), "fault", Some(why), &[]);
                fault = now_fault;
                redraw = true;
            }
            // The SD card: flushed when due; a failure shows and is reported.
            let (sd_changed, errors) = log.tick(log_t(&clock), ms_clock.now_ms(DWT::cycle_count()));
            if let Some(state) = sd_changed {
                defmt::error!("SD card: {}", state);
                redraw = true;
            }
            if let Some(e) = errors {
                defmt::warn!("session log errors: {}", e);
            }
            let sd_fault = log.sd_state().fault_label().is_some();
            fault_led.set_state((fault.is_some() || !screen_ok || sd_fault).into());
            // Pulses redraw the screen; without them it is redrawn at least every
            // REDRAW_MAX_US, so that "NO SIGNAL" and the arrow to a silent victim (carried
            // over the walk) show. Not at every tick: a flush holds the shared I2C bus
            // ≈ 25 ms, two or three IMU ticks.
            if redraw
                || drawn.is_none_or(|d| t.micros().saturating_sub(d.micros()) >= REDRAW_MAX_US)
            {
                drawn = Some(t);
                shown = receiver.display_model();
                if screen_ok && !show(&mut screen, &shown, fault, battery.state(), log.sd_state()) {
                    defmt::warn!("display write failed");
                }
            }
            // The tone of the moment (10 ms edges at the tick).
            let now_ms = ms_clock.now_ms(DWT::cycle_count());
            if sound_button.poll() {
                muted = !muted;
                if !muted {
                    chirp_until_ms = now_ms + sound::CHIRP_MS;
                }
                defmt::info!("sound {=str}", if muted { "off" } else { "on" });
            }
            let tone = if now_ms < chirp_until_ms {
                Some(sound::CHIRP_HZ)
            } else {
                sound::tone_at(
                    &SoundInput {
                        status: shown.status,
                        distance_m: shown.distance_m,
                        fault,
                        muted,
                    },
                    now_ms,
                )
            };
            if tone != playing {
                match tone {
                    Some(hz) => {
                        buzz_timer.set_period(hz.Hz());
                        buzzer.set_duty(buzzer.get_max_duty() / 2);
                    }
                    None => buzzer.set_duty(0),
                }
                playing = tone;
            }
            // A short hole in the ADC's samples holds the clock: skip that tick's sample.
            if let Some(imu) = imu.as_mut().filter(|_| last_imu_t.is_none_or(|l| t > l)) {
                last_imu_t = Some(t);
                match imu.read() {
                    Ok(r) => {
                        let mag = mag_cal.map_or(r.mag, |c| c.apply(&r.mag));
                        log.imu(t.secs_f64(), &r.acc, &r.gyr, Some(&mag));
                        if receiver.on_imu(t, &r.acc, &r.gyr, Some(&mag)).is_err() {
                            defmt::warn!("IMU sample refused");
                        }
                        sensors.imu_read(true);
                    }
                    Err(_) => {
                        defmt::warn!("IMU read failed");
                        log.event(t.secs_f64(), "read_error", Some("imu"), &[]);
                        sensors.imu_read(false);
                    }
                }
            }
            // A bus clear may have reset the devices or left them half-configured:
            // bring them up again.
            let stats = bus.borrow().stats();
            if stats != bus_stats {
                defmt::warn!(
                    "I2C bus: {=u32} errors, {=u32} stuck, {=u32} cleared, {=u32} clears failed",
                    stats.errors,
                    stats.stuck,
                    stats.recoveries,
                    stats.failed_recoveries
                );
                bus_stats = stats;
            }
            if bus.borrow_mut().take_reinit() {
                imu = imu_up(&bus, &mut delay);
                sensors.imu_up(imu.is_some());
                screen_ok = screen.init().is_ok();
                defmt::warn!("I2C devices re-initialised (display {=bool})", screen_ok);
            }
        }
        let dropped = DROPPED.load(Ordering::Relaxed);
        if dropped != 0 {
            let count = Detail::Int(i64::from(dropped));
            log.event(
                log_t(&clock),
                "overrun",
                Some("adc_queue"),
                &[("count", count)],
            );
            defmt::warn!(
                "{=u32} ADC samples dropped of {=u32}",
                dropped,
                SAMPLES.load(Ordering::Relaxed)
            );
            DROPPED.store(0, Ordering::Relaxed);
        }
        match watch.verdict(ms_clock.now_ms(DWT::cycle_count())) {
            Verdict::Feed => iwdg.feed(),
            Verdict::Stalled { work, for_ms } => {
                // Stop feeding: the IWDG resets within its period. Record why first.
                if !starving {
                    starving = true;
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
