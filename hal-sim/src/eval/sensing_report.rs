//! `hal-sim sensing-report`: how well the receiver senses, at the bus level (emulated chips
//! → the firmware's drivers → its DSP and motion code), over seeded simulated walks:
//! - motion from the IMU driver's readings (`firmware::motion`): step count, distance with
//!   the calibrated step length, heading;
//! - the DSP's pulses against the measurement level's on the same seeds;
//! - the estimator's final error when replaying bus-level and measurement-level logs of the
//!   `paper` preset ([`crate::io::replay::replay_with_config`]) against the world's truth.
use crate::eval::detection_report::{Detection, DetectionArgs};
use crate::io::replay::{ReplayLine, replay_with_config};
use crate::io::session::{Record, Session};
use crate::sensors::bus::run::{
    BusRun, PulseComparison, STRONG_FACTOR, UnitCalibration, compare_pulses, simulate_bus_default,
    simulate_bus_with,
};
use crate::world::rescuer::wrap_pi;
use crate::world::scenario::{Preset, ScenarioConfig};
use anyhow::Result;
use firmware::Vec3;
use firmware::board::{IfRange, REFERENCE};
use firmware::drivers::ads131m04::Gain;
use firmware::motion::{Motion, MotionConfig};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;

/// Options of `hal-sim sensing-report`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeds of the `paper` preset replayed for the estimator table (seeds
    /// first-seed..first-seed+tries), at least 1.
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..))]
    pub tries: u64,
    /// First seed of the `paper` runs and of the motion walks (1 for the checked-in
    /// report; another range validates it).
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Walks per route family (line, arc, zigzag) for the motion table.
    #[arg(long, default_value_t = 4)]
    pub walks: u64,
    /// Longest simulated time of a motion walk, s.
    #[arg(long, default_value_t = 120.0)]
    pub walk_s: f64,
    /// Hours of noise-only simulated time for the false-alarm rate.
    #[arg(long, default_value_t = 10)]
    pub noise_hours: u64,
    /// Pulses per field magnitude for the probability of detection.
    #[arg(long, default_value_t = 200)]
    pub probe_pulses: usize,
    /// Measure and print only the detection section (no report is written).
    #[arg(long)]
    pub detection_only: bool,
    /// Write the markdown report here, with its sidecar X.json (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

impl Args {
    /// The command that writes this report (the `--out` path is added by the sidecar).
    pub fn command(&self) -> String {
        let mut c = format!(
            "cargo sim sensing-report --tries {}{}",
            self.tries,
            crate::eval::sidecar::first_seed_flag(self.first_seed)
        );
        let _ = write!(
            c,
            " --walks {} --noise-hours {} --probe-pulses {}",
            self.walks, self.noise_hours, self.probe_pulses
        );
        if self.walk_s != 120.0 {
            let _ = write!(c, " --walk-s {}", self.walk_s);
        }
        c
    }

    /// The `paper` seeds.
    fn paper_seeds(&self) -> std::ops::Range<u64> {
        self.first_seed..self.first_seed.saturating_add(self.tries)
    }

    /// The seeds of each route family's walks.
    fn walk_seeds(&self) -> std::ops::Range<u64> {
        self.first_seed..self.first_seed.saturating_add(self.walks)
    }

    /// The last `paper` seed.
    fn last_seed(&self) -> u64 {
        self.paper_seeds().end.saturating_sub(1)
    }

    /// The last seed of each route family's walks.
    fn last_walk(&self) -> u64 {
        self.walk_seeds().end.saturating_sub(1)
    }
}

/// Motion errors of one walk.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct WalkResult {
    /// `preset/seed`.
    pub name: String,
    /// Steps detected.
    pub steps: u32,
    /// Steps taken (the gait's phase at the end).
    pub steps_true: f64,
    /// Distance from steps × calibrated step length, m.
    pub dist: f64,
    /// Torso path length, m.
    pub dist_true: f64,
    /// Yaw RMS error after the first 5 s, degrees.
    pub yaw_rms_deg: f64,
}

/// Horizontal torso position (the receiver's truth without the hold offset).
fn torso(run: &BusRun, t: f64) -> [f64; 2] {
    let s = run.sim.world.rescuer_state(t);
    let hold = &run.sim.draw.hold;
    let (sn, cs) = s.heading.sin_cos();
    [
        s.p.x - hold.forward_m * cs + hold.left_m * sn,
        s.p.y - hold.forward_m * sn - hold.left_m * cs,
    ]
}

fn v3(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// Runs the firmware's motion pipeline over the bus-level IMU records of `run`.
pub fn walk_result(run: &BusRun) -> WalkResult {
    let sim = &run.sim;
    let earth = sim
        .session
        .header
        .earth_field_ut
        .unwrap_or([21.792, 0.0, -42.768]);
    let step = sim.receiver.pdr.as_ref().map(|p| p.step_length_m as f32);
    let mut m = Motion::new(MotionConfig::new(v3(&earth), step));
    let (mut se, mut n) = (0.0, 0usize);
    for r in &sim.session.records {
        if let Record::Imu(s) = r {
            let mag = s.mag.as_ref().map(v3);
            if m.on_imu_sample(s.t as f32, &v3(&s.acc), &v3(&s.gyr), mag.as_ref())
                .is_err()
            {
                continue;
            }
            if s.t > 5.0 {
                let yaw = f64::from(m.attitude().0.z);
                let e = wrap_pi(yaw - sim.world.rescuer_state(s.t).rpy.z);
                se += e * e;
                n += 1;
            }
        }
    }
    let end = sim.draw.duration_s;
    let mut dist_true = 0.0;
    let mut last = torso(run, 0.0);
    for k in 1..=(end / 0.25) as usize {
        let p = torso(run, k as f64 * 0.25);
        dist_true += (p[0] - last[0]).hypot(p[1] - last[1]);
        last = p;
    }
    WalkResult {
        name: format!("{:?}/{}", sim.draw.config.preset, sim.draw.config.seed).to_lowercase(),
        steps: m.total_steps(),
        steps_true: sim.world.rescuer_state(end).steps,
        dist: f64::from(m.total_distance_m()),
        dist_true,
        yaw_rms_deg: (se / n.max(1) as f64).sqrt().to_degrees(),
    }
}

/// Final estimate error of a replay against the truth: the last line's first victim vs the
/// true victim relative to the receiver at that time (W and G_k share axes), m.
/// `None` when the estimator gave no estimate.
pub fn final_error(session: &Session, run: &BusRun) -> Result<Option<f64>> {
    let mut out = Vec::new();
    replay_with_config(session, &run.sim.receiver, &mut out)?;
    let text = String::from_utf8(out)?;
    let Some(last) = text.lines().last() else {
        return Ok(None);
    };
    let line: ReplayLine = serde_json::from_str(last)?;
    let Some(v) = line.victims.first() else {
        return Ok(None);
    };
    let s = run.sim.world.rescuer_state(line.t);
    let tx = run
        .sim
        .world
        .transmitters
        .first()
        .map_or([0.0; 3], |t| t.position);
    let truth = [tx[0] - s.p.x, tx[1] - s.p.y, tx[2] - s.p.z];
    Ok(Some(
        (0..3)
            .map(|i| (v.p[i] - truth[i]).powi(2))
            .sum::<f64>()
            .sqrt(),
    ))
}

/// One `paper` seed: pulse comparison and both final errors.
#[derive(Debug, Clone)]
pub struct PaperResult {
    /// The seed.
    pub seed: u64,
    /// Bus vs measurement pulses.
    pub pulses: PulseComparison,
    /// Final error replaying the measurement-level log, m.
    pub measurement_error: Option<f64>,
    /// Final error replaying the bus-level log, m.
    pub bus_error: Option<f64>,
    /// Motion errors of the walk.
    pub walk: WalkResult,
    /// The DSP's counters.
    pub frontend: firmware::frontend::FrontendStats,
    /// The same seed's unit without its bench calibration (the DSP holds the profile's
    /// nominal one): pulses, final error, DSP counters.
    pub uncalibrated: (
        PulseComparison,
        Option<f64>,
        firmware::frontend::FrontendStats,
    ),
}

/// Runs one `paper` seed at the bus level, with and without the unit's bench calibration.
pub fn paper(seed: u64) -> Result<PaperResult> {
    let cfg = ScenarioConfig::new(Preset::Paper, seed);
    let run = simulate_bus_default(&cfg)?;
    let p = &cfg.sensors.pulse;
    let raw = simulate_bus_with(&cfg, UnitCalibration::Nominal)?;
    Ok(PaperResult {
        seed,
        pulses: compare_pulses(&run, p.sigma_bkg_a_per_m, p.k_sen),
        measurement_error: final_error(&run.measurement, &run)?,
        bus_error: final_error(&run.sim.session, &run)?,
        uncalibrated: (
            compare_pulses(&raw, p.sigma_bkg_a_per_m, p.k_sen),
            final_error(&raw.sim.session, &raw)?,
            raw.frontend,
        ),
        walk: walk_result(&run),
        frontend: run.frontend,
    })
}

fn quantile(v: &[f64], q: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let i = ((v.len() as f64 - 1.0) * q).round().max(0.0) as usize;
    v.get(i).copied().unwrap_or(f64::NAN)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Renders the report from the walks and the `paper` results.
pub fn render(
    args: &Args,
    detection: &Detection,
    walks: &[WalkResult],
    papers: &[PaperResult],
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Sensing at the bus level\n\nGenerated by `{} --out {}`.\n\nEvery number comes from the bus level: the world drives emulated chips (`hal-sim/src/sensors/bus/`: ADS131M04 antenna ADC over SPI with DRDY, BMI160 and LSM303AGR over I2C), read by the firmware's drivers (`firmware::drivers::{{ads131m04, imu}}`), then the firmware's pulse DSP (`firmware::frontend`) and motion code (`firmware::motion`). DSP instruction counts are measured elsewhere (QEMU budget).\n",
        args.command(),
        args.out.as_ref().map_or_else(
            || "hal-sim/reports/sensing.md".into(),
            |p| p.display().to_string()
        )
    );
    s.push_str(&detection.render());
    // Motion.
    let _ = writeln!(
        s,
        "## Motion from the IMU driver's readings\n\nRoutes `line`, `arc`, `zigzag` (seeds {}..={}) and the `paper` seeds, at most {:.0} s each (paper: whole route). Distance: steps × the calibrated step length (≈2 % calibration error) against the torso's path length. Heading: RMS of the attitude filter's yaw error after 5 s.\n",
        args.first_seed,
        args.last_walk(),
        args.walk_s
    );
    let _ = writeln!(
        s,
        "| walks | step count error, mean abs / worst | distance error, mean abs / worst | heading RMS error, mean / worst |\n|---|---|---|---|"
    );
    let mut groups: Vec<(String, Vec<&WalkResult>)> = Vec::new();
    for w in walks.iter().chain(papers.iter().map(|p| &p.walk)) {
        let g = w.name.split('/').next().unwrap_or("").to_string();
        match groups.iter_mut().find(|(n, _)| *n == g) {
            Some((_, v)) => v.push(w),
            None => groups.push((g, vec![w])),
        }
    }
    let all: Vec<&WalkResult> = walks.iter().chain(papers.iter().map(|p| &p.walk)).collect();
    groups.push(("all".into(), all));
    for (name, ws) in &groups {
        let step: Vec<f64> = ws
            .iter()
            .map(|w| 100.0 * (f64::from(w.steps) - w.steps_true) / w.steps_true)
            .collect();
        let dist: Vec<f64> = ws
            .iter()
            .map(|w| 100.0 * (w.dist - w.dist_true) / w.dist_true)
            .collect();
        let yaw: Vec<f64> = ws.iter().map(|w| w.yaw_rms_deg).collect();
        let abs = |v: &[f64]| mean(&v.iter().map(|x| x.abs()).collect::<Vec<_>>());
        let worst = |v: &[f64]| {
            v.iter()
                .copied()
                .fold(0.0, |a: f64, x| if x.abs() > a.abs() { x } else { a })
        };
        let _ = writeln!(
            s,
            "| {name} ({}) | {:.2} % / {:+.2} % | {:.2} % / {:+.2} % | {:.2}° / {:.2}° |",
            ws.len(),
            abs(&step),
            worst(&step),
            abs(&dist),
            worst(&dist),
            mean(&yaw),
            yaw.iter().copied().fold(0.0, f64::max)
        );
    }
    let over: Vec<String> = walks
        .iter()
        .chain(papers.iter().map(|p| &p.walk))
        .filter(|w| ((w.dist - w.dist_true) / w.dist_true).abs() > 0.03)
        .map(|w| {
            format!(
                "{} ({} steps vs {:.1}, {:.1} m vs {:.1} m)",
                w.name, w.steps, w.steps_true, w.dist, w.dist_true
            )
        })
        .collect();
    let _ = writeln!(
        s,
        "\nTargets: distance ≤ 3 % of the distance walked, heading ≤ 3° RMS. Walks over 3 %: {}.\n",
        if over.is_empty() {
            "none".to_string()
        } else {
            over.join(", ")
        }
    );
    // Pulses.
    let mut c = PulseComparison::default();
    for p in papers {
        c.extend(p.pulses.clone());
    }
    let _ = writeln!(
        s,
        "## Pulses: bus level (ADC emulation → driver → DSP) vs measurement level\n\n`paper` seeds {}..={}, same worlds. Pairs: nearest pulse within 30 ms, each used once. Angles between the vectors' lines (sign ambiguity removed). NEES: squared difference per component over twice the model variance σ_bkg² + (k_sen·|H|)² (≈1 when both levels follow the model).\n",
        args.first_seed,
        args.last_seed()
    );
    let _ = writeln!(s, "| quantity | value |\n|---|---|");
    let rows: Vec<(String, String)> = vec![
        ("measurement-level pulses".into(), c.measurement.to_string()),
        (
            "bus-level pulses (DSP field vectors)".into(),
            c.bus.to_string(),
        ),
        ("matched pairs".into(), c.pairs.len().to_string()),
        (
            format!("measurement pulses with true |H| ≥ {STRONG_FACTOR} σ_bkg, matched"),
            format!("{} of {}", c.strong_matched, c.strong),
        ),
        (
            "median / 90 % relative magnitude difference".into(),
            format!(
                "{:.2} % / {:.2} %",
                100.0 * c.median(|x| x.rel_norm.abs()),
                100.0 * c.quantile(0.9, |x| x.rel_norm.abs())
            ),
        ),
        (
            "median / 90 % angle".into(),
            format!(
                "{:.2}° / {:.2}°",
                c.median(|x| x.angle_deg),
                c.quantile(0.9, |x| x.angle_deg)
            ),
        ),
        (
            "mean NEES per component".into(),
            format!("{:.2}", c.mean_nees()),
        ),
        (
            "median / worst |Δt|".into(),
            format!(
                "{:.2} ms / {:.2} ms",
                1e3 * c.median(|x| x.dt.abs()),
                1e3 * c.quantile(1.0, |x| x.dt.abs())
            ),
        ),
    ];
    for (k, v) in rows {
        let _ = writeln!(s, "| {k} | {v} |");
    }
    let sum = |f: fn(&firmware::frontend::FrontendStats) -> u32| -> u32 {
        papers.iter().map(|p| f(&p.frontend)).sum()
    };
    let _ = writeln!(
        s,
        "| DSP pulses: reported / saturated / overlap / truncated / too short | {} / {} / {} / {} / {} |",
        sum(|x| x.pulses),
        sum(|x| x.saturated),
        sum(|x| x.overlaps),
        sum(|x| x.truncated),
        sum(|x| x.rejected_short)
    );
    for (lo, hi) in [(0.0, 12.0), (12.0, 50.0), (50.0, 1e3), (1e3, f64::INFINITY)] {
        let sel: Vec<_> = c
            .pairs
            .iter()
            .filter(|p| {
                let r = p.h_true / 2.59e-9;
                r >= lo && r < hi
            })
            .collect();
        if sel.is_empty() {
            continue;
        }
        let ang: Vec<f64> = sel.iter().map(|p| p.angle_deg).collect();
        let rel: Vec<f64> = sel.iter().map(|p| 100.0 * p.rel_norm.abs()).collect();
        let _ = writeln!(
            s,
            "| pairs with |H|/σ_bkg in [{lo}, {hi}): median angle, median relative magnitude ({}) | {:.2}°, {:.2} % |",
            sel.len(),
            quantile(&ang, 0.5),
            quantile(&rel, 0.5)
        );
    }
    let _ = writeln!(
        s,
        "\nThe DSP detects a pulse when the three coils' coherent energy over a 64 ms window, at any carrier offset, exceeds the threshold set for one false alarm per 10 minutes (or a 32 ms window's energy exceeds 1.8× the noise floor): 90 % of pulses from about 8 σ_bkg (section above); the measurement level emits pulses from 3 σ_bkg (`detect_factor`), so it hears a far beacon a little earlier than the firmware would. Pulses the DSP flags as saturated or overlapping give no record. The DSP ranges its gain between pulses (`firmware::frontend::ranging`: the ADS131M04's PGA 128 … 1 and the IF range switch, full scale {:.1e} … {:.2} A/m; {} changes of setting over the `paper` seeds, each run starting at the most sensitive setting).\n\nEach seed runs its own unit (`hal_sim::sensors::bus::run::scenario_unit`): coil gain, phase, offset drawn about the board profile's nominal values with its tolerances (`firmware::board::REFERENCE`, 1 σ: gain {:.0} %, phase {:.0}°, offset {:.0} mV). The DSP holds the unit's bench calibration (`hal-sim/src/sensors/bus/bench.rs`, `docs/antenna-bench-calibration.md`: a reference transmitter at four jig poses, its moment known to 1 %, the poses to 0.5°), never the unit's exact values; the same units without it (the DSP holding the profile's nominal calibration) are compared below.\n",
        REFERENCE.full_scale_a_per_m(0, Gain::G128, IfRange::High),
        REFERENCE.full_scale_a_per_m(0, Gain::G1, IfRange::Low),
        sum(|x| x.range_changes),
        100.0 * REFERENCE.tolerances.coil_gain_rel,
        REFERENCE.tolerances.coil_phase_rad.to_degrees(),
        1e3 * REFERENCE.tolerances.adc_offset_v,
    );
    // Calibration.
    let mut raw = PulseComparison::default();
    for p in papers {
        raw.extend(p.uncalibrated.0.clone());
    }
    let raw_err: Vec<f64> = papers.iter().filter_map(|p| p.uncalibrated.1).collect();
    let cal_err: Vec<f64> = papers.iter().filter_map(|p| p.bus_error).collect();
    let _ = writeln!(
        s,
        "### The same units with and without their bench calibration\n\n| DSP holds | field vectors | flagged overlap | strong pulses matched | median / 90 % angle | median relative magnitude | final error median / mean / worst (m) |\n|---|---|---|---|---|---|---|"
    );
    let raw_overlaps: u32 = papers.iter().map(|p| p.uncalibrated.2.overlaps).sum();
    for (name, c, overlaps, err) in [
        ("bench calibration", &c, sum(|x| x.overlaps), &cal_err),
        ("nominal calibration", &raw, raw_overlaps, &raw_err),
    ] {
        let _ = writeln!(
            s,
            "| {name} | {} | {overlaps} | {} of {} | {:.2}° / {:.2}° | {:.2} % | {:.2} / {:.2} / {:.2} |",
            c.bus,
            c.strong_matched,
            c.strong,
            c.median(|x| x.angle_deg),
            c.quantile(0.9, |x| x.angle_deg),
            100.0 * c.median(|x| x.rel_norm.abs()),
            quantile(err, 0.5),
            mean(err),
            quantile(err, 1.0),
        );
    }
    let _ = writeln!(
        s,
        "\nWithout the bench calibration the coils' phase errors (3° per coil) put a share of every strong pulse in quadrature, which the DSP's overlap test (`max_quadrature_fraction`) reads as a second transmitter and withholds; the gain errors (3 %) turn and stretch the vectors that remain.\n"
    );
    // Replay.
    let me: Vec<f64> = papers.iter().filter_map(|p| p.measurement_error).collect();
    let be: Vec<f64> = papers.iter().filter_map(|p| p.bus_error).collect();
    let _ = writeln!(
        s,
        "## Estimator after replay (`paper` preset, seeds {}..={})\n\n`replay_with_config` (firmware motion + SOGs) over the measurement-level and the bus-level logs of the same worlds; error of the final estimate against the true victim position relative to the receiver, m.\n",
        args.first_seed,
        args.last_seed()
    );
    let _ = writeln!(
        s,
        "| log | runs with an estimate | median | mean | 90 % | worst |\n|---|---|---|---|---|---|"
    );
    for (name, v) in [("measurement level", &me), ("bus level", &be)] {
        let _ = writeln!(
            s,
            "| {name} | {} of {} | {:.2} | {:.2} | {:.2} | {:.2} |",
            v.len(),
            papers.len(),
            quantile(v, 0.5),
            mean(v),
            quantile(v, 0.9),
            quantile(v, 1.0)
        );
    }
    let _ = writeln!(s, "\nPer seed (m): measurement / bus final error\n");
    let mut line = String::new();
    for p in papers {
        let f = |x: Option<f64>| x.map_or("–".to_string(), |e| format!("{e:.2}"));
        let _ = write!(
            line,
            "{}: {} / {}; ",
            p.seed,
            f(p.measurement_error),
            f(p.bus_error)
        );
    }
    let _ = writeln!(s, "{}", line.trim_end_matches("; "));
    s
}

/// A `paper` seed's record for the sidecar: every number of the report that comes from it
/// (the pulse pairs by count and median, not one by one).
pub fn paper_record(p: &PaperResult) -> Result<serde_json::Value> {
    let stats = |f: &firmware::frontend::FrontendStats| {
        serde_json::json!({
            "pulses": f.pulses,
            "rejected_short": f.rejected_short,
            "overlaps": f.overlaps,
            "saturated": f.saturated,
            "truncated": f.truncated,
            "range_changes": f.range_changes,
        })
    };
    let pulses = |c: &PulseComparison| {
        serde_json::json!({
            "measurement": c.measurement,
            "bus": c.bus,
            "strong": c.strong,
            "strong_matched": c.strong_matched,
            "pairs": c.pairs.len(),
            "median_angle_deg": c.median(|x| x.angle_deg),
            "median_rel_norm": c.median(|x| x.rel_norm.abs()),
            "mean_nees": c.mean_nees(),
        })
    };
    Ok(serde_json::json!({
        "seed": p.seed,
        "measurement_error_m": p.measurement_error,
        "bus_error_m": p.bus_error,
        "pulses": pulses(&p.pulses),
        "frontend": stats(&p.frontend),
        "walk": crate::eval::sidecar::record(&p.walk, &[])?,
        "uncalibrated": {
            "error_m": p.uncalibrated.1,
            "pulses": pulses(&p.uncalibrated.0),
            "frontend": stats(&p.uncalibrated.2),
        },
    }))
}

/// Re-runs one sidecar record (its `paper` seed) with the current code.
pub fn rerun(record: &serde_json::Value) -> Result<serde_json::Value> {
    let seed = crate::eval::sidecar::seed_of(record, "/seed")?;
    paper_record(&paper(seed)?)
}

/// `paper` seeds whose records the sidecar stores (each costs two bus-level simulations
/// and three replays in the staleness test's debug build).
const CHECK_SEEDS: u64 = 1;

/// The report's headline numbers for its sidecar.
fn summary(detection: &Detection, papers: &[PaperResult]) -> serde_json::Value {
    let errors = |f: fn(&PaperResult) -> Option<f64>| {
        let v: Vec<f64> = papers.iter().filter_map(f).collect();
        serde_json::json!({
            "runs": v.len(),
            "median_m": quantile(&v, 0.5),
            "mean_m": mean(&v),
            "worst_m": quantile(&v, 1.0),
        })
    };
    serde_json::json!({
        "noise_s": detection.noise_s,
        "noise_field_vectors": detection.noise_fields,
        "pd_fields_per_snr": detection
            .points
            .iter()
            .map(|p| [p.snr, p.fields as f64 / p.n.max(1) as f64])
            .collect::<Vec<_>>(),
        "measurement_level": errors(|p| p.measurement_error),
        "bus_level": errors(|p| p.bus_error),
        "bus_level_uncalibrated": errors(|p| p.uncalibrated.1),
    })
}

/// Runs the report.
pub fn run(args: &Args, out: &mut impl Write) -> Result<()> {
    use indicatif::ParallelProgressIterator as _;
    let detection = crate::eval::detection_report::measure(DetectionArgs {
        noise_hours: args.noise_hours,
        pulses: args.probe_pulses,
    })?;
    if args.detection_only {
        out.write_all(detection.render().as_bytes())?;
        return Ok(());
    }
    let mut jobs: Vec<(Preset, u64)> = Vec::new();
    for preset in [Preset::Line, Preset::Arc, Preset::Zigzag] {
        jobs.extend(args.walk_seeds().map(|s| (preset, s)));
    }
    let walks: Vec<WalkResult> = jobs
        .par_iter()
        .progress_with(crate::cli::progress::bar(jobs.len() as u64, "motion walks"))
        .map(|&(preset, seed)| {
            let mut cfg = ScenarioConfig::new(preset, seed);
            cfg.max_duration_s = args.walk_s;
            // The motion table reads only the IMU: the antenna's calibration is moot.
            simulate_bus_with(&cfg, UnitCalibration::Nominal).map(|r| walk_result(&r))
        })
        .collect::<Result<_>>()?;
    let papers: Vec<PaperResult> = args
        .paper_seeds()
        .into_par_iter()
        .progress_with(crate::cli::progress::bar(args.tries, "paper seeds"))
        .map(paper)
        .collect::<Result<_>>()?;
    let text = render(args, &detection, &walks, &papers);
    match &args.out {
        Some(p) => {
            let check = papers
                .iter()
                .filter(|r| r.seed < args.first_seed.saturating_add(CHECK_SEEDS))
                .map(paper_record)
                .collect::<Result<_>>()?;
            let side = crate::eval::sidecar::Sidecar::new(
                "sensing-report",
                &args.command(),
                args.first_seed,
                args.tries,
                summary(&detection, &papers),
                check,
            );
            crate::eval::sidecar::write(p, &text, side)?;
        }
        None => out.write_all(text.as_bytes())?,
    }
    Ok(())
}
