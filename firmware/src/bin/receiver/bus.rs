//! The shared I2C1 bus (IMU, magnetometer, display): I2C1 driven by the bounded master
//! ([`firmware::board::i2c_master`]: every flag wait ends after 1 ms), taken apart for a
//! bus clear and rebuilt ([`firmware::board::i2c_bus`] guards it), behind the
//! priority-ceiling lock [`with_bus`], and the drivers' handle on it ([`BusHandle`]).

use super::{I2C_HZ, SYSCLK_HZ};
use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::DWT;
use embedded_hal::delay::DelayNs;
use firmware::board::i2c_bus::{self, ClearError, Cleared, Guarded, Recoverable};
use firmware::board::i2c_master::{self, BOARD_BUDGET_CYCLES, BoundedI2c, Regs};
use firmware::board::schedule::PRIO_IMU;
use stm32f4xx_hal::gpio::alt::I2cCommon;
use stm32f4xx_hal::gpio::{OpenDrain, Output, PB6, PB7};
use stm32f4xx_hal::i2c::I2c;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Rcc;

/// Busy-wait delay from the core clock, for the bus clear (SysTick is the init delay's).
pub struct CycleDelay;

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
pub fn clear_pins(
    scl: &mut PB6<Output<OpenDrain>>,
    sda: &mut PB7<Output<OpenDrain>>,
) -> Result<Cleared, ClearError> {
    i2c_bus::clear_bus(scl, sda, &mut CycleDelay)
}

/// I2C1's registers and the core's cycle counter, for the bounded master.
pub struct I2c1Regs(pac::I2C1);

impl Regs for I2c1Regs {
    fn cr1(&mut self) -> u16 {
        self.0.cr1().read().bits()
    }
    fn set_cr1(&mut self, value: u16) {
        // SAFETY: every CR1 bit pattern is a valid write (RM0090 §27.6.1).
        self.0.cr1().write(|w| unsafe { w.bits(value) });
    }
    fn sr1(&mut self) -> u16 {
        self.0.sr1().read().bits()
    }
    fn set_sr1(&mut self, value: u16) {
        // SAFETY: SR1's writable bits are clear-by-writing-0 error flags.
        self.0.sr1().write(|w| unsafe { w.bits(value) });
    }
    fn sr2(&mut self) -> u16 {
        self.0.sr2().read().bits()
    }
    fn dr(&mut self) -> u8 {
        // DR holds one byte in its low bits.
        self.0.dr().read().bits() as u8
    }
    fn set_dr(&mut self, value: u8) {
        // SAFETY: any byte is a valid DR write.
        self.0.dr().write(|w| unsafe { w.bits(u16::from(value)) });
    }
    fn now(&mut self) -> u32 {
        DWT::cycle_count()
    }
    fn critical<T>(&mut self, f: impl FnOnce(&mut Self) -> T) -> T {
        // A few register accesses (< 1 µs): the DRDY interrupt waits that long at most.
        cortex_m::interrupt::free(|_| f(self))
    }
}

/// I2C1's pins as the peripheral holds them (alternate function).
type I2cPins = (<pac::I2C1 as I2cCommon>::Scl, <pac::I2C1 as I2cCommon>::Sda);

/// Configures I2C1 with the HAL (clock, reset, CCR, TRISE, enable) and hands its registers
/// to the bounded master.
fn bounded(i2c: I2c<pac::I2C1>) -> (BoundedI2c<I2c1Regs>, I2cPins) {
    let (per, pins) = i2c.release();
    (BoundedI2c::new(I2c1Regs(per), BOARD_BUDGET_CYCLES), pins)
}

/// I2C1 that can be taken apart for a bus clear and rebuilt.
pub struct BoardI2c {
    /// `None` only if a clear could not get the pins back (then every transfer fails).
    i2c: Option<(BoundedI2c<I2c1Regs>, I2cPins)>,
    rcc: Rcc,
}

impl embedded_hal::i2c::ErrorType for BoardI2c {
    type Error = i2c_master::Error;
}

impl embedded_hal::i2c::I2c for BoardI2c {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), Self::Error> {
        match self.i2c.as_mut() {
            Some((i2c, _)) => embedded_hal::i2c::I2c::transaction(i2c, address, operations),
            None => Err(i2c_master::Error::Unavailable),
        }
    }
}

impl Recoverable for BoardI2c {
    fn lines_idle(&mut self) -> bool {
        self.i2c.is_some() && i2c_lines_high()
    }

    fn clear_and_reinit(&mut self) -> Result<Cleared, ClearError> {
        let Some((i2c, (scl, sda))) = self.i2c.take() else {
            return Err(ClearError::Pin);
        };
        let per = i2c.release().0;
        let (Ok(mut scl), Ok(mut sda)) = (
            PB6::<Output<OpenDrain>>::try_from(scl),
            PB7::<Output<OpenDrain>>::try_from(sda),
        ) else {
            return Err(ClearError::Pin);
        };
        let r = clear_pins(&mut scl, &mut sda);
        // The HAL's constructor resets I2C1 through the RCC: whatever state a hung
        // transfer left in the peripheral goes with it.
        self.i2c = Some(bounded(I2c::new(
            per,
            (scl, sda),
            I2C_HZ.Hz(),
            &mut self.rcc,
        )));
        r
    }

    fn needs_clear(&self, error: &i2c_master::Error) -> bool {
        BoundedI2c::<I2c1Regs>::needs_clear(error)
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

/// Puts I2C1 in place as the shared bus; it owns the clock controller from here (it
/// rebuilds I2C1 after a clear). Called once, at boot, before any task runs.
pub fn install(i2c: I2c<pac::I2C1>, rcc: Rcc) {
    // SAFETY: the only write of BUS, before BUS_READY lets anything use it; no task runs
    // during init.
    unsafe {
        (*BUS.0.get()).write(Guarded::new(BoardI2c {
            i2c: Some(bounded(i2c)),
            rcc,
        }))
    };
    BUS_READY.store(true, Ordering::Release);
}

/// BASEPRI value of the bus's ceiling (the IMU tick's priority), as RTIC computes it.
const BUS_CEILING: u8 = ((1 << pac::NVIC_PRIO_BITS) - PRIO_IMU) << (8 - pac::NVIC_PRIO_BITS);

/// Runs `f` on the bus with the tasks that use it masked (the priority-ceiling lock
/// RTIC uses for its resources, by hand: the drivers own a handle, not a borrow). The
/// DRDY interrupt (above the ceiling) still runs. `None` before the bus is in place.
pub fn with_bus<R>(f: impl FnOnce(&mut Guarded<BoardI2c>) -> R) -> Option<R> {
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
    type Error = i2c_bus::GuardError<i2c_master::Error>;
}

impl embedded_hal::i2c::I2c for BusHandle {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), Self::Error> {
        with_bus(|b| embedded_hal::i2c::I2c::transaction(b, address, operations)).unwrap_or(Err(
            i2c_bus::GuardError::Bus(i2c_master::Error::Unavailable),
        ))
    }
}
