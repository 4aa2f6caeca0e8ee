//! The markdown of `hal-sim accuracy`: the summary, one section per case, the consistency line
//! and the budget note.

use super::*;

pub(super) const ALL_CASES: [Case; 6] = [
    Case::Known,
    Case::Calibrated,
    Case::Uncalibrated,
    Case::Paths,
    Case::ClosedLoop,
    Case::Imu,
];

pub(super) fn fmt3(s: Option<[f64; 3]>) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.3} | {b:.3} | {c:.3}"),
        None => "– | – | –".into(),
    }
}

/// Markdown section for one case's runs.
pub fn case_report(case: Case, runs: &[RunResult]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let n = runs.len();
    let init = runs.iter().filter(|r| r.final_error_m.is_some()).count();
    let _ = writeln!(s, "### {case:?} ({n} tries, {init} initialized)\n");
    let _ = writeln!(s, "| metric | max | mean | median |\n|---|---|---|---|");
    let rows: [(&str, Option<[f64; 3]>); 7] = [
        (
            "final error 3-D (m)",
            stats(runs.iter().map(|r| r.final_error_m)),
        ),
        (
            "final error horizontal (m)",
            stats(runs.iter().map(|r| r.final_error_h_m)),
        ),
        (
            "final depth error (m)",
            stats(runs.iter().map(|r| r.final_error_z_m)),
        ),
        (
            "error at 20 m (m)",
            stats(runs.iter().map(|r| r.error_at_20m)),
        ),
        (
            "error at 10 m (m)",
            stats(runs.iter().map(|r| r.error_at_10m)),
        ),
        (
            "initial distance (m)",
            stats(runs.iter().map(|r| Some(r.start_distance_m))),
        ),
        (
            "final true distance (m)",
            stats(runs.iter().map(|r| Some(r.final_distance_m))),
        ),
    ];
    for (name, st) in rows {
        let _ = writeln!(s, "| {name} | {} |", fmt3(st));
    }
    if case == Case::ClosedLoop {
        let _ = writeln!(
            s,
            "| steps to probe | {} |",
            fmt3(stats(
                runs.iter().map(|r| r.steps_to_probe.map(|x| x as f64))
            ))
        );
        let _ = writeln!(
            s,
            "| ideal steps | {} |",
            fmt3(stats(runs.iter().map(|r| r.ideal_steps.map(|x| x as f64))))
        );
        let ratio = stats(
            runs.iter()
                .map(|r| match (r.steps_to_probe, r.ideal_steps) {
                    (Some(a), Some(b)) => Some(a as f64 / b.max(1) as f64),
                    _ => None,
                }),
        );
        let _ = writeln!(s, "| steps / ideal | {} |", fmt3(ratio));
    }
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let over_1m = runs
        .iter()
        .filter(|r| r.final_error_m.is_none_or(|e| e > 1.0))
        .count();
    let reinit: usize = runs.iter().map(|r| r.reinitializations).sum();
    let comps = stats(runs.iter().map(|r| Some(r.max_components as f64)));
    let _ = writeln!(
        s,
        "\nTruth inside the reported 3σ ellipsoid on {:.1} % of {evaluated} steps; final error > 1 m (or never initialized) in {over_1m} of {n} runs; {reinit} re-initializations; components max/mean/median {} (step cost on the target: `budget.md`).",
        100.0 * inside as f64 / evaluated.max(1) as f64,
        fmt3(comps),
    );
    let _ = writeln!(s, "{}", consistency_line(runs));
    if let (Some(b), Some(rel), Some(h), Some(norm)) = (
        bound_stats(runs, false, false),
        bound_stats(runs, true, false),
        bound_stats(runs, false, true),
        bound_normalized_mean(runs),
    ) {
        let _ = writeln!(
            s,
            "Cramér–Rao bound of the final 3-D error (`accuracy_bound`: an efficient unbiased estimator given the same pulses, dead reckoning and attitude) p99 / mean / median {} m, {:.1} / {:.1} / {:.1} % of the final distance, horizontal {} m; this filter's final error normalized by the bound, eᵀC⁻¹e, mean {norm:.2} (3 if efficient).",
            fmt3(Some(b)),
            100.0 * rel[0],
            100.0 * rel[1],
            100.0 * rel[2],
            fmt3(Some(h)),
        );
    }
    let mut worst: Vec<&RunResult> = runs.iter().collect();
    worst.sort_by(|a, b| {
        b.final_error_m
            .unwrap_or(f64::INFINITY)
            .total_cmp(&a.final_error_m.unwrap_or(f64::INFINITY))
    });
    let list: Vec<String> = worst
        .iter()
        .take(5)
        .map(|r| {
            let sigmas = bound_normalized_mean(std::slice::from_ref(*r))
                .map(|d2| format!(", {:.1} bound σ", d2.sqrt()))
                .unwrap_or_default();
            format!(
                "seed {} ({:.3} m{sigmas})",
                r.seed,
                r.final_error_m.unwrap_or(f64::NAN)
            )
        })
        .collect();
    let _ = writeln!(s, "Worst runs: {}.\n", list.join(", "));
    s
}

/// The NEES and innovation consistency figures of `runs` (slides 002), one sentence.
pub fn consistency_line(runs: &[RunResult]) -> String {
    let nees_in: usize = runs.iter().map(|r| r.nees_inside_95).sum();
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let nees_sum: f64 = runs.iter().map(|r| r.nees_sum).sum();
    let nis_in: usize = runs.iter().map(|r| r.nis_inside_95).sum();
    let nis_n: usize = runs.iter().map(|r| r.nis_evaluated).sum();
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    // The application pipeline (`Case::Imu`) does not expose its innovations.
    let innovation = if nis_n == 0 {
        String::new()
    } else {
        format!(
            "; innovation (best component) inside on {:.1} % of {nis_n} updates",
            pct(nis_in, nis_n)
        )
    };
    format!(
        "Consistency (95 % χ²(3) bound {CHI2_3DOF_95}, target ≥ 90 % inside): position NEES inside on {:.1} % of {evaluated} steps (mean NEES {:.2}, 3 when consistent){innovation}.",
        pct(nees_in, evaluated),
        nees_sum / evaluated.max(1) as f64,
    )
}

/// One case's headline: final 3-D error median and max, share inside 3σ, and the bound's
/// median where the case computes it.
#[derive(Debug, Clone, Copy)]
pub(super) struct SummaryRow {
    pub(super) median_m: f64,
    pub(super) max_m: f64,
    pub(super) inside_3sigma_pct: f64,
    pub(super) bound_median_m: Option<f64>,
}

pub(super) fn summary_row(runs: &[RunResult]) -> Option<SummaryRow> {
    let [max_m, _, median_m] = stats(runs.iter().map(|r| r.final_error_m))?;
    let evaluated: usize = runs.iter().map(|r| r.evaluated_steps).sum();
    let inside: usize = runs.iter().map(|r| r.inside_3sigma).sum();
    Some(SummaryRow {
        median_m,
        max_m,
        inside_3sigma_pct: 100.0 * inside as f64 / evaluated.max(1) as f64,
        bound_median_m: bound_stats(runs, false, false).map(|b| b[2]),
    })
}

/// The report's opening summary, generated from this run's cases.
pub(super) fn summary_section(rows: &[(Case, Option<SummaryRow>)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from(
        "**Summary** (final 3-D error median / max; share of steps with the truth inside the \
         reported 3σ; the Cramér–Rao bound's median where computed):\n\n",
    );
    for (case, row) in rows {
        let Some(r) = row else {
            let _ = writeln!(s, "- {case:?}: no run initialized.");
            continue;
        };
        let bound = r
            .bound_median_m
            .map_or(String::new(), |b| format!(", bound {b:.3} m"));
        let _ = writeln!(
            s,
            "- {case:?}: {:.3} / {:.3} m, {:.1} % inside 3σ{bound}.",
            r.median_m, r.max_m, r.inside_3sigma_pct
        );
    }
    let median = |c: Case| {
        rows.iter()
            .find(|(k, _)| *k == c)
            .and_then(|(_, r)| r.map(|r| r.median_m))
    };
    if let (Some(imu), Some(exact)) = (median(Case::Imu), median(Case::Calibrated)) {
        let _ = writeln!(
            s,
            "\nThe application pipeline (`Imu`: the firmware's attitude filter and PDR on the \
             simulated IMU) ends {:+.0} % from the calibrated case's synthetic motion in the \
             median (issue target: within 10 %).",
            100.0 * (imu / exact - 1.0)
        );
    }
    s.push('\n');
    s
}

/// How to read the budget table (written under it).
pub(super) const BUDGET_NOTE: &str = "Every row is the calibrated case on the same scenarios with the \
same noise draws, only their amplitudes changed (`budget` in `hal-sim/src/eval/accuracy.rs`); a \
\"removed\" source is kept at 10 % of its σ (1 % of its variance) so every declared covariance \
stays positive definite. \"bound\" columns: the Cramér–Rao bound of each run \
(`hal-sim/src/eval/accuracy_bound.rs`) as the error of an efficient unbiased estimator (p99 of 100 \
pooled draws per run standing for the largest run); `eᵀC⁻¹e`: the filter's final error \
normalized by its run's bound (mean 3 for an efficient estimator, larger when information \
is lost). \"mean NEES\" is the filter's own consistency against its reported covariance. \
What the budget has shown, and the estimator's gates and their measurements: \
`docs/decisions/estimator.md`.\n";
