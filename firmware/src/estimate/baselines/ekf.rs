//! A single EKF on the SOGs filter's robocentric state (slides `002_*`): the baseline
//! the mixture exists to beat.
//!
//! Same state `[Ψ; p_T; m; s]`, same predict / sign-chosen update / compose step
//! (`estimate::gaussian::step_component`, IROS Algorithm 1 for one Gaussian) and
//! attitude fusion as each Gaussian of the SOGs filter, but one Gaussian for the whole
//! belief. It is initialized on the first pulse's flux line: the cell of the initial
//! region (IROS III-B) closest to the horizontal field direction at the moment-prior mean
//! range (the geometric mean of the region's ranges), with the covariance of the whole
//! region about it (`Σ wᵢ (Pᵢ + (xᵢ − x̄)(xᵢ − x̄)ᵀ)`), i.e. the single Gaussian that
//! matches the prior's spread.
//!
//! # How it fails
//! The posterior after the first pulses is a ring around the receiver (and, with a
//! sign-ambiguous pulse, the flux line itself points either way). One Gaussian
//! linearized at one point of that ring either happens to sit in the victim's basin and
//! converges, or is pulled along the ring to a wrong point (a mirror of the truth that
//! explains the pulses nearly as well) and stays there with a confident covariance:
//! see the tests. Memory: 10 + 100 floats, 440 bytes plus bookkeeping.

use super::super::gaussian::step_component;
use super::super::model::{I_P, I_RPY, I_S, MOMENT_SCALE, StateMat, StateVec, m_of, p_of};
use super::super::{
    Attitude, Displacement, EstimateError, Estimator, Mode, SogConfig, StepOutcome, StepReport,
    VictimEstimate,
};
use super::{initial_region, noise_var, step_input, step_report, strong_enough};
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};

/// One EKF on the robocentric state `[Ψ; p_T; m; s]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SingleEkf {
    config: SogConfig,
    x: StateVec,
    p: StateMat,
    initialized: bool,
    inconsistent_pulses: u8,
    last_t: Option<f32>,
}

impl SingleEkf {
    /// An EKF with the SOGs filter's configuration, or `InvalidConfig`.
    pub fn new(config: SogConfig) -> Result<Self, EstimateError> {
        config.validate()?;
        Ok(Self {
            config,
            x: StateVec::zeros(),
            p: StateMat::zeros(),
            initialized: false,
            inconsistent_pulses: 0,
            last_t: None,
        })
    }

    /// Initializes on the flux line of pulse `z` (µA/m in `R_1`); `Waiting` when the pulse
    /// is too weak or cannot be inverted.
    fn try_initialize(&mut self, attitude: &Attitude, z: &Vec3, kind: StepOutcome) -> StepReport {
        self.initialized = false;
        self.inconsistent_pulses = 0;
        if !strong_enough(&self.config, z) {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        let region = initial_region(&self.config, attitude, z);
        let z_g = rotation_from_rpy(&attitude.rpy) * z;
        let flux = Vec3::new(z_g.x, z_g.y, 0.0);
        let flux = if flux.norm() > 0.0 {
            flux.normalize()
        } else {
            Vec3::x()
        };
        let n = region.len() as f32;
        let r_mid = libm::expf(
            region
                .iter()
                .map(|c| libm::logf(p_of(&c.x).norm()))
                .sum::<f32>()
                / n,
        );
        // The flux-line cell at the moment-prior mean range: largest cosine to the
        // field's horizontal direction, penalized by the log-range distance to r_mid.
        let score = |x: &StateVec| {
            let p = p_of(x);
            let h = Vec3::new(p.x, p.y, 0.0);
            let cos = if h.norm() > 0.0 {
                h.dot(&flux) / h.norm()
            } else {
                -1.0
            };
            cos - libm::fabsf(libm::logf(p.norm() / r_mid))
        };
        let Some(best) = region
            .iter()
            .max_by(|a, b| score(&a.x).total_cmp(&score(&b.x)))
        else {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        };
        let mean = best.x;
        let w_sum: f32 = region.iter().map(|c| libm::expf(c.log_w)).sum();
        let mut cov = StateMat::zeros();
        for c in region.iter() {
            let d = c.x - mean;
            cov += (c.p() + d * d.transpose()) * (libm::expf(c.log_w) / w_sum);
        }
        cov = (cov + cov.transpose()) * 0.5;
        if !(mean.iter().all(|v| v.is_finite()) && cov.iter().all(|v| v.is_finite())) {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        self.x = mean;
        self.p = cov;
        self.initialized = true;
        step_report(kind, 1, 0.0, 0)
    }
}

impl SingleEkf {
    /// One step of the initialized filter with pulse `z` (µA/m in `R_k`).
    fn advance(&mut self, motion: &Displacement, attitude: &Attitude, z: &Vec3) -> StepReport {
        let inp = step_input(&self.config, motion, z, noise_var(&self.config, z));
        let att_r = (attitude.cov + attitude.cov.transpose()) * 0.5;
        let att = (self.config.mode == Mode::Robocentric).then_some((&attitude.rpy, &att_r));
        match step_component(&inp, &self.x, &self.p, att) {
            Ok((x, p, inn)) => {
                self.x = x;
                self.p = p;
                if inn.d2 > self.config.divergence_d2 {
                    self.inconsistent_pulses = self.inconsistent_pulses.saturating_add(1);
                } else {
                    self.inconsistent_pulses = 0;
                }
                if self.inconsistent_pulses >= self.config.divergence_pulses {
                    let mut r = self.try_initialize(attitude, z, StepOutcome::Reinitialized);
                    r.best_d2 = inn.d2;
                    return r;
                }
                step_report(StepOutcome::Updated, 1, inn.d2, 0)
            }
            // The model failed (transmitter hypothesis inside the antenna, S not PD):
            // the Gaussian is lost, rebuild from this pulse as the SOGs filter does
            // when no component survives.
            Err(_) => {
                let mut r = self.try_initialize(attitude, z, StepOutcome::Reinitialized);
                r.dropped = 1;
                r
            }
        }
    }
}

impl Estimator for SingleEkf {
    super::staged_step!();

    fn estimate(&self) -> Option<VictimEstimate> {
        if !self.initialized {
            return None;
        }
        Some(VictimEstimate {
            p: p_of(&self.x),
            cov: Mat3::from_fn(|i, j| self.p[(I_P + i, I_P + j)]),
            moment: m_of(&self.x) / MOMENT_SCALE,
            scale: self.x[I_S],
            scale_sigma: libm::sqrtf(self.p[(I_S, I_S)].max(0.0)),
            rpy: Rpy::new(self.x[I_RPY], self.x[I_RPY + 1], self.x[I_RPY + 2]),
            n_components: 1,
            max_weight: 1.0,
        })
    }

    fn reset(&mut self) {
        self.initialized = false;
        self.inconsistent_pulses = 0;
        self.last_t = None;
        self.x = StateVec::zeros();
        self.p = StateMat::zeros();
    }

    fn is_initialized(&self) -> bool {
        self.initialized
    }
}
