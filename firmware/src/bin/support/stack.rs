//! Stack high-water mark by painting: fill the unused stack with a pattern at start-up,
//! find the deepest overwritten word at the end.
//!
//! With flip-link the stack sits at the bottom of RAM, growing down from `_stack_start`
//! towards `0x2000_0000`, so an overflow faults instead of corrupting `.data`/`.bss`.
#![allow(unsafe_code)] // Reading and writing raw stack memory below the live stack.

/// Bottom of the RAM region (the lowest address the stack may reach).
const RAM_ORIGIN: usize = 0x2000_0000;
/// Pattern written into the unused stack.
const PAINT: u32 = 0xC0DE_CAFE;

unsafe extern "C" {
    static _stack_start: u32;
}

fn stack_top() -> usize {
    // Only the symbol's address is taken (no read): it is defined by the linker script.
    core::ptr::addr_of!(_stack_start) as usize
}

/// Paints the stack below the current stack pointer (keeping a 256-byte margin).
pub fn paint() {
    let sp = cortex_m::register::msp::read() as usize - 256;
    let mut p = RAM_ORIGIN;
    while p < sp {
        // SAFETY: [RAM_ORIGIN, sp) is unused stack memory below the live frames.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Bytes of stack used at the deepest point since [`paint`].
pub fn high_water() -> usize {
    let mut p = RAM_ORIGIN;
    // SAFETY: reads of RAM inside the stack region.
    while p < stack_top() && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    stack_top() - p
}

/// Total bytes of the stack region.
pub fn size() -> usize {
    stack_top() - RAM_ORIGIN
}
