//! In-place radix-2 complex FFT, used once per pulse on at most
//! [`MAX_FFT`](super::MAX_FFT) block phasors to find the carrier offset.

use super::complex::C32;
use core::f32::consts::PI;

/// Forward FFT (`X_k = Σ x_n e^{−j2πkn/N}`) of `buf`, whose length must be a power of
/// two (returns `false` and leaves `buf` unchanged otherwise).
pub(crate) fn fft_in_place(buf: &mut [C32]) -> bool {
    let n = buf.len();
    if n < 2 || !n.is_power_of_two() {
        return false;
    }
    let bits = n.trailing_zeros();
    // Bit-reversal permutation; j < n by construction.
    for i in 0..n {
        let j = (i.reverse_bits() >> (usize::BITS - bits)) & (n - 1);
        if i < j {
            buf.swap(i, j);
        }
    }
    let mut m = 2;
    while m <= n {
        let half = m / 2;
        // Twiddles by recurrence from one libm call per stage: ≤ 256 steps keep the
        // accumulated rounding near 1e-5, far below the noise of any pulse.
        let wm = C32::cis(-2.0 * PI / m as f32);
        for chunk in buf.chunks_exact_mut(m) {
            let (lo, hi) = chunk.split_at_mut(half);
            let mut w = C32::new(1.0, 0.0);
            for (u, t) in lo.iter_mut().zip(hi.iter_mut()) {
                let tw = w * *t;
                let a = *u;
                *u = a + tw;
                *t = a - tw;
                w = w * wm;
            }
        }
        m *= 2;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_direct_dft() {
        let n = 64;
        let x: Vec<C32> = (0..n)
            .map(|i| {
                C32::new(
                    libm::sinf(i as f32 * 0.37),
                    libm::cosf(i as f32 * 1.3) + 0.1,
                )
            })
            .collect();
        let mut y = x.clone();
        assert!(fft_in_place(&mut y));
        for (k, yk) in y.iter().enumerate() {
            let mut d = C32::ZERO;
            for (i, xi) in x.iter().enumerate() {
                d += *xi * C32::cis(-2.0 * PI * (k * i) as f32 / n as f32);
            }
            assert!((d - *yk).abs() < 1e-3, "bin {k}: {d:?} vs {yk:?}");
        }
        assert!(!fft_in_place(&mut y[..48]));
    }
}
