//! On-target instruction budget of the hot paths, run under
//! `qemu-system-arm -M netduinoplus2 -icount shift=0` (see `support/icount.rs`).
//!
//! Prints one line per measurement, `budget <name> <instructions>`, then `done`.
#![no_std]
#![no_main]

#[path = "support/icount.rs"]
mod icount;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use firmware::{Vec3, dipole};
use icount::InstructionCounter;

#[entry]
fn main() -> ! {
    let Some(peripherals) = cortex_m::Peripherals::take() else {
        debug::exit(debug::EXIT_FAILURE);
        loop {}
    };
    let mut counter = InstructionCounter::start(peripherals.SYST);
    let mut ok = true;

    // Calibration: an empty measurement shows the counter's own overhead.
    let ((), overhead) = counter.measure(|| ());
    hprintln!("budget overhead {}", overhead);
    let ((), nops) = counter.measure(|| {
        for _ in 0..core::hint::black_box(100_000u32) {
            cortex_m::asm::nop();
        }
    });
    hprintln!("budget nop_loop_100k {}", nops);

    let r = core::hint::black_box(Vec3::new(12.0, -7.5, 2.25));
    let m = core::hint::black_box(Vec3::new(0.004, 0.011, -0.006));
    let (fj, n) = counter.measure(|| {
        let mut acc = 0.0f32;
        for i in 0..100 {
            let ri = r * (1.0 + i as f32 * 1e-3);
            if let Ok(fj) = dipole::field_with_jacobians(&ri, &m) {
                acc += fj.h.x + fj.d_r[(0, 0)];
            }
        }
        acc
    });
    ok &= fj.is_finite();
    hprintln!("budget dipole_field_with_jacobians {}", n / 100);

    hprintln!("done");
    debug::exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
