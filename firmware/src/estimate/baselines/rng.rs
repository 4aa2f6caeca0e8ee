//! The seeded `no_std` pseudo-random generator of the particle filters: Marsaglia's
//! xorshift128 from the `rand_xorshift` crate (16 bytes of state, no heap, identical
//! sequences on the host and the Cortex-M4F), with the two draws the filters need.

use rand_core::{Rng, SeedableRng};
use rand_xorshift::XorShiftRng;

/// A seeded generator of uniform and standard-normal `f32` draws.
#[derive(Debug, Clone, PartialEq)]
pub struct Prng {
    rng: XorShiftRng,
    /// The second normal of the last polar draw, not yet used.
    spare: Option<f32>,
}

/// 2⁻²⁴: the spacing of the 24-bit uniform grid (the `f32` mantissa).
const INV_2_24: f32 = 1.0 / 16_777_216.0;

impl Prng {
    /// A generator seeded from `seed` (same seed, same sequence).
    pub fn new(seed: u64) -> Self {
        Self {
            rng: XorShiftRng::seed_from_u64(seed),
            spare: None,
        }
    }

    /// Uniform in the open interval (0, 1): the top 24 bits, centred in their bin, so
    /// `ln u` is always finite.
    pub fn uniform(&mut self) -> f32 {
        ((self.rng.next_u32() >> 8) as f32 + 0.5) * INV_2_24
    }

    /// Uniform index in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        ((self.uniform() * n as f32) as usize).min(n.saturating_sub(1))
    }

    /// Standard normal draw: Marsaglia's polar method, two normals per accepted pair
    /// (acceptance π/4) and no trigonometry — the particle filters draw ~10 per particle
    /// per step, so this is a visible part of their cost on the target.
    pub fn gauss(&mut self) -> f32 {
        if let Some(g) = self.spare.take() {
            return g;
        }
        // P(8 rejections in a row) = (1 − π/4)⁸ ≈ 5e-6; then fall back to one
        // Box–Muller draw (still exact, just slower).
        for _ in 0..8 {
            let u = 2.0 * self.uniform() - 1.0;
            let v = 2.0 * self.uniform() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let f = libm::sqrtf(-2.0 * libm::logf(s) / s);
                self.spare = Some(v * f);
                return u * f;
            }
        }
        let (u1, u2) = (self.uniform(), self.uniform());
        libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(2.0 * core::f32::consts::PI * u2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeded_draws_repeat_and_have_the_right_moments() {
        let (mut a, mut b) = (Prng::new(7), Prng::new(7));
        let n = 20_000;
        let (mut s1, mut s2, mut u_min, mut u_max) = (0.0f64, 0.0f64, 1.0f32, 0.0f32);
        for _ in 0..n {
            let g = a.gauss();
            assert_eq!(g, b.gauss());
            s1 += f64::from(g);
            s2 += f64::from(g) * f64::from(g);
            let u = a.uniform();
            b.uniform();
            u_min = u_min.min(u);
            u_max = u_max.max(u);
        }
        let mean = s1 / f64::from(n);
        let var = s2 / f64::from(n) - mean * mean;
        // 5σ bounds of the sample mean and variance for n draws.
        assert!(mean.abs() < 5.0 / f64::from(n).sqrt(), "mean {mean}");
        assert!(
            (var - 1.0).abs() < 5.0 * (2.0 / f64::from(n)).sqrt(),
            "var {var}"
        );
        assert!(u_min > 0.0 && u_max < 1.0);
        assert_ne!(Prng::new(8).uniform(), Prng::new(7).uniform());
        assert_eq!(Prng::new(1).below(0), 0);
    }
}
