//! How the QEMU binaries end: a semihosting exit status (QEMU's own exit code) and a
//! panic handler that reports over semihosting and exits with failure.
use cortex_m_semihosting::{debug, hprintln};

/// Ends the QEMU run with success or failure.
pub fn exit(success: bool) -> ! {
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    // Only reached on a real board (no debugger to exit to).
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    exit(false)
}
