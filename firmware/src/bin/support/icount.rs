//! Deterministic instruction counting on the emulated STM32F405.
//!
//! QEMU's DWT cycle counter reads 0, but with `-icount shift=0` every guest instruction
//! advances virtual time by exactly 1 ns, and SysTick on the core clock (168 MHz on
//! `netduinoplus2`) then ticks 0.168 times per instruction, identically on every run.
//! These are *instructions*, not cycles: on a real M4 VDIV/VSQRT take 14 cycles and
//! flash wait states add more. Resolution: one tick ≈ 6 instructions.

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::{SYST, syst::SystClkSource};
use cortex_m_rt::exception;

/// SysTick reload value: the full 24-bit range.
const RELOAD: u32 = 0x00FF_FFFF;
/// Core clock of the emulated STM32F405 (Hz).
const CORE_HZ: u64 = 168_000_000;

static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// A free-running instruction counter built on SysTick.
pub struct InstructionCounter {
    syst: SYST,
}

impl InstructionCounter {
    /// Starts SysTick on the core clock with its wrap interrupt enabled.
    pub fn start(mut syst: SYST) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(RELOAD);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        Self { syst }
    }

    /// The measuring binaries' start-up: paints the stack (for its high-water mark), takes
    /// the core peripherals (exits with failure if they are gone) and starts counting.
    pub fn start_on_painted_stack() -> Self {
        crate::stack::paint();
        let Some(peripherals) = cortex_m::Peripherals::take() else {
            crate::exit::exit(false)
        };
        Self::start(peripherals.SYST)
    }

    /// SysTick ticks since [`InstructionCounter::start`].
    pub fn ticks(&mut self) -> u64 {
        loop {
            let before = WRAPS.load(Ordering::Acquire);
            let current = SYST::get_current();
            if WRAPS.load(Ordering::Acquire) == before && !self.syst.has_wrapped() {
                return u64::from(before) * u64::from(RELOAD + 1) + u64::from(RELOAD - current);
            }
            // A wrap happened meanwhile: let its interrupt run, then read again.
            cortex_m::asm::nop();
        }
    }

    /// Instructions executed since [`InstructionCounter::start`] (ticks × 1 ns / period).
    pub fn instructions(&mut self) -> u64 {
        self.ticks() * 1_000_000_000 / CORE_HZ
    }

    /// Instructions spent in `f` (including ≈ 40 instructions of measurement overhead).
    pub fn measure<T>(&mut self, f: impl FnOnce() -> T) -> (T, u64) {
        let start = self.instructions();
        let out = f();
        let end = self.instructions();
        (out, end.saturating_sub(start))
    }
}
