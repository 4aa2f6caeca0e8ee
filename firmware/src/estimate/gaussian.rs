//! One Gaussian of the mixture and its EKF step: prediction by augmenting the
//! displacement, update, and composition (IROS 2006 Algorithm 1, eq. 10–15).

use super::model::{
    I_RPY, I_S, MotionMat, MotionVec, NU, NX, StateMat, StateVec, compose_abs, compose_rot,
    measure, measure_rot, rpy_of,
};
use super::packed;
use super::rot::Rot;
use crate::frame::wrap_pi;
use crate::{Mat3, Vec3};
use nalgebra::SMatrix;

mod attitude;
use attitude::attitude_update;

/// How a measurement update forms the posterior covariance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CovarianceForm {
    /// `P − V Vᵀ` with `V = P Hᵀ L⁻ᵀ` (`S = L Lᵀ`): equal to the Joseph form for the
    /// optimal gain and the cheaper one, but the subtraction can lose digits in `f32`.
    Short,
    /// Joseph's `(I−KH) P (I−KH)ᵀ + K R Kᵀ`: a sum of PSD terms, the fallback.
    Joseph,
}

/// Floats in a packed 10×10 covariance.
pub(crate) const NP: usize = NX * (NX + 1) / 2;

/// One stored Gaussian: mean, packed covariance and log-weight.
///
/// Size: 10 + 55 + 1 floats = 264 bytes (see `component_size` test).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Component {
    /// Mean of the state.
    pub x: StateVec,
    /// Upper triangle of the state covariance.
    pub cov: [f32; NP],
    /// Natural log of the weight (normalized so the weights sum to 1).
    pub log_w: f32,
}

impl Component {
    /// A component from a mean, a full covariance (symmetrized) and a log-weight.
    pub fn new(x: StateVec, p: &StateMat, log_w: f32) -> Self {
        Self {
            x,
            cov: packed::pack(p),
            log_w,
        }
    }

    /// The full covariance.
    pub fn p(&self) -> StateMat {
        packed::unpack(&self.cov)
    }

    /// Element `(i, j)` of the covariance.
    pub fn p_at(&self, i: usize, j: usize) -> f32 {
        packed::get(&self.cov, NX, i, j)
    }

    /// The 3×3 covariance block starting at state index `k`.
    pub fn block3(&self, k: usize) -> Mat3 {
        Mat3::from_fn(|i, j| self.p_at(k + i, k + j))
    }
}

/// A matrix that should have been positive definite was not.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct NotPositiveDefinite;

/// Lower Cholesky factor `L` of a symmetric 3×3 matrix, `S = L Lᵀ`.
pub(crate) fn cholesky3(s: &Mat3) -> Result<Mat3, NotPositiveDefinite> {
    let mut l = Mat3::zeros();
    for j in 0..3 {
        let mut d = s[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        // `!(d > 0)` also catches NaN.
        if (d.is_nan() || d <= 0.0) || !d.is_finite() {
            return Err(NotPositiveDefinite);
        }
        let ljj = libm::sqrtf(d);
        l[(j, j)] = ljj;
        for i in (j + 1)..3 {
            let mut v = s[(i, j)];
            for k in 0..j {
                v -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = v / ljj;
        }
    }
    Ok(l)
}

/// Inverse of a lower-triangular 3×3 matrix with a positive diagonal.
pub(crate) fn lower_inverse3(l: &Mat3) -> Mat3 {
    let (a, b, c) = (l[(0, 0)], l[(1, 1)], l[(2, 2)]);
    let (d, e, f) = (l[(1, 0)], l[(2, 0)], l[(2, 1)]);
    let mut m = Mat3::zeros();
    m[(0, 0)] = 1.0 / a;
    m[(1, 1)] = 1.0 / b;
    m[(2, 2)] = 1.0 / c;
    m[(1, 0)] = -d / (a * b);
    m[(2, 1)] = -f / (b * c);
    m[(2, 0)] = (d * f - b * e) / (a * b * c);
    m
}

/// Squared Mahalanobis distance `vᵀ S⁻¹ v` from the Cholesky factor's inverse.
fn mahalanobis2(l_inv: &Mat3, v: &Vec3) -> f32 {
    (l_inv * v).norm_squared()
}

/// What the update saw for one component.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Innovation {
    /// Squared Mahalanobis distance of the innovation with the chosen sign.
    pub d2: f32,
    /// Log-likelihood of the pulse (both signs, up to a constant common to all
    /// components): IROS eq. 17 in the log domain.
    pub log_lik: f32,
    /// Whether the pulse was used with its sign flipped.
    pub flipped: bool,
}

/// Why a component could not be stepped (it is then dropped from the mixture).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ComponentFailure {
    /// The dipole model could not be evaluated (transmitter inside the receiver).
    Model,
    /// `S` was not positive definite.
    NotPositiveDefinite,
    /// The result was not finite.
    NonFinite,
}

/// What every component's step shares within one pulse: the displacement, its
/// covariance and rotation `R(ΔΨ)` (evaluated once per pulse), and the pulse.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StepInput {
    /// Displacement `u = [Δp; ΔΨ]`.
    pub u: MotionVec,
    /// Its covariance `Q`.
    pub q: MotionMat,
    /// `R(ΔΨ)` and its partials at `u`.
    rb: Rot,
    /// Pulse (µA/m in `R_k`).
    pub z: Vec3,
    /// Measurement noise variance per axis (ICRA eq. 10), in (µA/m)².
    pub r_var: f32,
    /// Absolute (unscaled) translation in `R_{k-1}` (m), added after the scale.
    pub a: Vec3,
    /// Its covariance (m²), or `None` when the pulse has no absolute part (the common
    /// case: then the step costs nothing extra).
    pub qa: Option<Mat3>,
    /// Mean reversion `(ρ, q)` of the scale over the interval (`SogConfig::scale_tau_s`),
    /// applied to each component before the step; `None` for a constant scale.
    pub scale_rev: Option<(f32, f32)>,
    /// The pulse's sign is known (`SogConfig::sign_ambiguous` false): only `+z` is tried.
    pub signed: bool,
}

impl StepInput {
    /// The shared inputs of one pulse.
    pub fn new(u: &MotionVec, q: &MotionMat, z: &Vec3, r_var: f32) -> Self {
        Self {
            u: *u,
            q: *q,
            rb: Rot::new(&Vec3::new(u[3], u[4], u[5])),
            z: *z,
            r_var,
            a: Vec3::zeros(),
            qa: None,
            scale_rev: None,
            signed: false,
        }
    }

    /// The same with an absolute (unscaled) translation `a` in `R_{k-1}` (m) of
    /// covariance `qa` (m²).
    pub fn with_absolute(mut self, a: &Vec3, qa: &Mat3) -> Self {
        self.a = *a;
        self.qa = Some(*qa);
        self
    }

    /// The component's prior with the scale's mean reversion applied (a first-order
    /// Gauss–Markov step of `s − 1`: `F_ss = ρ`, `P_ss += q`); the identity when
    /// `scale_rev` is `None`.
    pub fn revert_scale(&self, x: &mut StateVec, p: &mut StateMat) {
        if let Some((rho, q)) = self.scale_rev {
            x[I_S] = 1.0 + rho * (x[I_S] - 1.0);
            for i in 0..NX {
                p[(i, I_S)] *= rho;
                p[(I_S, i)] *= rho;
            }
            p[(I_S, I_S)] += q;
        }
    }

    /// The displacement covariance seen by the component `x`. `∂p'/∂a = ∂p'/∂Δp / s`,
    /// so the absolute part's noise enters exactly (to first order) as `Q_a / s²` on the
    /// dead-reckoned translation: one 3×3 add per component, no extra Jacobian.
    fn q_for(&self, x: &StateVec) -> MotionMat {
        let mut q = self.q;
        if let Some(qa) = &self.qa {
            let s2 = (x[I_S] * x[I_S]).max(1e-2);
            let mut t = q.fixed_view_mut::<3, 3>(0, 0);
            t += qa / s2;
        }
        q
    }
}

/// Smallest conditional variance, as a fraction of the variance, that
/// [`well_conditioned`] accepts from the short-form covariance updates.
const MIN_VARIANCE_RATIO: f32 = 1e-6;

/// Whether a symmetric matrix is positive definite with margin: every pivot of its
/// `LDLᵀ` factorization (the variance of a state given the ones before it) is at least
/// [`MIN_VARIANCE_RATIO`] of that state's variance (false on NaN). ≈ 200 multiply-adds.
fn well_conditioned(p: &StateMat) -> bool {
    // Right-looking LDLᵀ on a copy, lower triangle only: column j is eliminated from
    // the trailing matrix as soon as its pivot is known (165 multiply-adds in all).
    let mut a = *p;
    for j in 0..NX {
        let dj = a[(j, j)];
        if dj.is_nan() || dj <= MIN_VARIANCE_RATIO * p[(j, j)] {
            return false;
        }
        let inv = 1.0 / dj;
        for i in (j + 1)..NX {
            let l = a[(i, j)] * inv;
            for k in i..NX {
                a[(k, i)] -= l * a[(k, j)];
            }
        }
    }
    true
}

/// One component's whole step: [`step_gaussian`] then, when `attitude` is given,
/// [`attitude_update`] with `(Ψ measured, its covariance)`. Both use the
/// [`CovarianceForm::Short`] update `P − V Vᵀ`; when the result is not
/// [`well_conditioned`] (the subtraction lost too many digits in `f32`), the step is
/// redone in the [`CovarianceForm::Joseph`] form ([`step_gaussian_joseph_at`]), a sum of
/// PSD terms.
pub(crate) fn step_component(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    step_component_iterated(inp, x, p, attitude, 0)
}

/// [`step_component`] with up to `iters` iterated-EKF re-linearizations of the pulse
/// update ([`step_gaussian_iterated`]); the Joseph fallback uses the same
/// linearization point.
// Inlined into the mixture's loop: the plain path must cost what it did before (an
// extra call layer copies the ≈ 450-byte result once more per component).
#[inline(always)]
pub(crate) fn step_component_iterated(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
    iters: u8,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    if iters == 0 {
        step_component_plain(inp, x, p, attitude)
    } else {
        step_component_iekf(inp, x, p, attitude, iters)
    }
}

/// [`step_component_iterated`] with at least one re-linearization allowed, kept out of
/// line so the plain path of the other components compiles as before.
#[inline(never)]
fn step_component_iekf(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
    iters: u8,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    let mut lin = None;
    if let Ok((x1, p1, inn, lp)) = step_gaussian_iterated(inp, x, p, iters) {
        if let Ok(out) = then_attitude((x1, p1, inn), attitude, CovarianceForm::Short)
            && well_conditioned(&out.1)
        {
            return Ok(out);
        }
        lin = Some(lp);
    }
    step_component_joseph(inp, x, p, attitude, lin.as_ref()).and_then(positive_variances)
}

/// [`step_component`] with the plain EKF update: the hot path of every component the
/// iterated update leaves out, kept as lean as before the iteration existed.
#[inline(always)]
fn step_component_plain(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    if let Ok(out) = step_gaussian(inp, x, p)
        && let Ok(out) = then_attitude(out, attitude, CovarianceForm::Short)
        && well_conditioned(&out.1)
    {
        return Ok(out);
    }
    step_component_joseph(inp, x, p, attitude, None).and_then(positive_variances)
}

/// Refuses a component whose covariance lost a variance's sign to `f32` rounding (a
/// prior far wider than the attitude measurement, e.g. σ of radians against µrad): even
/// the Joseph form cannot repair a prior that was already not PSD.
fn positive_variances<T>(
    out: (StateVec, StateMat, T),
) -> Result<(StateVec, StateMat, T), ComponentFailure> {
    // ≥ 0, not > 0: the known-trajectory mode pins the attitude with zero variance.
    if (0..NX).all(|i| out.1[(i, i)] >= 0.0) {
        Ok(out)
    } else {
        Err(ComponentFailure::NotPositiveDefinite)
    }
}

/// [`step_component`] in the Joseph form (the rare fallback, kept out of line).
#[cold]
#[inline(never)]
fn step_component_joseph(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
    lin: Option<&LinPoint>,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    let q = inp.q_for(x);
    let out =
        step_gaussian_joseph_at(x, p, &inp.u, &inp.a, &q, &inp.z, inp.r_var, lin, inp.signed)?;
    then_attitude(out, attitude, CovarianceForm::Joseph)
}

/// A pulse update's `(x, P, innovation)` followed, when `attitude` is given, by the
/// attitude update in the same covariance `form`.
fn then_attitude<T>(
    (x1, p1, inn): (StateVec, StateMat, T),
    attitude: Option<(&Vec3, &Mat3)>,
    form: CovarianceForm,
) -> Result<(StateVec, StateMat, T), ComponentFailure> {
    match attitude {
        Some((z, r)) => attitude_update(&x1, &p1, z, r, form).map(|(x2, p2)| (x2, p2, inn)),
        None => Ok((x1, p1, inn)),
    }
}

/// The outlier gate's statistic for one component: the squared Mahalanobis distance of
/// the pulse's innovation at the prior augmented mean (IROS eq. 12–14), with the better
/// of the two signs. It is [`Innovation::d2`] of [`step_gaussian`] without the update
/// and composition (≈ a third of the step's cost), so the gate can be decided before
/// any component is touched.
pub(crate) fn gate_d2(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
) -> Result<f32, ComponentFailure> {
    let q = inp.q_for(x);
    let (prior_x, prior_j) = compose_rot(x, &inp.u, &inp.a, &Rot::new(&rpy_of(x)), &inp.rb);
    let meas =
        measure_rot(&prior_x, &Rot::new(&rpy_of(&prior_x))).map_err(|_| ComponentFailure::Model)?;
    let (ha, hb) = prior_j.chain(&meas.jac);
    // S = H* P* H*ᵀ + R (eq. 13), P* = diag(P, Q).
    let mut s = ha * (p * ha.transpose()) + hb * (q * hb.transpose());
    s = (s + s.transpose()) * 0.5;
    for i in 0..3 {
        s[(i, i)] += inp.r_var;
    }
    let l = cholesky3(&s).map_err(|_| ComponentFailure::NotPositiveDefinite)?;
    let l_inv = lower_inverse3(&l);
    let d2_pos = mahalanobis2(&l_inv, &(inp.z - meas.h));
    let d2 = if inp.signed {
        d2_pos
    } else {
        d2_pos.min(mahalanobis2(&l_inv, &(-inp.z - meas.h)))
    };
    if d2.is_nan() {
        return Err(ComponentFailure::NonFinite);
    }
    Ok(d2)
}

/// Prediction and composition of one Gaussian without a pulse update (IROS eq. 10–11
/// and 15 with `K = 0`): `x_k = f(x, u)`, `P_k = F P* Fᵀ`, then the IMU attitude update
/// as in [`step_component`]. Used for a pulse the outlier gate withheld: the receiver
/// still moved, so the robocentric state must follow it; only the pulse is not used.
pub(crate) fn predict_component(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    attitude: Option<(&Vec3, &Mat3)>,
) -> Result<(StateVec, StateMat), ComponentFailure> {
    let q = inp.q_for(x);
    let (x1, j) = compose_rot(x, &inp.u, &inp.a, &Rot::new(&rpy_of(x)), &inp.rb);
    let fp = j.apply_fx(p).transpose();
    let fq = j.apply_fu(&q).transpose();
    let mut p1 = j.apply_fx(&fp) + j.apply_fu(&fq);
    p1 = (p1 + p1.transpose()) * 0.5;
    let x1 = finish(x1, &p1, 0.0)?;
    let out = match attitude {
        None => (x1, p1),
        Some((z, r)) => match attitude_update(&x1, &p1, z, r, CovarianceForm::Short) {
            Ok(out) if well_conditioned(&out.1) => out,
            _ => attitude_update(&x1, &p1, z, r, CovarianceForm::Joseph)?,
        },
    };
    positive_variances((out.0, out.1, ())).map(|(x, p, ())| (x, p))
}

/// `a − v vᵀ`, symmetric by construction (upper triangle computed, then mirrored).
fn sub_outer<const C: usize>(a: &StateMat, v: &SMatrix<f32, NX, C>) -> StateMat {
    let mut out = *a;
    for j in 0..NX {
        for i in 0..=j {
            let d: f32 = (0..C).map(|k| v[(i, k)] * v[(j, k)]).sum();
            let e = 0.5 * (a[(i, j)] + a[(j, i)]) - d;
            out[(i, j)] = e;
            out[(j, i)] = e;
        }
    }
    out
}

/// Sign choice and log-likelihood of a pulse (see [`step_gaussian`]).
fn innovation(l: &Mat3, l_inv: &Mat3, z: &Vec3, h: &Vec3, signed: bool) -> (Vec3, Innovation) {
    let nu_pos = z - h;
    let nu_neg = -z - h;
    let d2_pos = mahalanobis2(l_inv, &nu_pos);
    // A known sign: `−z` is no hypothesis (an infinite distance drops it from the sum).
    let d2_neg = if signed {
        f32::INFINITY
    } else {
        mahalanobis2(l_inv, &nu_neg)
    };
    let (nu, d2, flipped) = if d2_neg < d2_pos {
        (nu_neg, d2_neg, true)
    } else {
        (nu_pos, d2_pos, false)
    };
    let half_log_det = libm::logf(l[(0, 0)] * l[(1, 1)] * l[(2, 2)]);
    // log(½e^{-d+/2} + ½e^{-d−/2}) up to the constant log ½ shared by all components.
    let (lo, hi) = if d2_pos < d2_neg {
        (d2_pos, d2_neg)
    } else {
        (d2_neg, d2_pos)
    };
    let log_lik = -0.5 * lo + libm::log1pf(libm::expf(-0.5 * (hi - lo))) - half_log_det;
    (
        nu,
        Innovation {
            d2,
            log_lik,
            flipped,
        },
    )
}

/// Wraps the orientation of a state to (−π, π] and checks that everything is finite.
fn finish(mut x: StateVec, p: &StateMat, log_lik: f32) -> Result<StateVec, ComponentFailure> {
    for i in 0..3 {
        x[I_RPY + i] = wrap_pi(x[I_RPY + i]);
    }
    // A NaN or an infinity anywhere makes the sum non-finite (contiguous slices: the
    // element iterators cost ≈ 10× more on the target).
    let sum: f32 = x.as_slice().iter().sum::<f32>() + p.as_slice().iter().sum::<f32>();
    if (sum + log_lik).is_finite() {
        Ok(x)
    } else {
        Err(ComponentFailure::NonFinite)
    }
}

/// Predict, update and compose one Gaussian (IROS Algorithm 1, one loop iteration).
///
/// - Prediction (eq. 10–11): the state is augmented with the displacement `u`,
///   `P* = diag(P, Q)` (the displacement is independent of the state, `C_k = 0`).
/// - Estimation (eq. 12–14): `h*(x*) = h(f(x, u))`, so `H* = H·[F_x F_u]` at the prior.
///   The pulse sign is unknown: the innovation is evaluated for `+z` and `−z` and the
///   update uses the sign with the smaller Mahalanobis distance. The likelihood used for
///   the weight is the sum over both signs (each with probability ½), so a component
///   far from the transmitter, where both signs fit equally, is not favoured.
/// - Composition (eq. 15) at the updated augmented mean `F = [F_x F_u]`:
///   `P_k = F (P* − K S Kᵀ) Fᵀ = F P* Fᵀ − (F V)(F V)ᵀ` with `V = P* H*ᵀ L⁻ᵀ`
///   (`S = L Lᵀ`, so `K S Kᵀ = V Vᵀ`, and `K = V L⁻¹`). `F` is sparse (only `Ψ` and
///   `p_T` change, see [`CompositionJac`]), so `F P* Fᵀ` costs ≈ 700 multiply-adds
///   instead of the 16×16 products. This equals the Joseph form
///   `F [(I−KH*) P* (I−KH*)ᵀ + K R Kᵀ] Fᵀ` for the optimal gain; [`step_component`]
///   falls back to that form when the subtraction lost too many digits.
pub(crate) fn step_gaussian(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    let u = &inp.u;
    let q_abs;
    let q = if inp.qa.is_some() {
        q_abs = inp.q_for(x);
        &q_abs
    } else {
        &inp.q
    };
    // Linearization point of the measurement: the prior augmented mean (eq. 14).
    let (prior_x, prior_j) = compose_rot(x, u, &inp.a, &Rot::new(&rpy_of(x)), &inp.rb);
    let meas =
        measure_rot(&prior_x, &Rot::new(&rpy_of(&prior_x))).map_err(|_| ComponentFailure::Model)?;
    // H* = J [F_x F_u] (eq. 14), through the structure of F.
    let (ha, hb) = prior_j.chain(&meas.jac);
    let wa: SMatrix<f32, NX, 3> = p * ha.transpose();
    let wb: SMatrix<f32, NU, 3> = q * hb.transpose();
    let mut s = ha * wa + hb * wb;
    s = (s + s.transpose()) * 0.5;
    for i in 0..3 {
        s[(i, i)] += inp.r_var;
    }
    let l = cholesky3(&s).map_err(|_| ComponentFailure::NotPositiveDefinite)?;
    let l_inv = lower_inverse3(&l);
    let (nu, inn) = innovation(&l, &l_inv, &inp.z, &meas.h, inp.signed);

    // EKF update of the augmented state (Algorithm 1): V = W L⁻ᵀ, K = V L⁻¹.
    let va: SMatrix<f32, NX, 3> = wa * l_inv.transpose();
    let vb: SMatrix<f32, NU, 3> = wb * l_inv.transpose();
    let x_post = x + va * (l_inv * nu);
    let u_post = u + vb * (l_inv * nu);

    // Composition at the updated augmented mean (eq. 15).
    let ra = Rot::new(&rpy_of(&x_post));
    let rb = Rot::new(&Vec3::new(u_post[3], u_post[4], u_post[5]));
    let (x_new, post_j) = compose_rot(&x_post, &u_post, &inp.a, &ra, &rb);
    // F P* Fᵀ = F [F_x P, F_u Q]ᵀ (P*, hence the product, symmetric).
    let fp = post_j.apply_fx(p).transpose();
    let fq = post_j.apply_fu(q).transpose();
    let fpf = post_j.apply_fx(&fp) + post_j.apply_fu(&fq);
    let fv = post_j.apply_fx(&va) + post_j.apply_fu(&vb);
    let p_new = sub_outer(&fpf, &fv);
    let x_new = finish(x_new, &p_new, inn.log_lik)?;
    Ok((x_new, p_new, inn))
}

/// Settings of the iterated pulse update (see [`step_gaussian_iterated`]).
///
/// Both thresholds compare a change of the predicted pulse with the measurement noise
/// `R = r_var·I` (ICRA eq. 10), not with `S`: after an informative pulse the posterior
/// spread of `h` is ≈ `R`, so a change `δh` of the linearized model moves the estimate
/// by ≈ `‖δh‖²/r_var` in units of the posterior covariance, whatever the range or the
/// transmitter's moment (`S ≫ R` far from the prior's 1σ would hide it).
pub(crate) mod iekf {
    /// A re-linearization is skipped when the linearization error of the first update,
    /// `‖h(x₁) − h(x̂) − H (x₁ − x̂)‖² / r_var`, is below this: re-linearizing would move
    /// the mean by less than ≈ 0.1 posterior σ.
    pub const NONLINEAR_D2: f32 = 0.01;
    /// The iterations stop when the re-linearized model's prediction at the prior mean
    /// moved by less than this (`‖δh‖² / r_var`): the next Gauss–Newton step would be
    /// below ≈ 0.1 posterior σ.
    pub const CONVERGED_D2: f32 = 0.01;
}

/// The measurement model linearized at an augmented point `(x_i, u_i)`, with what the
/// update of the prior `(x̂, û)` needs from it.
struct Linear {
    /// The linearized model's prediction at the prior mean,
    /// `h(x_i*) + H_i (x̂* − x_i*)` (= `h(x̂*)` at the prior).
    h: Vec3,
    /// `H_i` with respect to the state.
    ha: SMatrix<f32, 3, NX>,
    /// `H_i` with respect to the displacement.
    hb: SMatrix<f32, 3, NU>,
    /// `V = P* H_iᵀ L⁻ᵀ`, state rows.
    va: SMatrix<f32, NX, 3>,
    /// `V`, displacement rows.
    vb: SMatrix<f32, NU, 3>,
    /// Lower Cholesky factor of `S_i = H_i P* H_iᵀ + R`.
    l: Mat3,
    /// Its inverse.
    l_inv: Mat3,
}

/// `h*` (IROS eq. 14) at the augmented point `(xl, ul)` (`rb = R(ΔΨ_l)`) and its
/// Jacobian `H* = J [F_x F_u]`, through the structure of `F`.
fn measure_aug(
    inp: &StepInput,
    xl: &StateVec,
    ul: &MotionVec,
    rb: &Rot,
) -> Result<(Vec3, SMatrix<f32, 3, NX>, SMatrix<f32, 3, NU>), ComponentFailure> {
    let (prior_x, prior_j) = compose_rot(xl, ul, &inp.a, &Rot::new(&rpy_of(xl)), rb);
    let meas =
        measure_rot(&prior_x, &Rot::new(&rpy_of(&prior_x))).map_err(|_| ComponentFailure::Model)?;
    let (ha, hb) = prior_j.chain(&meas.jac);
    Ok((meas.h, ha, hb))
}

/// The update quantities of a linearization `(h, H*)`: `S = H* P* H*ᵀ + R` (eq. 13), its
/// Cholesky factor and `V = P* H*ᵀ L⁻ᵀ`.
fn factor(
    inp: &StepInput,
    p: &StateMat,
    q: &MotionMat,
    h: Vec3,
    ha: SMatrix<f32, 3, NX>,
    hb: SMatrix<f32, 3, NU>,
) -> Result<Linear, ComponentFailure> {
    let wa: SMatrix<f32, NX, 3> = p * ha.transpose();
    let wb: SMatrix<f32, NU, 3> = q * hb.transpose();
    let mut s = ha * wa + hb * wb;
    s = (s + s.transpose()) * 0.5;
    for i in 0..3 {
        s[(i, i)] += inp.r_var;
    }
    let l = cholesky3(&s).map_err(|_| ComponentFailure::NotPositiveDefinite)?;
    let l_inv = lower_inverse3(&l);
    Ok(Linear {
        h,
        ha,
        hb,
        va: wa * l_inv.transpose(),
        vb: wb * l_inv.transpose(),
        l,
        l_inv,
    })
}

/// `a − b` with the orientation entries wrapped to (−π, π].
fn state_diff(a: &StateVec, b: &StateVec) -> StateVec {
    let mut d = a - b;
    for i in 0..3 {
        d[I_RPY + i] = wrap_pi(d[I_RPY + i]);
    }
    d
}

/// The iterated-EKF (Gauss–Newton) pulse update of the augmented state, up to `iters`
/// re-linearizations: the augmented mean `(x, u)` after the update and the
/// linearization it used.
///
/// The first pass is the EKF update at the prior (IROS eq. 12–14), which also picks the
/// pulse's sign. Each further pass re-linearizes `h*` at the current estimate `x_i` and
/// sets `x_{i+1} = x̂ + K_i (z − h(x_i) − H_i (x̂ − x_i))` (Bell & Cathey 1993, eq. 9 of
/// the iterated filter: Gauss–Newton on the MAP cost
/// `‖x − x̂‖²_{P*} + ‖z − h(x)‖²_R`). At 2–5 m the field ∝ r⁻³ changes by tens of % over
/// a component's 1σ, so the update linearized at the prior mean is biased and
/// overconfident; iterating moves the linearization to the posterior mode. A pass is
/// skipped when the first update's linearization error is below
/// [`iekf::NONLINEAR_D2`], and the iteration stops when the linearized model moved by
/// less than [`iekf::CONVERGED_D2`]. A re-linearization that fails (transmitter inside
/// the receiver, `S` not PD) keeps the last good one: the iteration can only refine
/// the EKF update, never lose the component.
#[allow(clippy::type_complexity)]
fn iterate_update(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    q: &MotionMat,
    iters: u8,
) -> Result<(StateVec, MotionVec, Linear, Innovation, LinPoint), ComponentFailure> {
    let u = &inp.u;
    let (h0, ha0, hb0) = measure_aug(inp, x, u, &inp.rb)?;
    let mut lin = factor(inp, p, q, h0, ha0, hb0)?;
    let (mut nu, mut inn) = innovation(&lin.l, &lin.l_inv, &inp.z, &lin.h, inp.signed);
    let zs = if inn.flipped { -inp.z } else { inp.z };
    let mut x_post = x + lin.va * (lin.l_inv * nu);
    let mut u_post = u + lin.vb * (lin.l_inv * nu);
    let (mut lx, mut lu) = (*x, *u);
    for i in 0..iters {
        let dx = state_diff(x, &x_post);
        let du = u - u_post;
        let rb = Rot::new(&Vec3::new(u_post[3], u_post[4], u_post[5]));
        let Ok((h_at, ha, hb)) = measure_aug(inp, &x_post, &u_post, &rb) else {
            break;
        };
        if i == 0 {
            // Linearization error of the first update: h(x₁) vs h(x̂) + H₀ (x₁ − x̂).
            let e = h_at - (lin.h - lin.ha * dx - lin.hb * du);
            if e.norm_squared() < iekf::NONLINEAR_D2 * inp.r_var {
                break;
            }
        }
        // The re-linearized model's prediction at the prior mean.
        let h = h_at + ha * dx + hb * du;
        let Ok(next) = factor(inp, p, q, h, ha, hb) else {
            break;
        };
        let moved = (next.h - lin.h).norm_squared() < iekf::CONVERGED_D2 * inp.r_var;
        (lx, lu) = (x_post, u_post);
        lin = next;
        nu = zs - lin.h;
        x_post = x + lin.va * (lin.l_inv * nu);
        u_post = u + lin.vb * (lin.l_inv * nu);
        inn = final_innovation(&lin.l, &lin.l_inv, &zs, &lin.h, inn.flipped, inp.signed);
        if moved {
            break;
        }
    }
    let lp = LinPoint {
        x: lx,
        u: lu,
        flipped: inn.flipped,
    };
    Ok((x_post, u_post, lin, inn, lp))
}

/// [`step_gaussian`] with up to `iters` iterated-EKF re-linearizations of the pulse
/// update ([`iterate_update`]); also returns the final linearization point `(x*, u)`
/// and the sign used, for the Joseph-form fallback.
///
/// - Prediction (eq. 10–11): the state is augmented with the displacement `u`,
///   `P* = diag(P, Q)` (the displacement is independent of the state, `C_k = 0`).
/// - Estimation (eq. 12–14): `h*(x*) = h(f(x, u))`, so `H* = H·[F_x F_u]` at the
///   linearization point. The pulse sign is unknown: the innovation is evaluated for
///   `+z` and `−z` at the prior and the update uses the sign with the smaller
///   Mahalanobis distance (kept through the iterations). The likelihood used for the
///   weight is the sum over both signs (each with probability ½), so a component far
///   from the transmitter, where both signs fit equally, is not favoured. It is
///   evaluated with the final linearization, `ν = ±z − h(x_N) − H_N (x̂ − x_N)` and
///   `S_N`: the exact marginal likelihood of the model linearized at the posterior
///   mode (the Laplace approximation of `p(z)`), which reduces to the EKF's
///   `N(z − h(x̂), S)` when `iters = 0` or `h` is linear.
/// - Composition (eq. 15) at the updated augmented mean `F = [F_x F_u]`:
///   `P_k = F (P* − K S Kᵀ) Fᵀ = F P* Fᵀ − (F V)(F V)ᵀ` with `V = P* H*ᵀ L⁻ᵀ`
///   (`S = L Lᵀ`, so `K S Kᵀ = V Vᵀ`, and `K = V L⁻¹`), `H*` of the last
///   linearization. `F` is sparse (only `Ψ` and `p_T` change, see
///   [`CompositionJac`]), so `F P* Fᵀ` costs ≈ 700 multiply-adds instead of the
///   16×16 products. This equals the Joseph form
///   `F [(I−KH*) P* (I−KH*)ᵀ + K R Kᵀ] Fᵀ` for the optimal gain; [`step_component`]
///   falls back to that form when the subtraction lost too many digits.
#[allow(clippy::type_complexity)]
pub(crate) fn step_gaussian_iterated(
    inp: &StepInput,
    x: &StateVec,
    p: &StateMat,
    iters: u8,
) -> Result<(StateVec, StateMat, Innovation, LinPoint), ComponentFailure> {
    let q_abs;
    let q = if inp.qa.is_some() {
        q_abs = inp.q_for(x);
        &q_abs
    } else {
        &inp.q
    };
    let (x_post, u_post, lin, inn, lp) = iterate_update(inp, x, p, q, iters)?;
    let (va, vb) = (lin.va, lin.vb);

    // Composition at the updated augmented mean (eq. 15).
    let ra = Rot::new(&rpy_of(&x_post));
    let rb = Rot::new(&Vec3::new(u_post[3], u_post[4], u_post[5]));
    let (x_new, post_j) = compose_rot(&x_post, &u_post, &inp.a, &ra, &rb);
    // F P* Fᵀ = F [F_x P, F_u Q]ᵀ (P*, hence the product, symmetric).
    let fp = post_j.apply_fx(p).transpose();
    let fq = post_j.apply_fu(q).transpose();
    let fpf = post_j.apply_fx(&fp) + post_j.apply_fu(&fq);
    let fv = post_j.apply_fx(&va) + post_j.apply_fu(&vb);
    let p_new = sub_outer(&fpf, &fv);
    let x_new = finish(x_new, &p_new, inn.log_lik)?;
    Ok((x_new, p_new, inn, lp))
}

/// Where the (iterated) update last linearized the measurement, and the pulse sign it
/// used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LinPoint {
    /// State part of the augmented linearization point.
    pub x: StateVec,
    /// Displacement part.
    pub u: MotionVec,
    /// Whether the pulse was used with its sign flipped.
    pub flipped: bool,
}

/// [`Innovation`] of the final linearization: `d2` of the sign used (`zs`), the
/// two-sign log-likelihood (IROS eq. 17) around the linearized prediction `h`.
fn final_innovation(
    l: &Mat3,
    l_inv: &Mat3,
    zs: &Vec3,
    h: &Vec3,
    flipped: bool,
    signed: bool,
) -> Innovation {
    let (_, both) = innovation(l, l_inv, zs, h, signed);
    Innovation {
        d2: mahalanobis2(l_inv, &(zs - h)),
        log_lik: both.log_lik,
        flipped,
    }
}

/// [`step_gaussian`] in the Joseph form, with dense Jacobians (the fallback, and the
/// reference the short form is tested against):
/// `P_k = F (I−KH*) P* (I−KH*)ᵀ Fᵀ + F K R Kᵀ Fᵀ`, a sum of PSD terms. `a` is the
/// absolute translation; `q` already carries its noise (see [`StepInput`]).
#[cfg(test)]
pub(crate) fn step_gaussian_joseph(
    x: &StateVec,
    p: &StateMat,
    u: &MotionVec,
    a: &Vec3,
    q: &MotionMat,
    z: &Vec3,
    r_var: f32,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    step_gaussian_joseph_at(x, p, u, a, q, z, r_var, None, false)
}

/// [`step_gaussian_joseph`] with the measurement linearized at `lin` (the iterated
/// update's last point, see [`step_gaussian_iterated`]) instead of the prior:
/// `x⁺ = x̂ + K (±z − h(x_l) − H (x̂ − x_l))`, `K`, `H` at `x_l`, with `lin`'s sign.
#[allow(clippy::too_many_arguments)]
pub(crate) fn step_gaussian_joseph_at(
    x: &StateVec,
    p: &StateMat,
    u: &MotionVec,
    a: &Vec3,
    q: &MotionMat,
    z: &Vec3,
    r_var: f32,
    lin: Option<&LinPoint>,
    signed: bool,
) -> Result<(StateVec, StateMat, Innovation), ComponentFailure> {
    let (lx, lu) = lin.map_or((x, u), |l| (&l.x, &l.u));
    let prior = compose_abs(lx, lu, a);
    let meas = measure(&prior.x).map_err(|_| ComponentFailure::Model)?;
    let ha: SMatrix<f32, 3, NX> = meas.jac * prior.fx;
    let hb: SMatrix<f32, 3, NU> = meas.jac * prior.fu;
    let wa: SMatrix<f32, NX, 3> = p * ha.transpose();
    let wb: SMatrix<f32, NU, 3> = q * hb.transpose();
    let mut s = ha * wa + hb * wb;
    s = (s + s.transpose()) * 0.5;
    for i in 0..3 {
        s[(i, i)] += r_var;
    }
    let l = cholesky3(&s).map_err(|_| ComponentFailure::NotPositiveDefinite)?;
    let l_inv = lower_inverse3(&l);
    let s_inv = l_inv.transpose() * l_inv;
    let (nu, inn) = match lin {
        None => innovation(&l, &l_inv, z, &meas.h, signed),
        Some(lp) => {
            let h = meas.h + ha * state_diff(x, lx) + hb * (u - lu);
            let zs = if lp.flipped { -z } else { *z };
            (
                zs - h,
                final_innovation(&l, &l_inv, &zs, &h, lp.flipped, signed),
            )
        }
    };

    let ka: SMatrix<f32, NX, 3> = wa * s_inv;
    let kb: SMatrix<f32, NU, 3> = wb * s_inv;
    let x_post = x + ka * nu;
    let u_post = u + kb * nu;

    let post = compose_abs(&x_post, &u_post, a);
    let b: SMatrix<f32, NX, 3> = post.fx * ka + post.fu * kb;
    let a1: StateMat = post.fx - b * ha;
    let a2: SMatrix<f32, NX, NU> = post.fu - b * hb;
    let mut p_new = a1 * p * a1.transpose() + a2 * q * a2.transpose();
    p_new += b * b.transpose() * r_var;
    p_new = (p_new + p_new.transpose()) * 0.5;
    let x_new = finish(post.x, &p_new, inn.log_lik)?;
    Ok((x_new, p_new, inn))
}

#[cfg(test)]
#[path = "gaussian_tests.rs"]
mod tests;
