//! Per-pulse analysis of the buffered block phasors: edges, carrier offset, coherent
//! amplitude, common phase (relative signs) and the single-transmitter consistency tests.
//!
//! Model of one transmitter over the pulse's blocks `b = 0 … N−1`:
//! `p_b = G(ν) · a · e^{j(2πνb + φ)} + n_b`, with `a` the real field vector (A/m, after
//! calibration), `ν` the carrier offset in cycles per block, `φ` the unknown carrier
//! phase, `G(ν)` the block integrator's gain and `n_b` noise of energy `F` (the floor)
//! per block over the three coils.

use super::complex::C32;
use super::fft::fft_in_place;
use super::{FrontendConfig, MAX_FFT};
use crate::Vec3;
use core::f32::consts::PI;

/// Read-only view of a run of consecutive blocks in the ring buffer.
pub(crate) struct BlockView<'a> {
    pub blocks: &'a [[C32; 3]],
    pub energy: &'a [f32],
    pub saturated: &'a [bool],
    /// Ring index of the view's first block.
    pub first: usize,
    pub len: usize,
}

impl BlockView<'_> {
    fn idx(&self, i: usize) -> usize {
        (self.first + i) % self.blocks.len().max(1)
    }
    pub(crate) fn block(&self, i: usize) -> [C32; 3] {
        self.blocks
            .get(self.idx(i))
            .copied()
            .unwrap_or([C32::ZERO; 3])
    }
    fn energy(&self, i: usize) -> f32 {
        self.energy.get(self.idx(i)).copied().unwrap_or(0.0)
    }
    fn saturated(&self, i: usize) -> bool {
        self.saturated.get(self.idx(i)).copied().unwrap_or(false)
    }
}

/// The analysis of one pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Analysis {
    /// First block of the pulse, relative to the view.
    pub start: usize,
    /// Blocks in the pulse.
    pub len: usize,
    /// Carrier offset (Hz).
    pub offset_hz: f32,
    /// In-phase field vector (A/m), canonical sign.
    pub h: Vec3,
    /// See [`Pulse::amplitude`](super::Pulse::amplitude).
    pub amplitude: [C32; 3],
    /// Per-component noise standard deviation (A/m).
    pub sigma: f32,
    /// See [`Pulse::residual_fraction`](super::Pulse::residual_fraction).
    pub residual_fraction: f32,
    /// See [`Pulse::quadrature_fraction`](super::Pulse::quadrature_fraction).
    pub quadrature_fraction: f32,
    /// Whether the single-transmitter tests failed.
    pub overlap: bool,
    /// Whether any block of the pulse held a clipped sample.
    pub saturated: bool,
}

/// Largest mean energy of `w` consecutive blocks of the view.
fn peak_mean(view: &BlockView<'_>, w: usize) -> f32 {
    let n = view.len;
    let w = w.clamp(1, n.max(1));
    let mut sum = 0.0;
    let mut peak = 0.0f32;
    for i in 0..n {
        sum += view.energy(i);
        if i >= w {
            sum -= view.energy(i - w);
        }
        if i + 1 >= w {
            peak = peak.max(sum / w as f32);
        }
    }
    peak
}

/// Pulse edges within the view: the run of blocks maximising `Σ (e_b − τ)` with
/// `τ = F + P/2` halfway between the floor and the pulse level `P + F` (Kadane's
/// maximum subarray; for a rectangular pulse this puts each edge where a block is at
/// least half covered). `P` is first the peak `w`-block mean, then refined once.
pub(crate) fn edges(view: &BlockView<'_>, floor: f32, w: usize) -> Option<(usize, usize)> {
    let n = view.len;
    let mut level = peak_mean(view, w) - floor;
    let mut run = None;
    for _ in 0..2 {
        if level.is_nan() || level <= 0.0 {
            return None;
        }
        let tau = floor + 0.5 * level;
        let (mut best, mut best_run) = (0.0f32, None);
        let (mut cur, mut cur_start) = (0.0f32, 0usize);
        for i in 0..n {
            if cur <= 0.0 {
                cur = 0.0;
                cur_start = i;
            }
            cur += view.energy(i) - tau;
            if cur > best {
                best = cur;
                best_run = Some((cur_start, i + 1));
            }
        }
        let (s, e) = best_run?;
        let mean = (s..e).map(|i| view.energy(i)).sum::<f32>() / (e - s) as f32;
        level = mean - floor;
        run = Some((s, e));
    }
    run
}

/// `Σ_b p_b e^{−j2πνb}` over blocks `s .. s+n` of the view, per coil.
pub(crate) fn dtft(view: &BlockView<'_>, s: usize, n: usize, nu: f32) -> [C32; 3] {
    let step = C32::cis(-2.0 * PI * nu);
    let mut w = C32::new(1.0, 0.0);
    let mut acc = [C32::ZERO; 3];
    for i in 0..n {
        let p = view.block(s + i);
        for (a, x) in acc.iter_mut().zip(p.iter()) {
            *a += *x * w;
        }
        w = w * step;
    }
    acc
}

/// `Σ_b p_b e^{−j2πνb} (b − b̄)` over blocks `s .. s+n` per coil (b̄ the middle block): the
/// least-squares slope of each coil's envelope times `Σ (b − b̄)²`.
fn dtft_ramp(view: &BlockView<'_>, s: usize, n: usize, nu: f32) -> [C32; 3] {
    let step = C32::cis(-2.0 * PI * nu);
    let mid = 0.5 * (n as f32 - 1.0);
    let mut w = C32::new(1.0, 0.0);
    let mut acc = [C32::ZERO; 3];
    for i in 0..n {
        let p = view.block(s + i);
        let t = i as f32 - mid;
        for (a, x) in acc.iter_mut().zip(p.iter()) {
            *a += (*x * w).scale(t);
        }
        w = w * step;
    }
    acc
}

/// Energy of a pulse's blocks that a linear envelope change explains: the receiver moves
/// (≈ 0.1 m during a pulse, 15 % of |H| at 2 m range) and turns while a pulse lasts, so
/// the amplitudes drift; only what a straight ramp cannot explain counts as a second
/// transmitter. Ramps are centred, so this adds to the constant part's energy.
fn ramp_energy(view: &BlockView<'_>, s: usize, n: usize, nu: f32) -> f32 {
    let nf = n as f32;
    // Σ (b − b̄)² over n blocks.
    let spread = nf * (nf * nf - 1.0) / 12.0;
    if spread <= 0.0 {
        return 0.0;
    }
    power(&dtft_ramp(view, s, n, nu)) / spread
}

/// Share of a carrier's energy per block that leaks in as its image: mixing the real IF
/// with the digital local oscillator leaves a second component at `−(2·IF + offset)`,
/// which the block sum attenuates only to `|sin πν′| / (L |sin(πν′/L)|)` (ν′ = `nu_image`,
/// its frequency in cycles per block; `L` the block length) — 2.7 % in amplitude at a
/// 70 Hz offset with the 2 kHz IF at 8 kSPS. It turns against the carrier from block to
/// block, so it shows as residual energy; being deterministic it is taken out before the
/// overlap test. `main_gain` is the carrier's own block gain.
pub(super) fn image_share(nu_image: f32, block_len: f32, main_gain: f32) -> f32 {
    let den = block_len * libm::fabsf(libm::sinf(PI * nu_image / block_len));
    if den < 1e-6 {
        // The image falls on the carrier's own frequency: nothing separable.
        return 0.0;
    }
    let ratio = libm::fabsf(libm::sinf(PI * nu_image)) / den / main_gain.max(0.1);
    ratio * ratio
}

pub(crate) fn power(c: &[C32; 3]) -> f32 {
    c.iter().map(|z| z.norm_sqr()).sum()
}

/// Golden-section steps of the carrier search: the ±1-bin bracket shrinks to 0.618^16 ≈
/// 5e-4 of itself, so the carrier error costs < 1e-5 of a 100 ms pulse's coherent energy
/// and the residual test can see interferers down to ≈ 1 % of the amplitude.
const GOLDEN_STEPS: usize = 16;

/// Carrier offset (cycles per block) of blocks `s .. s+n`: peak of the three coils'
/// summed periodogram (zero-padded FFT, |offset| ≤ `max_nu`), refined by a parabola
/// through the peak bin and a golden-section search of the exact periodogram.
pub(crate) fn carrier(
    view: &BlockView<'_>,
    s: usize,
    n: usize,
    max_nu: f32,
    fft: &mut [C32; MAX_FFT],
    pow: &mut [f32; MAX_FFT],
) -> f32 {
    let m = (2 * n).next_power_of_two().clamp(64, MAX_FFT);
    let (Some(buf), Some(pw)) = (fft.get_mut(..m), pow.get_mut(..m)) else {
        return 0.0;
    };
    pw.fill(0.0);
    for axis in 0..3 {
        for (i, z) in buf.iter_mut().enumerate() {
            *z = if i < n {
                view.block(s + i).get(axis).copied().unwrap_or(C32::ZERO)
            } else {
                C32::ZERO
            };
        }
        fft_in_place(buf);
        for (p, z) in pw.iter_mut().zip(buf.iter()) {
            *p += z.norm_sqr();
        }
    }
    let nu_of = |k: usize| {
        if k < m / 2 {
            k as f32 / m as f32
        } else {
            (k as f32 - m as f32) / m as f32
        }
    };
    let mut best = (0usize, -1.0f32);
    for (k, p) in pw.iter().enumerate() {
        if libm::fabsf(nu_of(k)) <= max_nu && *p > best.1 {
            best = (k, *p);
        }
    }
    let k = best.0;
    let at = |j: usize| pw.get(j % m).copied().unwrap_or(0.0);
    let (y0, y1, y2) = (at(k + m - 1), at(k), at(k + 1));
    let den = y0 - 2.0 * y1 + y2;
    let delta = if den < 0.0 {
        (0.5 * (y0 - y2) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    let centre = nu_of(k) + delta / m as f32;
    // Golden-section search of the exact periodogram within ±1 bin.
    let g = 0.618_034f32;
    let (mut lo, mut hi) = (centre - 1.0 / m as f32, centre + 1.0 / m as f32);
    let f = |nu: f32| power(&dtft(view, s, n, nu));
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..GOLDEN_STEPS {
        if f1 < f2 {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        } else {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        }
    }
    (0.5 * (lo + hi)).clamp(-max_nu, max_nu)
}

/// How a pulse was found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pulse0 {
    /// The energy detector fired on it.
    pub energy: bool,
    /// View index of the last block of its best coherent window, if the coherent detector
    /// fired on it.
    pub anchor: Option<usize>,
}

/// Per-block signal-to-floor energy ratio below which the energy edges are not used when
/// a coherent window is known: at 2 the energy of a block stands 2 F above the floor
/// while noise scatters it by F/√3, so the half-level crossing is clear; below, the
/// edges come from the coherent projection (a 12–20 σ_bkg pulse lost ⅓ of its detections
/// to energy edges cut short).
const ENERGY_EDGES_MIN_SNR: f32 = 2.0;

/// Analyse the pulse in `view` against the noise floor `floor` (energy per block), found
/// as `how` says: a pulse found only by the coherent detector, or too weak for the
/// energy edges, takes its edges from the coherent projection around its best window
/// ([`super::coherent::edges`]). `None` when no pulse stands above the floor.
pub(crate) fn analyse(
    view: &BlockView<'_>,
    floor: f32,
    cfg: &FrontendConfig,
    how: Pulse0,
    fft: &mut [C32; MAX_FFT],
    pow: &mut [f32; MAX_FFT],
) -> Option<Analysis> {
    let floor = floor.max(f32::MIN_POSITIVE);
    let coherent = match how.anchor {
        Some(a) if !how.energy => Some(a),
        Some(a) if peak_mean(view, cfg.detect_blocks) < (1.0 + ENERGY_EDGES_MIN_SNR) * floor => {
            Some(a)
        }
        _ => None,
    };
    let (start, e) = match coherent {
        Some(best_end) => super::coherent::edges(view, best_end, cfg, fft, pow)?,
        None => edges(view, floor, cfg.detect_blocks)?,
    };
    let (s, n) = (start, e - start);
    let max_nu = cfg.max_offset_hz * cfg.block_s();
    // Carrier and amplitudes from the interior blocks only: an edge block is partly empty
    // (the pulse starts and stops between block boundaries) and would bias the amplitude
    // down by up to half a block's share (1.4 % on a 70 ms pulse) and pull the carrier.
    let (s, n) = if n > 8 { (s + 1, n - 2) } else { (s, n) };
    let nu = carrier(view, s, n, max_nu, fft, pow);
    let nf = n as f32;
    let raw = dtft(view, s, n, nu).map(|z| z.scale(1.0 / nf));
    // Block integrator gain at this offset: |Σ_{k<L} e^{j2πνk/L}| / L.
    let l = cfg.block_len as f32;
    let x = PI * nu / l;
    let gain = if libm::fabsf(x) < 1e-6 {
        1.0
    } else {
        libm::fabsf(libm::sinf(PI * nu) / (l * libm::sinf(x)))
    }
    .max(0.1);
    let c = raw.map(|z| z.scale(1.0 / gain));

    // Common phase of the coils: φ = ½ arg Σ c_i² maximises Σ Re(c_i e^{−jφ})², and is
    // blind to the overall sign, exactly the ambiguity of the measurement.
    let sq = c.iter().fold(C32::ZERO, |acc, z| acc + *z * *z);
    let rot = C32::cis(-0.5 * sq.arg());
    let aligned = c.map(|z| z * rot);
    let mut h = Vec3::new(aligned[0].re, aligned[1].re, aligned[2].re);
    let q = Vec3::new(aligned[0].im, aligned[1].im, aligned[2].im);
    let mut amplitude = aligned;
    if h.iter().fold(0.0f32, |m, v| {
        if libm::fabsf(*v) > libm::fabsf(m) {
            *v
        } else {
            m
        }
    }) < 0.0
    {
        h = -h;
        amplitude = aligned.map(|z| z.scale(-1.0));
    }

    // Noise on each real component of c (see module docs): F/6 per block, averaged over n.
    let var = floor / (6.0 * nf) / (gain * gain);
    let sig_energy = nf * power(&raw);
    let total: f32 = (s..s + n).map(|i| view.energy(i)).sum();
    let nu_image = 2.0 * cfg.if_hz * l / cfg.sample_rate_hz + nu;
    let explained =
        sig_energy * (1.0 + image_share(nu_image, l, gain)) + ramp_energy(view, s, n, nu);
    let residual = total - explained - (nf - 2.0) * floor;
    // Allowance: 5 standard deviations of the noise-only residual (6 real dof per block).
    let residual_allow = 5.0 * libm::sqrtf(nf / 3.0) * floor;
    // Capped: with (almost) no signal energy the ratio would be ±∞ (or NaN), and NaN/∞
    // must not leave the front end.
    let residual_fraction = residual / sig_energy.max(f32::MIN_POSITIVE);
    let residual_fraction = if residual_fraction.is_nan() {
        f32::MAX
    } else {
        residual_fraction.clamp(-f32::MAX, f32::MAX)
    };
    let hq = h.norm_squared();
    let qq = q.norm_squared();
    let quadrature_fraction = (qq / hq.max(f32::MIN_POSITIVE)).min(f32::MAX);
    let overlap = residual > residual_allow + cfg.max_residual_fraction * sig_energy
        || qq > 14.0 * var + cfg.max_quadrature_fraction * hq;
    let saturated = (start..e).any(|i| view.saturated(i));
    Some(Analysis {
        start,
        len: e - start,
        offset_hz: nu / cfg.block_s(),
        h,
        amplitude,
        sigma: libm::sqrtf(var),
        residual_fraction,
        quadrature_fraction,
        overlap,
        saturated,
    })
}
