//! The absolute-attitude measurement update of one Gaussian (the IMU's roll, pitch and
//! yaw, a linear measurement of `Ψ`), in either covariance form.

use super::{ComponentFailure, CovarianceForm, cholesky3, finish, lower_inverse3, sub_outer};
use crate::estimate::model::{I_RPY, NX, StateMat, StateVec};
use crate::frame::wrap_pi;
use crate::{Mat3, Vec3};
use nalgebra::SMatrix;

/// Absolute-attitude update of one Gaussian (beyond the papers: the receiver's IMU
/// measures its attitude in the geographic frame on every pulse, roll/pitch from
/// gravity and yaw from the tilt-compensated magnetometer).
///
/// The orientation state `Ψ = {G_k}Ψ_{R_k}` is otherwise only propagated by the
/// composition `Ψ_k = Ψ_{k-1} ⊕ ΔΨ_k` (IROS eq. 5), whose per-interval rotation noise
/// accumulates without bound, and through `p_T' = p_T − R(Ψ)·s·Δp` (eq. 7) that drift
/// becomes position error. The IMU attitude is a direct, linear measurement of `Ψ`:
/// `z = Ψ + v`, `v ~ N(0, R)`, `H = [I₃ 0]`, so the update is exact (no linearization):
/// `S = P_ΨΨ + R = L Lᵀ`, innovation `ν = wrap(z − Ψ)` (wrapped to (−π, π]), then by
/// `form`:
/// - [`CovarianceForm::Short`]: `V = P_{·Ψ} L⁻ᵀ`, `K = V L⁻¹`, `P' = P − V Vᵀ`
///   (= `P − K S Kᵀ`, the Joseph form's value for the optimal gain);
/// - [`CovarianceForm::Joseph`]: `K = P_{·Ψ} S⁻¹`,
///   `P' = (I−KH) P (I−KH)ᵀ + K R Kᵀ` (see [`step_component`](super::step_component)
///   for when it is used).
///
/// The component weights are *not* multiplied by this measurement's likelihood: the
/// attitude says nothing about where the transmitter is. Every component starts from
/// the same attitude (IROS III-B), sees the same displacements and the same IMU
/// readings, so their orientation priors differ only by what each pulse update pulled
/// (well below the IMU's σ), and the likelihood ratio between components is ≈ 1; the
/// Monte Carlo (`hal-sim accuracy`) showed no difference with it included.
pub(crate) fn attitude_update(
    x: &StateVec,
    p: &StateMat,
    z: &Vec3,
    r: &Mat3,
    form: CovarianceForm,
) -> Result<(StateVec, StateMat), ComponentFailure> {
    let p_xa: SMatrix<f32, NX, 3> = p.fixed_columns::<3>(I_RPY).into_owned();
    let mut s: Mat3 = p_xa.fixed_rows::<3>(I_RPY).into_owned() + r;
    s = (s + s.transpose()) * 0.5;
    let l = cholesky3(&s).map_err(|_| ComponentFailure::NotPositiveDefinite)?;
    let l_inv = lower_inverse3(&l);
    let nu = Vec3::from_fn(|i, _| wrap_pi(z[i] - x[I_RPY + i]));
    match form {
        CovarianceForm::Short => {
            let v: SMatrix<f32, NX, 3> = p_xa * l_inv.transpose();
            let p_new = sub_outer(p, &v);
            let x_new = finish(x + v * (l_inv * nu), &p_new, 0.0)?;
            Ok((x_new, p_new))
        }
        CovarianceForm::Joseph => {
            let s_inv = l_inv.transpose() * l_inv;
            let k: SMatrix<f32, NX, 3> = p_xa * s_inv;
            // A = I − K H: K H only fills the orientation columns.
            let mut a = StateMat::identity();
            for j in 0..3 {
                for i in 0..NX {
                    a[(i, I_RPY + j)] -= k[(i, j)];
                }
            }
            let mut p_new = a * p * a.transpose() + k * r * k.transpose();
            p_new = (p_new + p_new.transpose()) * 0.5;
            let x_new = finish(x + k * nu, &p_new, 0.0)?;
            Ok((x_new, p_new))
        }
    }
}
