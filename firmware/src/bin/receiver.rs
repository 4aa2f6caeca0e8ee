//! Board binary for the reference receiver (STM32F405RG, e.g. Adafruit Feather STM32F405
//! Express). Flash and run with `cargo board-run` (probe-rs); logs arrive over RTT (defmt).
//!
//! This first version boots the core, enables the FPU (done by cortex-m-rt for the
//! `eabihf` target), checks the dipole model against a closed-form value on the chip and
//! idles. The sensing front end and the application loop are added by later issues.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use defmt_rtt as _;
use firmware::{Vec3, dipole};
use panic_probe as _;

#[entry]
fn main() -> ! {
    defmt::info!("arva receiver: boot");
    // On the moment's axis the field is 2m / (4π r³): a self-check of the FPU path.
    let (range, moment) = (10.0f32, 0.02f32);
    let expected = 2.0 * moment / (4.0 * core::f32::consts::PI * range * range * range);
    match dipole::field(&Vec3::new(0.0, 0.0, range), &Vec3::new(0.0, 0.0, moment)) {
        Ok(h) if (h.z - expected).abs() <= 1e-6 * expected => {
            defmt::info!("dipole self-check ok: {=f32} A/m", h.z)
        }
        Ok(h) => defmt::error!("dipole self-check off: {=f32} vs {=f32}", h.z, expected),
        Err(_) => defmt::error!("dipole self-check refused its input"),
    }
    loop {
        cortex_m::asm::wfi();
    }
}
