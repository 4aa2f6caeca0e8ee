//! Mixture management: weight normalization in the log domain (IROS eq. 17), pruning,
//! merging of near-duplicates, splitting of components over which the field is too
//! nonlinear, and the mixture moments (IROS eq. 18).

use super::gaussian::{Component, cholesky3, lower_inverse3};
use super::model::{I_M, I_P, I_RPY, NX, StateMat, StateVec};
use crate::frame::wrap_pi;
use crate::{Mat3, Vec3};
use heapless::Vec;

/// Normalizes the log-weights so that the weights sum to one (log-sum-exp).
pub(crate) fn normalize<const N: usize>(comps: &mut Vec<Component, N>) {
    let max = comps
        .iter()
        .map(|c| c.log_w)
        .fold(f32::NEG_INFINITY, f32::max);
    if !max.is_finite() {
        let lw = -libm::logf(comps.len().max(1) as f32);
        comps.iter_mut().for_each(|c| c.log_w = lw);
        return;
    }
    let sum: f32 = comps.iter().map(|c| libm::expf(c.log_w - max)).sum();
    let log_sum = max + libm::logf(sum);
    comps.iter_mut().for_each(|c| c.log_w -= log_sum);
}

/// Removes components whose weight is below `min_weight`, always keeping the heaviest;
/// renormalizes. Returns how many were removed.
pub(crate) fn prune<const N: usize>(comps: &mut Vec<Component, N>, min_weight: f32) -> u16 {
    let before = comps.len();
    let max = comps
        .iter()
        .map(|c| c.log_w)
        .fold(f32::NEG_INFINITY, f32::max);
    let threshold = libm::logf(min_weight).min(max);
    comps.retain(|c| c.log_w >= threshold);
    normalize(comps);
    (before - comps.len()) as u16
}

/// `b`'s mean as seen from `a`: angles unwrapped next to `a`'s, and the moment's sign
/// aligned with `a`'s (the moment's sign is a free gauge under sign-ambiguous pulses).
/// With `signed` pulses (`SogConfig::sign_ambiguous` false) `m` and `−m` predict opposite
/// fields, two different hypotheses: the moment is never flipped then.
/// Returns the aligned mean and whether the moment was flipped.
fn aligned(a: &StateVec, b: &StateVec, signed: bool) -> (StateVec, bool) {
    let mut out = *b;
    for i in I_RPY..I_RPY + 3 {
        out[i] = a[i] + wrap_pi(b[i] - a[i]);
    }
    let ma = Vec3::new(a[I_M], a[I_M + 1], a[I_M + 2]);
    let mb = Vec3::new(b[I_M], b[I_M + 1], b[I_M + 2]);
    let flip = !signed && ma.dot(&mb) < 0.0;
    if flip {
        for i in I_M..I_M + 3 {
            out[i] = -out[i];
        }
    }
    (out, flip)
}

/// Flips the sign of the moment rows/columns of a covariance (the Jacobian of `m → −m`).
fn flip_moment_cov(p: &mut StateMat) {
    for i in I_M..I_M + 3 {
        for j in 0..NX {
            if !(I_M..I_M + 3).contains(&j) {
                p[(i, j)] = -p[(i, j)];
                p[(j, i)] = -p[(j, i)];
            }
        }
    }
}

/// Squared Mahalanobis distance of a 3-vector under `c` (∞ if `c` is not PD).
fn d2_3(c: &Mat3, v: &Vec3) -> f32 {
    match cholesky3(c) {
        Ok(l) => (lower_inverse3(&l) * v).norm_squared(),
        Err(_) => f32::INFINITY,
    }
}

/// Position, position covariance (upper triangle) and its trace of a component: what
/// the rejection tests of [`merge`] read, kept in a compact array so that the O(N²)
/// pair loop never unpacks covariance blocks for pairs that are far apart.
#[derive(Debug, Clone, Copy)]
struct MergeKey {
    p: [f32; 3],
    /// `[c00, c01, c02, c11, c12, c22]` of the position covariance.
    c: [f32; 6],
    trace: f32,
}

impl MergeKey {
    fn of(comp: &Component) -> Self {
        let at = |i, j| comp.p_at(I_P + i, I_P + j);
        let c = [at(0, 0), at(0, 1), at(0, 2), at(1, 1), at(1, 2), at(2, 2)];
        Self {
            p: [comp.x[I_P], comp.x[I_P + 1], comp.x[I_P + 2]],
            c,
            trace: c[0] + c[3] + c[5],
        }
    }

    /// Whether the pair certainly fails [`close`]: first `|dp|² > max_d2 · trace(C_a +
    /// C_b)` (then `d² ≥ |dp|² / λ_max > max_d2`, ≈ 10 instructions), then the position
    /// part of the distance alone, `dpᵀ (C_a + C_b)⁻¹ dp > max_d2` (LDLᵀ, no square root;
    /// the moment part only adds to it).
    fn far(&self, other: &Self, max_d2: f32) -> bool {
        let d = [
            self.p[0] - other.p[0],
            self.p[1] - other.p[1],
            self.p[2] - other.p[2],
        ];
        if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > max_d2 * (self.trace + other.trace) {
            return true;
        }
        let c: [f32; 6] = core::array::from_fn(|k| self.c[k] + other.c[k]);
        // LDLᵀ of the 3×3 sum; a non-positive pivot leaves the decision to `close`.
        let d0 = c[0];
        if d0.is_nan() || d0 <= 0.0 {
            return false;
        }
        let (l10, l20) = (c[1] / d0, c[2] / d0);
        let d1 = c[3] - l10 * c[1];
        if d1.is_nan() || d1 <= 0.0 {
            return false;
        }
        let l21 = (c[4] - l20 * c[1]) / d1;
        let d2 = c[5] - l20 * c[2] - l21 * (c[4] - l20 * c[1]);
        if d2.is_nan() || d2 <= 0.0 {
            return false;
        }
        // Forward substitution y = L⁻¹ dp, then Σ y_k² / d_k.
        let y0 = d[0];
        let y1 = d[1] - l10 * y0;
        let y2 = d[2] - l20 * y0 - l21 * y1;
        // A 1e-5 relative margin keeps pairs at the round-off boundary for `close`.
        (y0 * y0 / d0 + y1 * y1 / d1 + y2 * y2 / d2) > max_d2 * (1.0 + 1e-5)
    }
}

/// Merges pairs of near-duplicate components: position and moment (sign-aligned unless
/// `signed`, see [`aligned`]) within `max_d2` (squared Mahalanobis, with the sum of both
/// covariances). The merge preserves the pair's weight, mean and covariance (eq. 18
/// applied to the pair).
/// Returns the number of merges.
///
/// All pairs are visited in the same order as a plain double loop, but the cheap
/// rejection runs on a compact copy of the positions and traces ([`MergeKey`]), kept in
/// step with the mixture through every merge and `swap_remove`: the result is the same,
/// at ≈ 10 instructions per rejected pair. Never inlined: its key buffer then lives on
/// the stack only while it runs, not in the whole step's frame.
#[inline(never)]
pub(crate) fn merge<const N: usize>(
    comps: &mut Vec<Component, N>,
    max_d2: f32,
    signed: bool,
) -> u16 {
    let mut keys: Vec<MergeKey, N> = comps.iter().map(MergeKey::of).collect();
    let mut merged = 0u16;
    let mut i = 0;
    while i < keys.len() {
        let Some(&ki) = keys.get(i) else { break };
        let mut ki = ki;
        let mut j = i + 1;
        while j < keys.len() {
            let far = keys.get(j).is_none_or(|kj| ki.far(kj, max_d2));
            if far {
                j += 1;
                continue;
            }
            let (Some(a), Some(b)) = (comps.get(i), comps.get(j)) else {
                break;
            };
            if close(a, b, max_d2, signed) {
                let m = merge_pair(a, b, signed);
                ki = MergeKey::of(&m);
                if let (Some(slot), Some(key)) = (comps.get_mut(i), keys.get_mut(i)) {
                    *slot = m;
                    *key = ki;
                }
                comps.swap_remove(j);
                keys.swap_remove(j);
                merged += 1;
            } else {
                j += 1;
            }
        }
        i += 1;
    }
    merged
}

/// Whether two components are near-duplicates.
fn close(a: &Component, b: &Component, max_d2: f32, signed: bool) -> bool {
    let pa = Vec3::new(a.x[I_P], a.x[I_P + 1], a.x[I_P + 2]);
    let pb = Vec3::new(b.x[I_P], b.x[I_P + 1], b.x[I_P + 2]);
    let dp = pa - pb;
    let cpp = a.block3(I_P) + b.block3(I_P);
    // Cheap rejection: d² ≥ |dp|² / λ_max ≥ |dp|² / trace.
    if dp.norm_squared() > max_d2 * cpp.trace() {
        return false;
    }
    let (bx, _) = aligned(&a.x, &b.x, signed);
    let dm = Vec3::new(
        a.x[I_M] - bx[I_M],
        a.x[I_M + 1] - bx[I_M + 1],
        a.x[I_M + 2] - bx[I_M + 2],
    );
    let cmm = a.block3(I_M) + b.block3(I_M);
    d2_3(&cpp, &dp) + d2_3(&cmm, &dm) <= max_d2
}

/// Moment-preserving merge of two components.
fn merge_pair(a: &Component, b: &Component, signed: bool) -> Component {
    let (bx, flip) = aligned(&a.x, &b.x, signed);
    let mut pb = b.p();
    if flip {
        flip_moment_cov(&mut pb);
    }
    let (wa, wb) = (libm::expf(a.log_w), libm::expf(b.log_w));
    let w = wa + wb;
    let (fa, fb) = if w > 0.0 {
        (wa / w, wb / w)
    } else {
        (0.5, 0.5)
    };
    let mut x = a.x * fa + bx * fb;
    let (da, db) = (a.x - x, bx - x);
    let p = (a.p() + da * da.transpose()) * fa + (pb + db * db.transpose()) * fb;
    for i in I_RPY..I_RPY + 3 {
        x[i] = wrap_pi(x[i]);
    }
    let log_w = if w > 0.0 {
        libm::logf(w)
    } else {
        a.log_w.max(b.log_w)
    };
    Component::new(x, &p, log_w)
}

/// Three-component split of a unit Gaussian along one axis (weights and offsets of
/// Huber & Hanebeck's splitting library), with the variance chosen so that the split
/// preserves the mean and covariance exactly.
const SPLIT_W: [f32; 3] = [0.225_224_6, 0.549_550_8, 0.225_224_6];
const SPLIT_MU: [f32; 3] = [-1.057_515_5, 0.0, 1.057_515_5];

/// Splits components whose position uncertainty is large compared with their range
/// (largest σ > `ratio`·range): the field then changes too nonlinearly over the
/// component for one EKF linearization (|H| ∝ r⁻³, so σ = 0.1·r already means a 30 %
/// change of the field within 1σ). Splitting is along the principal position axis,
/// carried to the whole state through the covariance (so the correlated moment moves
/// with the position). The free capacity goes to the heaviest candidates first (they
/// carry the estimate); the rest wait for later pulses. Returns the number of
/// components split. Never inlined (its buffer stays out of the step's frame).
#[inline(never)]
pub(crate) fn split<const N: usize>(
    comps: &mut Vec<Component, N>,
    ratio: f32,
    min_weight: f32,
) -> u16 {
    let log_min_w = libm::logf(min_weight.max(f32::MIN_POSITIVE));
    // Candidates as (log-weight, index), heaviest first.
    let mut order: Vec<(f32, u16), N> = Vec::new();
    for (i, c) in comps.iter().enumerate() {
        if c.log_w >= log_min_w && order.push((c.log_w, i as u16)).is_err() {
            break;
        }
    }
    order.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    let mut count = 0u16;
    for &(_, i) in order.iter() {
        if comps.len() + 2 > N {
            break;
        }
        let Some(c) = comps.get(i as usize).copied() else {
            continue;
        };
        let Some(parts) = split_one(&c, ratio) else {
            continue;
        };
        if let Some(slot) = comps.get_mut(i as usize) {
            *slot = parts[1];
        }
        // Capacity was checked above; a failed push cannot happen.
        let _ = comps.push(parts[0]);
        let _ = comps.push(parts[2]);
        count += 1;
    }
    count
}

/// The three parts of `c` if it needs splitting (see [`split`]).
fn split_one(c: &Component, ratio: f32) -> Option<[Component; 3]> {
    let ppp = c.block3(I_P);
    let range = Vec3::new(c.x[I_P], c.x[I_P + 1], c.x[I_P + 2]).norm();
    // λ_max ≤ trace: most components are rejected before the power iteration.
    let limit = (ratio * range).max(0.02);
    if ppp.trace() <= limit * limit {
        return None;
    }
    let (axis, lambda) = principal_axis(&ppp);
    let sigma = libm::sqrtf(lambda.max(0.0));
    // Never split below 2 cm: the point-dipole model itself is not better than that.
    if sigma <= ratio * range || sigma < 0.02 {
        return None;
    }
    let p = c.p();
    // v = P e / sqrt(eᵀ P e): the state direction that moves the position by σ
    // along the axis and the rest of the state by its regression on it.
    let mut e = StateVec::zeros();
    e.fixed_rows_mut::<3>(I_P).copy_from(&axis);
    let pe = p * e;
    let var = e.dot(&pe);
    if var.is_nan() || var <= 0.0 {
        return None;
    }
    let v = pe / libm::sqrtf(var);
    let spread: f32 = SPLIT_W
        .iter()
        .zip(SPLIT_MU.iter())
        .map(|(w, mu)| w * mu * mu)
        .sum();
    // P' = P − spread·v vᵀ stays PSD because v vᵀ ≤ P (Cauchy–Schwarz) and spread < 1.
    let p_new = p - v * v.transpose() * spread;
    // … in exact arithmetic: in f32, with a variance of 10⁵ rad² beside ones of 10⁻² m²
    // (an attitude input far wider than π), v's rows lose the digits that keep it so and
    // a variance came out negative (fuzz `estimator_step`, crash-afc5f33d…). Not split then.
    if (0..p_new.nrows()).any(|i| p_new[(i, i)].is_nan() || p_new[(i, i)] < 0.0) {
        return None;
    }
    let mut parts = [*c; 3];
    for (k, part) in parts.iter_mut().enumerate() {
        let (w, mu) = (SPLIT_W[k], SPLIT_MU[k]);
        let mut x = c.x + v * mu;
        for a in I_RPY..I_RPY + 3 {
            x[a] = wrap_pi(x[a]);
        }
        *part = Component::new(x, &p_new, c.log_w + libm::logf(w));
    }
    Some(parts)
}

/// Unit principal eigenvector and eigenvalue of a symmetric PSD 3×3 matrix (power
/// iteration, started from the column with the largest diagonal).
fn principal_axis(c: &Mat3) -> (Vec3, f32) {
    let mut k = 0;
    for i in 1..3 {
        if c[(i, i)] > c[(k, k)] {
            k = i;
        }
    }
    let mut v = Vec3::zeros();
    v[k] = 1.0;
    for _ in 0..12 {
        let w = c * v;
        let n = w.norm();
        if n.is_nan() || n <= 0.0 {
            return (v, 0.0);
        }
        v = w / n;
    }
    (v, v.dot(&(c * v)))
}

/// Weighted mean and covariance of the transmitter position (IROS eq. 18), the weight
/// of the heaviest component and its index.
pub(crate) fn position_moments<const N: usize>(
    comps: &Vec<Component, N>,
) -> Option<(Vec3, Mat3, f32, usize)> {
    let mut best = 0usize;
    let mut best_lw = f32::NEG_INFINITY;
    let mut mean = Vec3::zeros();
    let mut wsum = 0.0f32;
    for (i, c) in comps.iter().enumerate() {
        let w = libm::expf(c.log_w);
        mean += Vec3::new(c.x[I_P], c.x[I_P + 1], c.x[I_P + 2]) * w;
        wsum += w;
        if c.log_w > best_lw {
            best_lw = c.log_w;
            best = i;
        }
    }
    if wsum.is_nan() || wsum <= 0.0 {
        return None;
    }
    mean /= wsum;
    let mut cov = Mat3::zeros();
    for c in comps.iter() {
        let w = libm::expf(c.log_w) / wsum;
        let d = Vec3::new(c.x[I_P], c.x[I_P + 1], c.x[I_P + 2]) - mean;
        cov += (c.block3(I_P) + d * d.transpose()) * w;
    }
    Some((mean, cov, libm::expf(best_lw) / wsum, best))
}

/// Weighted mean of the moment, each component's sign aligned with the heaviest one's
/// (unless `signed`: a known pulse sign makes the moment's sign part of the belief).
pub(crate) fn moment_mean<const N: usize>(
    comps: &Vec<Component, N>,
    best: usize,
    signed: bool,
) -> Vec3 {
    let Some(b) = comps.get(best) else {
        return Vec3::zeros();
    };
    let mb = Vec3::new(b.x[I_M], b.x[I_M + 1], b.x[I_M + 2]);
    let mut acc = Vec3::zeros();
    let mut wsum = 0.0;
    for c in comps.iter() {
        let w = libm::expf(c.log_w);
        let m = Vec3::new(c.x[I_M], c.x[I_M + 1], c.x[I_M + 2]);
        acc += if !signed && m.dot(&mb) < 0.0 { -m } else { m } * w;
        wsum += w;
    }
    if wsum > 0.0 { acc / wsum } else { mb }
}

#[cfg(test)]
mod tests {
    use super::super::model::{I_S, NX};
    use super::*;

    fn comp(p: Vec3, m: Vec3, sig_p: f32, log_w: f32) -> Component {
        let mut x = StateVec::zeros();
        x.fixed_rows_mut::<3>(I_P).copy_from(&p);
        x.fixed_rows_mut::<3>(I_M).copy_from(&m);
        x[I_S] = 1.0;
        let mut cov = StateMat::identity() * 1e-3;
        for i in 0..3 {
            cov[(I_P + i, I_P + i)] = sig_p * sig_p;
            cov[(I_M + i, I_M + i)] = 1.0;
        }
        // Correlate position x with moment x to exercise the sign flip.
        cov[(I_P, I_M)] = 0.5 * sig_p;
        cov[(I_M, I_P)] = 0.5 * sig_p;
        Component::new(x, &cov, log_w)
    }

    #[test]
    fn normalize_and_prune() {
        let mut v: Vec<Component, 8> = Vec::new();
        for k in 0..5 {
            let _ = v.push(comp(
                Vec3::new(10.0 + k as f32, 0.0, -2.0),
                Vec3::x(),
                1.0,
                -(k as f32) * 5.0,
            ));
        }
        normalize(&mut v);
        let s: f32 = v.iter().map(|c| libm::expf(c.log_w)).sum();
        assert!((s - 1.0).abs() < 1e-6);
        let removed = prune(&mut v, 1e-4);
        assert_eq!(removed, 3);
        let s: f32 = v.iter().map(|c| libm::expf(c.log_w)).sum();
        assert!((s - 1.0).abs() < 1e-6);
    }

    /// Two components 0.2 m apart with opposite moments (weights 0.3 and 0.7).
    fn opposite_moments() -> (Component, Component) {
        let a = comp(
            Vec3::new(10.0, 1.0, -2.0),
            Vec3::new(5.0, 1.0, 0.0),
            1.0,
            libm::logf(0.3),
        );
        let b = comp(
            Vec3::new(10.2, 1.0, -2.0),
            Vec3::new(-5.2, -1.0, 0.0),
            1.0,
            libm::logf(0.7),
        );
        (a, b)
    }

    /// A mixture of the two components.
    fn pair(a: Component, b: Component) -> Vec<Component, 4> {
        let mut v: Vec<Component, 4> = Vec::new();
        let _ = v.push(a);
        let _ = v.push(b);
        v
    }

    #[test]
    fn merge_preserves_moments_and_handles_moment_sign() {
        let (a, b) = opposite_moments();
        let mut v = pair(a, b);
        let (mean0, cov0, _, _) = position_moments(&v).unwrap();
        assert_eq!(merge(&mut v, 0.3, false), 1);
        assert_eq!(v.len(), 1);
        let (mean1, cov1, w, _) = position_moments(&v).unwrap();
        assert!((mean1 - mean0).norm() < 1e-5);
        assert!((cov1 - cov0).abs().max() < 1e-5);
        assert!((w - 1.0).abs() < 1e-5);
        // Moment: aligned with a's sign, weighted mean 0.3·5 + 0.7·5.2.
        let m = v[0].x[I_M];
        assert!((m - (0.3 * 5.0 + 0.7 * 5.2)).abs() < 1e-4, "{m}");
        // Far components are not merged.
        let _ = v.push(comp(Vec3::new(20.0, 1.0, -2.0), Vec3::x(), 1.0, 0.0));
        assert_eq!(merge(&mut v, 0.3, false), 0);
    }

    #[test]
    fn a_known_sign_never_flips_the_moment() {
        // Opposite moments at one position: the same hypothesis when the pulse sign is
        // ambiguous, opposite predicted fields when it is known (`signed`).
        let (a, b) = opposite_moments();
        let mut v = pair(a, b);
        assert!((moment_mean(&v, 1, false).x + (0.3 * 5.0 + 0.7 * 5.2)).abs() < 1e-4);
        let m = moment_mean(&v, 1, true).x;
        assert!((m - (0.3 * 5.0 - 0.7 * 5.2)).abs() < 1e-4, "{m}");
        assert_eq!(merge(&mut v, 0.3, true), 0);
        assert_eq!(v.len(), 2);
        // Equal signs still merge when the sign is known.
        let mut c = b;
        c.x.fixed_rows_mut::<3>(I_M)
            .copy_from(&Vec3::new(5.2, 1.0, 0.0));
        let mut v = pair(a, c);
        assert_eq!(merge(&mut v, 0.3, true), 1);
        let m = v[0].x[I_M];
        assert!((m - (0.3 * 5.0 + 0.7 * 5.2)).abs() < 1e-4, "{m}");
    }

    #[test]
    fn split_preserves_moments_and_stays_psd() {
        let mut v: Vec<Component, 8> = Vec::new();
        let _ = v.push(comp(
            Vec3::new(3.0, 0.0, -1.0),
            Vec3::new(5.0, 0.0, 0.0),
            1.0,
            0.0,
        ));
        let (mean0, cov0, _, _) = position_moments(&v).unwrap();
        assert_eq!(split(&mut v, 0.12, 1e-3), 1);
        assert_eq!(v.len(), 3);
        let (mean1, cov1, _, _) = position_moments(&v).unwrap();
        assert!((mean1 - mean0).norm() < 1e-5);
        assert!((cov1 - cov0).abs().max() < 1e-4, "{cov0} {cov1}");
        for c in v.iter() {
            assert!(nalgebra::Cholesky::new(c.p()).is_some());
            assert_eq!(c.p().nrows(), NX);
        }
        // Capacity is respected.
        let mut full: Vec<Component, 2> = Vec::new();
        let _ = full.push(v[0]);
        assert_eq!(split(&mut full, 0.01, 0.0), 0);
    }
}
