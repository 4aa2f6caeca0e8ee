//! On-target check of the dipole model: evaluates the field, its Jacobian and the inverse
//! on a fixed set of inputs on the Cortex-M4F (emulated by `qemu-system-arm -M
//! netduinoplus2`) and prints inputs and results over semihosting, one case per line, so
//! the host can compare them with its f64 evaluation (`tests/tests/qemu.rs`).
//!
//! Output lines: `case r=<x,y,z> m=<x,y,z> h=<x,y,z> dhdr00=<v> minv=<x,y,z>`, then
//! `done <n>`. Exit status 0 when every evaluation succeeded.
#![no_std]
#![no_main]

#[path = "support/exit.rs"]
mod exit;

use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use firmware::{Vec3, dipole};

/// Deterministic inputs spanning the search: ranges from 0.2 to 150 m, moments across
/// the standard's power range, every octant.
fn case(i: u32) -> (Vec3, Vec3) {
    // A small LCG so the inputs are reproducible without a RNG crate on the target.
    let mut s = i.wrapping_mul(2_654_435_761).wrapping_add(12345);
    let mut next = || {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (s >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
    };
    let dir = Vec3::new(next(), next(), next() + 0.01);
    let range = 0.2 * libm::powf(750.0, (i as f32) / 63.0);
    let mdir = Vec3::new(next(), next(), next() + 0.01);
    let m_mag = 3e-3 + 2.7e-2 * (0.5 + 0.5 * next());
    (dir.normalize() * range, mdir.normalize() * m_mag)
}

#[entry]
fn main() -> ! {
    let mut ok = true;
    let n = 64;
    for i in 0..n {
        let (r, m) = case(i);
        match dipole::field_with_jacobians(&r, &m) {
            Ok(fj) => {
                let minv = dipole::moment_from_field(&r, &fj.h).unwrap_or(Vec3::zeros());
                hprintln!(
                    "case r={:e},{:e},{:e} m={:e},{:e},{:e} h={:e},{:e},{:e} dhdr00={:e} minv={:e},{:e},{:e}",
                    r.x,
                    r.y,
                    r.z,
                    m.x,
                    m.y,
                    m.z,
                    fj.h.x,
                    fj.h.y,
                    fj.h.z,
                    fj.d_r[(0, 0)],
                    minv.x,
                    minv.y,
                    minv.z
                );
            }
            Err(_) => {
                hprintln!("error case {}", i);
                ok = false;
            }
        }
    }
    hprintln!("done {}", n);
    exit::exit(ok)
}
