//! Coherent detection of weak pulses: the three coils' block phasors integrated
//! coherently over a window nearly as long as the shortest pulse, at every carrier offset
//! the standard allows, against a threshold set from the false-alarm requirement.
//!
//! The optimum detector of one pulse of unknown complex amplitude per coil, unknown
//! carrier and unknown time in white noise is the coherent energy of the coils over the
//! pulse, `z = Σ_i |Σ_b p_{b,i} e^{−j2πνb}|² / (W·F/6)` (`W` blocks, floor `F` per block
//! over the three coils): χ² with 6 degrees of freedom on noise, non-central with
//! `λ = W·|H|²/(F/6)` on a pulse (Kay, *Fundamentals of Statistical Signal Processing II*,
//! §7.6, the GLRT for a sinusoid of unknown amplitude, phase and frequency). The window's
//! 64-point FFT (32 blocks zero-padded: bins half a resolution cell apart) gives `z` at
//! every offset; it is evaluated every [`FrontendConfig::coherent_hop`] blocks. The
//! 16-block energy detector (`k_on`) needs ≈ 15 σ_bkg for 90 % detection of a 70 ms
//! pulse; this one needs ≈ 8 σ_bkg, against the limit's 6.6 σ_bkg (`sensing.md`,
//! `docs/decisions/coherent-detection.md`).
//!
//! Threshold: every evaluated (bin, hop) test is one chance of a false alarm; the
//! per-test probability is the required rate × hop duration / bins (a union bound, so
//! the rate is met however correlated the tests are), and `η` solves
//! `P(χ²₆ > η) = e^{−η/2}(1 + η/2 + η²/8)` for it.
//!
//! Edges of a pulse found this way: its energy stands too little above the floor for the
//! energy edges, so each block is projected onto the pulse's own carrier and coil
//! amplitudes (from the best window): `y_b = Re(Σ_i x̂_i* p_{b,i} e^{−j2πνb})`, the
//! pulse's amplitude plus noise of σ² = F/6 inside the pulse, zero-mean noise outside;
//! the run maximising `Σ (y_b − A/2)` (A the pulse's amplitude, refined once) is the
//! maximum-likelihood rectangular pulse.
use super::analysis::{BlockView, carrier, dtft, power};
use super::complex::C32;
use super::fft::fft_in_place;
use super::{FrontendConfig, MAX_FFT};

/// `P(χ²₆ > t)`.
fn chi2_6_sf(t: f32) -> f32 {
    let x = 0.5 * t;
    libm::expf(-x) * (1.0 + x + 0.5 * x * x)
}

/// FFT length of a coherent window of `w` blocks (zero-padded to twice its length).
pub(crate) fn fft_len(w: usize) -> usize {
    2 * w
}

/// Bins `k` (of [`fft_len`]) searched: `|k| ≤ k_max` with `k_max/M ≤` the largest offset
/// in cycles per block, plus one bin so the band's edge is covered.
pub(crate) fn k_max(cfg: &FrontendConfig) -> usize {
    let m = fft_len(cfg.coherent_blocks) as f32;
    libm::ceilf(cfg.max_offset_hz * cfg.block_s() * m) as usize
}

/// The coherent threshold `η` for the configuration's false-alarm rate.
pub(crate) fn threshold(cfg: &FrontendConfig) -> f32 {
    let bins = (2 * k_max(cfg) + 1) as f32;
    let hop_s = cfg.coherent_hop as f32 * cfg.block_s();
    let p = (cfg.false_alarm_rate_hz * hop_s / bins).clamp(1e-30, 0.5);
    let (mut lo, mut hi) = (0.0f32, 400.0f32);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if chi2_6_sf(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// `z` of the window of `w` blocks ending with ring block index `last` (inclusive) and the
/// bin it peaks at, at floor `floor`. Uses `fft` and `pow` as scratch.
pub(crate) fn statistic(
    ring: &[[C32; 3]],
    last: usize,
    cfg: &FrontendConfig,
    floor: f32,
    fft: &mut [C32; MAX_FFT],
    pow: &mut [f32; MAX_FFT],
) -> (f32, i32) {
    let w = cfg.coherent_blocks;
    let m = fft_len(w);
    let n = ring.len().max(1);
    let (Some(buf), Some(pw)) = (fft.get_mut(..m), pow.get_mut(..m)) else {
        return (0.0, 0);
    };
    pw.fill(0.0);
    for axis in 0..3 {
        for (j, z) in buf.iter_mut().enumerate() {
            *z = if j < w {
                let i = (last + n + 1 + j - w) % n;
                ring.get(i)
                    .and_then(|p| p.get(axis))
                    .copied()
                    .unwrap_or(C32::ZERO)
            } else {
                C32::ZERO
            };
        }
        fft_in_place(buf);
        for (p, z) in pw.iter_mut().zip(buf.iter()) {
            *p += z.norm_sqr();
        }
    }
    let kmax = k_max(cfg).min(m / 2 - 1);
    let mut best = (0.0f32, 0i32);
    for k in 0..=kmax {
        for (kk, idx) in [(k as i32, k), (-(k as i32), (m - k) % m)] {
            let p = pw.get(idx).copied().unwrap_or(0.0);
            if p > best.0 {
                best = (p, kk);
            }
        }
    }
    let z = 6.0 * best.0 / (w as f32 * floor.max(f32::MIN_POSITIVE));
    (z.min(f32::MAX), best.1)
}

/// Edges (`start`, `end` exclusive) of a weak pulse in `view` whose best coherent window
/// of `w` blocks ends at view index `best_end` (inclusive); see the module docs.
pub(crate) fn edges(
    view: &BlockView<'_>,
    best_end: usize,
    cfg: &FrontendConfig,
    fft: &mut [C32; MAX_FFT],
    pow: &mut [f32; MAX_FFT],
) -> Option<(usize, usize)> {
    let w = cfg.coherent_blocks.min(best_end + 1);
    let s0 = best_end + 1 - w;
    let max_nu = cfg.max_offset_hz * cfg.block_s();
    let nu = carrier(view, s0, w, max_nu, fft, pow);
    let x = dtft(view, s0, w, nu);
    let norm = libm::sqrtf(power(&x));
    if !norm.is_finite() || norm <= 0.0 {
        return None;
    }
    let u = x.map(|z| z.conj().scale(1.0 / norm));
    // y_b with the same phase reference as the window's DTFT (e^{−j2πν(b − s0)}).
    let step = C32::cis(-2.0 * core::f32::consts::PI * nu);
    let start_rot = C32::cis(2.0 * core::f32::consts::PI * nu * s0 as f32);
    let y = |b: usize, rot: C32| -> f32 {
        let p = view.block(b);
        let mut acc = C32::ZERO;
        for (ui, pi) in u.iter().zip(p.iter()) {
            acc += *ui * *pi;
        }
        (acc * rot).re
    };
    let mut level = norm / w as f32;
    let mut run = None;
    for _ in 0..2 {
        if level.is_nan() || level <= 0.0 {
            return None;
        }
        let tau = 0.5 * level;
        let (mut best, mut best_run) = (0.0f32, None);
        let (mut cur, mut cur_start) = (0.0f32, 0usize);
        let mut rot = start_rot;
        let mut sum_y = [0.0f32; 2];
        for b in 0..view.len {
            if cur <= 0.0 {
                cur = 0.0;
                cur_start = b;
            }
            let yb = y(b, rot);
            rot = rot * step;
            cur += yb - tau;
            if cur > best {
                best = cur;
                best_run = Some((cur_start, b + 1));
                sum_y = [cur, (b + 1 - cur_start) as f32];
            }
        }
        let (s, e) = best_run?;
        // Mean of y over the run: Σ(y − τ)/len + τ.
        level = sum_y[0] / sum_y[1].max(1.0) + tau;
        run = Some((s, e));
    }
    run
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threshold_meets_the_false_alarm_rate_by_the_union_bound() {
        let cfg = FrontendConfig::default();
        // ±100 Hz at 2 ms blocks in 64-point bins: |k| ≤ 13.
        assert_eq!(k_max(&cfg), 13);
        let eta = threshold(&cfg);
        let tests_per_s = 27.0 / (cfg.coherent_hop as f32 * cfg.block_s());
        let rate = chi2_6_sf(eta) * tests_per_s;
        assert!(
            (rate / cfg.false_alarm_rate_hz - 1.0).abs() < 1e-3,
            "{eta} {rate}"
        );
        assert!((41.0..42.0).contains(&eta), "{eta}");
        // A looser requirement gives a lower threshold.
        let mut loose = cfg;
        loose.false_alarm_rate_hz = 1.0;
        assert!(threshold(&loose) < eta - 10.0);
    }
}
