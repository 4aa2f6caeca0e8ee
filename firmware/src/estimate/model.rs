//! The robocentric process and measurement models of one Gaussian, with their analytic
//! Jacobians (IROS 2006 eq. 5–9 and 12–14).
//!
//! State `x = [Ψ; p_T; m; s]` (10): orientation of `R_k` in `G_k` (roll, pitch, yaw,
//! rad), transmitter position in `G_k` (m), transmitter moment in `G_k` (mA·m², see
//! [`MOMENT_SCALE`]) and the walk-long scale factor `s` of the dead-reckoned translation.
//! Displacement `u = [Δp; ΔΨ]` (6): translation in `R_{k-1}` as dead-reckoned (m) and
//! rotation `R_{k-1} → R_k` (rad). An absolute (unscaled) translation `a` in `R_{k-1}` (m),
//! measured rather than dead-reckoned, is added after the scale: `p' = p − R(Ψ)(s·Δp + a)`.

use super::rot::{self, Rot};
use crate::dipole::{DipoleError, field_with_jacobians};
use crate::frame::Rpy;
use crate::{Mat3, Vec3};
use nalgebra::{SMatrix, SVector};

/// State dimension.
pub(crate) const NX: usize = 10;
/// Displacement dimension.
pub(crate) const NU: usize = 6;
/// Index of roll in the state (then pitch, yaw).
pub(crate) const I_RPY: usize = 0;
/// Index of the transmitter position's x in the state.
pub(crate) const I_P: usize = 3;
/// Index of the moment's x in the state.
pub(crate) const I_M: usize = 6;
/// Index of the scale factor in the state.
pub(crate) const I_S: usize = 9;

/// Internal field unit per A/m: fields are handled in µA/m.
pub(crate) const FIELD_SCALE: f32 = 1e6;
/// Internal moment unit per A·m²: moments are handled in mA·m².
pub(crate) const MOMENT_SCALE: f32 = 1e3;
/// `h_internal = K_H · dipole::field(r, m_internal)`.
pub(crate) const K_H: f32 = FIELD_SCALE / MOMENT_SCALE;

/// A state vector.
pub(crate) type StateVec = SVector<f32, NX>;
/// A state covariance.
pub(crate) type StateMat = SMatrix<f32, NX, NX>;
/// A displacement vector.
pub(crate) type MotionVec = SVector<f32, NU>;
/// A displacement covariance.
pub(crate) type MotionMat = SMatrix<f32, NU, NU>;

/// Parts of a state vector.
pub(crate) fn rpy_of(x: &StateVec) -> Rpy {
    Rpy::new(x[I_RPY], x[I_RPY + 1], x[I_RPY + 2])
}
/// Transmitter position of a state vector (m).
pub(crate) fn p_of(x: &StateVec) -> Vec3 {
    Vec3::new(x[I_P], x[I_P + 1], x[I_P + 2])
}
/// Moment of a state vector (mA·m²).
pub(crate) fn m_of(x: &StateVec) -> Vec3 {
    Vec3::new(x[I_M], x[I_M + 1], x[I_M + 2])
}

/// The composition `x_k = f(x_{k-1}, u_k)` (IROS eq. 9) and its Jacobians.
pub(crate) struct Composition {
    /// `f(x, u)`.
    pub x: StateVec,
    /// `∂f/∂x`.
    pub fx: StateMat,
    /// `∂f/∂u`.
    pub fu: SMatrix<f32, NX, NU>,
}

/// The non-trivial blocks of the composition's Jacobians (IROS eq. 6–8). Everything
/// else in `∂f/∂x` is the identity (`p`, `m`, `s` carry over) and in `∂f/∂u` zero:
///
/// ```text
/// Ψ' = Ψ ⊕ ΔΨ          ∂Ψ'/∂Ψ = ja,  ∂Ψ'/∂ΔΨ = jb
/// p' = p − R(Ψ)·(s·Δp + a)   ∂p'/∂Ψ = g, ∂p'/∂p = I, ∂p'/∂s = gs, ∂p'/∂Δp = rs
/// ```
///
/// (`∂p'/∂a = −R = rs / s`: the absolute part's noise is carried as `Q_a / s²` on `Δp`,
/// see [`super::gaussian::StepInput`].)
#[derive(Debug, Clone, Copy)]
pub(crate) struct CompositionJac {
    /// `∂Ψ'/∂Ψ`.
    pub ja: Mat3,
    /// `∂Ψ'/∂ΔΨ`.
    pub jb: Mat3,
    /// `∂p'/∂Ψ = −[∂R/∂ψ d, ∂R/∂θ d, ∂R/∂φ d]` with `d = s·Δp + a`.
    pub g: Mat3,
    /// `∂p'/∂s = −R Δp`.
    pub gs: Vec3,
    /// `∂p'/∂Δp = −s R`.
    pub rs: Mat3,
}

impl CompositionJac {
    /// The dense `∂f/∂x` (10×10).
    pub fn fx(&self) -> StateMat {
        let mut fx = StateMat::identity();
        fx.fixed_view_mut::<3, 3>(I_RPY, I_RPY).copy_from(&self.ja);
        fx.fixed_view_mut::<3, 3>(I_P, I_RPY).copy_from(&self.g);
        fx.fixed_view_mut::<3, 1>(I_P, I_S).copy_from(&self.gs);
        fx
    }

    /// The dense `∂f/∂u` (10×6).
    pub fn fu(&self) -> SMatrix<f32, NX, NU> {
        let mut fu = SMatrix::<f32, NX, NU>::zeros();
        fu.fixed_view_mut::<3, 3>(I_P, 0).copy_from(&self.rs);
        fu.fixed_view_mut::<3, 3>(I_RPY, 3).copy_from(&self.jb);
        fu
    }

    /// `(J·∂f/∂x, J·∂f/∂u)` for a 3×10 `J` whose scale column is zero (the measurement
    /// Jacobian): the chain rule `H* = J [F_x F_u]` of IROS eq. 14 through the structure.
    pub fn chain(&self, j: &SMatrix<f32, 3, NX>) -> (SMatrix<f32, 3, NX>, SMatrix<f32, 3, NU>) {
        let j_psi: Mat3 = j.fixed_columns::<3>(I_RPY).into_owned();
        let j_p: Mat3 = j.fixed_columns::<3>(I_P).into_owned();
        let mut ha = *j;
        ha.fixed_columns_mut::<3>(I_RPY)
            .copy_from(&(j_psi * self.ja + j_p * self.g));
        ha.set_column(I_S, &(j.column(I_S) + j_p * self.gs));
        let mut hb = SMatrix::<f32, 3, NU>::zeros();
        hb.fixed_columns_mut::<3>(0).copy_from(&(j_p * self.rs));
        hb.fixed_columns_mut::<3>(3).copy_from(&(j_psi * self.jb));
        (ha, hb)
    }

    /// `∂f/∂x · a` for a 10-row `a`, using the structure (21 multiply-adds per column).
    pub fn apply_fx<const C: usize>(&self, a: &SMatrix<f32, NX, C>) -> SMatrix<f32, NX, C> {
        let mut out = *a;
        let a_psi = a.fixed_rows::<3>(I_RPY);
        out.fixed_rows_mut::<3>(I_RPY).copy_from(&(self.ja * a_psi));
        let dp = self.g * a_psi + self.gs * a.fixed_rows::<1>(I_S);
        let mut p_rows = out.fixed_rows_mut::<3>(I_P);
        p_rows += dp;
        out
    }

    /// `∂f/∂u · b` for a 6-row `b` (18 multiply-adds per column; rows `m`, `s` are 0).
    pub fn apply_fu<const C: usize>(&self, b: &SMatrix<f32, NU, C>) -> SMatrix<f32, NX, C> {
        let mut out = SMatrix::<f32, NX, C>::zeros();
        out.fixed_rows_mut::<3>(I_RPY)
            .copy_from(&(self.jb * b.fixed_rows::<3>(3)));
        out.fixed_rows_mut::<3>(I_P)
            .copy_from(&(self.rs * b.fixed_rows::<3>(0)));
        out
    }
}

/// Composition (IROS eq. 5–9 with the scale state): `Ψ' = Ψ ⊕ ΔΨ`,
/// `p' = p − R(Ψ)·(s·Δp + a)`, `m' = m`, `s' = s`, from the rotations `ra = R(Ψ)` and
/// `rb = R(ΔΨ)` (with their partials) already evaluated at `x` and `u`; `a` is the
/// absolute (unscaled) translation in `R_{k-1}` (m).
// Inlined into every caller: the hot step (`step_gaussian`) must not pay a call for
// sharing it with the outlier gate and the predict-only step.
#[inline(always)]
pub(crate) fn compose_rot(
    x: &StateVec,
    u: &MotionVec,
    a: &Vec3,
    ra: &Rot,
    rb: &Rot,
) -> (StateVec, CompositionJac) {
    let p = p_of(x);
    let s = x[I_S];
    let dp = Vec3::new(u[0], u[1], u[2]);
    let (psi2, _, ja, jb) = rot::compose_rpy(ra, rb);
    let rdp = ra.r * dp;
    let d = dp * s + a;
    let p2 = p - ra.r * d;

    let mut out = *x;
    out.fixed_rows_mut::<3>(I_RPY).copy_from(&psi2);
    out.fixed_rows_mut::<3>(I_P).copy_from(&p2);
    let mut g = Mat3::zeros();
    for (i, part) in ra.d.iter().enumerate() {
        g.set_column(i, &(part * (-d)));
    }
    let jac = CompositionJac {
        ja,
        jb,
        g,
        gs: -rdp,
        rs: ra.r * (-s),
    };
    (out, jac)
}

/// [`compose_rot`] with the rotations evaluated here and the dense Jacobians.
pub(crate) fn compose_abs(x: &StateVec, u: &MotionVec, a: &Vec3) -> Composition {
    let ra = Rot::new(&rpy_of(x));
    let rb = Rot::new(&Rpy::new(u[3], u[4], u[5]));
    let (x2, jac) = compose_rot(x, u, a, &ra, &rb);
    Composition {
        x: x2,
        fx: jac.fx(),
        fu: jac.fu(),
    }
}

/// The predicted measurement and its Jacobian with respect to the state.
pub(crate) struct Measurement {
    /// `h(x) = K_H · R(Ψ)ᵀ · H(−p, m)` (µA/m in `R_k`), IROS eq. 14.
    pub h: Vec3,
    /// `∂h/∂x` (3×10).
    pub jac: SMatrix<f32, 3, NX>,
}

/// The measurement model (IROS eq. 12–14): the receiver sits at the origin of `G_k`, so
/// `r = p_R − p_T = −p_T`, and the field is rotated into the receiver frame.
pub(crate) fn measure(x: &StateVec) -> Result<Measurement, DipoleError> {
    measure_rot(x, &Rot::new(&rpy_of(x)))
}

/// [`measure`] with `rot = R(Ψ)` and its partials already evaluated at `x`.
// Inlined into every caller: the hot step (`step_gaussian`) must not pay a call for
// sharing it with the outlier gate and the predict-only step.
#[inline(always)]
pub(crate) fn measure_rot(x: &StateVec, rot: &Rot) -> Result<Measurement, DipoleError> {
    let fj = field_with_jacobians(&(-p_of(x)), &m_of(x))?;
    let rt = rot.r.transpose();
    let hg = fj.h * K_H;
    let mut jac = SMatrix::<f32, 3, NX>::zeros();
    for (i, part) in rot.d.iter().enumerate() {
        jac.set_column(I_RPY + i, &(part.tr_mul(&hg)));
    }
    let d_p: Mat3 = rt * fj.d_r * (-K_H);
    let d_m: Mat3 = rt * fj.d_m * K_H;
    jac.fixed_view_mut::<3, 3>(0, I_P).copy_from(&d_p);
    jac.fixed_view_mut::<3, 3>(0, I_M).copy_from(&d_m);
    Ok(Measurement { h: rt * hg, jac })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::frame::wrap_pi;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    pub(crate) fn random_state(rng: &mut SmallRng) -> StateVec {
        let mut x = StateVec::zeros();
        x[0] = rng.random_range(-0.3..0.3);
        x[1] = rng.random_range(-0.3..0.3);
        x[2] = rng.random_range(-3.0..3.0);
        let range = rng.random_range(1.5f32..60.0);
        let az = rng.random_range(-3.1f32..3.1);
        x[3] = range * libm::cosf(az);
        x[4] = range * libm::sinf(az);
        x[5] = -rng.random_range(1.0..4.0);
        for i in 6..9 {
            x[i] = rng.random_range(-20.0..20.0);
        }
        x[9] = rng.random_range(0.9..1.1);
        x
    }

    pub(crate) fn random_motion(rng: &mut SmallRng) -> MotionVec {
        MotionVec::from_column_slice(&[
            rng.random_range(0.3..1.2),
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.4..0.4),
        ])
    }

    fn angle_diff(a: &StateVec, b: &StateVec) -> StateVec {
        let mut d = a - b;
        for i in 0..3 {
            d[i] = wrap_pi(d[i]);
        }
        d
    }

    #[test]
    fn composition_jacobians_match_central_differences() {
        let mut rng = SmallRng::seed_from_u64(21);
        for n in 0..300 {
            let x = random_state(&mut rng);
            let u = random_motion(&mut rng);
            // Half the cases with an absolute (unscaled) translation.
            let a = if n % 2 == 0 {
                Vec3::zeros()
            } else {
                Vec3::new(
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.5..0.5),
                )
            };
            let c = compose_abs(&x, &u, &a);
            let h = 1e-3;
            for k in 0..NX {
                let (mut xp, mut xm) = (x, x);
                xp[k] += h;
                xm[k] -= h;
                let fd = angle_diff(&compose_abs(&xp, &u, &a).x, &compose_abs(&xm, &u, &a).x)
                    / (2.0 * h);
                let err = (fd - c.fx.column(k)).abs().max();
                assert!(
                    err < 5e-3 * (1.0 + c.fx.column(k).abs().max()),
                    "∂f/∂x{k}: {err}"
                );
            }
            for k in 0..NU {
                let (mut up, mut um) = (u, u);
                up[k] += h;
                um[k] -= h;
                let fd = angle_diff(&compose_abs(&x, &up, &a).x, &compose_abs(&x, &um, &a).x)
                    / (2.0 * h);
                let err = (fd - c.fu.column(k)).abs().max();
                assert!(
                    err < 5e-3 * (1.0 + c.fu.column(k).abs().max()),
                    "∂f/∂u{k}: {err}"
                );
            }
            // ∂p'/∂a = −R(Ψ) = ∂p'/∂Δp / s: the absolute part is not scaled.
            let fu_t: Mat3 = c.fu.fixed_view::<3, 3>(I_P, 0).into_owned() / x[I_S];
            for k in 0..3 {
                let (mut ap, mut am) = (a, a);
                ap[k] += h;
                am[k] -= h;
                let fd = (compose_abs(&x, &u, &ap).x - compose_abs(&x, &u, &am).x) / (2.0 * h);
                let col = fd.fixed_rows::<3>(I_P).into_owned();
                assert!((col - fu_t.column(k)).abs().max() < 5e-3, "∂f/∂a{k}");
                assert!(fd[I_S].abs() < 1e-6);
            }
        }
    }

    #[test]
    fn measurement_jacobian_matches_central_differences() {
        let mut rng = SmallRng::seed_from_u64(22);
        for _ in 0..300 {
            let x = random_state(&mut rng);
            let m = measure(&x).unwrap();
            let range = p_of(&x).norm();
            for k in 0..NX {
                // Relative step: the field varies on the scale of the range.
                let h = if (I_P..I_P + 3).contains(&k) {
                    1e-3 * range
                } else {
                    1e-3
                };
                let (mut xp, mut xm) = (x, x);
                xp[k] += h;
                xm[k] -= h;
                let fd = (measure(&xp).unwrap().h - measure(&xm).unwrap().h) / (2.0 * h);
                let scale = m.h.norm()
                    / if (I_P..I_P + 3).contains(&k) {
                        range
                    } else {
                        1.0
                    };
                let err = (fd - m.jac.column(k)).norm() / (scale + 1e-30);
                assert!(err < 2e-3, "∂h/∂x{k}: rel {err}");
            }
            // The scale state does not enter the measurement directly.
            assert_eq!(m.jac.column(I_S).norm(), 0.0);
        }
    }

    #[test]
    fn measurement_closed_form_level_receiver() {
        // Level receiver facing north, transmitter 10 m north, moment pointing north:
        // the receiver is on the axis, H = 2m/(4π r³) along +x.
        let mut x = StateVec::zeros();
        x[I_P] = 10.0;
        x[I_M] = 20.0; // 0.02 A·m²
        x[I_S] = 1.0;
        let m = measure(&x).unwrap();
        let expect = 2.0 * 0.02 / (4.0 * core::f32::consts::PI * 1000.0) * FIELD_SCALE;
        assert!((m.h - Vec3::new(expect, 0.0, 0.0)).norm() < 1e-5 * expect);
        // Turning the receiver 90° left (yaw +π/2): the field along north is now along
        // the receiver's −y (its right side).
        x[I_RPY + 2] = core::f32::consts::FRAC_PI_2;
        let m = measure(&x).unwrap();
        assert!((m.h - Vec3::new(0.0, -expect, 0.0)).norm() < 1e-5 * expect);
    }
}
