//! Victim-position estimators: the [`Estimator`] trait, its inputs and outputs, and the
//! robocentric Sum-of-Gaussians filter [`SogFilter`] (Piniés, Tardós & Neira, IROS 2006;
//! known-trajectory variant: Piniés & Tardós, ICRA 2006).
//!
//! # Data flow per pulse
//! The caller hands the estimator, for every received pulse `k`:
//! - the [`Displacement`] of the receiver since the previous pulse (translation in
//!   `R_{k-1}` as dead-reckoned, rotation `R_{k-1} → R_k`, 6×6 covariance);
//! - the receiver's absolute [`Attitude`] from the IMU: it sets the orientation when the
//!   filter (re)initializes (IROS III-B takes the initial misalignment between `G_1` and
//!   `R_1`) and, beyond the paper, is fused on every later pulse as a linear measurement
//!   of the orientation state, which otherwise drifts with the accumulated rotation
//!   noise of the composition (IROS eq. 5) — robocentric mode only;
//! - the [`Pulse`]: the field vector in `R_k` (A/m), whose overall sign may be arbitrary.
//!
//! It returns a [`StepReport`], and [`Estimator::estimate`] gives the victim's position
//! relative to the receiver in `G_k` (x north, y west, z up, origin at the receiver).
//!
//! # Internal units
//! The field spans ~1e-9 … 1e-3 A/m. Internally fields are in µA/m and moments in
//! mA·m², so that noise variances (~1e-5 (µA/m)²), moments (3 … 30) and positions (m)
//! are all far from the ends of the `f32` range; the public API is SI.

pub mod baselines;
mod gaussian;
mod init;
mod mixture;
mod model;
mod packed;
mod rot;
pub mod sog;
#[cfg(test)]
mod testsim;

pub use sog::{DefaultSog, Phase, SOG_CAPACITY, SogFilter};

use crate::frame::Rpy;
use crate::{Mat3, Vec3};
use nalgebra::SMatrix;

pub use crate::motion::Mat6;

/// One received beacon pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    /// Field strength vector in the receiver frame `R_k` (A/m); its overall sign may be
    /// arbitrary (session-log `sign_ambiguous`).
    pub h: Vec3,
    /// Time of the pulse (s); must not decrease from one pulse to the next.
    pub t: f32,
}

/// The receiver's motion between two pulses (IROS 2006 eq. 4): `x_{R_k}` seen from `R_{k-1}`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Displacement {
    /// Translation from `R_{k-1}` to `R_k`, in `R_{k-1}` axes, as dead-reckoned (m). The
    /// filter multiplies it by its walk-long scale state (see [`SogConfig::scale_sigma`]).
    pub translation: Vec3,
    /// Rotation `Ψ_{R_{k-1} R_k}` as roll, pitch, yaw (rad).
    pub rotation: Rpy,
    /// Covariance `Q_k` of `[translation; rotation]` (m², rad²): the per-step noise on
    /// top of the scale error. Must be symmetric with a non-negative diagonal.
    pub cov: Mat6,
    /// Absolute part of the translation, in `R_{k-1}` axes (m): measured, not
    /// dead-reckoned (e.g. the accelerometer-integrated excursion of a lift of the
    /// device), so the filter adds it *after* the scale state multiplies `translation`:
    /// `s·translation + absolute`. It breaks the range/scale symmetry of the field.
    pub absolute: Vec3,
    /// Covariance of `absolute` (m²), independent of `cov`; zero when there is none.
    pub absolute_cov: Mat3,
}

impl Displacement {
    /// No motion, no uncertainty.
    pub fn zero() -> Self {
        Self {
            translation: Vec3::zeros(),
            rotation: Rpy::zeros(),
            cov: Mat6::zeros(),
            absolute: Vec3::zeros(),
            absolute_cov: Mat3::zeros(),
        }
    }

    /// A displacement with independent noise: `sigma_t` (m) per translation axis and
    /// `sigma_r` (rad) per rotation angle.
    pub fn with_sigmas(translation: Vec3, rotation: Rpy, sigma_t: f32, sigma_r: f32) -> Self {
        let mut cov = Mat6::zeros();
        for i in 0..3 {
            cov[(i, i)] = sigma_t * sigma_t;
            cov[(i + 3, i + 3)] = sigma_r * sigma_r;
        }
        Self {
            translation,
            rotation,
            cov,
            absolute: Vec3::zeros(),
            absolute_cov: Mat3::zeros(),
        }
    }

    /// Whether the displacement has an absolute part (non-zero mean or covariance).
    pub fn has_absolute(&self) -> bool {
        self.absolute != Vec3::zeros() || self.absolute_cov != Mat3::zeros()
    }
}

/// Absolute orientation of the receiver in the geographic frame, from the IMU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Attitude {
    /// Roll, pitch, yaw of `R` in `G` (rad), `R_GR = Rz(yaw) Ry(pitch) Rx(roll)`.
    pub rpy: Rpy,
    /// Covariance of `rpy` (rad²).
    pub cov: Mat3,
}

impl Attitude {
    /// An attitude with independent errors: `sigma_tilt` for roll and pitch, `sigma_yaw`
    /// for yaw (rad).
    pub fn with_sigmas(rpy: Rpy, sigma_tilt: f32, sigma_yaw: f32) -> Self {
        let v = Vec3::new(
            sigma_tilt * sigma_tilt,
            sigma_tilt * sigma_tilt,
            sigma_yaw * sigma_yaw,
        );
        Self {
            rpy,
            cov: Mat3::from_diagonal(&v),
        }
    }

    /// The same attitude with every angle variance above π² (rad²) lowered to π², its
    /// row and column scaled so that the correlations stay as they were.
    ///
    /// A σ of π already means "any direction" (the motion filter's own prior for an
    /// unknown yaw): a larger Gaussian variance carries no more information, and the
    /// linearized filter turns it into huge position spreads (a yaw variance of 2·10⁵
    /// rad² once split a component into a negative variance). It is clamped rather than
    /// refused because a search without a magnetometer starts at π² and grows past it.
    pub fn bounded(&self) -> Self {
        const MAX_VAR: f32 = core::f32::consts::PI * core::f32::consts::PI;
        let f = self.cov.diagonal().map(|v| {
            if v > MAX_VAR {
                libm::sqrtf(MAX_VAR / v)
            } else {
                1.0
            }
        });
        if f == Vec3::repeat(1.0) {
            return *self;
        }
        let mut cov = self.cov;
        for i in 0..3 {
            for j in 0..3 {
                cov[(i, j)] *= f[i] * f[j];
            }
            // Exactly π², not π² ± one rounding.
            if f[i] < 1.0 {
                cov[(i, i)] = MAX_VAR;
            }
        }
        Self { rpy: self.rpy, cov }
    }
}

/// The estimator's current belief about the victim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VictimEstimate {
    /// Mixture mean of the transmitter position in `G_k` (m, relative to the receiver;
    /// x north, y west, z up): IROS 2006 eq. 18.
    pub p: Vec3,
    /// Mixture covariance of `p` (m²): IROS 2006 eq. 18.
    pub cov: Mat3,
    /// Transmitter moment in `G_k` (A·m²) of the mixture, with the sign of the heaviest
    /// component (the overall sign is not observable when pulses are sign-ambiguous).
    pub moment: Vec3,
    /// Mean of the walk-long scale factor applied to the dead-reckoned translation.
    pub scale: f32,
    /// Standard deviation of that scale factor.
    pub scale_sigma: f32,
    /// Orientation of the receiver in `G_k` of the heaviest component (rad).
    pub rpy: Rpy,
    /// Number of Gaussians in the mixture.
    pub n_components: usize,
    /// Weight of the heaviest Gaussian (1 when the mixture has become unimodal).
    pub max_weight: f32,
}

/// What a call to [`Estimator::step`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepOutcome {
    /// Not initialized yet, and this pulse was too weak to initialize from.
    Waiting,
    /// The mixture was created from this pulse (IROS III-B).
    Initialized,
    /// A normal predict / update / compose step (IROS Algorithm 1).
    Updated,
    /// Every component had been inconsistent with the pulses for several pulses (or none
    /// survived): the mixture was rebuilt from this pulse.
    Reinitialized,
    /// The pulse failed the outlier gate for every component (both signs): the mixture
    /// followed the motion, but the pulse updated neither states nor weights.
    Withheld,
}

/// Diagnostics of one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// What happened.
    pub outcome: StepOutcome,
    /// Gaussians in the mixture after the step.
    pub n_components: usize,
    /// Smallest innovation Mahalanobis distance² over the components (0 when not updated).
    pub best_d2: f32,
    /// Components removed for negligible weight.
    pub pruned: u16,
    /// Pairs of near-duplicate components merged.
    pub merged: u16,
    /// Components split because the measurement is too nonlinear over them.
    pub split: u16,
    /// Components removed because their model could not be evaluated (e.g. the
    /// transmitter hypothesis fell inside the receiver's own antenna).
    pub dropped: u16,
}

impl StepReport {
    fn new(outcome: StepOutcome, n_components: usize) -> Self {
        Self {
            outcome,
            n_components,
            best_d2: 0.0,
            pruned: 0,
            merged: 0,
            split: 0,
            dropped: 0,
        }
    }
}

/// Why an input was refused. A refused input leaves the estimator's state unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimateError {
    /// An input contained NaN or an infinity.
    #[error("input NaN or infinite")]
    NonFinite,
    /// The pulse's field vector was exactly zero.
    #[error("zero field vector")]
    ZeroField,
    /// A field component reached the receiver's saturation level.
    #[error("field component at the saturation level")]
    Saturated,
    /// A covariance had a negative variance, was not symmetric, or had a correlation
    /// outside [-1, 1].
    #[error("invalid covariance")]
    InvalidCovariance,
    /// The pulse's time was earlier than the previous pulse's.
    #[error("pulse time before the previous pulse")]
    TimeWentBackwards,
    /// The configuration is inconsistent (see [`SogConfig::validate`]).
    #[error("inconsistent estimator configuration")]
    InvalidConfig,
    /// A matrix that must be positive definite was not (typed error of the Cholesky
    /// factorization of the innovation covariance `S`).
    #[error("innovation covariance not positive definite")]
    NotPositiveDefinite,
    /// A finite input outside any physical range (e.g. a displacement of 1e38 m between
    /// two pulses, angles of 1e38 rad, displacement variances beyond 1e6): refused before
    /// it can overflow the filter's arithmetic.
    #[error("input outside any physical range")]
    OutOfRange,
}

/// Which problem the filter solves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Full robocentric SLAM (IROS 2006): orientation, transmitter and scale are estimated
    /// from noisy displacements.
    Robocentric,
    /// Known receiver trajectory (ICRA 2006): displacements and the initial attitude are
    /// taken as exact (their covariances and the scale uncertainty are ignored), so the
    /// same filter only estimates `[p_T, m]`.
    KnownTrajectory,
}

/// Configuration of the SOG filter. [`SogConfig::default`] is the papers' Monte Carlo
/// setting with a calibrated step length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SogConfig {
    /// Robocentric or known trajectory.
    pub mode: Mode,
    /// Smallest transmitter moment magnitude (A·m²).
    pub m_min: f32,
    /// Largest transmitter moment magnitude (A·m²).
    pub m_max: f32,
    /// Shallowest burial depth below the snow surface (m); negative for a transmitter
    /// that may lie above it (a drone's receiver with the victim anywhere in a ball).
    pub depth_min: f32,
    /// Deepest burial depth below the snow surface (m).
    pub depth_max: f32,
    /// Height of the receiver above the snow surface (m).
    pub receiver_height: f32,
    /// Background noise per field component (A/m), ICRA 2006 eq. 10.
    pub sigma_bkg: f32,
    /// Sensor noise proportional to |H|, ICRA 2006 eq. 10.
    pub k_sen: f32,
    /// Whether a pulse's overall sign is unknown (the front end's phase reference is
    /// arbitrary): then every update tries `+z` and `−z` (IROS eq. 17). `false` when the
    /// receiver knows the sign: only `+z` is used.
    pub sign_ambiguous: bool,
    /// Standard deviation of the walk-long scale factor multiplying the dead-reckoned
    /// translation: ≈ 0.02 with a calibrated step length, ≈ 0.10 without.
    pub scale_sigma: f32,
    /// Field component magnitude (A/m) at or above which a pulse counts as saturated.
    pub h_saturation: f32,
    /// Smallest |H| / `sigma_bkg` of a pulse that may initialize the mixture.
    pub init_snr: f32,
    /// Fraction of the capacity filled at initialization (the rest is room for splits).
    pub init_fill: f32,
    /// Every point of the initial region lies within this squared Mahalanobis distance
    /// (3 dof) of some component (IROS III-B, ICRA V-C): the corner of each cell sits
    /// exactly on it. The 95 % bound would be 7.81; the default 1.2 makes neighbours
    /// overlap generously (σ ≈ 1.6 × the cell's half-size), which the convergence tests
    /// found more robust and better calibrated.
    pub init_chi2: f32,
    /// Components whose normalized weight falls below this are removed.
    pub prune_weight: f32,
    /// Two components closer than this (squared Mahalanobis distance of position and
    /// moment, with the sum of their covariances) are merged.
    pub merge_d2: f32,
    /// A component is split in three when its largest position standard deviation
    /// exceeds this fraction of its range (the dipole field is then too nonlinear over it:
    /// |H| ∝ r⁻³ changes by ≈ 3× this fraction within 1σ). The default 0.06 (≈ 18 %)
    /// keeps the linearization error below the 3 % sensor noise over most of a
    /// component's mass, using the capacity freed as the mixture collapses.
    pub split_ratio: f32,
    /// Components with less weight than this are never split.
    pub split_min_weight: f32,
    /// Innovation gate (squared Mahalanobis, 3 dof) above which a component is
    /// inconsistent with a pulse; a pulse above it for every component is withheld
    /// as an outlier (`StepOutcome::Withheld`). The default 16.27 is χ²₃ at 99.9 %.
    pub divergence_d2: f32,
    /// Consecutive pulses on which every component must be inconsistent before the
    /// mixture is rebuilt.
    pub divergence_pulses: u8,
    /// Scale-prior divergence gate (squared, 1 dof; 0 disables). A Gaussian that started
    /// from the calibration prior `s ~ N(1, scale_sigma²)` and was updated consistently
    /// has its posterior mean `ŝ` distributed as `N(1, scale_sigma² − P_ss)`
    /// (`P_ss` its posterior variance); a pulse on which every component has
    /// `(ŝ − 1)² / (scale_sigma² − P_ss)` above this gate counts as inconsistent, like a
    /// failed innovation gate (see `divergence_pulses`): the mixture has lost the
    /// transmitter and explains the pulses by a scale the calibration rules out. The
    /// default 16 is the 4σ gate (1-dof tail ≈ 6e-5); ignored with a known trajectory.
    pub scale_divergence_d2: f32,
    /// The scale-prior divergence gate counts only components whose horizontal distance
    /// from the receiver is above this (m). The scale's share of the position error is
    /// its error times the distance still to walk, so near the victim an off scale costs
    /// centimetres, while rebuilding the mixture there costs the estimate: from one spot
    /// a fresh mixture cannot separate position from moment and may settle on a wrong
    /// mode (rescue seed 2082: rebuilt 3 m from the victim on a 4.1σ scale, probed 1.9 m
    /// off with σ_h 0.14 m; the mixture before it was 0.04 m off).
    pub scale_divergence_min_range_m: f32,
    /// Correlation time (s) of the step-length scale: the scale is a first-order
    /// Gauss–Markov process `s − 1` around the calibrated length with stationary σ
    /// `scale_sigma` (a walker's step length wanders with snow, slope and fatigue, while
    /// the calibration bounds how far). Over a pulse interval `Δt`,
    /// `s' = 1 + ρ(s − 1)`, `P_ss' = ρ² P_ss + (1 − ρ²)·scale_sigma²`, `ρ = e^{−Δt/τ}`.
    /// It keeps the scale from integrating small linearization biases over an hour
    /// (`hal-sim/reports/reliability.md`, soak). 0 = a walk-long constant (IROS 2006).
    pub scale_tau_s: f32,
    /// Most re-linearizations of the iterated-EKF pulse update of one component (0 = the
    /// plain EKF update of IROS eq. 12–14; see `gaussian::step_gaussian_iterated`).
    pub iekf_iterations: u8,
    /// Only components whose normalized weight is at least this are iterated: at most
    /// `1 / iekf_min_weight` of them, so a step costs at most
    /// `iekf_iterations / iekf_min_weight` extra linearizations whatever the capacity.
    pub iekf_min_weight: f32,
    /// Coefficient of the linearization-error variance added to each component's pulse
    /// noise (see `sog::linearization_var`): per axis `(k · |z| · σ_r² / r²)²`, the
    /// second-order Taylor term of the r⁻³ dipole field over the component's range
    /// variance `σ_r²` (rms coefficient 6), for the components the update leaves
    /// linearized at the prior. 0 (the default) = the plain EKF noise of ICRA eq. 10;
    /// [`NONLINEAR_K`] with a known trajectory, whose pulses are near-noiseless.
    pub nonlinear_k: f32,
}

impl Default for SogConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Robocentric,
            m_min: 3e-3,
            m_max: 3e-2,
            depth_min: 0.0,
            depth_max: 5.0,
            receiver_height: 1.0,
            sigma_bkg: 2.59e-9,
            k_sen: 0.03,
            sign_ambiguous: true,
            scale_sigma: SCALE_SIGMA_CALIBRATED,
            h_saturation: 1.0,
            init_snr: 10.0,
            init_fill: 0.6,
            init_chi2: 1.2,
            prune_weight: 1e-6,
            merge_d2: 0.3,
            split_ratio: 0.06,
            split_min_weight: 1e-3,
            divergence_d2: 16.27,
            divergence_pulses: 5,
            scale_divergence_d2: 16.0,
            scale_divergence_min_range_m: 5.0,
            scale_tau_s: 300.0,
            iekf_iterations: 2,
            iekf_min_weight: 0.2,
            nonlinear_k: 0.0,
        }
    }
}

/// [`SogConfig::nonlinear_k`] of the known-trajectory setting: half the second-order
/// term's rms coefficient (6), because the scalar noise spreads a term that lies along
/// `h` over all three axes and so also discounts the pulse's direction. Chosen among
/// 0, 3, 6, 9 on the known-trajectory seeds 1–100 and checked on 101–200
/// (`hal-sim/reports/accuracy.md`): 6 and 9 discount so much that mixtures stay wide and
/// re-initialize more. Off (0) in [`SogConfig::default`]: at the default 3 % pulse noise
/// it changed no accuracy number beyond run-to-run noise, but in the closed-loop rescue
/// it turned one shallow victim (`rescue-report --first-seed 1000`, seed 1044, 0.36 m
/// deep, probed from ≈ 0.5 m) into a 3.4 m miss: at such ranges the isotropic noise
/// throws away the pulse direction the fine search needs.
pub const NONLINEAR_K: f32 = 3.0;

/// Scale-factor standard deviation with a calibrated step length (session-log `pdr`).
pub const SCALE_SIGMA_CALIBRATED: f32 = 0.02;
/// Scale-factor standard deviation without step-length calibration.
pub const SCALE_SIGMA_UNCALIBRATED: f32 = 0.10;

impl SogConfig {
    /// The known-trajectory (ICRA 2006) setting.
    pub fn known_trajectory() -> Self {
        Self {
            mode: Mode::KnownTrajectory,
            scale_sigma: 0.0,
            nonlinear_k: NONLINEAR_K,
            ..Self::default()
        }
    }

    /// Sets the scale prior from whether the step length was calibrated.
    pub fn with_calibrated_step(self, calibrated: bool) -> Self {
        Self {
            scale_sigma: if calibrated {
                SCALE_SIGMA_CALIBRATED
            } else {
                SCALE_SIGMA_UNCALIBRATED
            },
            ..self
        }
    }

    /// Checks that every field is finite and within its meaningful range.
    pub fn validate(&self) -> Result<(), EstimateError> {
        let finite = [
            self.m_min,
            self.m_max,
            self.depth_min,
            self.depth_max,
            self.receiver_height,
            self.sigma_bkg,
            self.k_sen,
            self.scale_sigma,
            self.h_saturation,
            self.init_snr,
            self.init_fill,
            self.init_chi2,
            self.prune_weight,
            self.merge_d2,
            self.split_ratio,
            self.split_min_weight,
            self.divergence_d2,
            self.scale_divergence_d2,
            self.scale_divergence_min_range_m,
            self.scale_tau_s,
            self.iekf_min_weight,
            self.nonlinear_k,
        ];
        if !finite.iter().all(|v| v.is_finite()) {
            return Err(EstimateError::InvalidConfig);
        }
        let ok = self.m_min > 0.0
            && self.nonlinear_k >= 0.0
            && self.iekf_min_weight > 0.0
            && self.iekf_min_weight <= 1.0
            && self.m_max >= self.m_min
            && self.depth_max >= self.depth_min
            && self.receiver_height >= 0.0
            && self.sigma_bkg > 0.0
            && self.k_sen >= 0.0
            && self.scale_sigma >= 0.0
            && self.scale_sigma < 0.5
            && self.h_saturation > 0.0
            && self.init_snr >= 0.0
            && self.init_fill > 0.0
            && self.init_fill <= 1.0
            && self.init_chi2 > 0.0
            && (0.0..0.5).contains(&self.prune_weight)
            && self.merge_d2 >= 0.0
            && self.split_ratio > 0.0
            && self.split_min_weight >= 0.0
            && self.divergence_d2 > 0.0
            && self.divergence_pulses > 0
            && self.scale_divergence_d2 >= 0.0
            && self.scale_divergence_min_range_m >= 0.0
            && self.scale_tau_s >= 0.0;
        if ok {
            Ok(())
        } else {
            Err(EstimateError::InvalidConfig)
        }
    }
}

/// A victim-position estimator fed one pulse at a time.
pub trait Estimator {
    /// Processes one pulse: initializes from it when not yet initialized (using
    /// `attitude`; `motion` is then ignored), otherwise predicts with `motion`, updates
    /// with `pulse` and composes into the new frame `G_k`. A refused input returns an
    /// error and leaves the state unchanged.
    fn step(
        &mut self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Result<StepReport, EstimateError>;

    /// The current estimate, or `None` before initialization.
    fn estimate(&self) -> Option<VictimEstimate>;

    /// Forgets everything; the next usable pulse initializes again.
    fn reset(&mut self);

    /// Whether the estimator holds a belief (has been initialized).
    fn is_initialized(&self) -> bool;
}

/// Checks a covariance's necessary conditions for being positive semi-definite: finite,
/// symmetric (relative 1e-4), non-negative diagonal, correlations within [-1, 1].
pub(crate) fn check_covariance<const D: usize>(
    c: &SMatrix<f32, D, D>,
) -> Result<(), EstimateError> {
    if !c.iter().all(|v| v.is_finite()) {
        return Err(EstimateError::NonFinite);
    }
    for i in 0..D {
        if c[(i, i)] < 0.0 {
            return Err(EstimateError::InvalidCovariance);
        }
        for j in (i + 1)..D {
            let bound = libm::sqrtf(c[(i, i)] * c[(j, j)]);
            let (a, b) = (c[(i, j)], c[(j, i)]);
            if libm::fabsf(a - b) > 1e-4 * bound + f32::MIN_POSITIVE
                || libm::fabsf(a) > bound * (1.0 + 1e-4) + f32::MIN_POSITIVE
            {
                return Err(EstimateError::InvalidCovariance);
            }
        }
    }
    Ok(())
}
