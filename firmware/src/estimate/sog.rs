//! The robocentric Sum-of-Gaussians filter (IROS 2006 Algorithm 1) with fixed capacity.
//!
//! # Memory
//! Each Gaussian is stored as a 10-float mean, a packed 10×10 covariance (55 floats) and
//! a log-weight: **264 bytes per component**. [`SOG_CAPACITY`] = 240 components take
//! 63 360 bytes, so the whole filter ([`DefaultSog`], ≈ 63.5 KB with its bookkeeping) fits the
//! STM32F405's 64 KB CCM on its own and leaves the 128 KB SRAM to the rest of the
//! firmware. Initialization fills `init_fill` (60 %) of the capacity; the rest is room
//! for splitting components where the field is too nonlinear.
//!
//! # Per step (IROS Algorithm 1)
//! For every Gaussian: predict by augmenting the displacement, EKF update with the
//! pulse (sign chosen per component), compose into `G_k`
//! (`gaussian::step_gaussian`), then (robocentric mode, beyond the paper) a
//! linear update of the orientation with the IMU's absolute attitude of `R_k`
//! (`gaussian::attitude_update`); then normalize the weights in the log domain
//! (eq. 17), check divergence, prune, merge near-duplicates and split where needed
//! (heaviest components first).

use super::gaussian::{Component, StepInput, gate_d2, predict_component, step_component_iterated};
use super::init::initialize;
use super::mixture::{merge, moment_mean, normalize, position_moments, prune, split};
use super::model::{FIELD_SCALE, I_P, I_RPY, I_S, MOMENT_SCALE, MotionMat, MotionVec};
use super::{
    Attitude, Displacement, EstimateError, Estimator, Mode, Pulse, SogConfig, StepOutcome,
    StepReport, VictimEstimate, check_covariance,
};
use crate::frame::Rpy;
use crate::{Mat3, Vec3};
use heapless::Vec;

/// Largest scale variance of a component whose pulse update may be iterated: that of a
/// calibrated step length (`SCALE_SIGMA_CALIBRATED`², with 0.1 % for rounding).
const IEKF_MAX_SCALE_VAR: f32 =
    super::SCALE_SIGMA_CALIBRATED * super::SCALE_SIGMA_CALIBRATED * 1.001;

/// Capacity of the default filter: 240 components × 264 bytes = 63 360 bytes, which
/// fits the STM32F405's 64 KB core-coupled RAM.
pub const SOG_CAPACITY: usize = 240;

/// Longest run of consecutive pulses the outlier gate withholds. An interferer, another
/// device or a corrupted vector gives isolated pulses between the transmitter's regular
/// ones (one every ≈ 1 s), so one pulse that fails the gate after a consistent pulse is
/// withheld. A mixture that lost the transmitter, a transmitter that moved, or a
/// mixture grown overconfident fails on every pulse: from the second failure on, the
/// pulses update the mixture as before (they are the best information there is) and
/// `divergence_pulses` consecutive failures rebuild it (IROS Algorithm 1's
/// re-initialization), which withholding them all would only delay.
const OUTLIER_RUN: u8 = 1;

/// The filter with the default capacity.
pub type DefaultSog = SogFilter<SOG_CAPACITY>;

/// Robocentric Sum-of-Gaussians filter with room for `N` Gaussians (no heap).
#[derive(Debug, Clone, PartialEq)]
pub struct SogFilter<const N: usize> {
    config: SogConfig,
    comps: Vec<Component, N>,
    initialized: bool,
    /// Consecutive pulses on which every component was inconsistent.
    inconsistent_pulses: u8,
    last_t: Option<f32>,
}

impl<const N: usize> SogFilter<N> {
    /// A filter with the given configuration, or `InvalidConfig`.
    pub fn new(config: SogConfig) -> Result<Self, EstimateError> {
        Self::check_config(&config)?;
        Ok(Self::new_checked(config))
    }

    /// Whether [`SogFilter::new`] accepts `config` at this capacity (`InvalidConfig` if
    /// not), without building the filter.
    pub fn check_config(config: &SogConfig) -> Result<(), EstimateError> {
        config.validate()?;
        if N < 8 {
            return Err(EstimateError::InvalidConfig);
        }
        Ok(())
    }

    /// [`SogFilter::new`] for a configuration [`SogFilter::check_config`] accepted:
    /// infallible, so a caller can build the filter straight into its final place
    /// (a `Result` of a ≈ 20 KB filter would be built on the stack first).
    #[inline(always)]
    pub(crate) fn new_checked(config: SogConfig) -> Self {
        Self {
            config,
            comps: Vec::new(),
            initialized: false,
            inconsistent_pulses: 0,
            last_t: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SogConfig {
        &self.config
    }

    /// The receiver's height above the snow now (m, as tracked from its measured
    /// vertical moves): the depth prior of the next (re)initialization places the victim
    /// `height + depth_min … height + depth_max` below the receiver (ICRA eq. 16's grid),
    /// so a mixture started with the receiver lowered to the snow is not a metre too
    /// deep. A non-finite or negative height is ignored.
    pub fn set_receiver_height(&mut self, height_m: f32) {
        if height_m.is_finite() && height_m >= 0.0 {
            self.config.receiver_height = height_m;
        }
    }

    /// Number of Gaussians currently in the mixture.
    pub fn len(&self) -> usize {
        self.comps.len()
    }

    /// Whether the mixture is empty (not initialized).
    pub fn is_empty(&self) -> bool {
        self.comps.is_empty()
    }

    /// Iterates over the components as `(weight, position in G_k (m), position
    /// covariance (m²))`, e.g. for plotting.
    pub fn components(&self) -> impl Iterator<Item = (f32, Vec3, crate::Mat3)> + '_ {
        self.comps.iter().map(|c| {
            (
                libm::expf(c.log_w),
                Vec3::new(c.x[3], c.x[4], c.x[5]),
                c.block3(3),
            )
        })
    }

    /// Replaces an initialized mixture by one Gaussian with mean `[Ψ (rad), p_T (m),
    /// m (A·m²), s]` and covariance `cov` (same units): the "oracle start" of the
    /// accuracy report's error budget, an EKF without any mixture approximation to
    /// compare the mixture with. `InvalidConfig` before the first initialization (the
    /// pulse clock starts there); bad values leave the state unchanged.
    pub fn reset_to_single(
        &mut self,
        mean: &nalgebra::SVector<f32, 10>,
        cov: &nalgebra::SMatrix<f32, 10, 10>,
    ) -> Result<(), EstimateError> {
        if !self.initialized {
            return Err(EstimateError::InvalidConfig);
        }
        if !mean.iter().all(|v| v.is_finite()) {
            return Err(EstimateError::NonFinite);
        }
        check_covariance(cov)?;
        // External → internal units: the moment rows and columns in mA·m².
        let mut d = super::model::StateVec::repeat(1.0);
        d.fixed_rows_mut::<3>(super::model::I_M).fill(MOMENT_SCALE);
        let x = mean.component_mul(&d);
        let p = cov.component_mul(&(d * d.transpose()));
        self.comps.clear();
        let _ = self.comps.push(Component::new(x, &p, 0.0));
        self.inconsistent_pulses = 0;
        Ok(())
    }

    /// Measurement noise variance per axis for a pulse (ICRA eq. 10), in (µA/m)².
    fn noise_var(&self, z: &Vec3) -> f32 {
        let bkg = self.config.sigma_bkg * FIELD_SCALE;
        let sen = self.config.k_sen * z.norm();
        bkg * bkg + sen * sen
    }

    fn exact_motion(&self) -> bool {
        self.config.mode == Mode::KnownTrajectory
    }

    /// Builds the mixture from a pulse; `Waiting` if it is too weak.
    fn try_initialize(
        &mut self,
        attitude: &Attitude,
        z: &Vec3,
        outcome: StepOutcome,
    ) -> StepReport {
        let snr = z.norm() / (self.config.sigma_bkg * FIELD_SCALE);
        if snr < self.config.init_snr {
            self.comps.clear();
            self.initialized = false;
            return StepReport::new(StepOutcome::Waiting, 0);
        }
        let r_var = self.noise_var(z);
        let exact = self.exact_motion();
        let n = initialize(&mut self.comps, &self.config, attitude, z, r_var, exact);
        self.initialized = n > 0;
        self.inconsistent_pulses = 0;
        normalize(&mut self.comps);
        let outcome = if n > 0 { outcome } else { StepOutcome::Waiting };
        StepReport::new(outcome, n)
    }

    /// `(ρ, (1 − ρ²)·σ_s²)` of the scale's mean reversion from the last pulse to `t`
    /// (see `SogConfig::scale_tau_s`); `None` when the scale is a constant (τ = 0, no
    /// scale uncertainty, a known trajectory, or no previous pulse).
    fn scale_reversion(&self, t: f32) -> Option<(f32, f32)> {
        let tau = self.config.scale_tau_s;
        let s0 = self.config.scale_sigma * self.config.scale_sigma;
        let dt = t - self.last_t?;
        if tau <= 0.0 || s0 <= 0.0 || self.exact_motion() || dt <= 0.0 {
            return None;
        }
        let rho = libm::expf(-dt / tau);
        Some((rho, (1.0 - rho * rho) * s0))
    }

    /// The outlier gate: `Some(smallest d²)` when the pulse fails the χ² gate
    /// `divergence_d2` (3 dof) for every component with both signs ([`gate_d2`]),
    /// `None` as soon as one component explains it. Under the model each component's
    /// `d²` is χ²(3) when it holds the truth, so a pulse no component explains is, at
    /// the 0.1 % level, not the transmitter's: an interferer, another device, a
    /// corrupted vector. Components are tried heaviest first (they carry the estimate
    /// and nearly always explain a real pulse) and the scan stops at the first
    /// consistent one, so a normal pulse costs about one component's gate statistic
    /// (≈ ⅓ of its step; the sort, a few thousand instructions).
    #[inline(never)]
    fn outlier_d2(&self, inp: &StepInput) -> Option<f32> {
        let mut order: Vec<(f32, u16), N> = Vec::new();
        for (i, c) in self.comps.iter().enumerate() {
            let _ = order.push((c.log_w, i as u16));
        }
        order.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
        let mut best = f32::INFINITY;
        let mut inp_c = *inp;
        for c in order
            .iter()
            .filter_map(|&(_, i)| self.comps.get(usize::from(i)))
        {
            let (mut x, mut p) = (c.x, c.p());
            inp.revert_scale(&mut x, &mut p);
            inp_c.r_var = inp.r_var + linearization_var(self.config.nonlinear_k, &inp.z, c);
            match gate_d2(&inp_c, &x, &p) {
                Ok(d2) if d2 <= self.config.divergence_d2 => return None,
                Ok(d2) => best = best.min(d2),
                Err(_) => {}
            }
        }
        Some(best)
    }

    /// Read-only: whether some component explains `pulse` after `motion` (its outlier
    /// gate, eq. 12–14: d² ≤ `divergence_d2`). `None` before initialization or for inputs
    /// [`Estimator::step`] would refuse. Used to give a new front-end track to the
    /// victim whose transmitter it is (issue 9); the state is not touched.
    pub fn explains(
        &self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Option<bool> {
        if !self.initialized {
            return None;
        }
        check_inputs(&self.config, self.last_t, motion, attitude, pulse).ok()?;
        let z = pulse.h * FIELD_SCALE;
        let mut inp = step_input(&self.config, motion, &z, self.noise_var(&z));
        inp.scale_rev = self.scale_reversion(pulse.t);
        Some(self.outlier_d2(&inp).is_none())
    }

    /// A pulse the outlier gate refused: the mixture follows the receiver's motion
    /// ([`predict_component`]) but the pulse updates neither states nor weights
    /// (`Withheld`). It counts as an inconsistent pulse towards `divergence_pulses`
    /// (see [`OUTLIER_RUN`]); isolated outliers between consistent pulses never reach
    /// that count.
    #[cold]
    #[inline(never)]
    fn withhold(
        &mut self,
        inp: &StepInput,
        att: Option<(&Vec3, &Mat3)>,
        attitude: &Attitude,
        z: &Vec3,
        best_d2: f32,
        mark: &mut impl FnMut(Phase),
    ) -> StepReport {
        self.inconsistent_pulses = self.inconsistent_pulses.saturating_add(1);
        let mut dropped = 0u16;
        if self.inconsistent_pulses < self.config.divergence_pulses {
            let mut i = 0;
            while let Some(c) = self.comps.get(i).copied() {
                let (mut x0, mut p0) = (c.x, c.p());
                inp.revert_scale(&mut x0, &mut p0);
                match predict_component(inp, &x0, &p0, att) {
                    Ok((x, p)) => {
                        if let Some(slot) = self.comps.get_mut(i) {
                            *slot = Component::new(x, &p, c.log_w);
                        }
                        i += 1;
                    }
                    Err(_) => {
                        self.comps.swap_remove(i);
                        dropped += 1;
                    }
                }
                mark(Phase::Update);
            }
            if !self.comps.is_empty() {
                if dropped > 0 {
                    normalize(&mut self.comps);
                }
                let mut report = StepReport::new(StepOutcome::Withheld, self.comps.len());
                report.best_d2 = best_d2;
                report.dropped = dropped;
                return report;
            }
        }
        let mut report = self.try_initialize(attitude, z, StepOutcome::Reinitialized);
        report.dropped = dropped;
        report.best_d2 = best_d2;
        report
    }
}

/// Per-axis variance (µA/m)² of the EKF's linearization error over component `c`'s
/// range uncertainty, added to the pulse noise of that component's update, gate and
/// likelihood (IROS eq. 12–14, 17).
///
/// The EKF keeps the first-order Taylor term of `h` only; the second-order term is the
/// error of that model. Along the range the dipole field is `h(r) = h(r₀)(r₀/r)³`, so
/// for `r = r₀ + δ`, `δ ~ N(0, σ_r²)`, the term is `6 h δ² / r₀²`: its mean square is
/// `108 |h|² σ_r⁴ / r₀⁴`, i.e. an rms of `6 |h| σ_r² / r₀²` per axis (checked against
/// the model in the tests). Ignoring it is harmless while it stays below the sensor
/// noise (ICRA eq. 10, 3 % of `|h|` by default) but not under the paper-level low noise
/// of the known-trajectory case (1 %): there a wide component holding the truth was
/// pulled off it overconfidently by one update and pruned, the mixture collapsed onto a
/// wrong mode 3–6 m off at 37 m, and the re-initialized Gaussian ended 9σ off near the
/// transmitter (`hal-sim/reports/accuracy.md`, seed 146). Counting the term as noise
/// keeps `S` and the weights honest, as the second-order EKF does (Gelb 1974 §6.1); it
/// vanishes as a component shrinks (∝ σ_r²/r²), so the converged accuracy is unchanged.
/// The term lies along `h`, while this adds it on all three axes and so also discounts
/// the pulse's direction; hence `k` (`SogConfig::nonlinear_k`) is set below the full
/// `6` (see `NONLINEAR_K`). `|h|` is taken from the pulse.
fn linearization_var(k: f32, z: &Vec3, c: &Component) -> f32 {
    // Off by default: the hot loop then pays one comparison per component.
    if k <= 0.0 {
        return 0.0;
    }
    let p = Vec3::new(c.x[I_P], c.x[I_P + 1], c.x[I_P + 2]);
    let r2 = p.norm_squared();
    // σ_r² = p̂ᵀ P_pp p̂, the variance of the range.
    let var_r = p.dot(&(c.block3(I_P) * p)) / r2;
    let e = k * z.norm() * var_r / r2;
    if e.is_finite() { e * e } else { 0.0 }
}

#[cfg(test)]
#[path = "sog_linearization_tests.rs"]
mod linearization_tests;

/// The phases of a step, reported to the `mark` callback of
/// [`SogFilter::step_marked`] as each one ends (for profiling on the target).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Input checks, per-pulse shared terms (or the whole initialization).
    Setup,
    /// One component's predict / pulse update / compose and absolute-attitude update,
    /// including unpacking.
    Update,
    /// One component packed back into the mixture.
    Store,
    /// Divergence check, weight normalization and pruning.
    Prune,
    /// Merging of near-duplicates.
    Merge,
    /// Splitting.
    Split,
}

impl<const N: usize> SogFilter<N> {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        if let Some(t) = self.last_t.as_mut() {
            *t -= shift_s;
        }
    }

    /// [`Estimator::step`], calling `mark` at the end of each [`Phase`] (the plain step
    /// passes a no-op, which compiles away).
    pub fn step_marked(
        &mut self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
        mut mark: impl FnMut(Phase),
    ) -> Result<StepReport, EstimateError> {
        // Validate every input before touching the state.
        check_inputs(&self.config, self.last_t, motion, attitude, pulse)?;
        let attitude = &attitude.bounded();
        let scale_rev = self.scale_reversion(pulse.t);
        self.last_t = Some(pulse.t);
        let z = pulse.h * FIELD_SCALE;

        if !self.initialized {
            let report = self.try_initialize(attitude, &z, StepOutcome::Initialized);
            mark(Phase::Setup);
            return Ok(report);
        }

        let r_var = self.noise_var(&z);
        // Absolute attitude of R_k (see `gaussian::attitude_update`); with a known trajectory the
        // orientation is already exact.
        let fuse_attitude = !self.exact_motion();
        let att_r = (attitude.cov + attitude.cov.transpose()) * 0.5;

        let mut inp = step_input(&self.config, motion, &z, r_var);
        inp.scale_rev = scale_rev;
        mark(Phase::Setup);
        let att = fuse_attitude.then_some((&attitude.rpy, &att_r));
        // Outlier gate, only on a pulse that follows a consistent one (see `OUTLIER_RUN`).
        if self.inconsistent_pulses < OUTLIER_RUN
            && let Some(best_d2) = self.outlier_d2(&inp)
        {
            return Ok(self.withhold(&inp, att, attitude, &z, best_d2, &mut mark));
        }
        // Scale-prior divergence (see `SogConfig::scale_divergence_d2`): the posterior
        // mean of a consistent Gaussian has ŝ − 1 ~ N(0, σ_s² − P_ss).
        let s0 = self.config.scale_sigma * self.config.scale_sigma;
        let scale_gate = if self.exact_motion() {
            0.0
        } else {
            self.config.scale_divergence_d2
        };
        let near2 =
            self.config.scale_divergence_min_range_m * self.config.scale_divergence_min_range_m;
        let scale_d2 = |x: &super::model::StateVec, p: &super::model::StateMat| {
            let v = s0 - p[(I_S, I_S)];
            let range2 = x[I_P] * x[I_P] + x[I_P + 1] * x[I_P + 1];
            if scale_gate <= 0.0 || v <= 0.0 || range2 < near2 {
                0.0
            } else {
                (x[I_S] - 1.0) * (x[I_S] - 1.0) / v
            }
        };
        let mut best_s2 = f32::INFINITY;
        let mut best_d2 = f32::INFINITY;
        let mut dropped = 0u16;
        // Iterated update only for the components that carry the estimate (bounded
        // count: the weights are normalized, so at most 1 / iekf_min_weight of them).
        let iekf_log_w = libm::logf(self.config.iekf_min_weight);
        let mut i = 0;
        while i < self.comps.len() {
            let Some(c) = self.comps.get(i).copied() else {
                break;
            };
            let (mut x0, mut p0) = (c.x, c.p());
            inp.revert_scale(&mut x0, &mut p0);
            // … and only once the component's scale is known as well as a calibrated
            // step length: the field is invariant under r → s·r, m → s³·m, so with a
            // loose scale the MAP cost is nearly flat along that direction and a
            // Gauss–Newton step slides along it (ARCHITECTURE, "Physics that shapes
            // the design"; seen as rare multi-metre probe errors without calibration).
            let iters = if c.log_w >= iekf_log_w && c.p_at(I_S, I_S) <= IEKF_MAX_SCALE_VAR {
                self.config.iekf_iterations
            } else {
                0
            };
            // Second-order noise only where the update stays linearized at the prior
            // (see `linearization_var`); the iterated update re-linearizes at the
            // posterior mode instead.
            inp.r_var = if iters == 0 {
                r_var + linearization_var(self.config.nonlinear_k, &z, &c)
            } else {
                r_var
            };
            let stepped = step_component_iterated(&inp, &x0, &p0, att, iters);
            mark(Phase::Update);
            match stepped {
                Ok((x, p, inn)) => {
                    best_d2 = best_d2.min(inn.d2);
                    best_s2 = best_s2.min(scale_d2(&x, &p));
                    // The weight takes the pulse's likelihood only (eq. 17); see
                    // `attitude_update` for why the attitude's is left out.
                    if let Some(slot) = self.comps.get_mut(i) {
                        *slot = Component::new(x, &p, c.log_w + inn.log_lik);
                    }
                    mark(Phase::Store);
                    i += 1;
                }
                Err(_) => {
                    self.comps.swap_remove(i);
                    dropped += 1;
                }
            }
        }

        // Divergence: every component inconsistent (innovation gate, or scale many σ off
        // its calibration prior) for several pulses, or none left.
        if best_d2 > self.config.divergence_d2 || (scale_gate > 0.0 && best_s2 > scale_gate) {
            self.inconsistent_pulses = self.inconsistent_pulses.saturating_add(1);
        } else {
            self.inconsistent_pulses = 0;
        }
        if self.comps.is_empty() || self.inconsistent_pulses >= self.config.divergence_pulses {
            let mut report = self.try_initialize(attitude, &z, StepOutcome::Reinitialized);
            report.dropped = dropped;
            report.best_d2 = best_d2;
            return Ok(report);
        }

        normalize(&mut self.comps);
        let pruned = prune(&mut self.comps, self.config.prune_weight);
        mark(Phase::Prune);
        let merged = merge(
            &mut self.comps,
            self.config.merge_d2,
            !self.config.sign_ambiguous,
        );
        mark(Phase::Merge);
        let split = split(
            &mut self.comps,
            self.config.split_ratio,
            self.config.split_min_weight,
        );
        mark(Phase::Split);
        Ok(StepReport {
            outcome: StepOutcome::Updated,
            n_components: self.comps.len(),
            best_d2,
            pruned,
            merged,
            split,
            dropped,
        })
    }
}

impl<const N: usize> Estimator for SogFilter<N> {
    fn step(
        &mut self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Result<StepReport, EstimateError> {
        self.step_marked(motion, attitude, pulse, |_| {})
    }

    fn estimate(&self) -> Option<VictimEstimate> {
        if !self.initialized {
            return None;
        }
        let (p, cov, max_weight, best) = position_moments(&self.comps)?;
        let heaviest = self.comps.get(best)?;
        let moment = moment_mean(&self.comps, best, !self.config.sign_ambiguous) / MOMENT_SCALE;
        let mut scale = 0.0;
        let mut scale_var = 0.0;
        for c in self.comps.iter() {
            let w = libm::expf(c.log_w);
            scale += w * c.x[I_S];
            scale_var += w * (c.p_at(I_S, I_S) + c.x[I_S] * c.x[I_S]);
        }
        scale_var -= scale * scale;
        Some(VictimEstimate {
            p,
            cov,
            moment,
            scale,
            scale_sigma: libm::sqrtf(scale_var.max(0.0)),
            rpy: Rpy::new(
                heaviest.x[I_RPY],
                heaviest.x[I_RPY + 1],
                heaviest.x[I_RPY + 2],
            ),
            n_components: self.comps.len(),
            max_weight,
        })
    }

    fn reset(&mut self) {
        self.comps.clear();
        self.initialized = false;
        self.inconsistent_pulses = 0;
        self.last_t = None;
    }

    fn is_initialized(&self) -> bool {
        self.initialized
    }
}

/// The input checks of one step (finite, unsaturated, non-zero pulse, time not going
/// back after `last_t`, valid covariances, physical ranges), shared with the baselines:
/// they run before the state is touched, so a refused input changes nothing.
pub(crate) fn check_inputs(
    config: &SogConfig,
    last_t: Option<f32>,
    motion: &Displacement,
    attitude: &Attitude,
    pulse: &Pulse,
) -> Result<(), EstimateError> {
    if !(pulse.h.iter().all(|v| v.is_finite()) && pulse.t.is_finite()) {
        return Err(EstimateError::NonFinite);
    }
    if pulse.h.iter().all(|v| *v == 0.0) {
        return Err(EstimateError::ZeroField);
    }
    if pulse
        .h
        .iter()
        .any(|v| libm::fabsf(*v) >= config.h_saturation)
    {
        return Err(EstimateError::Saturated);
    }
    if last_t.is_some_and(|t| pulse.t < t) {
        return Err(EstimateError::TimeWentBackwards);
    }
    if !(motion.translation.iter().all(|v| v.is_finite())
        && motion.absolute.iter().all(|v| v.is_finite())
        && motion.rotation.iter().all(|v| v.is_finite())
        && attitude.rpy.iter().all(|v| v.is_finite()))
    {
        return Err(EstimateError::NonFinite);
    }
    check_covariance(&motion.cov)?;
    check_covariance(&motion.absolute_cov)?;
    check_covariance(&attitude.cov)?;
    check_physical_range(motion, attitude)
}

/// The EKF input of one step (IROS eq. 5–9) for pulse `z` (µA/m) with noise variance
/// `r_var` after `motion`: the odometry and its covariance and the absolute part, both
/// exact (zero covariance) with a known trajectory. Shared with the baselines.
pub(crate) fn step_input(
    config: &SogConfig,
    motion: &Displacement,
    z: &Vec3,
    r_var: f32,
) -> StepInput {
    let exact = config.mode == Mode::KnownTrajectory;
    let u = MotionVec::from_column_slice(&[
        motion.translation.x,
        motion.translation.y,
        motion.translation.z,
        motion.rotation.x,
        motion.rotation.y,
        motion.rotation.z,
    ]);
    let q = if exact {
        MotionMat::zeros()
    } else {
        (motion.cov + motion.cov.transpose()) * 0.5
    };
    let mut inp = StepInput::new(&u, &q, z, r_var);
    inp.signed = !config.sign_ambiguous;
    if motion.has_absolute() {
        // With a known trajectory the absolute part is exact too.
        let qa = if exact {
            Mat3::zeros()
        } else {
            (motion.absolute_cov + motion.absolute_cov.transpose()) * 0.5
        };
        inp.with_absolute(&motion.absolute, &qa)
    } else {
        inp
    }
}

/// Largest translation between two pulses the filter accepts (m): a walking rescuer
/// covers a few metres per pulse; even a long reception gap stays far below this.
const MAX_TRANSLATION_M: f32 = 1.0e3;
/// Largest angle magnitude accepted (rad): any orientation is within ±2π; beyond a few
/// turns f32 angles lose their meaning.
const MAX_ANGLE_RAD: f32 = 4.0 * core::f32::consts::PI;
/// Largest variance accepted in a displacement covariance (m², rad²); attitude variances
/// are bounded by [`Attitude::bounded`] instead.
const MAX_VARIANCE: f32 = 1.0e6;

/// Refuses finite inputs outside any physical range (found by fuzzing: ±f32::MAX
/// translations and angles overflowed the composition to ±∞ and broke covariances).
pub(crate) fn check_physical_range(
    motion: &Displacement,
    attitude: &Attitude,
) -> Result<(), EstimateError> {
    let in_range = motion.translation.norm() <= MAX_TRANSLATION_M
        && motion.absolute.norm() <= MAX_TRANSLATION_M
        && (0..3).all(|i| motion.absolute_cov[(i, i)] <= MAX_VARIANCE)
        && motion.rotation.amax() <= MAX_ANGLE_RAD
        && attitude.rpy.amax() <= MAX_ANGLE_RAD
        && (0..6).all(|i| motion.cov[(i, i)] <= MAX_VARIANCE);
    if in_range {
        Ok(())
    } else {
        Err(EstimateError::OutOfRange)
    }
}

#[cfg(test)]
#[path = "sog_tests.rs"]
mod tests;
