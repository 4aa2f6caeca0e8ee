//! Team map (RFID-SLAM style, Kleiner, Dornhege & Dali 2006): several rescuers' session
//! logs joined at the victims' beacons.
//!
//! Pipeline: each log alone ([`local`]: the firmware's dead reckoning and one firmware
//! estimator per `src` track) → signatures from pulse times and association across logs
//! ([`signature`]) → pose graph with dead-reckoning, beacon and start-fix edges solved by
//! least squares on the Mahalanobis distance ([`graph`], [`map`]; the paper's eq. 5) → a
//! JSON map and a PNG ([`plot`]). [`scenario`] simulates team searches, [`report`] writes
//! `hal-sim/reports/team.md`.
pub mod graph;
pub mod local;
pub mod map;
pub mod plot;
pub mod report;
pub mod scenario;
pub mod signature;

use crate::receiver_config::ReceiverConfig;
use anyhow::Context;
use std::path::{Path, PathBuf};

/// `hal-sim team-scenario`.
#[derive(clap::Args, Debug)]
pub struct ScenarioArgs {
    /// Seed of every random draw.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Rescuers (2–4).
    #[arg(long, default_value_t = 3)]
    pub rescuers: usize,
    /// Victims (2–5).
    #[arg(long, default_value_t = 4)]
    pub victims: usize,
    /// Output directory (r<i>/session.jsonl … , starts.json, team-truth.json).
    #[arg(long, default_value = "runs/team")]
    pub out: PathBuf,
}

/// `hal-sim team-map`.
#[derive(clap::Args, Debug)]
pub struct MapArgs {
    /// The rescuers' session logs; a `receiver.json` beside a log is used for it.
    #[arg(required = true)]
    pub logs: Vec<PathBuf>,
    /// The rescuers' start fixes (JSON list of `{"p":[north,west],"sigma_m":σ}` in the
    /// logs' order); without it the first log starts at the origin, the others are free.
    #[arg(long)]
    pub starts: Option<PathBuf>,
    /// Output directory for team-map.json and team-map.png.
    #[arg(long, default_value = "runs/team-map")]
    pub out: PathBuf,
    /// Largest horizontal σ of a track's estimate that still counts as an observation, m.
    #[arg(long, default_value_t = 3.0)]
    pub max_sigma_m: f64,
    /// Half-width of the searched strip either side of a walk, m.
    #[arg(long, default_value_t = 20.0)]
    pub strip_m: f64,
}

/// Processes every log (in parallel), printing progress on stderr.
pub fn process_logs(
    logs: &[(crate::session::Session, ReceiverConfig)],
) -> anyhow::Result<Vec<local::LocalRun>> {
    use rayon::prelude::*;
    logs.par_iter()
        .enumerate()
        .map(|(i, (s, rc))| {
            let run = local::process(s, rc, |done, total| {
                eprintln!(
                    "log {i}: {:3.0} %",
                    100.0 * done as f64 / total.max(1) as f64
                );
            })?;
            eprintln!(
                "log {i}: {} pulses, {} tracks, {} localized",
                run.dr.len(),
                run.tracks.len(),
                run.tracks.iter().filter(|t| t.best.is_some()).count()
            );
            Ok(run)
        })
        .collect()
}

fn read_receiver(log: &Path) -> anyhow::Result<ReceiverConfig> {
    let p = log.with_file_name("receiver.json");
    if p.exists() {
        ReceiverConfig::read_file(&p)
    } else {
        Ok(ReceiverConfig::default())
    }
}

/// Runs `team-scenario`.
pub fn run_scenario(args: &ScenarioArgs, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    let cfg = scenario::TeamConfig::new(args.seed, args.rescuers, args.victims);
    let sim = scenario::simulate(&cfg);
    for p in scenario::write(&sim, &args.out)? {
        writeln!(out, "{}", p.display())?;
    }
    Ok(())
}

/// Runs `team-map`: writes team-map.json and team-map.png, prints the JSON path.
pub fn run_map(args: &MapArgs, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    let mut logs = Vec::new();
    for p in &args.logs {
        let s = crate::session::read_file(p).with_context(|| format!("reading {}", p.display()))?;
        for w in &s.warnings {
            eprintln!("warning: {}: {w}", p.display());
        }
        logs.push((s, read_receiver(p)?));
    }
    let starts: Vec<Option<scenario::StartFix>> = match &args.starts {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            let v: Vec<scenario::StartFix> =
                serde_json::from_str(&text).with_context(|| format!("parsing {}", p.display()))?;
            v.into_iter().map(Some).collect()
        }
        None => Vec::new(),
    };
    let runs = process_logs(&logs)?;
    let opt = map::MapOptions {
        max_sigma_m: args.max_sigma_m,
        strip_half_width_m: args.strip_m,
        ..map::MapOptions::default()
    };
    eprintln!("solving the pose graph");
    let m = map::build(&runs, &starts, &opt)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let json = args.out.join("team-map.json");
    std::fs::write(&json, serde_json::to_string(&m)?)?;
    plot::plot(&m, None, &args.out.join("team-map.png"))?;
    writeln!(out, "{}", json.display())?;
    Ok(())
}
