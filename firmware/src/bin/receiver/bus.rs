//! The shared I2C1 bus (IMU, magnetometer, display): I2C1 taken apart for a bus clear and
//! rebuilt ([`firmware::board::i2c_bus`] guards it), behind the priority-ceiling lock
//! [`with_bus`], and the drivers' handle on it ([`BusHandle`]).

use super::{I2C_HZ, SYSCLK_HZ};
use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use embedded_hal::delay::DelayNs;
use firmware::board::i2c_bus::{self, ClearError, Cleared, Guarded, Recoverable};
use firmware::board::schedule::PRIO_IMU;
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

/// I2C1 that can be taken apart for a bus clear and rebuilt.
pub struct BoardI2c {
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

/// Puts I2C1 in place as the shared bus; it owns the clock controller from here (it
/// rebuilds I2C1 after a clear). Called once, at boot, before any task runs.
pub fn install(i2c: I2c<pac::I2C1>, rcc: Rcc) {
    // SAFETY: the only write of BUS, before BUS_READY lets anything use it; no task runs
    // during init.
    unsafe {
        (*BUS.0.get()).write(Guarded::new(BoardI2c {
            i2c: Some(i2c),
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
