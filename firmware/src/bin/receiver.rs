//! Board binary of the receiver (reference board: STM32F405RG, e.g. the Adafruit Feather
//! STM32F405 Express, 12 MHz crystal). Flash and run with `cargo board-run` (probe-rs);
//! logs arrive over RTT (defmt), the session log over USART3.
//!
//! The application itself is [`firmware::app::Receiver`] — the very type `hal-sim`
//! drives on the PC; this file only binds it to the hardware:
//!
//! | function | peripheral | MCU pins |
//! |---|---|---|
//! | antenna ADC ADS131M04 (SPI mode 1, 8 MHz; CLKIN 8.192 MHz from its own oscillator) | SPI2, EXTI7 | SCK PB13, MISO PB14, MOSI PB15, CS PB12, DRDY PC7 |
//! | IMU BMI160 (acc+gyr) + LSM303AGR (mag), SSD1306 128×64 display | I2C1, 400 kHz, shared | SCL PB6, SDA PB7 |
//! | session-log stream (spec `arva-session` v1, 921 600 Bd) | USART3 TX | PB10 |
//! | IMU sample clock (100 Hz) | TIM2 | – |
//! | mark button (push button to ground, internal pull-up; polled at 100 Hz, debounced) | GPIO | PC6 |
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
// Narrow uses, each with its SAFETY note: the statics of the receiver, the sample queue
// and the front end (each taken once, in `main`, before interrupts are enabled).
#![allow(unsafe_code)]

use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::interrupt::Mutex;
use cortex_m_rt::entry;
use defmt_rtt as _;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_hal_bus::i2c::RefCellDevice;
use embedded_hal_bus::spi::ExclusiveDevice;
use firmware::app::Receiver;
use firmware::board::{self, BoardProfile};
use firmware::drivers::ads131m04::Ads131m04;
use firmware::drivers::imu::Imu;
use firmware::frontend::{Frontend, PulseMeasurement};
use firmware::timebase::{ClockEvent, SampleClock};
use firmware::victims::MarkButton;
use firmware::{display, session_log};
use heapless::spsc::{Consumer, Producer, Queue};
use panic_probe as _;
use ssd1306::{I2CDisplayInterface, Ssd1306, prelude::*};
use stm32f4xx_hal::gpio::{Edge, ExtiPin, Input, PC7};
use stm32f4xx_hal::{interrupt, pac, prelude::*, rcc::Config, spi};

/// The board this binary runs on: analog chain, ADC, IMU mounting and rates, defaults.
const PROFILE: BoardProfile = board::REFERENCE;
/// Longest time (s) the screen goes without a redraw when no pulse redraws it.
const REDRAW_MAX_S: f32 = 1.0;
/// ADC frames buffered between the DRDY interrupt and the main loop: 250 ms at 8 kSPS,
/// room for the worst estimator step plus a display flush.
const QUEUE_LEN: usize = 2048;

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
    stm32f4xx_hal::gpio::PB12<stm32f4xx_hal::gpio::Output>,
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
            Err(_) => Sample {
                volts: [0.0; 3],
                clipped: true,
            },
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
fn watch_adc(event: ClockEvent) {
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
}

#[entry]
fn main() -> ! {
    let (Some(dp), Some(cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        defmt::panic!("peripherals taken twice");
    };
    let mut rcc = dp.RCC.freeze(Config::hse(12.MHz()).sysclk(168.MHz()));
    let mut delay = cp.SYST.delay(&rcc.clocks);
    let mut syscfg = dp.SYSCFG.constrain(&mut rcc);
    let mut exti = dp.EXTI;
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);

    // Session-log stream first, so everything after it can be recorded.
    let Ok(mut log) = dp.USART3.tx(gpiob.pb10, 921_600.bps(), &mut rcc) else {
        defmt::panic!("USART3 configuration refused");
    };
    let earth = PROFILE.default_earth_field();
    if session_log::write_header(&mut log, PROFILE.imu.rate_hz, &earth, true).is_err() {
        defmt::warn!("session log: header not written");
    }

    // Antenna ADC on SPI2, mode 1.
    let mode = spi::Mode {
        polarity: spi::Polarity::IdleLow,
        phase: spi::Phase::CaptureOnSecondTransition,
    };
    let bus = dp.SPI2.spi(
        (Some(gpiob.pb13), Some(gpiob.pb14), Some(gpiob.pb15)),
        mode,
        8.MHz(),
        &mut rcc,
    );
    let Ok(adc_spi) = ExclusiveDevice::new_no_delay(bus, gpiob.pb12.into_push_pull_output());
    let mut adc = Ads131m04::new(adc_spi, DrdyAsserted);
    let adc_ok = adc.reset(&mut delay).is_ok()
        && adc.check_id().is_ok()
        && adc.configure(&PROFILE.adc.config).is_ok();
    if !adc_ok {
        defmt::error!("antenna ADC not answering: no pulses will be received");
    }

    // IMU and display share I2C1.
    let i2c = RefCell::new(dp.I2C1.i2c((gpiob.pb6, gpiob.pb7), 400.kHz(), &mut rcc));
    let mut imu = match Imu::with_mounting(
        RefCellDevice::new(&i2c),
        RefCellDevice::new(&i2c),
        PROFILE.imu.mounting,
        &mut delay,
    ) {
        Ok(imu) => Some(imu),
        Err(_) => {
            defmt::error!("IMU not answering: no dead reckoning");
            None
        }
    };
    let mut screen = Ssd1306::new(
        I2CDisplayInterface::new(RefCellDevice::new(&i2c)),
        DisplaySize128x64,
        DisplayRotation::Rotate0,
    )
    .into_buffered_graphics_mode();
    let screen_ok = screen.init().is_ok();

    // The application in SRAM.
    let cfg = PROFILE.app_config(earth, PROFILE.defaults.step_length_m);
    // SAFETY: the only reference ever taken to RECEIVER, here, once, before any interrupt
    // that could run is enabled; no interrupt touches it.
    let slot = unsafe { &mut *core::ptr::addr_of_mut!(RECEIVER) };
    let Ok(receiver) = Receiver::emplace(slot, cfg) else {
        defmt::panic!("default configuration refused");
    };
    // The nominal calibration of the design until the unit's bench calibration is stored.
    let fe_cfg = PROFILE.frontend_config(&PROFILE.analog.nominal);
    let rate = fe_cfg.sample_rate_hz;
    let Ok(new_frontend) = Frontend::new(fe_cfg) else {
        defmt::panic!("front-end configuration refused");
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

    let mut imu_tick = dp.TIM2.counter_hz(&mut rcc);
    if imu_tick.start((IMU_HZ as u32).Hz()).is_err() {
        defmt::error!("IMU timer refused 100 Hz");
    }
    defmt::info!(
        "receiver running (ADC {=bool}, display {=bool})",
        adc_ok,
        screen_ok
    );

    let mut taken: u32 = 0;
    // Board time: samples taken through the front end, kept running by the IMU timer if
    // the ADC stalls (see `firmware::timebase`).
    let Ok(mut clock) = SampleClock::new(rate, IMU_HZ, taken) else {
        defmt::panic!("sample clock refused its rates");
    };
    let mut last_imu_t = f32::NEG_INFINITY;
    // Every redraw goes through here; `drawn_s` is the board time of the last one.
    let drawn_s = core::cell::Cell::new(f32::NEG_INFINITY);
    let mut show = |model: &firmware::app::DisplayModel, now_s: f32| {
        if !screen_ok {
            return;
        }
        drawn_s.set(now_s);
        screen.clear(BinaryColor::Off).ok();
        if display::draw(model, &mut screen).is_err() || screen.flush().is_err() {
            defmt::warn!("display write failed");
        }
    };
    loop {
        while let Some(sample) = consumer.dequeue() {
            taken = taken.wrapping_add(1);
            match frontend.push(sample.volts, sample.clipped) {
                Ok(Some(pulse)) => {
                    // The DSP counts only the samples it saw: stalls are added back.
                    let t_pulse = pulse.t_s + clock.offset_s();
                    let model = match pulse.measurement {
                        PulseMeasurement::Field(h) => {
                            let _ = session_log::write_pulse(
                                &mut log,
                                f64::from(t_pulse),
                                &h,
                                pulse.src,
                            );
                            receiver.on_pulse(t_pulse, &h, pulse.src).ok()
                        }
                        // Overlap, clipping, truncation: held out of the estimators.
                        _ => Some(receiver.on_withheld(t_pulse)),
                    };
                    if let Some(model) = model {
                        show(&model, clock.now_s());
                    }
                }
                Ok(None) => {}
                Err(_) => defmt::warn!("front end refused a sample"),
            }
        }
        if imu_tick.wait().is_ok() {
            watch_adc(clock.tick(taken));
            // The mark button, polled at the IMU tick (debounced over 3 ticks).
            if mark.poll() {
                match receiver.mark() {
                    Ok(n) => defmt::info!("victim {=u8} marked", n),
                    Err(_) => defmt::info!("mark: no victim to mark"),
                }
                show(&receiver.display_model(), clock.now_s());
            }
            let t = clock.now_s();
            // Pulses redraw the screen; without them it is redrawn at least every
            // REDRAW_MAX_S, so that "NO SIGNAL" and the arrow to a silent victim (carried
            // over the walk) show. Not at every tick: a flush holds the shared I2C bus
            // ≈ 25 ms, two or three IMU ticks.
            if t - drawn_s.get() >= REDRAW_MAX_S {
                show(&receiver.display_model(), t);
            }
            // A short hole in the ADC's samples holds the clock: skip that tick's sample.
            if let Some(imu) = imu.as_mut().filter(|_| t > last_imu_t) {
                last_imu_t = t;
                match imu.read() {
                    Ok(r) => {
                        let _ = session_log::write_imu(
                            &mut log,
                            f64::from(t),
                            &r.acc,
                            &r.gyr,
                            Some(&r.mag),
                        );
                        if receiver.on_imu(t, &r.acc, &r.gyr, Some(&r.mag)).is_err() {
                            defmt::warn!("IMU sample refused");
                        }
                    }
                    Err(_) => defmt::warn!("IMU read failed"),
                }
            }
        }
        let dropped = DROPPED.load(Ordering::Relaxed);
        if dropped != 0 {
            defmt::warn!(
                "{=u32} ADC samples dropped of {=u32}",
                dropped,
                SAMPLES.load(Ordering::Relaxed)
            );
            DROPPED.store(0, Ordering::Relaxed);
        }
    }
}
