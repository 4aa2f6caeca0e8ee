//! The markdown of `rescue-report`: per-case tables, phase and dead-reckoning tables,
//! comparisons, and the protocol text.

use super::*;

/// Median of sorted values (NaN when empty).
pub(super) fn median(sorted: &[f64]) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

pub(super) fn fmt3(s: Option<[f64; 3]>, digits: usize) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.digits$} | {b:.digits$} | {c:.digits$}"),
        None => "– | – | –".into(),
    }
}

/// The papers' Table II (ICRA 2006): (row, max, mean, median).
pub(super) const PAPER: [(&str, [f64; 3]); 5] = [
    ("DS error", [2.62, 0.52, 0.42]),
    ("SOG error", [0.07, 0.02, 0.02]),
    ("Steps DS", [128.0, 71.0, 70.0]),
    ("Steps SOG", [100.0, 63.0, 62.0]),
    ("Steps Ideal", [69.0, 54.0, 53.0]),
];

pub(super) fn paper(row: &str) -> String {
    PAPER
        .iter()
        .find(|(r, _)| *r == row)
        .map_or_else(|| "| | ".into(), |(_, v)| fmt3(Some(*v), 2))
}

/// Markdown table of one case in the papers' layout, with Table II's values beside.
pub fn case_report(case: Case, runs: &[Rescue]) -> String {
    let mut s = String::new();
    let n = runs.len();
    let probed = runs.iter().filter(|r| r.steps.is_some()).count();
    let (err_row, steps_row) = match case {
        Case::DirectionalSearch => ("DS error", "Steps DS"),
        _ => ("SOG error", "Steps SOG"),
    };
    let _ = writeln!(
        s,
        "### {} ({n} tries, {probed} reached {})\n",
        case.title(),
        if case == Case::DirectionalSearch {
            "the maximum"
        } else {
            "\"probe here\""
        }
    );
    let _ = writeln!(
        s,
        "| metric | max | mean | median | paper max | paper mean | paper median |\n|---|---|---|---|---|---|---|"
    );
    let st = |f: &dyn Fn(&Rescue) -> Option<f64>| stats(runs.iter().map(f));
    let rows: Vec<(String, Option<[f64; 3]>, usize, String)> = vec![
        (
            format!("probe-point error, horizontal (m) [{err_row}]"),
            st(&|r| r.error_h_m),
            3,
            paper(err_row),
        ),
        (
            "rescuer's receiver to victim at the end, horizontal (m)".into(),
            st(&|r| Some(r.stand_h_m)),
            3,
            paper(""),
        ),
        (
            "depth error at \"probe here\" (m)".into(),
            st(&|r| r.depth_error_m),
            3,
            paper(""),
        ),
        (
            "receiver's horizontal σ at \"probe here\" (m)".into(),
            st(&|r| r.sigma_h_at_probe_m),
            3,
            paper(""),
        ),
        (
            "probe-point error / that σ (a consistent belief: median ≤ 1.18, the Rayleigh median)"
                .into(),
            st(&|r| {
                r.error_h_m
                    .zip(r.sigma_h_at_probe_m)
                    .map(|(e, s)| e / s.max(1e-6))
            }),
            2,
            paper(""),
        ),
        (
            format!("steps (pulses) from the start [{steps_row}]"),
            st(&|r| r.steps_from_start),
            1,
            paper(steps_row),
        ),
        (
            "ideal steps from the start [Steps Ideal]".into(),
            st(&|r| Some(r.ideal_steps_from_start)),
            1,
            paper("Steps Ideal"),
        ),
        (
            "steps / ideal, from the start".into(),
            st(&|r| Rescue::ratio(r.steps_from_start, Some(r.ideal_steps_from_start))),
            3,
            format!(
                "{:.3} | {:.3} | {:.3}",
                PAPER[3].1[0] / PAPER[4].1[0],
                PAPER[3].1[1] / PAPER[4].1[1],
                PAPER[3].1[2] / PAPER[4].1[2]
            ),
        ),
        (
            "steps (pulses) from the first received pulse".into(),
            st(&|r| r.steps),
            1,
            paper(""),
        ),
        (
            "ideal steps from the first received pulse".into(),
            st(&|r| r.ideal_steps),
            1,
            paper(""),
        ),
        (
            "**steps / ideal, from the first received pulse**".into(),
            st(&|r| Rescue::ratio(r.steps, r.ideal_steps)),
            3,
            paper(""),
        ),
        (
            "seconds from the first received pulse".into(),
            st(&|r| r.seconds),
            1,
            paper(""),
        ),
        (
            "ideal seconds from the first received pulse".into(),
            st(&|r| r.ideal_seconds),
            1,
            paper(""),
        ),
        (
            "seconds / ideal".into(),
            st(&|r| Rescue::ratio(r.seconds, r.ideal_seconds)),
            3,
            paper(""),
        ),
        (
            "path walked / ideal path, from the first received pulse".into(),
            st(&|r| Rescue::ratio(Some(r.path_m), r.first_rx_distance_m)),
            3,
            paper(""),
        ),
        (
            "start distance (m)".into(),
            st(&|r| Some(r.start_distance_m)),
            1,
            paper(""),
        ),
        (
            "distance at the first received pulse (m)".into(),
            st(&|r| r.first_rx_distance_m),
            1,
            paper(""),
        ),
    ];
    for (name, v, digits, p) in rows {
        let _ = writeln!(s, "| {name} | {} | {p} |", fmt3(v, digits));
    }
    let failed: Vec<String> = runs
        .iter()
        .filter(|r| r.failed)
        .map(|r| match r.steps.zip(r.ideal_steps) {
            Some((a, b)) => format!("seed {} ({a:.0} steps vs ideal {b:.0})", r.seed),
            None => format!("seed {} (never)", r.seed),
        })
        .collect();
    let reinit: u32 = runs.iter().map(|r| r.reinitializations).sum();
    let over = |lim: f64| {
        runs.iter()
            .filter(|r| r.error_h_m.is_some_and(|e| e > lim))
            .count()
    };
    let _ = writeln!(
        s,
        "\nFailures (never reached the end within 3× the ideal steps from the first received pulse): {}. \
         Probe-point error > 0.05 m in {} runs, > 0.20 m in {}; {reinit} mixture re-initializations.",
        if failed.is_empty() {
            "none".into()
        } else {
            format!("{} — {}", failed.len(), failed.join(", "))
        },
        over(0.05),
        over(0.20),
    );
    let mut worst: Vec<&Rescue> = runs.iter().filter(|r| r.error_h_m.is_some()).collect();
    worst.sort_by(|a, b| {
        b.error_h_m
            .unwrap_or(0.0)
            .total_cmp(&a.error_h_m.unwrap_or(0.0))
    });
    let list: Vec<String> = worst
        .iter()
        .take(5)
        .map(|r| {
            format!(
                "seed {} ({:.3} m; depth {:.1} m)",
                r.seed,
                r.error_h_m.unwrap_or(f64::NAN),
                r.depth_m
            )
        })
        .collect();
    let mut slow: Vec<&Rescue> = runs.iter().filter(|r| r.steps.is_some()).collect();
    slow.sort_by(|a, b| {
        Rescue::ratio(b.steps, b.ideal_steps)
            .unwrap_or(0.0)
            .total_cmp(&Rescue::ratio(a.steps, a.ideal_steps).unwrap_or(0.0))
    });
    let slow: Vec<String> = slow
        .iter()
        .take(5)
        .map(|r| {
            format!(
                "seed {} ({:.2}×; pulses per phase {:?})",
                r.seed,
                Rescue::ratio(r.steps, r.ideal_steps).unwrap_or(f64::NAN),
                r.phases
            )
        })
        .collect();
    if case != Case::DirectionalSearch {
        s.push_str(&phase_table(runs));
    }
    if case == Case::SogCalibrated {
        s.push_str(&dead_reckoning_table(runs));
    }
    let _ = writeln!(
        s,
        "Largest errors: {}. Slowest: {}.\n",
        list.join(", "),
        slow.join(", ")
    );
    s
}

/// Where the pulses from the first received one to "probe here" went, per phase.
pub(super) fn phase_table(runs: &[Rescue]) -> String {
    let done: Vec<&Rescue> = runs.iter().filter(|r| !r.failed).collect();
    let mut s = format!(
        "\nPulses per phase, from the first received pulse to \"probe here\" (mean over the {} \
         rescues that did not fail; the failures separately; per seed in the same order in \
         the slowest list below):\n\n| phase | mean pulses | share | mean pulses, failures |\n|---|---|---|---|\n",
        done.len()
    );
    let failed: Vec<&Rescue> = runs.iter().filter(|r| r.failed).collect();
    let mean = |v: &[&Rescue], k: usize| {
        if v.is_empty() {
            0.0
        } else {
            v.iter()
                .map(|r| f64::from(r.phases.get(k).copied().unwrap_or(0)))
                .sum::<f64>()
                / v.len() as f64
        }
    };
    let total: f64 = (0..Phase::COUNT).map(|k| mean(&done, k)).sum();
    for (k, p) in Phase::ALL.iter().enumerate() {
        let m = mean(&done, k);
        let _ = writeln!(
            s,
            "| {} | {m:.1} | {:.0} % | {:.1} |",
            p.label(),
            100.0 * m / total.max(1e-9),
            mean(&failed, k)
        );
    }
    let ideal = done.iter().filter_map(|r| r.ideal_steps).sum::<f64>() / done.len().max(1) as f64;
    let _ = writeln!(s, "| total (ideal {ideal:.1}) | {total:.1} | 100 % | |\n");
    if let Some([first, start]) = fine_search_at_walking_pace(&done) {
        let _ = writeln!(
            s,
            "Had the fine search (the last three phases) taken no longer than walking its \
             {FINE_WALK_M:.0} m at the ideal pace, the median steps / ideal would be \
             {first:.3} from the first received pulse ({start:.3} from the start), about the least \
             any fine-search policy could take after this approach.\n"
        );
    }
    s
}

/// Median steps / ideal (from the first received pulse, from the start) of `runs` had
/// their fine search (approach within [`FINE_WALK_M`], over the mean, standing for the
/// receiver's height) taken only the pulses of walking [`FINE_WALK_M`] at the ideal pace.
/// `None` without a run that reached "probe here".
pub(super) fn fine_search_at_walking_pace(runs: &[&Rescue]) -> Option<[f64; 2]> {
    let fine = [Phase::FineApproach, Phase::OverMean, Phase::Lift];
    let mut first = Vec::new();
    let mut start = Vec::new();
    for r in runs {
        let (Some(steps), Some(ideal), Some(d)) = (r.steps, r.ideal_steps, r.first_rx_distance_m)
        else {
            continue;
        };
        let fine_pulses: u32 = Phase::ALL
            .iter()
            .zip(r.phases)
            .filter(|(p, _)| fine.contains(p))
            .map(|(_, n)| n)
            .sum();
        let walk_pulses = FINE_WALK_M.min(d) * ideal / d.max(1e-9);
        let saved = f64::from(fine_pulses) - walk_pulses;
        first.push((steps - saved) / ideal.max(1e-9));
        if let Some(from_start) = r.steps_from_start {
            start.push((from_start - saved) / r.ideal_steps_from_start.max(1e-9));
        }
    }
    if first.is_empty() || start.is_empty() {
        return None;
    }
    first.sort_by(f64::total_cmp);
    start.sort_by(f64::total_cmp);
    Some([median(&first), median(&start)])
}

/// The dead reckoning's consistency per kind of interval, over all rescues of a case.
pub(super) fn dead_reckoning_table(runs: &[Rescue]) -> String {
    let mut s = String::from(
        "\nDead-reckoning consistency of the motion between pulses up to \"probe here\" \
         (every rescue): the firmware's horizontal translation against the true one, both in \
         the device frame at the previous pulse, normalized by the covariance it hands the \
         filter (consistent: mean eᵀC⁻¹e 2, 0.1 % above the χ² 99.9 % point 13.8):\n\n\
         | interval | count | mean forward error (m) | RMS error (m) | RMS σ (m) | mean eᵀC⁻¹e | above 13.8 |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for (k, kind) in DrKind::ALL.iter().enumerate() {
        let mut t = DrStats::default();
        for r in runs {
            if let Some(x) = r.dead_reckoning.get(k) {
                t.merge(x);
            }
        }
        let n = f64::from(t.n.max(1));
        let _ = writeln!(
            s,
            "| {} | {} | {:+.3} | {:.3} | {:.3} | {:.2} | {:.1} % |",
            kind.label(),
            t.n,
            t.forward_sum_m / n,
            (t.err2_sum_m2 / n).sqrt(),
            (t.var_sum_m2 / n).sqrt(),
            t.nees_sum / n,
            100.0 * f64::from(t.over) / n
        );
    }
    s.push('\n');
    s
}

/// One metric of a rescue.
pub(super) type Metric = fn(&Rescue) -> Option<f64>;

/// The gain of the lowering to the snow: the default cases against the receiver kept at
/// the walking height.
pub(super) fn lower_gain(all: &[Rescue]) -> String {
    let head = "### Gain of the lowering to the snow\n\n\
Localized within 2 m of the estimate, the receiver shows \"LOWER TO SNOW\" (once, whatever \
the estimated depth: the filter's initialization prior follows the tracked height): the rescuer stops, pauses 0.5 s and lowers it to 0.2 m above the \
snow in a 1 s minimum-jerk move, then goes on step by step bent over. The accelerometer \
measures the 0.8 m as an absolute displacement (the filter's unscaled part) and the receiver \
tracks its height from it (depth shown = −p_z − height). Errors over the rescues that \
reached \"probe here\"; median / mean.\n\n\
| step length | metric | lowered | kept at 1 m |\n|---|---|---|---|\n";
    let mut s = compare(
        all,
        head,
        [
            (Case::SogCalibrated, Case::SogCalibratedHigh),
            (Case::SogUncalibrated, Case::SogUncalibratedHigh),
        ],
        ("lowerings and raisings per rescue", |r| {
            Some(f64::from(r.height_moves))
        }),
    );
    let failed = |c: Case| all.iter().filter(|r| r.case == c && r.failed).count();
    let _ = writeln!(
        s,
        "\nFailures lowered / kept at 1 m: calibrated {} / {}, uncalibrated {} / {}.\n",
        failed(Case::SogCalibrated),
        failed(Case::SogCalibratedHigh),
        failed(Case::SogUncalibrated),
        failed(Case::SogUncalibratedHigh)
    );
    s
}

/// A with / without table of `pairs` (calibrated, uncalibrated) under `head`: probe-point
/// and depth errors, steps / ideal and `extra`.
pub(super) fn compare(
    all: &[Rescue],
    head: &str,
    pairs: [(Case, Case); 2],
    extra: (&str, Metric),
) -> String {
    let pick = |case: Case, f: Metric| -> Vec<f64> {
        all.iter()
            .filter(|r| r.case == case)
            .filter_map(f)
            .collect()
    };
    let med_mean = |v: &[f64]| {
        let s = stats(v.iter().map(|x| Some(*x)));
        match s {
            Some([_, mean, median]) => format!("{median:.3} / {mean:.3}"),
            None => "–".to_string(),
        }
    };
    let mut s = String::from(head);
    for (name, (with, without)) in ["calibrated", "uncalibrated"].into_iter().zip(pairs) {
        let rows: [(&str, Metric); 4] = [
            ("probe-point error, horizontal (m)", |r| r.error_h_m),
            ("depth error at \"probe here\" (m)", |r| r.depth_error_m),
            ("steps / ideal, from the first received pulse", |r| {
                Rescue::ratio(r.steps, r.ideal_steps)
            }),
            extra,
        ];
        for (label, f) in rows {
            let _ = writeln!(
                s,
                "| {name} | {label} | {} | {} |",
                med_mean(&pick(with, f)),
                med_mean(&pick(without, f))
            );
        }
    }
    s
}

/// The gain of the fine-search lift: probe-point and depth errors with and without it.
pub(super) fn lift_gain(all: &[Rescue]) -> String {
    let head = "### Gain of the fine-search lift\n\n\
When the horizontal distance to the estimate is below 1 m, the depth σ above 0.2 m and the \
receiver was not lowered to the snow, the receiver shows \"LIFT\": the rescuer stands and \
lifts it 0.4 m up and down over 2 s; the accelerometer-integrated vertical excursion (zero \
velocity at both ends) enters the filter as an absolute, unscaled displacement. Both sides \
with the lowering. Errors over the rescues that reached \"probe here\"; median / mean.\n\n\
| step length | metric | with lift | without lift |\n|---|---|---|---|\n";
    let mut s = compare(
        all,
        head,
        [
            (Case::SogCalibrated, Case::SogCalibratedNoLift),
            (Case::SogUncalibrated, Case::SogUncalibratedNoLift),
        ],
        ("lifts per rescue", |r| Some(f64::from(r.lifts))),
    );
    let failed = |c: Case| all.iter().filter(|r| r.case == c && r.failed).count();
    let _ = writeln!(
        s,
        "\nFailures with / without the lift: calibrated {} / {}, uncalibrated {} / {}.\n",
        failed(Case::SogCalibrated),
        failed(Case::SogCalibratedNoLift),
        failed(Case::SogUncalibrated),
        failed(Case::SogUncalibratedNoLift)
    );
    s
}

/// How to read the phase tables and follow one rescue; the constants they justify are
/// recorded in `docs/decisions/fine-search-guidance.md`.
pub(super) const READING: &str = "\
### Reading the tables

The phase tables split the pulses from the first reception to \"probe here\" by what the \
display showed; each ends with the bound the fine search would give if it took only the \
pulses of walking its 2 m at the ideal pace, so the gap between that bound and the measured \
steps / ideal is the fine search's stop-and-go, lowering and confirming pulses. \
`hal-sim rescue-report --trace SEED [--trace-case sog-uncalibrated]` prints one rescue pulse \
by pulse; `--first-seed 1000` runs a separate range of scenarios. The search control's tuned \
constants (probe radius, flux-line rules, bracketing, lowering) and what was measured for \
each are in `docs/decisions/fine-search-guidance.md`.\n";

pub(super) const PROTOCOL: &str = "\
Protocol (ICRA 2006 §VI): per seed a victim 40–70 m (horizontally) from the start at a random \
bearing, 0.3–3 m deep, moment direction uniform and magnitude log-uniform in 3e-3 … 3e-2 A·m²; \
transmitter period 0.7–1.3 s; rescuer at 0.56 m × 1.8 steps/s ≈ 1.0 m/s, receiver 1 m above the \
snow, lowered to 0.2 m in the fine search when the receiver asks (\"LOWER TO SNOW\", see the \
gain of the lowering below; not in the cases \"kept 1 m above the snow\"). The same 100 scenarios for every case. Pulses carry the noise of ICRA eq. 10 \
(σ_bkg = 2.59e-9 A/m, k_sen = 0.03) and a random sign, and are received only when \
|H| ≥ 3 σ_bkg: a weak beacon is not heard from 70 m. Until the first pulse the rescuer walks \
straight toward the victim (a primary-search strip over it); then the SOG rescuer follows the \
receiver's display (0.5 s reading lag, ≈ 5° heading error, turning limits, step-by-step in the \
fine search) until \"probe here\", with the IMU synthesized from the walk (dead reckoning, \
attitude, gyro bias); with calibration the receiver knows the step length within ≈ 2 %, without \
it the firmware assumes 0.7 m (25 % long). The rescuer model turns back once when the \
display says \"no signal\" after a signal was heard (DS: after 3.5 s without a pulse). DS is the classical directional search as the \
rescuer's policy, optimistic as in ICRA (the rescuer follows the true field's flux line perfectly, without lag or heading \
error; |H| is the noisy reading; reversed \
when |H| has not grown over 5 m; then a cross search with the receiver 0.2 m above the snow, \
0.5 m then 0.2 m spacing, one pulse per point) until the rescuer stands at the strongest point.\n\n\
**Steps** are transmitter pulses (the papers: one measurement per second at 1 m/s, so steps = \
seconds = metres). They are counted from the first received pulse to \"probe here\" (DS: to \
standing at the found maximum), against the ideal straight walk from the point of first \
reception to the victim at the same speed and pulse period; \"from the start\" adds the \
primary-search walk, which is straight toward the victim and therefore ideal, on both sides \
(the basis of the papers' Table II, whose values are shown beside). Probe-point error: the \
receiver's victim estimate at \"probe here\" (DS: the found maximum) against the truth, \
horizontally. Failure: no \"probe here\" within 3× the ideal steps.";
