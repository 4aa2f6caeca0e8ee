//! Faults at the chips' buses and in the analog signal, under the firmware's real drivers
//! (`firmware::drivers::ads131m04`, `firmware::drivers::imu`) over the emulated chips of
//! [`crate::sensors::bus`]:
//!
//! - [`FaultySpi`]: the antenna ADC's SPI transfers fail (a bus error or a peripheral
//!   timeout, reported as [`embedded_hal::spi::ErrorKind::Other`]) or arrive with a flipped
//!   bit (the driver's CRC check catches it), with a seeded probability in a time window;
//! - [`FaultyI2c`]: the IMU chips stop acknowledging or the transfer times out, likewise;
//! - [`Disturbed`]: the coils' signal with an EMI burst (broadband noise) or overdriven
//!   into the ADC's full scale (saturation) in a time window.
//!
//! [`adc_window`] runs the ADC, its driver, the front end and the application over a time
//! window of a world with the board's policy (`firmware/src/bin/receiver.rs`): a frame
//! that cannot be read becomes a clipped zero sample, so the sample clock (the time base)
//! is kept and the pulse it falls in is withheld as saturated.
use super::super::bus::ads131m04::{F_CLKIN_HZ, ads131m04};
use super::super::bus::if_signal::{AnalogChain, AnalogInput, IfSignal};
use super::super::bus::{NoDelay, SimClock};
use crate::stamp;
use crate::world::World;
use embedded_hal::i2c::{ErrorKind as I2cErrorKind, NoAcknowledgeSource};
use embedded_hal::spi::ErrorKind as SpiErrorKind;
use firmware::app::{AppError, DisplayModel, Receiver};
use firmware::drivers::ads131m04::{Ads131m04, Config, Error as AdcError};
use firmware::frontend::{Calibration, Frontend, FrontendConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::convert::Infallible;

/// When and how often transfers fail: with probability `p` in `[from_s, to_s)` of the
/// shared clock, seeded.
#[derive(Debug, Clone)]
pub struct FaultWindow {
    /// Start of the window, s.
    pub from_s: f64,
    /// End of the window, s.
    pub to_s: f64,
    /// Probability that a transfer in the window fails.
    pub p: f64,
    rng: ChaCha8Rng,
}

impl FaultWindow {
    /// Failures with probability `p` in `[from_s, to_s)`, drawn from `seed`.
    pub fn new(from_s: f64, to_s: f64, p: f64, seed: u64) -> Self {
        Self {
            from_s,
            to_s,
            p,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// No failures.
    pub fn none() -> Self {
        Self::new(0.0, 0.0, 0.0, 0)
    }

    fn fails(&mut self, t: f64) -> bool {
        t >= self.from_s && t < self.to_s && self.rng.random_bool(self.p.clamp(0.0, 1.0))
    }
}

/// How a failing SPI transfer fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpiFault {
    /// The bus reports an error (a peripheral timeout, an overrun).
    Error,
    /// The transfer completes with one bit flipped in what was received.
    BitFlip,
}

/// An SPI device whose transfers fail in a [`FaultWindow`]. The transfer still reaches the
/// chip (it clocks its frame out), so the chip's sample clock goes on, as on the board.
#[derive(Debug)]
pub struct FaultySpi<S> {
    inner: S,
    clock: SimClock,
    window: FaultWindow,
    kind: SpiFault,
    /// Transfers failed so far.
    pub injected: u32,
}

impl<S> FaultySpi<S> {
    /// `inner` failing as `kind` in `window` of `clock`.
    pub fn new(inner: S, clock: SimClock, window: FaultWindow, kind: SpiFault) -> Self {
        Self {
            inner,
            clock,
            window,
            kind,
            injected: 0,
        }
    }
}

impl<S: embedded_hal::spi::ErrorType<Error = Infallible>> embedded_hal::spi::ErrorType
    for FaultySpi<S>
{
    type Error = SpiErrorKind;
}

impl<S: embedded_hal::spi::SpiDevice<u8, Error = Infallible>> embedded_hal::spi::SpiDevice<u8>
    for FaultySpi<S>
{
    fn transaction(
        &mut self,
        operations: &mut [embedded_hal::spi::Operation<'_, u8>],
    ) -> Result<(), SpiErrorKind> {
        use embedded_hal::spi::Operation;
        match self.inner.transaction(operations) {
            Ok(()) => {}
            Err(e) => match e {},
        }
        if !self.window.fails(self.clock.now()) {
            return Ok(());
        }
        self.injected += 1;
        match self.kind {
            SpiFault::Error => Err(SpiErrorKind::Other),
            SpiFault::BitFlip => {
                let received = operations.iter_mut().find_map(|op| match op {
                    Operation::Read(b) | Operation::TransferInPlace(b) => Some(b),
                    Operation::Transfer(r, _) => Some(r),
                    _ => None,
                });
                if let Some(b) = received
                    && !b.is_empty()
                {
                    let i = self.window.rng.random_range(0..b.len());
                    let bit = self.window.rng.random_range(0..8);
                    if let Some(x) = b.get_mut(i) {
                        *x ^= 1 << bit;
                    }
                }
                Ok(())
            }
        }
    }
}

/// How a failing I2C transfer fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum I2cFault {
    /// The chip does not acknowledge its address.
    Nack,
    /// The transfer times out (clock stretched too long, bus stuck).
    Timeout,
}

/// An I2C bus whose transfers fail in a [`FaultWindow`] (the failing transfer does not
/// reach the chip).
#[derive(Debug, Clone)]
pub struct FaultyI2c<I> {
    inner: I,
    clock: SimClock,
    window: std::rc::Rc<std::cell::RefCell<FaultWindow>>,
    kind: I2cFault,
}

impl<I> FaultyI2c<I> {
    /// `inner` failing as `kind` in `window` of `clock` (clones share the window).
    pub fn new(inner: I, clock: SimClock, window: FaultWindow, kind: I2cFault) -> Self {
        Self {
            inner,
            clock,
            window: std::rc::Rc::new(std::cell::RefCell::new(window)),
            kind,
        }
    }
}

impl<I> embedded_hal::i2c::ErrorType for FaultyI2c<I> {
    type Error = I2cErrorKind;
}

impl<I: embedded_hal::i2c::I2c<Error = I2cErrorKind>> embedded_hal::i2c::I2c for FaultyI2c<I> {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), I2cErrorKind> {
        if self.window.borrow_mut().fails(self.clock.now()) {
            return Err(match self.kind {
                I2cFault::Nack => I2cErrorKind::NoAcknowledge(NoAcknowledgeSource::Address),
                I2cFault::Timeout => I2cErrorKind::Other,
            });
        }
        self.inner.transaction(address, operations)
    }
}

/// A disturbance of the coils' signal in a time window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Disturbance {
    /// Broadband EMI: white noise of `sigma_v` volts at the ADC on every coil.
    Emi {
        /// Start, s.
        from_s: f64,
        /// End, s.
        to_s: f64,
        /// Noise σ at the ADC input, V.
        sigma_v: f64,
    },
    /// The signal amplified by `gain` (a transmitter centimetres away, a gain fault):
    /// the ADC clips at its full scale.
    Overdrive {
        /// Start, s.
        from_s: f64,
        /// End, s.
        to_s: f64,
        /// Amplification.
        gain: f64,
    },
}

/// An analog input with [`Disturbance`]s.
#[derive(Debug, Clone)]
pub struct Disturbed<A> {
    inner: A,
    disturbances: Vec<Disturbance>,
    rng: ChaCha8Rng,
}

impl<A> Disturbed<A> {
    /// `inner` with `disturbances`, the noise drawn from `seed`.
    pub fn new(inner: A, disturbances: Vec<Disturbance>, seed: u64) -> Self {
        Self {
            inner,
            disturbances,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
}

impl<A: AnalogInput> AnalogInput for Disturbed<A> {
    fn volts(&mut self, t: f64) -> [f64; 4] {
        let mut v = self.inner.volts(t);
        for d in &self.disturbances {
            match *d {
                Disturbance::Emi {
                    from_s,
                    to_s,
                    sigma_v,
                } if t >= from_s && t < to_s => {
                    for x in v.iter_mut().take(3) {
                        let n: f64 = rand_distr::Distribution::sample(
                            &rand_distr::StandardNormal,
                            &mut self.rng,
                        );
                        *x += sigma_v * n;
                    }
                }
                Disturbance::Overdrive { from_s, to_s, gain } if t >= from_s && t < to_s => {
                    v.iter_mut().take(3).for_each(|x| *x *= gain);
                }
                _ => {}
            }
        }
        v
    }
}

/// Read errors of the ADC driver by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AdcErrors {
    /// `Error::Comm` (the SPI bus failed).
    pub comm: u32,
    /// `Error::Crc` (a corrupted frame).
    pub crc: u32,
    /// Any other error.
    pub other: u32,
}

/// What kind of pulse the front end reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PulseKind {
    /// A field vector (given to the estimator).
    Field,
    /// Withheld: overlapping transmitters.
    Overlap,
    /// Withheld: clipped samples in the pulse.
    Saturated,
    /// Withheld: cut short.
    Truncated,
}

/// One pulse the front end reported during an [`adc_window`].
#[derive(Debug, Clone)]
pub struct WindowPulse {
    /// Sample count at the pulse's end (the time base), s of world time.
    pub t: f64,
    /// What the front end reported.
    pub kind: PulseKind,
    /// The application's answer (the display on a pulse).
    pub result: Result<Option<DisplayModel>, AppError>,
}

/// What an [`adc_window`] saw.
#[derive(Debug, Clone, Default)]
pub struct AdcWindow {
    /// The pulses, in order.
    pub pulses: Vec<WindowPulse>,
    /// Frames read.
    pub samples: u64,
    /// Driver errors by kind.
    pub errors: AdcErrors,
    /// Samples flagged clipped (saturated frames and unreadable ones).
    pub clipped: u64,
}

/// Runs the world's antenna signal `input` through the emulated ADS131M04 on a
/// [`FaultySpi`] (`spi_window`, `spi_fault`), the firmware's driver, front end (holding
/// the calibration `cal`: the unit's, not its chain's exact values) and `rx`
/// ([`Receiver::on_adc_sample`]) from `from_s` to `to_s` of world time.
pub fn adc_window<A: AnalogInput>(
    input: A,
    cal: &Calibration,
    (from_s, to_s): (f64, f64),
    (spi_window, spi_fault): (FaultWindow, SpiFault),
    rx: &mut Receiver,
) -> anyhow::Result<AdcWindow> {
    let clock = SimClock::new();
    clock.set(from_s);
    let adc_cfg = Config::default();
    let fs = f64::from(adc_cfg.data_rate_hz(F_CLKIN_HZ as f32));
    let (spi, drdy) = ads131m04(input, clock.clone());
    let spi = FaultySpi::new(spi, clock.clone(), spi_window, spi_fault);
    let mut adc = Ads131m04::new(spi, drdy);
    adc.reset(&mut NoDelay)
        .map_err(|e| anyhow::anyhow!("ADC reset: {e:?}"))?;
    adc.configure(&adc_cfg)
        .map_err(|e| anyhow::anyhow!("ADC configure: {e:?}"))?;
    adc.set_drdy_poll_limit(1);
    let mut frontend = Frontend::new(FrontendConfig {
        sample_rate_hz: fs as f32,
        calibration: *cal,
        ..FrontendConfig::default()
    })
    .map_err(|e| anyhow::anyhow!("front end: {e:?}"))?;
    rx.set_adc_epoch(stamp(from_s));
    let mut out = AdcWindow::default();
    let ticks = ((to_s - from_s) * 100.0).floor() as u64;
    for k in 0..=ticks {
        clock.set(from_s + k as f64 / 100.0);
        loop {
            let (volts, clipped) = match adc.read_frame_when_ready() {
                Ok(frame) => {
                    let v = adc.to_volts(&frame);
                    ([v[0], v[1], v[2]], frame.coils_saturated())
                }
                Err(AdcError::Timeout) => break,
                // The board's policy: keep the time base, flag the sample.
                Err(e) => {
                    match e {
                        AdcError::Comm(_) => out.errors.comm += 1,
                        AdcError::Crc => out.errors.crc += 1,
                        _ => out.errors.other += 1,
                    }
                    ([0.0; 3], true)
                }
            };
            out.samples += 1;
            out.clipped += u64::from(clipped);
            let before = frontend.stats();
            let result = rx.on_adc_sample(&mut frontend, volts, clipped);
            let after = frontend.stats();
            if after.pulses != before.pulses {
                let kind = if after.saturated != before.saturated {
                    PulseKind::Saturated
                } else if after.overlaps != before.overlaps {
                    PulseKind::Overlap
                } else if after.truncated != before.truncated {
                    PulseKind::Truncated
                } else {
                    PulseKind::Field
                };
                out.pulses.push(WindowPulse {
                    t: from_s + out.samples as f64 / fs,
                    kind,
                    result,
                });
            }
        }
    }
    Ok(out)
}

/// The antenna signal of `world` behind `chain` with the scenario's EMI level, as the
/// bus-level simulation builds it.
pub fn antenna<'w>(
    world: &'w World,
    chain: AnalogChain,
    sigma_bkg: f64,
    k_sen: f64,
    seed: u64,
) -> IfSignal<'w> {
    let fs = f64::from(Config::default().data_rate_hz(F_CLKIN_HZ as f32));
    IfSignal::new(world, chain, sigma_bkg, k_sen, fs, seed)
}
