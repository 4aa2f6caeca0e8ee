//! The SOGs filter and the RBPF under IROS 2006 §V's protocol, both in closed loop: the
//! rescuer walks by the estimator's own belief (flux line until the receiver is outside
//! the belief's 3σ, then to its mean, probe when over it: IROS III-C), as the paper runs
//! both; start 40–60 m away, 1 m/s, one pulse per second, the transmitter's position,
//! orientation and power random, the error of the estimate at the end.
//!
//! The walker and the guidance are `accuracy`'s closed loop
//! ([`accuracy::run_closed_loop_with`]); this module adds what the RBPF's tail needs to
//! be explained: per run, where the filter first had an estimate, how depleted its
//! particles were ([`fb::Rbpf::n_eff`], resamplings), whether it ended confident and
//! wrong (the truth outside its reported 3σ), and where the receiver stood.
use crate::eval::accuracy::{self, MotionNoise, RunResult, stats};
use crate::world::physics::V3;
use firmware::estimate::baselines as fb;
use firmware::estimate::{DefaultSog, Estimator, VictimEstimate};
use std::fmt::Write as _;

/// IROS §V's start distances, m.
pub const START_M: std::ops::RangeInclusive<f64> = 40.0..=60.0;

/// The particle count of IROS §IV's RBPF.
const PARTICLES: usize = 5000;

/// The RBPF's generator seed (as in the common protocol's rows).
const FILTER_SEED: u64 = 1;

/// One closed-loop try and what explains its outcome.
#[derive(Debug, Clone)]
pub struct IrosRun {
    /// The walk's bookkeeping (final error, steps to "probe here", re-initializations, …).
    pub run: RunResult,
    /// True distance (3-D) when the filter first had an estimate, m.
    pub first_estimate_at_m: Option<f64>,
    /// Resamplings over the walk (RBPF only).
    pub resamples: Option<u32>,
    /// The reported position standard deviation at the end, `√(tr P / 3)`, m.
    pub final_sigma_m: Option<f64>,
    /// Squared Mahalanobis distance of the truth from the final estimate (NEES).
    pub final_nees: Option<f64>,
    /// Receiver's horizontal distance from the victim at the end, m.
    pub final_receiver_h_m: f64,
}

impl IrosRun {
    /// Whether the final error exceeds 1 m (or there is no estimate).
    pub fn over_1m(&self) -> bool {
        self.run.final_error_m.is_none_or(|e| e > 1.0)
    }

    /// Whether the truth ends outside the reported 3σ (NEES > 9): a confident belief
    /// that does not hold the victim.
    pub fn outside_3sigma(&self) -> bool {
        self.final_nees.is_none_or(|d2| d2 > 9.0)
    }
}

/// Per-pulse diagnostics gathered by the observer.
#[derive(Default)]
struct Watch {
    first_at: Option<f64>,
    resamples: Option<u32>,
    last: Option<(VictimEstimate, V3)>,
}

impl Watch {
    fn see(&mut self, est: Option<VictimEstimate>, truth: &V3, resamples: Option<u32>) {
        let Some(e) = est else {
            return;
        };
        self.first_at.get_or_insert(truth.norm());
        self.resamples = resamples;
        self.last = Some((e, *truth));
    }

    fn finish(self, run: RunResult) -> IrosRun {
        let (sigma, nees, rx_h) = match self.last {
            Some((e, truth)) => {
                let cov = crate::world::physics::M3::from_fn(|i, j| f64::from(e.cov[(i, j)]));
                let d = V3::new(
                    f64::from(e.p.x) - truth.x,
                    f64::from(e.p.y) - truth.y,
                    f64::from(e.p.z) - truth.z,
                );
                let nees = cov
                    .try_inverse()
                    .map(|inv| (d.transpose() * inv * d)[(0, 0)]);
                (
                    Some((cov.trace() / 3.0).max(0.0).sqrt()),
                    nees,
                    truth.xy().norm(),
                )
            }
            None => (None, None, f64::NAN),
        };
        IrosRun {
            run,
            first_estimate_at_m: self.first_at,
            resamples: self.resamples,
            final_sigma_m: sigma,
            final_nees: nees,
            final_receiver_h_m: rx_h,
        }
    }
}

/// An RBPF configuration: ours, or with the additions to IROS Alg. 3 taken out.
#[derive(Debug, Clone, Copy)]
pub struct RbpfVariant {
    /// Row label.
    pub label: &'static str,
    /// Roughening of the resampled copies' positions (fraction of the range, 1σ; ours
    /// 0.01, IROS Alg. 3 has none).
    pub roughen: f32,
    /// Re-initialization from the pulse when no particle has been consistent for
    /// `divergence_pulses` pulses (ours; IROS Alg. 3 has none).
    pub reinitialize: bool,
    /// Drawn from the first pulse heard, however weak (IROS §V: "after the first
    /// measurement"), instead of the first with |H| ≥ `init_snr` σ_bkg (ours: 10).
    pub first_pulse: bool,
}

/// The RBPF rows: ours, then IROS Alg. 3 as the paper states it, one addition at a time.
pub const RBPF_VARIANTS: [RbpfVariant; 5] = [
    RbpfVariant {
        label: "RBPF (5000), ours: roughening 1 %, re-initialized on divergence",
        roughen: 0.01,
        reinitialize: true,
        first_pulse: false,
    },
    RbpfVariant {
        label: "RBPF (5000), no roughening",
        roughen: 0.0,
        reinitialize: true,
        first_pulse: false,
    },
    RbpfVariant {
        label: "RBPF (5000), no re-initialization",
        roughen: 0.01,
        reinitialize: false,
        first_pulse: false,
    },
    RbpfVariant {
        label: "RBPF (5000), IROS Alg. 3 as stated: neither",
        roughen: 0.0,
        reinitialize: false,
        first_pulse: false,
    },
    RbpfVariant {
        label: "RBPF (5000), IROS Alg. 3 as stated, drawn from the first pulse at the start",
        roughen: 0.0,
        reinitialize: false,
        first_pulse: true,
    },
];

/// One IROS §V closed-loop try of the RBPF (5000 particles) `v` on `seed`.
pub fn run_rbpf(v: &RbpfVariant, seed: u64) -> IrosRun {
    run_rbpf_with(v, seed, &MotionNoise::default())
}

/// [`run_rbpf`] with the given noise (the pulse noise multiplier for the noise sweep).
pub fn run_rbpf_with(v: &RbpfVariant, seed: u64, noise: &MotionNoise) -> IrosRun {
    let mut w = Watch::default();
    let params = fb::ParticleConfig {
        roughen: v.roughen,
        ..fb::ParticleConfig::seeded(FILTER_SEED)
    };
    let (reinitialize, first_pulse) = (v.reinitialize, v.first_pulse);
    let run = accuracy::run_closed_loop_with(
        seed,
        noise,
        START_M,
        |mut c| {
            if !reinitialize {
                // Never `divergence_pulses` inconsistent pulses in a row within a walk
                // (at most 3 × 60 + 10 pulses).
                c.divergence_pulses = u8::MAX;
            }
            if first_pulse {
                c.init_snr = 0.0;
            }
            fb::Rbpf::<PARTICLES>::with_params(c, params)
                .ok()
                .map(Box::new)
        },
        &mut |f: &fb::Rbpf<PARTICLES>, truth| {
            w.see(f.estimate(), truth, Some(f.resamples()));
        },
    );
    w.finish(run)
}

/// One IROS §V closed-loop try of the SOGs filter on `seed`.
pub fn run_sog(seed: u64) -> IrosRun {
    run_sog_with(seed, &MotionNoise::default())
}

/// [`run_sog`] with the given noise.
pub fn run_sog_with(seed: u64, noise: &MotionNoise) -> IrosRun {
    let mut w = Watch::default();
    let run = accuracy::run_closed_loop_with(
        seed,
        noise,
        START_M,
        |c| DefaultSog::new(c).ok().map(Box::new),
        &mut |f: &DefaultSog, truth| w.see(f.estimate(), truth, None),
    );
    w.finish(run)
}

/// The SOGs filter and every RBPF variant over seeds `first..first + n`, in parallel.
pub fn run_all(first: u64, n: u64) -> (Vec<IrosRun>, Vec<Vec<IrosRun>>) {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    eprintln!("baselines: SOGs, IROS closed loop × {n} …");
    let sog = (first..first + n)
        .into_par_iter()
        .progress_with(crate::cli::progress::bar(n, "IROS closed loop, SOGs"))
        .map(run_sog)
        .collect();
    let rbpf = RBPF_VARIANTS
        .iter()
        .map(|v| {
            eprintln!("baselines: {} × {n} …", v.label);
            (first..first + n)
                .into_par_iter()
                .progress_with(crate::cli::progress::bar(n, "IROS closed loop, RBPF"))
                .map(|seed| run_rbpf(v, seed))
                .collect()
        })
        .collect();
    (sog, rbpf)
}

fn fmt3(s: Option<[f64; 3]>, digits: usize) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.digits$} / {b:.digits$} / {c:.digits$}"),
        None => "–".into(),
    }
}

/// Median of the present values.
fn median(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    stats(v).map(|[_, _, m]| m)
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

/// A row of the IROS table for `runs`.
fn row(label: &str, runs: &[IrosRun]) -> String {
    let n = runs.len();
    let over = runs.iter().filter(|r| r.over_1m()).count();
    let far = runs
        .iter()
        .filter(|r| r.run.final_error_m.is_none_or(|e| e > 5.0))
        .count();
    let probed = runs
        .iter()
        .filter(|r| r.run.steps_to_probe.is_some())
        .count();
    let reinit: usize = runs.iter().map(|r| r.run.reinitializations).sum();
    format!(
        "| {label} | {n} | {} | {} ({probed} probed) | {} | {} | {over} of {n} | {far} | {reinit} |\n",
        fmt3(stats(runs.iter().map(|r| Some(r.run.start_distance_m))), 1),
        fmt3(
            stats(runs.iter().map(|r| r.run.steps_to_probe.map(|k| k as f64))),
            0
        ),
        fmt3(
            stats(runs.iter().map(|r| r.run.steps_to_mean.map(|k| k as f64))),
            0
        ),
        fmt3(stats(runs.iter().map(|r| r.run.final_error_m)), 2),
    )
}

/// The IROS table: the SOGs filter and the RBPF variants in closed loop, then the
/// paper's Table I.
pub fn iros_table(sog: &[IrosRun], rbpf: &[Vec<IrosRun>]) -> String {
    let mut s = String::from(
        "| method, IROS §V closed loop | tries | start distance max / mean / median (m) | steps to \"probe here\" max / mean / median | steps until first over the mean max / mean / median | final error max / mean / median (m) | error > 1 m | error > 5 m | re-initializations |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    s.push_str(&row("SOGs filter", sog));
    for (v, runs) in RBPF_VARIANTS.iter().zip(rbpf) {
        s.push_str(&row(v.label, runs));
    }
    s.push_str("| **IROS 2006 Table I**: SOGs | 100 | 60 / 50.4 / 51 | 93 / 62 / 61 | – | 0.66 / 0.23 / 0.21 | – | – | – |\n");
    s.push_str("| **IROS 2006 Table I**: RBPF (5000 particles) | 100 | 60 / 50.4 / 51 | 99 / 64 / 64 | – | 32.5 / 2.27 / 0.28 | 25 of 100 (their Fig. 5) | – | – |\n");
    s.push_str(&steps_reading(sog));
    s
}

/// The SOGs filter's steps against the paper's, split at the receiver's first arrival
/// over the mean: the walk, then our stop rule (which the paper does not state).
fn steps_reading(sog: &[IrosRun]) -> String {
    let probe = stats(sog.iter().map(|r| r.run.steps_to_probe.map(|k| k as f64)));
    let mean = stats(sog.iter().map(|r| r.run.steps_to_mean.map(|k| k as f64)));
    let arrived = sog.iter().filter(|r| r.run.steps_to_mean.is_some()).count();
    let rule: Vec<f64> = sog
        .iter()
        .filter_map(|r| Some((r.run.steps_to_probe? - r.run.steps_to_mean?) as f64))
        .collect();
    format!(
        "\nSteps. The SOGs filter's pulses to \"probe here\" ({} max / mean / median, {} probed) split at the receiver's first arrival within the probe radius of the mean ({} of {} arrived): the walk to the mean takes {}, then our stop rule takes {} more (max / mean / median over the probed runs: standing still for {} pulses once 3σ ≤ {} m, or sweeping across the mean up to {} pulses while it is wider). The paper's 93 / 62 / 61 counts to its stop, whose rule it does not state; the walk alone is what both protocols share.\n",
        fmt3(probe, 0),
        sog.iter()
            .filter(|r| r.run.steps_to_probe.is_some())
            .count(),
        arrived,
        sog.len(),
        fmt3(mean, 0),
        fmt3(stats(rule.into_iter().map(Some)), 1),
        crate::eval::accuracy::PROBE_STILL_PULSES,
        crate::eval::accuracy::PROBE_RADIUS_M,
        4 * crate::eval::accuracy::PROBE_STILL_PULSES,
    )
}

/// What a variant's tries over 1 m have in common against its good ones: one row per
/// group (final error ≤ 1 m, > 1 m, the five worst), then the five worst one by one.
pub fn rbpf_anatomy(runs: &[IrosRun]) -> String {
    let mut sorted: Vec<&IrosRun> = runs.iter().collect();
    let key = |r: &IrosRun| r.run.final_error_m.unwrap_or(f64::INFINITY);
    sorted.sort_by(|a, b| key(b).total_cmp(&key(a)));
    let good: Vec<&IrosRun> = runs.iter().filter(|r| !r.over_1m()).collect();
    let bad: Vec<&IrosRun> = runs.iter().filter(|r| r.over_1m()).collect();
    let worst: Vec<&IrosRun> = sorted.iter().take(5).copied().collect();
    let mut s = String::from(
        "| tries | n | start, median (m) | first estimate at, median (m) | resamplings, median | reported σ at the end, median (m) | truth outside the reported 3σ | reached \"probe here\" | receiver's final distance to the victim, median (m) | final error, median (m) |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (label, g) in [
        ("final error ≤ 1 m", &good),
        ("final error > 1 m", &bad),
        ("the five worst", &worst),
    ] {
        let n = g.len();
        let outside = g.iter().filter(|r| r.outside_3sigma()).count();
        let probed = g.iter().filter(|r| r.run.steps_to_probe.is_some()).count();
        let _ = writeln!(
            s,
            "| {label} | {n} | {} | {} | {} | {} | {outside} of {n} | {probed} of {n} | {} | {} |",
            opt(median(g.iter().map(|r| Some(r.run.start_distance_m))), 1),
            opt(median(g.iter().map(|r| r.first_estimate_at_m)), 1),
            opt(median(g.iter().map(|r| r.resamples.map(f64::from))), 0),
            opt(median(g.iter().map(|r| r.final_sigma_m)), 3),
            opt(median(g.iter().map(|r| Some(r.final_receiver_h_m))), 2),
            opt(median(g.iter().map(|r| r.run.final_error_m)), 2),
        );
    }
    s.push_str("\nThe five worst tries:\n\n| seed | final error (m) | start (m) | first estimate at (m) | resamplings | re-initializations | reported σ (m) | NEES at the end | pulses (probe?) | receiver's final distance to the victim (m) |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for r in &worst {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {} | {} | {} | {} | {:.0} | {} ({}) | {:.2} |",
            r.run.seed,
            opt(r.run.final_error_m, 2),
            r.run.start_distance_m,
            opt(r.first_estimate_at_m, 1),
            r.resamples.map_or("–".into(), |k| k.to_string()),
            r.run.reinitializations,
            opt(r.final_sigma_m, 3),
            r.final_nees.unwrap_or(f64::NAN),
            r.run.pulses,
            if r.run.steps_to_probe.is_some() {
                "probed"
            } else {
                "never probed"
            },
            r.final_receiver_h_m,
        );
    }
    s
}

/// Pulse-noise multipliers of the noise sweep (ICRA eq. 10's σ_bkg and k_sen, simulated
/// and declared alike): the paper gives neither, ×1 is the firmware's calibrated pair.
pub const NOISE_SWEEP: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// The SOGs filter and our RBPF at one pulse-noise level.
#[derive(Debug, Clone)]
pub struct NoiseLevel {
    /// Pulse-noise multiplier.
    pub k: f64,
    /// SOGs filter tries.
    pub sog: Vec<IrosRun>,
    /// RBPF (ours) tries.
    pub rbpf: Vec<IrosRun>,
}

/// Runs the SOGs filter and our RBPF at every level of [`NOISE_SWEEP`] on seeds
/// `first..first + n`; the ×1 level reuses `sog` and `ours` (the main table's runs).
pub fn noise_sweep(first: u64, n: u64, sog: &[IrosRun], ours: &[IrosRun]) -> Vec<NoiseLevel> {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    NOISE_SWEEP
        .iter()
        .map(|&k| {
            if k == 1.0 {
                return NoiseLevel {
                    k,
                    sog: sog.to_vec(),
                    rbpf: ours.to_vec(),
                };
            }
            let noise = MotionNoise {
                pulse_multiplier: k,
                ..MotionNoise::default()
            };
            eprintln!("baselines: IROS closed loop, pulse noise ×{k} × {n} …");
            NoiseLevel {
                k,
                sog: (first..first + n)
                    .into_par_iter()
                    .progress_with(crate::cli::progress::bar(n, "IROS closed loop, SOGs"))
                    .map(|seed| run_sog_with(seed, &noise))
                    .collect(),
                rbpf: (first..first + n)
                    .into_par_iter()
                    .progress_with(crate::cli::progress::bar(n, "IROS closed loop, RBPF"))
                    .map(|seed| run_rbpf_with(&RBPF_VARIANTS[0], seed, &noise))
                    .collect(),
            }
        })
        .collect()
}

/// The noise sweep's table and its reading (which level matches the paper's SOGs row,
/// the RBPF's median there, and the median without our roughening, `no_roughening`).
pub fn noise_section(levels: &[NoiseLevel], no_roughening: Option<&[IrosRun]>) -> String {
    let median_of = |runs: &[IrosRun]| median(runs.iter().map(|r| r.run.final_error_m));
    let mut s = String::from(
        "| pulse noise (σ_bkg and k_sen ×) | SOGs final error max / mean / median (m) | SOGs > 1 m | RBPF (ours) final error max / mean / median (m) | RBPF > 1 m | RBPF truth outside its 3σ |\n|---|---|---|---|---|---|\n",
    );
    for l in levels {
        let over = |r: &[IrosRun]| r.iter().filter(|r| r.over_1m()).count();
        let _ = writeln!(
            s,
            "| ×{} | {} | {} of {} | {} | {} of {} | {} of {} |",
            l.k,
            fmt3(stats(l.sog.iter().map(|r| r.run.final_error_m)), 2),
            over(&l.sog),
            l.sog.len(),
            fmt3(stats(l.rbpf.iter().map(|r| r.run.final_error_m)), 2),
            over(&l.rbpf),
            l.rbpf.len(),
            l.rbpf.iter().filter(|r| r.outside_3sigma()).count(),
            l.rbpf.len(),
        );
    }
    s.push_str("| **IROS 2006 Table I** (noise not given) | 0.66 / 0.23 / 0.21 | – | 32.5 / 2.27 / 0.28 | 25 of 100 | – |\n");
    // The level whose SOGs median is nearest the paper's 0.21 m (log distance).
    let nearest = levels
        .iter()
        .filter_map(|l| median_of(&l.sog).map(|m| (l, (m / 0.21).ln().abs())))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(l, _)| l);
    let rbpf_medians: Vec<String> = levels
        .iter()
        .map(|l| format!("×{}: {}", l.k, opt(median_of(&l.rbpf), 2)))
        .collect();
    let below = levels
        .iter()
        .filter(|l| median_of(&l.rbpf).is_some_and(|m| m <= 0.28))
        .map(|l| format!("×{}", l.k))
        .collect::<Vec<_>>();
    if let Some(l) = nearest {
        let _ = write!(
            s,
            "\nReading. The paper gives no pulse noise, so the sweep scales ICRA eq. 10's σ_bkg and k_sen together (simulated and declared to both filters). The SOGs filter's median is nearest the paper's 0.21 m at ×{} ({} m); there our RBPF's median is {} m against the paper's 0.28 m. Our RBPF's median by level: {}. ",
            l.k,
            opt(median_of(&l.sog), 2),
            opt(median_of(&l.rbpf), 2),
            rbpf_medians.join(", "),
        );
        if below.is_empty() {
            s.push_str("At no level does it reach the paper's 0.28 m, so the noise level does not explain the paper's lower median.");
            if let Some(nr) = no_roughening.and_then(median_of) {
                let _ = write!(
                    s,
                    " What moves it is our roughening of the resampled copies (1 % of the range, not in IROS Alg. 3): without it, at ×1, the median is {nr:.2} m (second RBPF row above), at the price of more re-initializations.",
                );
            }
            s.push('\n');
        } else {
            let _ = writeln!(
                s,
                "It reaches the paper's 0.28 m or less at {}, where the SOGs filter's median is {}: one noise level does not give both of the paper's medians, so the noise alone does not explain the RBPF's lower paper median.",
                below.join(", "),
                levels
                    .iter()
                    .filter(|l| median_of(&l.rbpf).is_some_and(|m| m <= 0.28))
                    .map(|l| format!("{} m", opt(median_of(&l.sog), 2)))
                    .collect::<Vec<_>>()
                    .join(", "),
            );
        }
    }
    s
}

/// The IROS section: protocol, table, the RBPF's failures dissected, the reading; and its
/// headline numbers for the sidecar.
pub fn iros_section(first: u64, n: u64) -> (String, serde_json::Value) {
    let (sog, rbpf) = run_all(first, n);
    let mut s = String::from(
        "### SOGs filter and RBPF under IROS 2006 §V's protocol\n\nProtocol (IROS §V): 100 tries, start 40–60 m away, 1 m/s, one measurement per second, the transmitter's position, orientation and power random, the search control of §III-C (flux line until the receiver is outside the belief's 3σ, then to its mean), the error of the estimate at the end. Ours (`baselines::paper::iros`): `accuracy`'s closed-loop walker and guidance (`accuracy::run_closed_loop_with`), start drawn 40–60 m, stop at \"probe here\" (over the mean with 3σ ≤ 0.3 m for 4 pulses, or after 16 pulses of sweeping over it) or after 3× the ideal steps + 10; each filter guides its own walk, as in the paper (same seeds, so the same victims and starts); the 3-D error at the last pulse. The RBPF is IROS Alg. 3 (5000 particles, systematic resampling at N_eff < N/2) with two additions of ours, each taken out in a row of its own: roughening of the resampled copies' positions (1 % of the range, 1σ) and re-initialization from the pulse after 5 pulses no particle explains (the SOGs filter's divergence rule).\n\n",
    );
    s.push_str(&reading(&sog, &rbpf));
    s.push('\n');
    s.push_str(&iros_table(&sog, &rbpf));
    let mut levels = Vec::new();
    if let Some(ours) = rbpf.first() {
        s.push_str("\nThe pulse noise, which the paper does not give: the SOGs filter and our RBPF (first RBPF row) on the same seeds with ICRA eq. 10's σ_bkg and k_sen scaled together.\n\n");
        levels = noise_sweep(first, n, &sog, ours);
        s.push_str(&noise_section(&levels, rbpf.get(1).map(Vec::as_slice)));
    }
    for (v, runs) in RBPF_VARIANTS.iter().zip(&rbpf) {
        let _ = write!(
            s,
            "\nWhat the tries over 1 m have in common, {} (\"truth outside the reported 3σ\": the final estimate's NEES above 9):\n\n",
            v.label
        );
        s.push_str(&rbpf_anatomy(runs));
    }
    let summary = iros_summary(&sog, &rbpf, &levels);
    (s, summary)
}

/// Final error max / mean / median and tries over 1 m of the SOGs filter, every RBPF row
/// and every noise level (the sidecar's headline numbers).
fn iros_summary(
    sog: &[IrosRun],
    rbpf: &[Vec<IrosRun>],
    levels: &[NoiseLevel],
) -> serde_json::Value {
    let one = |runs: &[IrosRun]| {
        serde_json::json!({
            "final_error_m_max_mean_median": stats(runs.iter().map(|r| r.run.final_error_m)),
            "over_1m": runs.iter().filter(|r| r.over_1m()).count(),
        })
    };
    serde_json::json!({
        "sog": one(sog),
        "rbpf": RBPF_VARIANTS.iter().zip(rbpf).map(|(v, r)| serde_json::json!({"variant": v.label, "runs": one(r)})).collect::<Vec<_>>(),
        "noise_sweep": levels.iter().map(|l| serde_json::json!({"pulse_noise_x": l.k, "sog": one(&l.sog), "rbpf": one(&l.rbpf)})).collect::<Vec<_>>(),
    })
}

/// The reading of the IROS section, from the runs of [`RBPF_VARIANTS`] (current result
/// first).
pub fn reading(sog: &[IrosRun], rbpf: &[Vec<IrosRun>]) -> String {
    let line = |runs: &[IrosRun]| {
        let n = runs.len();
        let over = runs.iter().filter(|r| r.over_1m()).count();
        format!(
            "{} m with {over} of {n} over 1 m",
            fmt3(stats(runs.iter().map(|r| r.run.final_error_m)), 2)
        )
    };
    let (Some(ours), Some(alg3), Some(first)) = (rbpf.first(), rbpf.get(3), rbpf.get(4)) else {
        return String::new();
    };
    let mut s = String::new();
    let _ = write!(
        s,
        "Reading. In IROS §V's closed loop (final error max / mean / median) the SOGs filter ends at {} (the paper: 0.66 / 0.23 / 0.21 m, none over 1 m) and our RBPF at {} (the paper: 32.5 / 2.27 / 0.28 m, 25 of 100 over 1 m). ",
        line(sog),
        line(ours),
    );
    let _ = write!(
        s,
        "The paper's heavier tail is measured here as IROS Alg. 3 without our two additions: {} when drawn from the first pulse of ≥ 10 σ_bkg, as ours, and {} when drawn from the first pulse at the start, as the paper's §V describes (\"after the first measurement\"): the paper's 32.5 / 2.27 / 0.28 m and 25 failures lie between these two rows, and it states neither its initial threshold nor its pulse noise. ",
        line(alg3),
        line(first),
    );
    // What the failures have in common, from the runs.
    let bad: Vec<&IrosRun> = first.iter().filter(|r| r.over_1m()).collect();
    let outside = bad.iter().filter(|r| r.outside_3sigma()).count();
    let far: Vec<&IrosRun> = first
        .iter()
        .filter(|r| r.run.final_error_m.is_none_or(|e| e > 10.0))
        .collect();
    let far_unprobed = far
        .iter()
        .filter(|r| r.run.steps_to_probe.is_none())
        .count();
    let alg3_bad: Vec<&IrosRun> = alg3.iter().filter(|r| r.over_1m()).collect();
    let alg3_good: Vec<&IrosRun> = alg3.iter().filter(|r| !r.over_1m()).collect();
    let _ = write!(
        s,
        "What every failure has in common is a deprived particle set: in the first-pulse row {outside} of its {} tries over 1 m end with the truth outside the reported 3σ (reported σ {} m, median, for an error of {} m) — the particles collapsed onto a place the victim is not, as the paper's supervised runs found (\"loosing particles near the real location\"). Errors of tens of metres come from the rescuer following that belief: the {} tries over 10 m (largest {} m) end with the receiver a median {} m from the victim, {far_unprobed} of them never reaching \"probe here\" — the walk goes where the collapsed cloud says and never comes back over the victim to correct it. Drawn later, from a stronger pulse, the initial ring is smaller and better covered: Alg. 3's failures then first had an estimate {} m from the victim (its good tries: {} m) and stay within {} m. ",
        bad.len(),
        opt(median(bad.iter().map(|r| r.final_sigma_m)), 3),
        opt(median(bad.iter().map(|r| r.run.final_error_m)), 2),
        far.len(),
        opt(
            stats(far.iter().map(|r| r.run.final_error_m)).map(|[m, _, _]| m),
            1
        ),
        opt(median(far.iter().map(|r| Some(r.final_receiver_h_m))), 1),
        opt(median(alg3_bad.iter().map(|r| r.first_estimate_at_m)), 1),
        opt(median(alg3_good.iter().map(|r| r.first_estimate_at_m)), 1),
        opt(
            stats(alg3.iter().map(|r| r.run.final_error_m)).map(|[m, _, _]| m),
            1
        ),
    );
    let (Some(no_rough), Some(no_reinit)) = (rbpf.get(1), rbpf.get(2)) else {
        return s;
    };
    let _ = writeln!(
        s,
        "Our two additions each rescue most of those: without roughening {}, without re-initialization {}; with both, {}. Even our RBPF is over-confident at the end (the truth outside its reported 3σ in {} of {} tries, the SOGs filter in {} of {}): 5000 particles over the 7-D sampled state cannot represent a posterior that narrows to centimetres. The SOGs filter's errors are below the paper's: our pulses carry the noise of ICRA eq. 10 with the firmware's calibrated σ_bkg and k_sen, and the paper does not give its noise levels (the pulse-noise sweep below scales them).",
        line(no_rough),
        line(no_reinit),
        line(ours),
        ours.iter().filter(|r| r.outside_3sigma()).count(),
        ours.len(),
        sog.iter().filter(|r| r.outside_3sigma()).count(),
        sog.len(),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rbpf_walks_by_its_own_estimate_and_finds_most_victims() {
        // Four seeded tries: every one starts 40–60 m away, every one gets an estimate
        // before the end, and most end within a metre (the paper: 75 of 100).
        // The particle filter lives on the stack; an unoptimized (test-profile) build needs
        // more than the test thread's default 2 MiB for it.
        let runs: Vec<IrosRun> = std::thread::Builder::new()
            .stack_size(256 << 20)
            .spawn(|| (1..=4).map(|s| run_rbpf(&RBPF_VARIANTS[0], s)).collect())
            .expect("spawn the test thread")
            .join()
            .expect("the runs finish");
        for r in &runs {
            assert!(START_M.contains(&r.run.start_distance_m), "{r:?}");
            assert!(r.first_estimate_at_m.is_some(), "never estimated: {r:?}");
            assert!(r.resamples.is_some_and(|k| k > 0), "{r:?}");
        }
        let good = runs.iter().filter(|r| !r.over_1m()).count();
        assert!(good >= 3, "only {good} of 4 within 1 m: {runs:?}");
        // The walk came to the victim: the receiver ends near where it stopped.
        let near = runs.iter().filter(|r| r.final_receiver_h_m < 2.0).count();
        assert!(near >= 3, "{runs:?}");
    }

    /// One variant's anatomy on 100 seeds, printed (a measuring aid, not a check).
    #[test]
    #[ignore]
    fn iros_variant_probe() {
        let i: usize = std::env::var("IROS_VARIANT").map_or(4, |v| v.parse().unwrap());
        let runs: Vec<IrosRun> = {
            use rayon::prelude::*;
            (1..=100u64)
                .into_par_iter()
                .map(|s| run_rbpf(&RBPF_VARIANTS[i], s))
                .collect()
        };
        println!("{}", row(RBPF_VARIANTS[i].label, &runs));
        println!("{}", rbpf_anatomy(&runs));
    }

    /// The noise sweep on 100 seeds, printed (a measuring aid, not a check).
    #[test]
    #[ignore]
    fn noise_probe() {
        use rayon::prelude::*;
        let sog: Vec<IrosRun> = (1..=100u64).into_par_iter().map(run_sog).collect();
        let ours: Vec<IrosRun> = (1..=100u64)
            .into_par_iter()
            .map(|s| run_rbpf(&RBPF_VARIANTS[0], s))
            .collect();
        println!("{}", noise_section(&noise_sweep(1, 100, &sog, &ours), None));
    }

    /// The IROS section on 100 seeds, printed (a measuring aid, not a check).
    #[test]
    #[ignore]
    fn iros_probe() {
        println!("{}", iros_section(1, 100).0);
    }
}
