//! `hal-sim baselines-report`: every [`Method`] on the same seeded scenarios, the papers'
//! numbers beside ours, error-vs-time and final-error CDF plots (PNG).
use super::plot::{Axis, COLOURS, Series, plot};
use super::{Method, MethodRuns, run_method};
use crate::eval::accuracy::stats;
use anyhow::{Context, Result, bail};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Options of `hal-sim baselines-report`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeded scenarios per method (at least 1).
    #[arg(long, alias = "runs", default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
    pub tries: u64,
    /// First scenario seed (seeds `first_seed..first_seed + tries`).
    #[arg(long, alias = "seed", default_value_t = 1)]
    pub first_seed: u64,
    /// The markdown report to write (`X.md`); its sidecar `X.json` and the PNG plots go
    /// beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Methods to run (default: all).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub methods: Vec<Method>,
    /// Skip the paper-protocol sections (only the common protocol's tables).
    #[arg(long)]
    pub no_paper_protocols: bool,
}

/// Median error against time, per method.
pub const ERROR_PNG: &str = "baselines_error_vs_time.png";
/// CDF of the final error, per method.
pub const CDF_PNG: &str = "baselines_cdf.png";

/// The final errors of a method's runs: 3-D at the last pulse open loop; for
/// closed-loop-only methods the horizontal error of the found point.
fn final_errors(r: &MethodRuns) -> Vec<Option<f64>> {
    if r.open.is_empty() {
        r.closed.iter().map(|c| c.error_h_m).collect()
    } else {
        r.open.iter().map(|o| o.final_error_m).collect()
    }
}

fn fmt3(s: Option<[f64; 3]>) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.2} / {b:.2} / {c:.2}"),
        None => "–".into(),
    }
}

fn fmt2(s: Option<[f64; 3]>) -> String {
    match s {
        Some([_, b, c]) => format!("{b:.2} / {c:.2}"),
        None => "–".into(),
    }
}

/// The accuracy table (one row per method).
fn accuracy_table(all: &[MethodRuns]) -> String {
    let mut s = String::from(
        "| method | runs (with an estimate) | final error max / mean / median (m) | paper max / mean / median (m) | error at 20 m mean / median (m) | error at 10 m mean / median (m) | final error > 1 m |\n|---|---|---|---|---|---|---|\n",
    );
    for r in all {
        let errs = final_errors(r);
        let n = errs.len();
        let with = errs.iter().flatten().count();
        let over = errs.iter().filter(|e| e.is_none_or(|e| e > 1.0)).count();
        let paper = r.method.paper().map_or("–".into(), |(src, v)| {
            format!("{} ({src})", fmt3(Some(v)))
        });
        let (at20, at10) = if r.open.is_empty() {
            ("–".to_string(), "–".to_string())
        } else {
            (
                fmt2(stats(r.open.iter().map(|o| o.error_at_20m))),
                fmt2(stats(r.open.iter().map(|o| o.error_at_10m))),
            )
        };
        let name = if r.open.is_empty() {
            format!("{} ¹", r.method.name())
        } else {
            r.method.name().to_string()
        };
        let _ = writeln!(
            s,
            "| {name} | {n} ({with}) | {} | {paper} | {at20} | {at10} | {over} of {n} ({:.0} %) |",
            fmt3(stats(errs.into_iter())),
            100.0 * over as f64 / n.max(1) as f64,
        );
    }
    s
}

/// The closed-loop table (methods that guide the rescuer).
fn closed_loop_table(all: &[MethodRuns]) -> String {
    let mut s = String::from(
        "| method | rescues (reached the end) | steps from the first received pulse max / mean / median | steps / ideal max / mean / median | found-point error, horizontal, max / mean / median (m) | failures (> 3× ideal or never) |\n|---|---|---|---|---|---|\n",
    );
    for r in all.iter().filter(|r| !r.closed.is_empty()) {
        let n = r.closed.len();
        let done = r.closed.iter().filter(|c| c.steps.is_some()).count();
        let ratio = stats(
            r.closed
                .iter()
                .map(|c| c.steps.zip(c.ideal_steps).map(|(a, b)| a / b.max(1e-9))),
        );
        let failed = r.closed.iter().filter(|c| c.failed).count();
        let _ = writeln!(
            s,
            "| {} | {n} ({done}) | {} | {} | {} | {failed} |",
            r.method.name(),
            fmt3(stats(r.closed.iter().map(|c| c.steps))),
            fmt3(ratio),
            fmt3(stats(r.closed.iter().map(|c| c.error_h_m))),
        );
    }
    s
}

/// Whether the SOGs filter beats each baseline on median and max, stated plainly.
fn verdict(all: &[MethodRuns]) -> String {
    let mut s = String::new();
    let Some(sog) = all.iter().find(|r| r.method == Method::Sog) else {
        return "The SOGs filter was not run: no comparison.\n".into();
    };
    let sog_open = stats(sog.open.iter().map(|o| o.final_error_m));
    let sog_closed = stats(sog.closed.iter().map(|c| c.error_h_m));
    for r in all.iter().filter(|r| r.method != Method::Sog) {
        // Like with like: open-loop estimators against the SOGs filter open loop (3-D);
        // closed-loop-only methods against the SOGs receiver closed loop (horizontal).
        let (mine, what) = if r.open.is_empty() {
            (
                sog_closed,
                "closed loop, horizontal error of the found point",
            )
        } else {
            (sog_open, "open loop, 3-D final error")
        };
        let theirs = stats(final_errors(r).into_iter());
        // A run without any estimate counts as an unbounded error.
        let missing = final_errors(r).iter().filter(|e| e.is_none()).count();
        let (Some([sm, _, smed]), Some([bmax, _, bmed])) = (mine, theirs) else {
            let _ = writeln!(s, "- {}: no comparable runs.", r.method.name());
            continue;
        };
        let bm = if missing > 0 { f64::INFINITY } else { bmax };
        let med = if smed < bmed {
            "beats"
        } else {
            "does **not** beat"
        };
        let max = if sm < bm {
            "beats"
        } else {
            "does **not** beat"
        };
        let never = if missing > 0 {
            format!(" ∞: in {missing} runs it gave no position at all; {bmax:.2} m over the others")
        } else {
            format!(" {bmax:.2} m")
        };
        let _ = writeln!(
            s,
            "- vs {} ({what}): the SOGs filter {med} it on the median ({smed:.2} vs {bmed:.2} m) and {max} it on the max ({sm:.2} m vs{never}).",
            r.method.name(),
        );
    }
    s
}

/// Markdown of the whole report.
pub fn markdown(args: &Args, all: &[MethodRuns]) -> String {
    let mut s = format!(
        "## Baselines beside the SOGs filter (`{}`)\n\n",
        command(args)
    );
    s.push_str("This one command regenerates every table and plot below: first every method under one common protocol, then each baseline under its own paper's protocol beside the paper's numbers (`--no-paper-protocols` leaves the second part out).\n\n");
    s.push_str(
        "Scenarios: the `accuracy` report's calibrated open-loop case (the papers' protocol: the rescuer starts 40–70 m from the victim and walks the `paper` path at ≈ 1 m/s, one pulse per transmitter period, random transmitter position, depth, orientation and power; pulses with the noise of ICRA eq. 10 and a random sign), the same seeds for every method. Every open-loop method gets exactly the SOGs filter's inputs from `accuracy::run_open_loop_with`: the dead-reckoned displacement between pulses (true displacement with the calibrated step length's scale error and per-step noise) and the noisy absolute attitude. Methods that guide the rescuer also run closed loop with the `rescue-report` rescuer (same seeds, its own scenario draw under the same protocol): the SOGs filter inside the firmware's application, and the classical directional search as the rescuer's policy.\n\n",
    );
    s.push_str("### Accuracy (final error: 3-D at the last pulse)\n\n");
    s.push_str(&accuracy_table(all));
    s.push_str("\n¹ Closed loop only (DS has no estimate before it stands on the maximum): the horizontal error of the point it found, from the closed-loop rescues; a rescue that never found the maximum has no position (counted in \"> 1 m\").\n\nThe cost per step is not timed on the host (a timing depends on the machine and its load): the firmware's filters are counted in Cortex-M4F instructions under QEMU in [baselines_qemu.md](baselines_qemu.md).\n\n");
    s.push_str("The papers' own numbers (final error max / mean / median over 100 tries, their simulations): IROS 2006 Table I — SOGs 0.66 / 0.23 / 0.21 m, RBPF 32.5 / 2.27 / 0.28 m; ICRA 2006 Table II — DS 2.62 / 0.52 / 0.42 m.\n\n");
    s.push_str("### Steps to find (closed loop, where the method guides)\n\n");
    s.push_str(&closed_loop_table(all));
    s.push_str("\nSteps are transmitter pulses from the first received pulse to \"probe here\" (DS: standing at the found maximum); the ideal walks straight there at the same speed (see `rescue.md`).\n\n");
    s.push_str("### Does the SOGs filter beat every baseline on median and max?\n\n");
    s.push_str(&verdict(all));
    s.push_str("\nWhy, method by method:\n\n");
    for r in all.iter() {
        let _ = writeln!(s, "- **{}**: {}", r.method.name(), r.method.why());
    }
    s.push_str("\n### Plots\n\n");
    let _ = writeln!(
        s,
        "![median error against time]({ERROR_PNG})\n\nMedian (over the runs still going) of the 3-D error against the pulse index, open loop. The SOGs filter's curve starts when half the runs have a pulse strong enough to initialize from (|H| ≥ 10 σ_bkg); the batch methods use every pulse from the first. Runs end at different pulses (the walk's length), so the tail mixes fewer, longer runs.\n\n![CDF of the final error]({CDF_PNG})\n\nFraction of runs with a final error below x (open loop: 3-D; closed loop: horizontal error of the found point).\n"
    );
    s.push_str("### Instructions per step on the Cortex-M4F\n\nThe firmware's filters (SOGs, EKF, PF, RBPF, histogram) are counted under QEMU in [baselines_qemu.md](baselines_qemu.md). The LM fit and the RLS identifier are host-only (`f64`, every pulse kept).\n\n");
    s
}

/// Median error against the pulse index (log scale), per open-loop method.
fn error_vs_time(all: &[MethodRuns], path: &Path) -> Result<()> {
    let mut series = Vec::new();
    let mut kmax = 10usize;
    for (i, r) in all.iter().enumerate().filter(|(_, r)| !r.open.is_empty()) {
        let len = r
            .open
            .iter()
            .map(|o| o.error_trace.len())
            .max()
            .unwrap_or(0);
        let mut pts = Vec::new();
        for k in 0..len {
            // Only while at least half the runs are still going.
            let going = r.open.iter().filter(|o| o.error_trace.len() > k).count();
            if going * 2 < r.open.len() {
                break;
            }
            let mut v: Vec<f64> = r
                .open
                .iter()
                .filter_map(|o| o.error_trace.get(k).copied())
                .filter(|e| e.is_finite())
                .collect();
            // Before half the runs have an estimate there is no median.
            if v.len() * 2 < going {
                continue;
            }
            v.sort_by(f64::total_cmp);
            let med = v.get(v.len() / 2).copied().unwrap_or(f64::NAN);
            pts.push(((k + 1) as f64, med));
        }
        kmax = kmax.max(pts.len());
        series.push(Series {
            name: r.method.name().to_string(),
            colour: COLOURS[i % COLOURS.len()],
            points: pts,
        });
    }
    plot(
        path,
        "Median 3-D error of the estimate against time (open loop, same scenarios)",
        &Axis {
            range: (0.0, kmax as f64),
            log: false,
            title: "pulse index (one pulse per transmitter period, ≈ 1 s)",
        },
        &Axis {
            range: (0.01, 300.0),
            log: true,
            title: "median 3-D error (m, log scale)",
        },
        &series,
    )
}

/// CDF of the final errors (log x), per method, plus the SOGs receiver closed loop.
fn cdf(all: &[MethodRuns], path: &Path) -> Result<()> {
    let series = cdf_series(cdf_curves(all));
    plot(
        path,
        "Cumulative distribution of the final error (100 seeds per method)",
        &Axis {
            range: (0.01, 300.0),
            log: true,
            title: "final error (m, log scale; open loop 3-D, closed loop horizontal)",
        },
        &Axis {
            range: (0.0, 1.0),
            log: false,
            title: "fraction of runs with a smaller error",
        },
        &series,
    )
}

/// The CDF's curves: one per method, then one per method that also runs closed loop
/// (its found-point errors), as `(legend, errors)`.
fn cdf_curves(all: &[MethodRuns]) -> Vec<(String, Vec<Option<f64>>)> {
    let mut curves: Vec<(String, Vec<Option<f64>>)> = all
        .iter()
        .map(|r| {
            let name = if r.open.is_empty() {
                format!("{} (closed loop, horizontal)", r.method.name())
            } else {
                r.method.name().to_string()
            };
            (name, final_errors(r))
        })
        .collect();
    for r in all
        .iter()
        .filter(|r| !r.open.is_empty() && !r.closed.is_empty())
    {
        curves.push((
            format!("{} (closed loop, horizontal)", r.method.name()),
            r.closed.iter().map(|c| c.error_h_m).collect(),
        ));
    }
    curves
}

/// The CDF's series: every curve in its own colour (the methods' colours as in the
/// error-against-time plot, then the closed-loop curves').
fn cdf_series(curves: Vec<(String, Vec<Option<f64>>)>) -> Vec<Series> {
    curves
        .into_iter()
        .enumerate()
        .map(|(i, (name, errs))| {
            let n = errs.len().max(1) as f64;
            let mut v: Vec<f64> = errs.into_iter().flatten().collect();
            v.sort_by(f64::total_cmp);
            Series {
                name,
                colour: COLOURS[i % COLOURS.len()],
                points: v
                    .iter()
                    .enumerate()
                    .map(|(i, e)| (*e, (i + 1) as f64 / n))
                    .collect(),
            }
        })
        .collect()
}

/// The command that regenerates the report (the header's and the sidecar's).
pub fn command(args: &Args) -> String {
    let mut c = format!(
        "cargo sim baselines-report --tries {} --first-seed {}",
        args.tries, args.first_seed
    );
    if !args.methods.is_empty() {
        let names: Vec<String> = args
            .methods
            .iter()
            .filter_map(|m| clap::ValueEnum::to_possible_value(m).map(|v| v.get_name().to_owned()))
            .collect();
        c.push_str(&format!(" --methods {}", names.join(",")));
    }
    if args.no_paper_protocols {
        c.push_str(" --no-paper-protocols");
    }
    format!("{c} --out {}", args.out.display())
}

/// The directory of the PNG plots: the report's.
fn plot_dir(out: &Path) -> &Path {
    out.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Runs the methods and returns the markdown, writing the report (`args.out`), its
/// sidecar (`X.json`) and the plots beside it.
pub fn generate(args: &Args) -> Result<String> {
    if args.tries == 0 {
        bail!("--tries must be at least 1");
    }
    if args.out.extension().and_then(|e| e.to_str()) != Some("md") {
        bail!(
            "--out must name the markdown report (X.md; its sidecar X.json and the plots go beside it), not {}",
            args.out.display()
        );
    }
    let methods: Vec<Method> = if args.methods.is_empty() {
        Method::ALL.to_vec()
    } else {
        args.methods.clone()
    };
    let mut all = Vec::new();
    for m in methods {
        eprintln!("baselines: {} × {} …", m.name(), args.tries);
        all.push(run_method(m, args.first_seed, args.tries)?);
    }
    let dir = plot_dir(&args.out);
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    error_vs_time(&all, &dir.join(ERROR_PNG))?;
    cdf(&all, &dir.join(CDF_PNG))?;
    let mut md = markdown(args, &all);
    let mut paper = serde_json::Map::new();
    if !args.no_paper_protocols {
        md.push_str("\n## Each baseline under its own paper's protocol\n\n");
        let (ds, ds_summary) = super::paper::search::ds_section(args.first_seed, args.tries)?;
        md.push_str(&ds);
        md.push('\n');
        let (iros, iros_summary) = super::paper::iros::iros_section(args.first_seed, args.tries);
        md.push_str(&iros);
        md.push('\n');
        let (drone, drone_summary) =
            super::paper::report::drone_section(args.first_seed, args.tries, dir)?;
        md.push_str(&drone);
        paper.insert("directional_search_icra".into(), ds_summary);
        paper.insert("iros_closed_loop".into(), iros_summary);
        paper.insert("rls_drone_protocol".into(), drone_summary);
    }
    let side = super::record::sidecar(&command(args), args, &all, paper)?;
    crate::eval::sidecar::write(&args.out, &md, side)?;
    Ok(md)
}

/// `hal-sim baselines-report` (the markdown is also printed).
pub fn run(args: &Args, out: &mut impl std::io::Write) -> Result<()> {
    let md = generate(args)?;
    out.write_all(md.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_on_three_runs_has_every_row_and_the_plots() {
        let dir = tempfile::tempdir().unwrap();
        let args = Args {
            tries: 3,
            first_seed: 1,
            out: dir.path().join("b.md"),
            methods: Vec::new(),
            no_paper_protocols: true,
        };
        let md = generate(&args).unwrap();
        for m in Method::ALL {
            assert!(
                md.contains(&format!("| {}", m.name())),
                "no row for {m:?}:\n{md}"
            );
        }
        assert!(md.contains("0.66 / 0.23 / 0.21"));
        assert!(md.contains("the SOGs filter"));
        for f in ["b.md", "b.json", ERROR_PNG, CDF_PNG] {
            assert!(dir.path().join(f).metadata().unwrap().len() > 0, "{f}");
        }
        // No host timing in the report: it would depend on the machine's load.
        assert!(!md.contains("µs") && !md.contains("Wall time"), "{md}");
        let side = crate::eval::sidecar::read(&dir.path().join("b.json")).unwrap();
        assert_eq!(side.command, command(&args));
        assert_eq!(
            side.markdown_fnv64,
            crate::eval::sidecar::fnv64(md.as_bytes())
        );
    }

    #[test]
    fn out_must_name_a_markdown_file() {
        let args = Args {
            tries: 1,
            first_seed: 1,
            out: PathBuf::from("hal-sim/reports"),
            methods: vec![Method::SingleEkf],
            no_paper_protocols: true,
        };
        let e = generate(&args).unwrap_err().to_string();
        assert!(e.contains("X.md"), "{e}");
    }

    #[test]
    fn every_cdf_curve_has_its_own_colour() {
        // As many curves as the report draws: every method, plus a closed-loop curve for
        // each method that runs both open and closed loop.
        let both = Method::ALL
            .iter()
            .filter(|m| m.open_loop() && m.closed_loop().is_some())
            .count();
        let curves = (0..Method::ALL.len() + both)
            .map(|i| (format!("curve {i}"), vec![Some(1.0)]))
            .collect();
        let series = cdf_series(curves);
        for (i, a) in series.iter().enumerate() {
            for b in &series[i + 1..] {
                assert_ne!(
                    a.colour, b.colour,
                    "{} and {} share a colour",
                    a.name, b.name
                );
            }
        }
    }
}
