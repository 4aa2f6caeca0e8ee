//! The papers' baselines beside the SOGs filter (issue 8), on the same seeded scenarios.
//!
//! Every method is a [`Method`]: estimators run open loop on the scenarios of
//! [`crate::eval::accuracy`] (the papers' protocol: start 40–70 m away, 1 m/s, a pulse per
//! period, random transmitter position, orientation and power) through
//! [`accuracy::run_open_loop_with`], so they see exactly the pulses, dead-reckoning and
//! attitude errors the SOGs filter sees; methods that guide the rescuer (the SOGs receiver
//! via the firmware's application, the classical directional search) also run closed loop
//! through [`crate::eval::rescue_report`]. `hal-sim baselines-report` ([`report`]) writes the
//! side-by-side report.
//!
//! Here (host only): the Levenberg–Marquardt batch fit ([`lm`]) and the RLS identifier of
//! Mimmo, Bernard & Marconi ([`rls`]); the classical directional search is the rescuer
//! policy of [`crate::sim::closed_loop`]. The `no_std` filters of the firmware
//! (`firmware::estimate::baselines`: single EKF, particle filter, RBPF, histogram filter)
//! are registered in [`Method`] with one variant and one factory line each.
use crate::eval::accuracy::{self, Case, MotionNoise, RunResult};
use crate::eval::rescue_report::{self, Rescue};
use firmware::estimate::baselines as fb;
use firmware::estimate::{Estimator, SogConfig};

pub mod dr;
pub mod lm;
pub mod paper;
mod plot;
pub mod record;
pub mod report;
pub mod rls;

/// Builds an estimator from the SOGs filter's configuration for the scenario (moment and
/// depth ranges, pulse noise, scale prior); `None` when it cannot be built.
pub type Factory = fn(&SogConfig) -> Option<Box<dyn Estimator>>;

/// A compared method.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
pub enum Method {
    /// The firmware's SOGs filter (IROS 2006 Alg. 1), run by `accuracy`'s own runner.
    Sog,
    /// Levenberg–Marquardt batch fit of position and moment (host).
    Lm,
    /// RLS identifier with the linear-in-parameters approximation (host).
    Rls,
    /// Single EKF on the SOGs state (slides 002), firmware library.
    SingleEkf,
    /// Vanilla particle filter (IROS Alg. 2), firmware library, 5000 particles.
    ParticleFilter,
    /// Rao-Blackwellized particle filter (IROS Alg. 3), firmware library, 5000 particles.
    Rbpf,
    /// 2-D histogram (grid) filter, firmware library, 64 × 64 cells × 3 depth layers.
    Histogram,
    /// Classical directional search (ICRA II-A): closed loop only.
    DirectionalSearch,
}

impl Method {
    /// Every method, in report order.
    pub const ALL: &'static [Method] = &[
        Method::Sog,
        Method::Lm,
        Method::Rls,
        Method::SingleEkf,
        Method::ParticleFilter,
        Method::Rbpf,
        Method::Histogram,
        Method::DirectionalSearch,
    ];

    /// Display name.
    pub fn name(self) -> &'static str {
        match self {
            Method::Sog => "SOGs filter",
            Method::Lm => "Levenberg–Marquardt batch fit",
            Method::Rls => "RLS identifier (Mimmo et al.)",
            Method::SingleEkf => "single EKF",
            Method::ParticleFilter => "particle filter (5000)",
            Method::Rbpf => "Rao-Blackwellized PF (5000)",
            Method::Histogram => "histogram filter (64×64×3)",
            Method::DirectionalSearch => "directional search (DS)",
        }
    }

    /// The factory of an estimator run open loop (the SOGs filter has its own runner;
    /// closed-loop-only methods have none).
    pub fn factory(self) -> Option<Factory> {
        match self {
            Method::Sog | Method::DirectionalSearch => None,
            Method::Lm => Some(|c| {
                lm::LmFit::new(lm::LmConfig::from_sog(c))
                    .ok()
                    .map(|f| Box::new(f) as Box<dyn Estimator>)
            }),
            Method::Rls => Some(|c| {
                rls::RlsIdentifier::new(rls::RlsConfig::from_sog(c))
                    .ok()
                    .map(|f| Box::new(f) as Box<dyn Estimator>)
            }),
            Method::SingleEkf => Some(|c| boxed(fb::SingleEkf::new(*c))),
            Method::ParticleFilter => {
                Some(|c| boxed(fb::ParticleFilter::<PAPER_PARTICLES>::new(*c, FILTER_SEED)))
            }
            Method::Rbpf => Some(|c| boxed(fb::Rbpf::<PAPER_PARTICLES>::new(*c, FILTER_SEED))),
            Method::Histogram => Some(|c| boxed(fb::HistogramFilter::<64, 64>::new(*c))),
        }
    }

    /// Whether the method runs open loop on the accuracy scenarios.
    pub fn open_loop(self) -> bool {
        self == Method::Sog || self.factory().is_some()
    }

    /// The closed-loop rescue that this method guides, if it guides one.
    pub fn closed_loop(self) -> Option<rescue_report::Case> {
        match self {
            Method::Sog => Some(rescue_report::Case::SogCalibrated),
            Method::DirectionalSearch => Some(rescue_report::Case::DirectionalSearch),
            _ => None,
        }
    }

    /// How the method is built and why it does as it does against the SOGs filter (the
    /// report's explanation; the numbers are measured, this is the mechanism).
    pub fn why(self) -> &'static str {
        match self {
            Method::Sog => WHY_SOG,
            Method::Lm => WHY_LM,
            Method::Rls => WHY_RLS,
            Method::DirectionalSearch => WHY_DS,
            Method::SingleEkf => WHY_EKF,
            Method::ParticleFilter => WHY_PF,
            Method::Rbpf => WHY_RBPF,
            Method::Histogram => WHY_GRID,
        }
    }

    /// The papers' final error max / mean / median (m) for this method, with its source.
    pub fn paper(self) -> Option<(&'static str, [f64; 3])> {
        match self {
            Method::Sog => Some(("IROS 2006 Table I", [0.66, 0.23, 0.21])),
            Method::Rbpf => Some(("IROS 2006 Table I", [32.5, 2.27, 0.28])),
            Method::DirectionalSearch => Some(("ICRA 2006 Table II", [2.62, 0.52, 0.42])),
            _ => None,
        }
    }
}

/// The particle count of the papers' RBPF (IROS 2006 §IV), used for both particle filters.
const PAPER_PARTICLES: usize = 5000;

/// The particle filters' generator seed: fixed, so every run of the report is identical.
const FILTER_SEED: u64 = 1;

/// Boxes a firmware baseline filter as an estimator (`None` when its constructor refused).
fn boxed<E: Estimator + 'static>(
    f: Result<E, firmware::estimate::EstimateError>,
) -> Option<Box<dyn Estimator>> {
    f.ok().map(|f| Box::new(f) as Box<dyn Estimator>)
}

const WHY_EKF: &str = "One Gaussian started on the first pulse's flux line at the moment prior's mean range, with the covariance of the whole initial region: the posterior after the first pulses is a ring of modes (IROS III-B), which a single linearization cannot hold, so it locks onto whichever part of the ring its first updates favour and its covariance stops being consistent (firmware test `single_ekf_fails_where_the_sog_does_not`).";
const WHY_PF: &str = "Particles over attitude, position, moment and scale drawn from the SOGs filter's initial region, systematic resampling at N_eff < N/2 (IROS eq. 20) plus roughening: with 5000 particles over a 10-D state the region is sparsely covered, and the sharp likelihood at short range leaves few particles near the truth (sample impoverishment).";
const WHY_RBPF: &str = "IROS Alg. 3: particles over attitude, position and scale, a Kalman filter per particle for the moment (the field is linear in m), plus two additions of ours (roughening of the resampled copies' positions, re-initialization on divergence). Marginalizing the moment removes three dimensions from the sampled part, but the remaining 7-D particle part is still sparsely covered by 5000 particles over the initial ring and collapses near the victim, where the likelihood sharpens, into a cloud narrower than its error (sample impoverishment): a median within decimetres and a tail of metres. Under IROS §V's closed loop, beside the paper's Table I, see \"SOGs filter and RBPF under IROS 2006 §V's protocol\" below, where each addition is taken out and the tries over 1 m are dissected.";
const WHY_GRID: &str = "A 2-D histogram over the horizontal victim position (3 depth layers, a running moment per cell) fixed at the first pulse and zooming ×2 as the belief narrows: its resolution is bounded by the cell size and it never re-centres, so a belief locked on a wrong place stays there.";

/// One method's runs.
#[derive(Debug, Clone)]
pub struct MethodRuns {
    /// Which method.
    pub method: Method,
    /// Open-loop runs on the accuracy scenarios (empty for closed-loop-only methods).
    pub open: Vec<RunResult>,
    /// Closed-loop rescues (empty for methods that do not guide).
    pub closed: Vec<Rescue>,
}

/// One open-loop run of `method` on scenario `seed` (the calibrated `paper` case).
pub fn run_open(method: Method, seed: u64, noise: &MotionNoise) -> Option<RunResult> {
    match (method, method.factory()) {
        (Method::Sog, _) => Some(accuracy::run_open_loop(Case::Calibrated, seed, noise)),
        (_, Some(make)) => Some(accuracy::run_open_loop_with(
            Case::Calibrated,
            seed,
            noise,
            make,
        )),
        _ => None,
    }
}

/// Runs `method` on seeds `first_seed..first_seed + runs`, in parallel over scenarios.
pub fn run_method(method: Method, first_seed: u64, runs: u64) -> anyhow::Result<MethodRuns> {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    let noise = MotionNoise::default();
    let seeds = first_seed..first_seed + runs;
    let open: Vec<RunResult> = if method.open_loop() {
        seeds
            .clone()
            .into_par_iter()
            .progress_with(crate::cli::progress::bar(
                runs,
                &format!("{} runs", method.name()),
            ))
            .filter_map(|s| run_open(method, s, &noise))
            .collect()
    } else {
        Vec::new()
    };
    let closed = match method.closed_loop() {
        Some(case) => seeds
            .into_par_iter()
            .progress_with(crate::cli::progress::bar(
                runs,
                &format!("{} rescues", method.name()),
            ))
            .map(|s| rescue_report::run_one(case, s))
            .collect::<anyhow::Result<Vec<_>>>()?,
        None => Vec::new(),
    };
    Ok(MethodRuns {
        method,
        open,
        closed,
    })
}

const WHY_SOG: &str = "the reference: a bank of EKFs over the robocentric state (IROS Alg. 1) with the walk-long scale factor and the orientation in the state, initialized on the first pulse's ring; constant work per pulse in fixed memory.";
const WHY_LM: &str = "the maximum-likelihood fit of position and moment to every pulse so far, with the same noise model and priors (moment and depth), restarted from the first pulse's ring to escape the mirror minima and re-linearized over the whole history at every pulse, so with enough pulses it is close to the best any estimator can do with these measurements (re-linearizing is also why it can be ahead in the middle of the walk, where the SOGs filter's components are still wide and each pulse was linearized once). It does not estimate the dead-reckoning scale factor nor the attitude errors (it takes the dead-reckoned poses as exact), which the SOGs filter carries in its state; and early in the walk, when the measurements allow several separated solutions, it commits to one (the lowest cost) where the SOGs filter keeps them all. Its cost grows with the number of pulses and it needs the whole history in memory: host only.";
const WHY_RLS: &str = "the identifier of Mimmo et al. uses only |H| (eq. 12: the direction of the field is discarded), replaces the dipole pattern by an ellipsoid (eq. 7, a few per cent error), and needs a persistently exciting receiver path to identify its ten unknowns. A rescuer walks at a nearly constant receiver height, and then four of the ten regressors are linearly dependent on the others (the test `a_planar_path_is_not_persistently_exciting`), so the unknowns that carry the victim's depth and its coupling with the horizontal position are not identified and Υ returns a position tens of metres off: faithful to the paper, and it fails on a walk. In its own paper's protocol — a drone flying the reference generator of eq. 22 with 2 m sinusoids on every axis — the same identifier converges in most flights, and it stops converging as the excitation shrinks to what a walking person can swing: see \"RLS identifier + trajectory generator in Mimmo et al.'s own protocol\" below (measured over the same seeds).";
const WHY_DS: &str = "the classical search stops at the strongest reading of a cross search with the receiver above the snow: the maximum of |H| at the surface is offset from the point above a deep, tilted transmitter, and the search's 0.2 m spacing and the noise of single pulses add to that. It is compared with the SOGs receiver's closed-loop rescues (the same rescuer and scenario draw), horizontally.";
