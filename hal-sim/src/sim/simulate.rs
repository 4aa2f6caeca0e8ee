//! `hal-sim simulate`: writes the session log, its truth, `receiver.json` and
//! `scenario.json` of one or more seeded scenarios.
use crate::world::scenario::{Preset, ScenarioConfig, Simulation, simulate};
use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Options of `hal-sim simulate`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Scenario family: the papers' protocol, an open-loop route family or a hard case.
    #[arg(long, value_enum, default_value_t = Preset::Paper)]
    pub preset: Preset,
    /// Seed of the first scenario (every random draw); the same seed and options give
    /// byte-identical files. `--seed` is the same flag.
    #[arg(long = "first-seed", visible_alias = "seed", default_value_t = 1)]
    pub seed: u64,
    /// Output directory. With --tries 1 the files go directly into it; otherwise into
    /// one sub-directory per scenario named PRESET-SEED.
    #[arg(long, default_value = "sim-out")]
    pub out: PathBuf,
    /// Number of scenarios (≥ 1), with seeds SEED, SEED+1, … `--count` is the same flag.
    #[arg(long = "tries", visible_alias = "count", default_value_t = 1,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub count: u64,
    /// Longest simulated time per scenario, s (the route usually ends earlier).
    #[arg(long, default_value_t = 900.0)]
    pub max_duration_s: f64,
    /// Number of buried transmitters (pulses carry `src` when more than one).
    #[arg(long, default_value_t = 1)]
    pub victims: usize,
    /// Keep the sign of each pulse vector (default: random overall sign).
    #[arg(long)]
    pub no_sign_ambiguity: bool,
    /// Leave the calibrated step length out of receiver.json.
    #[arg(long)]
    pub uncalibrated: bool,
    /// No random stops along the route.
    #[arg(long)]
    pub no_stops: bool,
    /// Background noise of the pulse vectors, A/m per component (default 2.59e-9: EMI
    /// equivalent to a beacon ~80 m away).
    #[arg(long)]
    pub sigma_bkg: Option<f64>,
    /// Pulse noise proportional to |H| (default 0.03).
    #[arg(long)]
    pub k_sen: Option<f64>,
    /// Largest gyro bias per axis, rad/s (default 0.01; 0.05 in the gyro-bias preset).
    #[arg(long)]
    pub gyr_bias_max: Option<f64>,
    /// Transmitter moment range MIN,MAX in A·m² (default 3e-3,3e-2).
    #[arg(long, value_parser = parse_moment_range)]
    pub moment_range: Option<[f64; 2]>,
    /// Bus level: generate the log through emulated chips (ADS131M04 antenna ADC, BMI160
    /// and LSM303AGR IMU) read by the firmware's drivers, and the firmware's pulse DSP,
    /// instead of the measurement-level sensor models. Pulses are then always
    /// sign-ambiguous; truth records follow the DSP's pulse times.
    #[arg(long)]
    pub bus: bool,
    /// Print nothing on stdout.
    #[arg(long)]
    pub quiet: bool,
}

impl Args {
    /// The scenario configuration for one seed.
    pub fn config(&self, seed: u64) -> ScenarioConfig {
        let mut c = ScenarioConfig::new(self.preset, seed);
        c.max_duration_s = self.max_duration_s;
        c.victims = self.victims.max(1);
        c.sensors.sign_ambiguous = !self.no_sign_ambiguity;
        c.calibrated = !self.uncalibrated;
        c.random_stops = !self.no_stops;
        if let Some(x) = self.sigma_bkg {
            c.sensors.pulse.sigma_bkg_a_per_m = x;
        }
        if let Some(x) = self.k_sen {
            c.sensors.pulse.k_sen = x;
        }
        if let Some(x) = self.gyr_bias_max {
            c.sensors.imu.gyr_bias_max_rad_s = x;
        }
        if let Some(r) = self.moment_range {
            c.transmitter.moment_range = r;
        }
        c
    }
}

/// `--moment-range MIN,MAX`: two finite moments, 0 < MIN ≤ MAX (A·m²).
fn parse_moment_range(s: &str) -> Result<[f64; 2], String> {
    let (min, max) = s
        .split_once(',')
        .ok_or_else(|| format!("expected MIN,MAX in A·m², got {s:?}"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|e| format!("{v:?} is not a number: {e}"))
    };
    let (min, max) = (parse(min)?, parse(max)?);
    if !(min.is_finite() && max.is_finite() && min > 0.0 && min <= max) {
        return Err(format!("need 0 < MIN ≤ MAX, finite; got {min},{max}"));
    }
    Ok([min, max])
}

/// Names of the files one scenario writes.
pub const SESSION_FILE: &str = "session.jsonl";
/// Ground truth file (a header line, then truth records).
pub const TRUTH_FILE: &str = "truth.jsonl";
/// Receiver configuration file.
pub const RECEIVER_FILE: &str = "receiver.json";
/// Every random choice of the scenario, for evaluation and debugging.
pub const SCENARIO_FILE: &str = "scenario.json";

/// Writes the four files of a simulation into `dir`; returns the session log's size in bytes.
pub fn write_simulation(sim: &Simulation, dir: &Path) -> Result<u64> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let session = sim.session_bytes();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).with_context(|| format!("writing {}", p.display()))
    };
    write(SESSION_FILE, &session)?;
    write(TRUTH_FILE, &sim.truth_bytes())?;
    write(
        RECEIVER_FILE,
        format!("{}\n", sim.receiver.to_json()).as_bytes(),
    )?;
    let scenario = serde_json::to_string_pretty(&sim.draw)?;
    write(SCENARIO_FILE, format!("{scenario}\n").as_bytes())?;
    Ok(session.len() as u64)
}

/// Runs `simulate`: generates and writes the scenarios, reporting each on `out`, a
/// progress bar and the generation speed on stderr.
pub fn run(args: &Args, out: &mut impl Write) -> Result<()> {
    let start = std::time::Instant::now();
    let bar = indicatif::ProgressBar::new(args.count);
    if args.count > 1 {
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} scenarios, {elapsed} elapsed, eta {eta}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
    } else {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let (mut bytes, mut seconds) = (0u64, 0.0f64);
    for k in 0..args.count {
        let seed = args.seed.wrapping_add(k);
        let cfg = args.config(seed);
        let sim = if args.bus {
            crate::sensors::bus::run::simulate_bus_default(&cfg)?.sim
        } else {
            simulate(&cfg)
        };
        let dir = if args.count == 1 {
            args.out.clone()
        } else {
            let name = serde_json::to_value(args.preset)?
                .as_str()
                .unwrap_or("scenario")
                .to_string();
            args.out.join(format!("{name}-{seed}"))
        };
        bytes += write_simulation(&sim, &dir)?;
        seconds += sim.draw.duration_s;
        if !args.quiet {
            let pulses = sim.session.pulses().count();
            writeln!(
                out,
                "{}: {:.1} s simulated, {} pulses, {} IMU samples",
                dir.display(),
                sim.draw.duration_s,
                pulses,
                sim.session.imu().count()
            )?;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    eprintln!(
        "{} scenario(s) in {wall:.2} s ({:.2} per second); {:.1} s simulated; session logs {:.1} kB per simulated minute",
        args.count,
        args.count as f64 / wall.max(1e-9),
        seconds,
        bytes as f64 / 1000.0 / (seconds / 60.0).max(1e-9)
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_moment_range;

    #[test]
    fn moment_range_takes_min_comma_max_and_refuses_the_rest() {
        assert_eq!(parse_moment_range("3e-3,3e-2"), Ok([3e-3, 3e-2]));
        assert_eq!(parse_moment_range("0.01, 0.01"), Ok([0.01, 0.01]));
        for bad in [
            "3e-3",
            "3e-2,3e-3",
            "0,1",
            "-1,1",
            "nan,1",
            "1,inf",
            "a,b",
            "",
        ] {
            assert!(parse_moment_range(bad).is_err(), "{bad:?} accepted");
        }
    }
}
