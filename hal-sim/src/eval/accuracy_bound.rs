//! The Cramér–Rao bound of the robocentric estimate (`hal-sim accuracy --budget`): what
//! the pulses, the dead reckoning and the absolute attitude of one run allow at best,
//! whatever the estimator.
//!
//! The filter's problem, written as a batch (full-trajectory) estimation in W: unknowns
//! the receiver's poses `(p_k, Ψ_k)` at every pulse from the initializing one on, the
//! transmitter's position `p_T` and moment `m`, and the walk-long scale `c` of the dead
//! reckoning. Measurements, with exactly the accuracy harness's noise model:
//! - dead-reckoned translation `c · R(Ψ_{k-1})ᵀ (p_k − p_{k-1})`, per-axis σ from
//!   [`crate::eval::accuracy::MotionNoise::translation_sigmas`] (IROS eq. 10–11's `Q_k`);
//! - dead-reckoned rotation `rpy(R(Ψ_{k-1})ᵀ R(Ψ_k))`, σ_r per angle;
//! - absolute attitude `Ψ_k`, σ tilt / yaw;
//! - pulse `R(Ψ_k)ᵀ H(p_k − p_T, m)` (IROS eq. 12), σ of ICRA eq. 10 per axis;
//! - prior `c ~ N(1, σ_s²)` (the calibration) and a gauge `p_0 = 0`.
//!
//! The Fisher information `F = Σ Jᵀ R⁻¹ J` (Jacobians at the truth, central differences
//! in f64) inverted gives the bound on the covariance of any unbiased estimate; the
//! robocentric target `p_T − p_N` (the filter's `p_T` in `G_N`) is a linear function of
//! the unknowns, so its bound is `A F⁻¹ Aᵀ`. The pulse's sign ambiguity and the
//! information in the field-dependent noise variance are left out (both change the
//! bound by far less than the pulse noise at the SNRs here).
use crate::world::physics::{M3, V3, dipole_field, rotation_from_rpy};
use nalgebra::{DMatrix, DVector};

/// One run's truth and noise levels, recorded from the initializing pulse on.
#[derive(Debug, Clone, Default)]
pub struct BoundInput {
    /// True receiver position (W, m) and attitude (rpy, rad) at each pulse.
    pub poses: Vec<(V3, V3)>,
    /// Per-interval translation σ (horizontal, vertical), m, for `poses[k-1] → poses[k]`.
    pub translation_sigmas: Vec<(f64, f64)>,
    /// Per-interval rotation σ, rad.
    pub sigma_r: f64,
    /// Absolute attitude σ (tilt, yaw), rad.
    pub attitude_sigma: [f64; 2],
    /// True scale of the dead reckoning (measured / true translation).
    pub scale: f64,
    /// Prior σ of the scale (the filter's `scale_sigma`).
    pub scale_sigma: f64,
    /// Transmitter position (W, m) and moment (A·m²).
    pub transmitter: (V3, V3),
    /// Pulse noise: background σ (A/m) and relative sensor error (ICRA eq. 10).
    pub pulse_noise: (f64, f64),
}

/// Unknowns per pose.
const NPOSE: usize = 6;

/// `[roll, pitch, yaw]` of a rotation `R = Rz Ry Rx` (inverse of [`rotation_from_rpy`]).
fn rpy_from_rotation(r: &M3) -> V3 {
    V3::new(
        r[(2, 1)].atan2(r[(2, 2)]),
        (-r[(2, 0)]).clamp(-1.0, 1.0).asin(),
        r[(1, 0)].atan2(r[(0, 0)]),
    )
}

/// Adds `Jᵀ R⁻¹ J` of a 3-vector measurement `h` of the unknowns at `idx` (diagonal
/// noise variances `var`) to `f`, with the Jacobian by central differences at `x`.
fn add_factor(
    f: &mut DMatrix<f64>,
    x: &DVector<f64>,
    idx: &[usize],
    var: &V3,
    h: impl Fn(&DVector<f64>) -> V3,
) {
    let mut j = DMatrix::<f64>::zeros(3, idx.len());
    let mut xp = x.clone();
    for (c, &i) in idx.iter().enumerate() {
        let step = 1e-6 * x[i].abs().max(1e-3);
        xp[i] = x[i] + step;
        let hp = h(&xp);
        xp[i] = x[i] - step;
        let hm = h(&xp);
        xp[i] = x[i];
        j.set_column(c, &((hp - hm) / (2.0 * step)));
    }
    let w = DMatrix::from_diagonal(&DVector::from_iterator(3, var.iter().map(|v| 1.0 / v)));
    let jtj = j.transpose() * w * &j;
    for (a, &ia) in idx.iter().enumerate() {
        for (b, &ib) in idx.iter().enumerate() {
            f[(ia, ib)] += jtj[(a, b)];
        }
    }
}

fn v3(x: &DVector<f64>, i: usize) -> V3 {
    V3::new(x[i], x[i + 1], x[i + 2])
}

/// The bound on the covariance (W axes, m²) of the robocentric position `p_T − p_N` at
/// the last pose; `None` for fewer than two poses or a singular information matrix.
pub fn final_position_bound(input: &BoundInput) -> Option<M3> {
    let n = input.poses.len();
    if n < 2 || input.translation_sigmas.len() + 1 < n {
        return None;
    }
    let (i_t, i_m, i_c) = (NPOSE * n, NPOSE * n + 3, NPOSE * n + 6);
    let dim = i_c + 1;
    let mut x = DVector::<f64>::zeros(dim);
    for (k, (p, rpy)) in input.poses.iter().enumerate() {
        x.fixed_rows_mut::<3>(NPOSE * k).copy_from(p);
        x.fixed_rows_mut::<3>(NPOSE * k + 3).copy_from(rpy);
    }
    x.fixed_rows_mut::<3>(i_t).copy_from(&input.transmitter.0);
    x.fixed_rows_mut::<3>(i_m).copy_from(&input.transmitter.1);
    x[i_c] = input.scale;
    let mut f = DMatrix::<f64>::zeros(dim, dim);
    // Gauge (W's origin) and the scale's calibration prior.
    for i in 0..3 {
        f[(i, i)] += 1e8;
    }
    f[(i_c, i_c)] += 1.0 / input.scale_sigma.powi(2).max(1e-12);
    let [tilt, yaw] = input.attitude_sigma;
    let att_var = V3::new(tilt * tilt, tilt * tilt, yaw * yaw);
    let rot_var = V3::repeat(input.sigma_r * input.sigma_r);
    let (bkg, k_sen) = input.pulse_noise;
    // Pulses in µA/m so the information stays well scaled.
    const UA: f64 = 1e6;
    for k in 0..n {
        let (ip, ia) = (NPOSE * k, NPOSE * k + 3);
        let psi: Vec<usize> = (ia..ia + 3).collect();
        add_factor(&mut f, &x, &psi, &att_var, |x| v3(x, ia));
        let h_true = dipole_field(
            &(input.poses[k].0 - input.transmitter.0),
            &input.transmitter.1,
        );
        let sigma = bkg.hypot(k_sen * h_true.norm()) * UA;
        let idx: Vec<usize> = (ip..ip + 6).chain(i_t..i_t + 6).collect();
        add_factor(&mut f, &x, &idx, &V3::repeat(sigma * sigma), |x| {
            let r = v3(x, ip) - v3(x, i_t);
            rotation_from_rpy(&v3(x, ia)).transpose() * dipole_field(&r, &v3(x, i_m)) * UA
        });
        if k == 0 {
            continue;
        }
        let (jp, ja) = (NPOSE * (k - 1), NPOSE * (k - 1) + 3);
        let (st, sz) = input.translation_sigmas[k - 1];
        let idx: Vec<usize> = (jp..jp + 6).chain(ip..ip + 6).chain([i_c]).collect();
        add_factor(&mut f, &x, &idx, &V3::new(st * st, st * st, sz * sz), |x| {
            rotation_from_rpy(&v3(x, ja)).transpose() * (v3(x, ip) - v3(x, jp)) * x[i_c]
        });
        let idx: Vec<usize> = (ja..ja + 3).chain(ia..ia + 3).collect();
        add_factor(&mut f, &x, &idx, &rot_var, |x| {
            rpy_from_rotation(
                &(rotation_from_rpy(&v3(x, ja)).transpose() * rotation_from_rpy(&v3(x, ia))),
            )
        });
    }
    let cov = f.cholesky()?.inverse();
    // A selects p_T − p_N.
    let last = NPOSE * (n - 1);
    let mut a = DMatrix::<f64>::zeros(3, dim);
    for i in 0..3 {
        a[(i, i_t + i)] = 1.0;
        a[(i, last + i)] = -1.0;
    }
    let c = &a * cov * a.transpose();
    Some(M3::from_fn(|i, j| 0.5 * (c[(i, j)] + c[(j, i)])))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(n: usize, sigma_t: f64) -> BoundInput {
        let tx = (V3::new(6.0, 2.0, -1.5), V3::new(0.0, 0.004, 0.003));
        BoundInput {
            poses: (0..n)
                .map(|k| {
                    (
                        V3::new(k as f64, 0.3 * k as f64, 1.0),
                        V3::new(0.0, 0.1, 0.3),
                    )
                })
                .collect(),
            translation_sigmas: vec![(sigma_t, 0.5 * sigma_t); n],
            sigma_r: 0.01,
            attitude_sigma: [0.02, 0.05],
            scale: 1.0,
            scale_sigma: 0.02,
            transmitter: tx,
            pulse_noise: (2.59e-9, 0.03),
        }
    }

    #[test]
    fn rpy_round_trips() {
        let rpy = V3::new(0.1, -0.2, 2.9);
        assert!((rpy_from_rotation(&rotation_from_rpy(&rpy)) - rpy).norm() < 1e-12);
    }

    #[test]
    fn the_bound_shrinks_with_more_pulses_and_grows_with_the_motion_noise() {
        let b = |n, s| final_position_bound(&input(n, s)).map(|c| c.trace().sqrt());
        let (short, long) = (b(4, 0.05).unwrap(), b(8, 0.05).unwrap());
        let noisy = b(8, 0.2).unwrap();
        assert!(short.is_finite() && long > 0.0);
        assert!(long < short, "{long} vs {short}");
        assert!(noisy > long, "{noisy} vs {long}");
        assert!(final_position_bound(&input(1, 0.05)).is_none());
    }

    #[test]
    fn a_single_pulse_factor_matches_its_closed_form_information() {
        // One pose, pulse only: the finite-difference JᵀR⁻¹J equals the analytic
        // information of H(r, m) w.r.t. m (linear: H = G(r) m, so J = G).
        let inp = input(2, 0.05);
        let x = DVector::from_vec(vec![0.0; 3]);
        let r = inp.poses[0].0 - inp.transmitter.0;
        let g = M3::from_columns(&[
            dipole_field(&r, &V3::x()),
            dipole_field(&r, &V3::y()),
            dipole_field(&r, &V3::z()),
        ]);
        let mut f = DMatrix::zeros(3, 3);
        add_factor(&mut f, &x, &[0, 1, 2], &V3::repeat(4.0), |x| g * v3(x, 0));
        let exact = g.transpose() * g / 4.0;
        for i in 0..3 {
            for j in 0..3 {
                assert!((f[(i, j)] - exact[(i, j)]).abs() <= 1e-6 * exact.norm());
            }
        }
    }
}
