//! `hal-sim`: the receiver's world on a PC.
use anyhow::{Context, Result};
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use hal_sim::cli::{demo, field_map};
use hal_sim::eval::{accuracy, budget_data};
use hal_sim::io::receiver_config::ReceiverConfig;
use hal_sim::io::{inspect, replay, session};
use hal_sim::sim::simulate;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Simulator, replay and analysis tools for the avalanche-beacon receiver firmware.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Simulate seeded searches and write, per scenario, the session log
    /// (session.jsonl), its ground truth (truth.jsonl), the receiver configuration
    /// (receiver.json) and every random choice (scenario.json).
    Simulate(simulate::Args),
    /// Run the firmware's estimator over a session log and print one JSON line per pulse
    /// on stdout (the spec's replay output). Warnings and progress go to stderr.
    ///
    /// The log is streamed (bounded memory); pulse records written up to 2 s late are put
    /// in order; a malformed line is reported with its number and skipped; a second header
    /// starts a new segment (a fresh receiver); `seq` gaps are reported. A summary of what
    /// was read, skipped and refused ends the run on stderr. `-` reads standard input live:
    /// each record is processed as it arrives and each pulse's line is flushed at once.
    Replay {
        /// The session log (JSON Lines), or `-` for standard input (live mode).
        log: PathBuf,
        /// receiver.json to tell the receiver about its world; without it the built-in
        /// defaults apply.
        #[arg(long)]
        receiver: Option<PathBuf>,
        /// Stop with exit status 1 at the first malformed line instead of skipping it.
        #[arg(long)]
        strict: bool,
    },
    /// Summarize a session log, per segment (a second header starts one): duration, pulse
    /// count, IMU rate, gaps; then what was skipped. Streamed (bounded memory).
    Inspect {
        /// The session log (JSON Lines).
        log: PathBuf,
    },
    /// Print the field magnitude of a beacon on a horizontal grid around it, evaluated
    /// with the firmware's own f32 dipole model (an ASCII map, strongest field darkest).
    FieldMap(field_map::Args),
    /// Monte Carlo accuracy of the SOGs estimator over seeded scenarios (the papers'
    /// protocol), printed as a markdown report in the papers' table layout.
    Accuracy(accuracy::Args),
    /// Write the recorded estimator steps that the on-target budget binary replays under
    /// QEMU (a Rust source of constants).
    BudgetData(budget_data::Args),
    /// Run one seeded closed-loop rescue with the firmware's application in the loop:
    /// the receiver's screen live in the terminal, then a PNG plot of the search and of
    /// the final screen.
    Demo(demo::Args),
    /// Sensing at the bus level (emulated chips → firmware drivers → DSP and motion):
    /// motion errors, bus vs measurement pulses, estimator error after replay; a markdown
    /// report.
    SensingReport(hal_sim::eval::sensing_report::Args),
    /// Seeded closed-loop rescues under the papers' protocol (start 40–70 m away): the
    /// receiver with and without step-length calibration and the classical directional
    /// search, steps and probe-point errors against the ideal walk; a markdown report.
    RescueReport(hal_sim::eval::rescue_report::Args),
    /// The papers' baselines (LM batch fit, RLS identifier, directional search and the
    /// firmware's baseline filters) beside the SOGs filter on the same seeded scenarios:
    /// a markdown report with PNG plots.
    BaselinesReport(hal_sim::eval::baselines::report::Args),
    /// NEES of the application's estimate (IMU → PDR → SOGs) against the truth over
    /// seeded simulated searches (slides 002 consistency test); a markdown table.
    Consistency(hal_sim::sensors::faults::consistency::Args),
    /// Simulate a team search (2–4 rescuers, 2–5 victims): one session log per rescuer,
    /// their truth, receiver.json, the start fixes (starts.json) and the team truth.
    TeamScenario(hal_sim::team::ScenarioArgs),
    /// Join several rescuers' session logs into one map at their shared beacons (pose
    /// graph, least squares on the Mahalanobis distance): team-map.json and team-map.png.
    TeamMap(hal_sim::team::MapArgs),
    /// Seeded team scenarios through team-map, scored against the truth; a markdown
    /// report and a PNG.
    TeamReport(hal_sim::team::report::Args),
    /// Seeded multi-victim rescues (2–4 victims, close pairs, long pulse overlaps) with
    /// marking: victims found, per-victim error, time to find all, wrong-victim marks;
    /// a markdown report.
    MultiReport(hal_sim::eval::multi_report::Args),
    /// Seeded closed-loop rescues with the receiver in its "classic" mode (the firmware's
    /// classical directional search) beside the idealized DS and the SOG; a markdown report.
    ClassicReport(hal_sim::sim::classic_loop::Args),
}

/// `hal-sim inspect`: streams the log and summarizes each segment.
fn run_inspect(log: &Path) -> Result<()> {
    let name = log.display().to_string();
    let f = std::fs::File::open(log).with_context(|| format!("reading {name}"))?;
    let mut cap = replay::WarningCap::new(&name, replay::WARNINGS_SHOWN);
    let input = std::io::BufReader::with_capacity(1 << 16, f);
    let report = inspect::inspect_stream(input, |w| cap.warn(w, &mut std::io::stderr()))
        .with_context(|| format!("reading {name}"))?;
    if let Some(more) = cap.finish() {
        eprintln!("{more}");
    }
    write!(std::io::stdout().lock(), "{report}")?;
    Ok(())
}

/// `hal-sim replay`: streams the log (or standard input, live) through the firmware.
fn run_replay(log: &Path, receiver: Option<&Path>, strict: bool) -> Result<()> {
    let config = match receiver {
        Some(p) => ReceiverConfig::read_file(p)?,
        None => ReceiverConfig::default(),
    };
    let live = log.as_os_str() == "-";
    let name = if live {
        "<stdin>".to_string()
    } else {
        log.display().to_string()
    };
    let opts = replay::StreamOptions { strict, live };
    let mut cap = replay::WarningCap::new(&name, replay::WARNINGS_SHOWN);
    let on_warning = |w: &session::Warning| cap.warn(w, &mut std::io::stderr());
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let (result, bar) = if live {
        let stdin = std::io::stdin().lock();
        let r = replay::replay_stream(stdin, &config, &mut out, opts, on_warning, |_| {});
        (r, None)
    } else {
        let f = std::fs::File::open(log).with_context(|| format!("reading {name}"))?;
        let len = f.metadata().map(|m| m.len()).unwrap_or(0);
        let bar = indicatif::ProgressBar::new(len);
        let input = std::io::BufReader::with_capacity(1 << 16, f);
        let r = replay::replay_stream(input, &config, &mut out, opts, on_warning, |b| {
            bar.set_position(b)
        });
        (r, Some(bar))
    };
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    if let Some(more) = cap.finish() {
        eprintln!("{more}");
    }
    match result {
        Ok(summary) => {
            eprint!("{summary}");
            Ok(())
        }
        // The reader of the output closed it (`replay … | head -1`): done, quietly.
        Err(e) if replay::is_broken_pipe(&e) => Ok(()),
        Err(e) => Err(e.context(format!("replaying {name}"))),
    }
}

fn main() -> Result<()> {
    let stdout = std::io::stdout();
    let matches = hal_sim::cli::help::wrapped(Cli::command()).get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    match cli.command {
        Command::Simulate(args) => simulate::run(&args, &mut stdout.lock()),
        Command::Replay {
            log,
            receiver,
            strict,
        } => run_replay(&log, receiver.as_deref(), strict),
        Command::Inspect { log } => run_inspect(&log),
        Command::FieldMap(args) => field_map::run(&args, &mut stdout.lock()),
        Command::Accuracy(args) => accuracy::run(&args, &mut stdout.lock()),
        Command::BudgetData(args) => budget_data::run(&args),
        Command::Demo(args) => demo::run(&args, &mut stdout.lock()),
        Command::SensingReport(args) => {
            hal_sim::eval::sensing_report::run(&args, &mut stdout.lock())
        }
        Command::RescueReport(args) => hal_sim::eval::rescue_report::run(&args, &mut stdout.lock()),
        Command::BaselinesReport(args) => {
            hal_sim::eval::baselines::report::run(&args, &mut stdout.lock())
        }
        Command::Consistency(args) => {
            hal_sim::sensors::faults::consistency::run(&args, &mut stdout.lock())
        }
        Command::TeamScenario(args) => hal_sim::team::run_scenario(&args, &mut stdout.lock()),
        Command::TeamMap(args) => hal_sim::team::run_map(&args, &mut stdout.lock()),
        Command::TeamReport(args) => hal_sim::team::report::run(&args, &mut stdout.lock()),
        Command::MultiReport(args) => {
            hal_sim::eval::multi_report::report(&args, &mut stdout.lock())
        }
        Command::ClassicReport(args) => {
            hal_sim::sim::classic_loop::report(&args, &mut stdout.lock())
        }
    }
}
