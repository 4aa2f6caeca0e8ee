//! The error budget of the calibrated case: each motion error source scaled or removed, the
//! oracle starts, and the Cramér–Rao bound's efficient error.

use super::*;

/// The error sources of the calibrated case, for the error budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// Horizontal dead-reckoning noise `σ_t` (m/√m).
    Translation,
    /// Vertical dead-reckoning noise `σ_z` (m/√m).
    Vertical,
    /// Hand wobble per interval (m).
    Hand,
    /// Per-interval rotation noise `σ_r` (rad).
    Rotation,
    /// Walk-long step-length scale error (and the filter's prior on it).
    Scale,
    /// Absolute roll/pitch error.
    Tilt,
    /// Absolute yaw error.
    Yaw,
    /// Pulse noise (ICRA eq. 10).
    Pulse,
}

/// Every source, in the budget's order.
pub const SOURCES: [Source; 8] = [
    Source::Translation,
    Source::Vertical,
    Source::Hand,
    Source::Rotation,
    Source::Scale,
    Source::Tilt,
    Source::Yaw,
    Source::Pulse,
];

/// Multiplier standing for a removed source: 10 % of its level (1 % of its variance),
/// not 0, so every declared covariance stays positive definite and the pulses keep a
/// noise floor (the error's variance adds up over the sources, so 1 % of a source's
/// variance leaves ≈ nothing of its share).
pub const REMOVED: f64 = 0.1;

/// `noise` with source `source` multiplied by `k` (the true error and the filter's
/// declared variance alike).
pub fn scaled(noise: &MotionNoise, source: Source, k: f64) -> MotionNoise {
    let mut n = *noise;
    match source {
        Source::Translation => n.sigma_t_m_per_sqrt_m *= k,
        Source::Vertical => n.sigma_z_m_per_sqrt_m *= k,
        Source::Hand => n.sigma_hand_m *= k,
        Source::Rotation => n.sigma_r_rad *= k,
        Source::Scale => n.scale_multiplier *= k,
        Source::Tilt => n.attitude_sigma_rad[0] *= k,
        Source::Yaw => n.attitude_sigma_rad[1] *= k,
        Source::Pulse => n.pulse_multiplier *= k,
    }
    n
}

/// `noise` with every motion source but `keep` removed ([`REMOVED`]), the pulse noise
/// kept (it is the measurement: without it the updates are only as good as their
/// linearization); `None` keeps the pulse noise alone.
pub fn only(noise: &MotionNoise, keep: Option<Source>) -> MotionNoise {
    SOURCES
        .iter()
        .filter(|&&s| Some(s) != keep && s != Source::Pulse)
        .fold(*noise, |n, &s| scaled(&n, s, REMOVED))
}

/// Draws per run of the bound-efficient estimator's error (see [`bound_stats`]).
pub(super) const BOUND_DRAWS: usize = 200;

/// The final 3-D error an efficient unbiased estimator would have on `runs`, from
/// their Cramér–Rao bounds ([`crate::eval::accuracy_bound`]): errors drawn from
/// `N(0, C_bound)`, [`BOUND_DRAWS`] per run (seeded), pooled; `[99th percentile, mean,
/// median]` (the 99th percentile stands for the largest of 100 runs), each divided by
/// the run's final distance when `relative`; horizontal errors when `horizontal`.
pub fn bound_stats(runs: &[RunResult], relative: bool, horizontal: bool) -> Option<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(0xb0_0d);
    let mut draws: Vec<f64> = Vec::new();
    for r in runs {
        let Some(l) = r.final_bound.and_then(|c| c.cholesky()) else {
            continue;
        };
        let d = if relative { r.final_distance_m } else { 1.0 };
        for _ in 0..BOUND_DRAWS {
            let n = V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng));
            let e = l.l() * n;
            let e = if horizontal { e.xy().norm() } else { e.norm() };
            draws.push(e / d);
        }
    }
    let [_, mean, median] = stats(draws.iter().map(|&x| Some(x)))?;
    draws.sort_by(f64::total_cmp);
    let p99 = draws
        .get(((draws.len() - 1) as f64 * 0.99) as usize)
        .copied()?;
    Some([p99, mean, median])
}

/// Mean over `runs` of the final error normalized by the bound, `eᵀ C_bound⁻¹ e`: 3 for
/// an efficient estimator, more when the estimator loses information.
pub fn bound_normalized_mean(runs: &[RunResult]) -> Option<f64> {
    let v: Vec<f64> = runs
        .iter()
        .filter_map(|r| {
            let inv = r.final_bound?.try_inverse()?;
            let e = r.final_error_vec?;
            Some((e.transpose() * inv * e)[(0, 0)])
        })
        .collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// One row of the error budget: final 3-D error max/mean/median, truth inside 3σ, mean
/// NEES, the bound's efficient error and the error normalized by the bound.
pub(super) fn budget_row(label: &str, runs: &[RunResult]) -> String {
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let nees: f64 = runs.iter().map(|r| r.nees_sum).sum();
    format!(
        "| {label} | {} | {:.1} | {:.2} | {} | {:.2} |\n",
        fmt3(stats(runs.iter().map(|r| r.final_error_m))),
        100.0 * inside as f64 / evaluated.max(1) as f64,
        nees / evaluated.max(1) as f64,
        fmt3(bound_stats(runs, false, false)),
        bound_normalized_mean(runs).unwrap_or(f64::NAN),
    )
}

/// The error budget of the calibrated case (seeds `first_seed..`): the pulse noise with
/// each motion source, every source removed, and the oracle starts (an EKF without
/// mixture near the truth). Every variant sees the same scenarios and the same noise
/// draws (only their amplitudes change), so the rows compare run by run.
pub fn budget(first_seed: u64, tries: u64, noise: &MotionNoise) -> String {
    use rayon::prelude::*;
    let case = Case::Calibrated;
    let seeds = first_seed..first_seed + tries;
    let run = |n: MotionNoise| -> Vec<RunResult> {
        seeds
            .clone()
            .into_par_iter()
            .map(|seed| run_open_loop(case, seed, &n))
            .collect()
    };
    let mut s = String::from(
        "| variant | max | mean | median | inside 3σ (%) | mean NEES | bound: p99 | bound: mean | bound: median | eᵀC⁻¹e mean |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let base = run(*noise);
    s.push_str(&budget_row("SOG, all sources (default)", &base));
    s.push_str(&budget_row(
        "SOG, pulse noise only (motion sources removed)",
        &run(only(noise, None)),
    ));
    for src in SOURCES {
        eprintln!("accuracy budget: {src:?} …");
        if src != Source::Pulse {
            s.push_str(&budget_row(
                &format!("SOG, pulse noise + {src:?} only"),
                &run(only(noise, Some(src))),
            ));
        }
        s.push_str(&budget_row(
            &format!("SOG, all but {src:?}"),
            &run(scaled(noise, src, REMOVED)),
        ));
    }
    for rel in ORACLE_REL_SIGMAS {
        let o: Vec<RunResult> = seeds
            .clone()
            .into_par_iter()
            .map(|seed| run_open_loop_oracle(case, seed, noise, rel))
            .collect();
        let name = format!("EKF, oracle start (σ_p {:.0} % of range)", 100.0 * rel);
        s.push_str(&budget_row(&name, &o));
        s.push_str(&paired_line(&base, &o));
    }
    s
}

/// Relative position σ of the oracle starts in the budget.
pub const ORACLE_REL_SIGMAS: [f64; 2] = [0.05, 0.15];

/// A table row comparing the SOG's final error with the oracle's, run by run.
pub(super) fn paired_line(sog: &[RunResult], oracle: &[RunResult]) -> String {
    let d: Vec<Option<f64>> = sog
        .iter()
        .zip(oracle)
        .map(|(a, b)| Some(a.final_error_m? - b.final_error_m?))
        .collect();
    let worse = d.iter().flatten().filter(|&&x| x > 0.0).count();
    format!(
        "| ↳ SOG − oracle, per run (SOG worse in {worse} of {}) | {} | | | | | | |\n",
        d.iter().flatten().count(),
        fmt3(stats(d.into_iter())),
    )
}
