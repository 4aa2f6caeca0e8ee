//! `hal-sim multi-report`: seeded multi-victim rescues of [`crate::sim::multi`] (2–4
//! victims, close pairs, long pulse overlaps) with marking, scored per layout: victims
//! found, per-victim error, time to find all, wrong-victim marks; its sidecar and trace.
use crate::eval::accuracy::stats;
use crate::sim::multi::*;
use firmware::app::Receiver;
use std::fmt::Write as _;

/// Options of `hal-sim multi-report`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeded rescues per layout (seeds first-seed..first-seed+tries; the victim count
    /// cycles 2, 3, 4), at least 1.
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..))]
    pub tries: u64,
    /// First seed (seeds first-seed..first-seed+tries), e.g. to check on unseen seeds.
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Write the markdown report here (default: stdout only).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Write every rescue's outcome as JSON Lines here.
    #[arg(long = "jsonl", alias = "runs", value_name = "PATH")]
    pub runs: Option<std::path::PathBuf>,
    /// Single-victim rescues (rescue-report's calibrated case) re-run with the per-victim
    /// mixture capacity, to compare with `rescue.md`.
    #[arg(long, default_value_t = 100)]
    pub single_tries: u64,
    /// Trace one rescue instead (`SEED,LAYOUT`, layout 0–3 in report order) to stderr.
    #[arg(long)]
    pub trace: Option<String>,
}

/// Runs every layout and writes the report.
pub fn report(args: &Args, out: &mut dyn std::io::Write) -> anyhow::Result<()> {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    if let Some(spec) = &args.trace {
        return trace(spec);
    }
    let command = format!(
        "cargo sim multi-report --tries {}{}",
        args.tries,
        crate::eval::sidecar::first_seed_flag(args.first_seed)
    );
    let mut md = String::new();
    let _ = writeln!(md, "## Multiple burials (`{command}`)\n");
    md.push_str(PROTOCOL);
    let mut all: Vec<MultiOutcome> = Vec::new();
    for layout in Layout::ALL {
        let seeds = args.first_seed..args.first_seed.saturating_add(args.tries);
        let runs: Vec<MultiOutcome> = seeds
            .into_par_iter()
            .progress_with(crate::cli::progress::bar(
                args.tries,
                &format!("{layout:?} rescues"),
            ))
            .map(|seed| run(&MultiConfig::new(seed, victims_for(seed), layout)))
            .collect::<anyhow::Result<_>>()?;
        md.push_str(&layout_report(layout, &runs));
        all.extend(runs);
    }
    md.push_str(&summary(&all));
    md.push_str(&single_victim_check(args.single_tries)?);
    md.push_str(&capacity());
    if let Some(p) = &args.runs {
        let mut s = String::new();
        for o in &all {
            s.push_str(&serde_json::to_string(o)?);
            s.push('\n');
        }
        std::fs::write(p, s)?;
    }
    if let Some(p) = &args.out {
        crate::eval::sidecar::write(p, &md, sidecar(&command, args, &all)?)?;
    }
    out.write_all(md.as_bytes())?;
    Ok(())
}

/// The report's sidecar: per-layout headline numbers and the first seeds' rescues.
fn sidecar(
    command: &str,
    args: &Args,
    all: &[MultiOutcome],
) -> anyhow::Result<crate::eval::sidecar::Sidecar> {
    let mut headline = serde_json::Map::new();
    for layout in Layout::ALL {
        let runs: Vec<&MultiOutcome> = all.iter().filter(|r| r.layout == layout).collect();
        let victims: usize = runs.iter().map(|r| r.victims.len()).sum();
        let found: usize = runs
            .iter()
            .map(|r| r.victims.iter().filter(|v| v.found).count())
            .sum();
        let errors = runs
            .iter()
            .flat_map(|r| r.victims.iter().map(|v| v.error_h_m));
        headline.insert(
            format!("{layout:?}"),
            serde_json::json!({
                "rescues": runs.len(),
                "victims": victims,
                "found": found,
                "wrong_victim_marks": runs.iter().map(|r| r.wrong_marks()).sum::<usize>(),
                "reinitializations": runs.iter().map(|r| r.reinitializations).sum::<u32>(),
                "error_h_m_max_mean_median": stats(errors),
            }),
        );
    }
    let check = crate::eval::sidecar::records(
        all.iter().filter(|r| {
            r.seed < args.first_seed + crate::eval::sidecar::CHECK_SEEDS
                && r.layout == Layout::ALL[0]
        }),
        &[],
    )?;
    Ok(crate::eval::sidecar::Sidecar::new(
        "multi-report",
        command,
        args.first_seed,
        args.tries,
        serde_json::Value::Object(headline),
        check,
    ))
}

/// Re-runs one sidecar record (its seed and layout) with the current code.
pub fn rerun(record: &serde_json::Value) -> anyhow::Result<serde_json::Value> {
    let layout: Layout = crate::eval::sidecar::field(record, "/layout")?;
    let seed = crate::eval::sidecar::seed_of(record, "/seed")?;
    let o = run(&MultiConfig::new(seed, victims_for(seed), layout))?;
    crate::eval::sidecar::record(&o, &[])
}

/// Runs one rescue (`SEED,LAYOUT`) with the trace on.
fn trace(spec: &str) -> anyhow::Result<()> {
    let mut it = spec.split(',').map(str::trim);
    let seed: u64 = it.next().unwrap_or("1").parse()?;
    let layout: usize = it.next().unwrap_or("0").parse()?;
    let layout = *Layout::ALL
        .get(layout)
        .ok_or_else(|| anyhow::anyhow!("layout index 0–3"))?;
    let mut cfg = MultiConfig::new(seed, victims_for(seed), layout);
    cfg.trace = true;
    let o = run(&cfg)?;
    for (i, v) in o.victims.iter().enumerate() {
        eprintln!(
            "v{}: period {:.4} carrier {:+.1} found {} err {:?} pulses {} withheld {} ids {}",
            i + 1,
            v.period_s,
            v.carrier_offset_hz,
            v.found,
            v.error_h_m,
            v.pulses,
            v.withheld,
            v.ids
        );
    }
    eprintln!(
        "end {:.1} s, marks {}, wrong {}, other_source {}, refused {}, reinit {}",
        o.end_t,
        o.marks.len(),
        o.wrong_marks(),
        o.other_source,
        o.refused,
        o.reinitializations
    );
    Ok(())
}

const PROTOCOL: &str = "Protocol: per seed 2, 3 or 4 victims (cycling with the seed), 0.3–2 m deep, \
random moments (3e-3 … 3e-2 A·m², direction uniform), periods 0.7–1.3 s, carriers \
457 kHz ± 80 Hz; the first victim 30–45 m from the start (moved in until a beacon is \
usable), the others 8–25 m from it (layouts below). The rescuer, the IMU synthesis and \
the pulse noise are those of `rescue-report` (calibrated step length, lift allowed). \
Pulses whose on-times intersect are withheld as overlaps and reported to the \
tracker as occlusions, except a pulse whose strongest interferer is ≤ 1 % of its \
amplitude (≥ 40 dB weaker; the firmware's `frontend::overlap_verdict`): that one is kept, \
its vector carrying the interferer's field × the share of the pulse it covers × the \
cosine of a random relative carrier phase; every heard pulse's `src` comes from the firmware's \
`TransmitterTracker` (timing ±1 ms, carrier estimate ±2 Hz), not from the truth. At \
\"probe here\" the rescuer probes for 10 s and presses mark; a mark finds the nearest \
unfound victim within 1 m of the probe point (the marked mixture's mean), else it is a \
wrong-victim mark. Per-victim error: horizontal error of the probe point of the mark \
that found it. Time to find all: from the first received pulse to the last finding mark \
(including the 10 s probing per victim).\n\n";

/// Single-victim regression check: `rescue-report`'s calibrated case with this build's
/// per-victim capacity.
fn single_victim_check(tries: u64) -> anyhow::Result<String> {
    use crate::eval::rescue_report::{Case, run_case};
    let mut s = String::new();
    if tries == 0 {
        return Ok(s);
    }
    let runs = run_case(Case::SogCalibrated, 1, tries)?;
    let probed = runs.iter().filter(|r| r.steps.is_some()).count();
    let err = stats(runs.iter().map(|r| r.error_h_m));
    let ratio = stats(
        runs.iter()
            .map(|r| r.steps.zip(r.ideal_steps).map(|(a, b)| a / b.max(1e-9))),
    );
    let _ = writeln!(
        s,
        "### Single victim with the per-victim capacity ({} components)\n\n\
         `rescue-report`'s calibrated case (same seeds 1..={tries}) run by this build, \
         where one victim gets one slot of the bank: {probed}/{tries} reached \"probe \
         here\"; probe-point error max / mean / median {} m; steps / ideal from the first \
         received pulse {}.\n",
        firmware::victims::VICTIM_CAPACITY,
        fmt(err, 3).replace(" | ", " / "),
        fmt(ratio, 3).replace(" | ", " / "),
    );
    Ok(s)
}

/// The memory budget of the victim bank, from the types this build compiles.
fn capacity() -> String {
    use firmware::victims::{MAX_VICTIMS, VICTIM_CAPACITY, VictimSog};
    let filter = core::mem::size_of::<VictimSog>();
    format!(
        "### Memory budget and the capacity per victim\n\n\
         {MAX_VICTIMS} victim slots (`MAX_VICTIMS`) × one {VICTIM_CAPACITY}-component filter \
         of {filter} B (`VictimSog`) = {} B of mixture state; the receiver application is \
         {} B (`size_of::<Receiver>()`, bounded by `app::tests`), in SRAM; the ADC queue and \
         the front end sit in the 64 KB CCM (`firmware/src/bin/receiver.rs`). Why 80 per \
         victim and not one shared pool: `docs/decisions/component-pool.md`.\n",
        MAX_VICTIMS * filter,
        core::mem::size_of::<Receiver>(),
    )
}

fn fmt(s: Option<[f64; 3]>, d: usize) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.d$} | {b:.d$} | {c:.d$}"),
        None => "– | – | –".into(),
    }
}

/// The markdown section of one layout.
pub fn layout_report(layout: Layout, runs: &[MultiOutcome]) -> String {
    let mut s = String::new();
    let n = runs.len();
    let victims: usize = runs.iter().map(|r| r.victims.len()).sum();
    let found: usize = runs
        .iter()
        .map(|r| r.victims.iter().filter(|v| v.found).count())
        .sum();
    let all = runs.iter().filter(|r| r.all_found()).count();
    let wrong: usize = runs.iter().map(MultiOutcome::wrong_marks).sum();
    let _ = writeln!(
        s,
        "### {} ({n} rescues, {victims} victims)\n",
        layout.title()
    );
    let _ = writeln!(
        s,
        "Victims found: **{found} / {victims} ({:.1} %)**; rescues with every victim found: \
         **{all} / {n} ({:.1} %)**; wrong-victim marks: **{wrong}**.\n",
        100.0 * found as f64 / victims.max(1) as f64,
        100.0 * all as f64 / n.max(1) as f64
    );
    s.push_str("| metric | max | mean | median |\n|---|---|---|---|\n");
    let per_victim = |f: &dyn Fn(&VictimOutcome) -> Option<f64>| {
        stats(runs.iter().flat_map(|r| r.victims.iter().map(f)))
    };
    let _ = writeln!(
        s,
        "| per-victim error at its mark, horizontal (m) | {} |",
        fmt(per_victim(&|v| v.error_h_m), 3)
    );
    let _ = writeln!(
        s,
        "| time to find all (s) | {} |",
        fmt(stats(runs.iter().map(|r| r.time_to_all_s)), 1)
    );
    let _ = writeln!(
        s,
        "| path walked (m) | {} |",
        fmt(stats(runs.iter().map(|r| Some(r.path_m))), 1)
    );
    let _ = writeln!(
        s,
        "| pulses withheld per victim | {} |",
        fmt(per_victim(&|v| Some(f64::from(v.withheld))), 1)
    );
    let _ = writeln!(
        s,
        "| longest run of withheld pulses per victim | {} |",
        fmt(per_victim(&|v| Some(f64::from(v.longest_withheld))), 1)
    );
    let _ = writeln!(
        s,
        "| tracker ids per victim (1: kept across overlaps) | {} |",
        fmt(per_victim(&|v| Some(v.ids as f64)), 2)
    );
    let _ = writeln!(
        s,
        "| largest victim list shown | {} |",
        fmt(stats(runs.iter().map(|r| Some(f64::from(r.list_max)))), 2)
    );
    let reinit: u32 = runs.iter().map(|r| r.reinitializations).sum();
    let other: u32 = runs.iter().map(|r| r.other_source).sum();
    let _ = writeln!(
        s,
        "\nMixture re-initializations: {reinit}; pulses beyond the list's capacity: {other}."
    );
    let missed: Vec<String> = runs
        .iter()
        .filter(|r| !r.all_found())
        .map(|r| {
            let m: Vec<String> = r
                .victims
                .iter()
                .enumerate()
                .filter(|(_, v)| !v.found)
                .map(|(i, v)| {
                    format!(
                        "#{} ({} pulses, {} withheld, {} ids)",
                        i + 1,
                        v.pulses,
                        v.withheld,
                        v.ids
                    )
                })
                .collect();
            format!(
                "seed {} ({} victims, {} marks, {} wrong): missed {}",
                r.seed,
                r.victims.len(),
                r.marks.len(),
                r.wrong_marks(),
                m.join(", ")
            )
        })
        .collect();
    if !missed.is_empty() {
        let _ = writeln!(s, "Rescues with a victim missed: {}.", missed.join("; "));
    }
    s.push('\n');
    s
}

fn summary(all: &[MultiOutcome]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "### By number of victims (all layouts)\n");
    s.push_str(
        "| victims | rescues | victims found | rescues with all found | per-victim error median (m) \
         | time to find all, median (s) | pulses withheld (share) | wrong-victim marks |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for n in 2..=firmware::victims::MAX_VICTIMS {
        let runs: Vec<&MultiOutcome> = all.iter().filter(|r| r.victims.len() == n).collect();
        if runs.is_empty() {
            continue;
        }
        let vs = || runs.iter().flat_map(|r| r.victims.iter());
        let total = vs().count();
        let found = vs().filter(|v| v.found).count();
        let all_n = runs.iter().filter(|r| r.all_found()).count();
        let med = stats(vs().map(|v| v.error_h_m)).map_or("–".into(), |m| format!("{:.3}", m[2]));
        let t = stats(runs.iter().map(|r| r.time_to_all_s))
            .map_or("–".into(), |m| format!("{:.0}", m[2]));
        let withheld: u32 = vs().map(|v| v.withheld).sum();
        let heard: u32 = vs().map(|v| v.pulses).sum();
        let _ = writeln!(
            s,
            "| {n} | {} | {found} / {total} ({:.1} %) | {all_n} / {} | {med} | {t} | {:.0} % | {} |",
            runs.len(),
            100.0 * found as f64 / total.max(1) as f64,
            runs.len(),
            100.0 * f64::from(withheld) / f64::from((withheld + heard).max(1)),
            runs.iter().map(|r| r.wrong_marks()).sum::<usize>()
        );
    }
    s.push('\n');
    let victims: usize = all.iter().map(|r| r.victims.len()).sum();
    let found: usize = all
        .iter()
        .map(|r| r.victims.iter().filter(|v| v.found).count())
        .sum();
    let all_n = all.iter().filter(|r| r.all_found()).count();
    let med = stats(
        all.iter()
            .flat_map(|r| r.victims.iter().map(|v| v.error_h_m)),
    );
    let _ = writeln!(s, "### All layouts\n");
    let failed: Vec<&MultiOutcome> = all.iter().filter(|r| !r.all_found()).collect();
    let churn = |r: &&&MultiOutcome| r.other_source > 0 || r.victims.iter().any(|v| v.ids > 1);
    let timed_out = |r: &&&MultiOutcome| r.end_t >= max_time_s(r.victims.len()) - 1.0;
    let n_churn = failed.iter().filter(churn).count();
    let n_churn_to = failed.iter().filter(churn).filter(timed_out).count();
    let n_clean_to = failed
        .iter()
        .filter(|r| !churn(r))
        .filter(timed_out)
        .count();
    let n_other = failed.len() - n_churn - n_clean_to;
    let _ = writeln!(
        s,
        "Rescues with a victim missed: {} — {n_churn} with tracker id churn (a victim's \
         pulses under several ids, or more tracks than the list holds; {n_churn_to} of them \
         ran out of time), {n_clean_to} with clean ids that ran out of time (the fine search \
         on some victim did not reach \"probe here\" within the run, see below), \
         {n_other} ended believing every listed victim marked.\n",
        failed.len()
    );
    let share = 100.0 * found as f64 / victims.max(1) as f64;
    let median = med.map_or(f64::NAN, |m| m[2]);
    let _ = writeln!(
        s,
        "**Targets** (every victim found in ≥ 98 % of runs; per-victim median error ≤ 0.15 m): \
         victims found {share:.1} % — **{}**; per-victim median error {median:.3} m — **{}**. \
         With 3–4 victims a third to nearly a half of all pulses are withheld as \
         overlapping (after keeping those ≥ 40 dB above their interferer; each pulse overlaps \
         another's with probability ≈ Σ on-times / period). `multi-report --trace \
         SEED,LAYOUT` prints one rescue pulse by pulse.\n",
        if share >= 98.0 { "met" } else { "missed" },
        if median <= 0.15 { "met" } else { "missed" },
    );
    let _ = writeln!(
        s,
        "Victims found {found} / {victims} ({:.1} %), rescues with all found {all_n} / {} \
         ({:.1} %), per-victim median error {} m, wrong-victim marks {}.\n",
        100.0 * found as f64 / victims.max(1) as f64,
        all.len(),
        100.0 * all_n as f64 / all.len().max(1) as f64,
        med.map_or("–".into(), |m| format!("{:.3}", m[2])),
        all.iter().map(MultiOutcome::wrong_marks).sum::<usize>()
    );
    s
}
