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

use crate::io::receiver_config::ReceiverConfig;
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
    logs: &[(crate::io::session::Session, ReceiverConfig)],
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
        let s =
            crate::io::session::read_file(p).with_context(|| format!("reading {}", p.display()))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Signatures fitted from each log's pulse times group the local `src` labels of a
    /// seeded scenario exactly as the truth's label maps do.
    #[test]
    fn association_on_a_seeded_scenario() {
        let sim = scenario::simulate(&scenario::TeamConfig::new(7, 3, 4));
        let sigs: Vec<Vec<Option<signature::Signature>>> = sim
            .logs
            .iter()
            .zip(&sim.truth.rescuers)
            .map(|((s, ..), rt)| {
                (0..rt.src_map.len() as u32)
                    .map(|src| {
                        let t: Vec<f64> = s
                            .pulses()
                            .filter(|p| p.src == Some(src))
                            .map(|p| p.t)
                            .collect();
                        signature::fit(&t)
                    })
                    .collect()
            })
            .collect();
        let ids = signature::associate(&sigs, 50.0);
        let mut pairs = 0;
        for (a, ra) in sim.truth.rescuers.iter().enumerate() {
            for (b, rb) in sim.truth.rescuers.iter().enumerate() {
                for (la, ta) in ra.src_map.iter().enumerate() {
                    for (lb, tb) in rb.src_map.iter().enumerate() {
                        let same_id = ids[a][la] == ids[b][lb];
                        let both = sigs[a][la].is_some() && sigs[b][lb].is_some();
                        // A track without a signature is a group of its own.
                        let want = ta == tb && (both || (a == b && la == lb));
                        assert_eq!(same_id, want, "log {a} src {la} vs log {b} src {lb}");
                        pairs += usize::from(a != b && ta == tb && both);
                    }
                }
            }
        }
        // The test means something only if some transmitter is heard in several logs
        // under different labels.
        assert!(pairs > 0);
        let relabelled = sim
            .truth
            .rescuers
            .iter()
            .any(|r| r.src_map != sim.truth.rescuers[0].src_map);
        assert!(relabelled || sim.truth.rescuers.len() < 2);
    }

    /// `team-scenario` then `team-map` through files: the JSON and PNG appear, every
    /// localized victim lies within 4σ (+ 0.5 m of model slack) of the truth, and the
    /// correction does not make the tracks worse on average.
    #[test]
    fn small_team_map_end_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let args = ScenarioArgs {
            seed: 3,
            rescuers: 2,
            victims: 2,
            out: dir.path().to_path_buf(),
        };
        let mut out = Vec::new();
        run_scenario(&args, &mut out).unwrap();
        let logs: Vec<PathBuf> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(PathBuf::from)
            .collect();
        assert_eq!(logs.len(), 2);
        let margs = MapArgs {
            logs: logs.clone(),
            starts: Some(dir.path().join("starts.json")),
            out: dir.path().join("map"),
            max_sigma_m: 3.0,
            strip_m: 20.0,
        };
        run_map(&margs, &mut Vec::new()).unwrap();
        assert!(dir.path().join("map/team-map.png").exists());
        let text = std::fs::read_to_string(dir.path().join("map/team-map.json")).unwrap();
        let m: map::TeamMap = serde_json::from_str(&text).unwrap();
        let truth: scenario::TeamTruth = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("team-truth.json")).unwrap(),
        )
        .unwrap();
        let truths: Vec<crate::io::session::Session> = logs
            .iter()
            .map(|p| crate::io::session::read_file(&p.with_file_name("truth.jsonl")).unwrap())
            .collect();
        let refs: Vec<&crate::io::session::Session> = truths.iter().collect();
        let sc = report::score(&truth, &refs, &m);
        assert_eq!(sc.association.0, sc.association.1);
        let localized: Vec<_> = sc.victims.iter().filter(|v| v.joint_m.is_some()).collect();
        assert!(!localized.is_empty());
        for v in localized {
            let (e, s) = (v.joint_m.unwrap(), v.joint_sigma_m.unwrap());
            assert!(
                e <= 4.0 * s + 0.5,
                "victim {}: error {e:.2} m, σ {s:.2} m",
                v.truth
            );
        }
        let dr: f64 = sc.tracks.iter().map(|t| t.0).sum();
        let corrected: f64 = sc.tracks.iter().map(|t| t.1).sum();
        assert!(corrected <= dr, "{corrected} > {dr}");
        assert!(
            m.covered_area_m2 > 0.0
                && m.rescuers
                    .iter()
                    .all(|r| r.covered_area_m2 <= m.covered_area_m2)
        );
    }

    #[test]
    fn a_malformed_log_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.jsonl");
        std::fs::write(&p, "not json\n").unwrap();
        let args = MapArgs {
            logs: vec![p],
            starts: None,
            out: dir.path().join("map"),
            max_sigma_m: 3.0,
            strip_m: 20.0,
        };
        let err = run_map(&args, &mut Vec::new()).unwrap_err();
        assert!(format!("{err:#}").contains("bad.jsonl"));
    }

    #[test]
    fn an_empty_team_gives_an_empty_map() {
        let m = map::build(&[], &[], &map::MapOptions::default()).unwrap();
        assert!(m.victims.is_empty() && m.rescuers.is_empty());
    }
}
