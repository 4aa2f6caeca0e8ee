//! `hal-sim rescue-report`: seeded closed-loop rescues under the papers' protocol (ICRA
//! 2006 §VI, Table II): the firmware's receiver ([`crate::sim::closed_loop`], SOGs and search
//! control) with and without step-length calibration, and the classical directional search
//! as a rescuer policy, each against the ideal straight walk.
//!
//! Protocol: the victim lies 40–70 m (horizontally) from the start at a random bearing,
//! 0.3–3 m deep, with a random moment (direction uniform, magnitude log-uniform in
//! 3e-3 … 3e-2 A·m²); the rescuer walks at ≈ 1 m/s and the transmitter pulses once per
//! period (0.7–1.3 s). A pulse is received only when |H| ≥ 3 σ_bkg, so weak beacons are
//! not heard from 70 m: until the first pulse the rescuer walks straight toward the victim
//! (the primary search's strip over the victim), then follows the display (or, for the
//! directional search, the flux line). "Steps" are transmitter pulses, counted from the
//! first received pulse to "probe here" (the directional search: to standing at the
//! found maximum); the ideal walks straight from the point of first reception to the
//! victim at the rescuer's speed. The same numbers from the start are given too (the
//! primary-search part is straight toward the victim, so it is ideal on both sides).
use crate::eval::accuracy::stats;
use crate::sim::closed_loop::{self, ClosedLoopConfig, Outcome, Policy, PulseRow, StartMode};
use firmware::guidance::{GuidanceConfig, HeightPrompt, Status};
use std::fmt::Write as _;
use std::time::Instant;

mod render;
pub use render::case_report;
use render::*;

/// Options of `hal-sim rescue-report`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeded rescues per case (seeds first-seed..first-seed+tries), at least 1.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
    pub tries: u64,
    /// Write the markdown report here (default: stdout only).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Write every rescue's summary as JSON Lines here.
    #[arg(long = "jsonl", alias = "runs", value_name = "PATH")]
    pub runs: Option<std::path::PathBuf>,
    /// Leave out the fine-search lift and lowering: only the SOG cases without it and DS
    /// (the report before the lift existed).
    #[arg(long)]
    pub no_lift: bool,
    /// First seed (seeds first_seed..first_seed+tries): a separate range checks that a
    /// change was not tuned to seeds 1..=100.
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Run only the SOG case with calibrated step length (lowering and lift; diagnostics).
    #[arg(long)]
    pub calibrated_only: bool,
    /// Print every pulse of this seed's rescue to stderr (with `--trace-case`).
    #[arg(long)]
    pub trace: Option<u64>,
    /// The case traced by `--trace`.
    #[arg(long, value_enum, default_value = "sog-calibrated")]
    pub trace_case: Case,
    /// Append the trade-off between steps and probe-point error: the calibrated case
    /// again with these probe radii (m, comma-separated; the firmware's is 0.45).
    #[arg(long, value_delimiter = ',')]
    pub probe_tradeoff: Vec<f64>,
}

/// The compared searches.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
pub enum Case {
    /// The receiver (SOGs + search control), calibrated step length.
    SogCalibrated,
    /// The receiver without step-length calibration.
    SogUncalibrated,
    /// As `sog-calibrated`, the receiver never asking for a lift.
    SogCalibratedNoLift,
    /// As `sog-uncalibrated`, the receiver never asking for a lift.
    SogUncalibratedNoLift,
    /// As `sog-calibrated`, the receiver never asking to be lowered to the snow
    /// (the whole fine search 1 m above the snow).
    SogCalibratedHigh,
    /// As `sog-uncalibrated`, the receiver never asking to be lowered.
    SogUncalibratedHigh,
    /// The classical directional search with a cross search (optimistic).
    DirectionalSearch,
}

impl Case {
    /// All cases, in report order.
    pub const ALL: [Case; 7] = [
        Case::SogCalibrated,
        Case::SogUncalibrated,
        Case::SogCalibratedNoLift,
        Case::SogUncalibratedNoLift,
        Case::SogCalibratedHigh,
        Case::SogUncalibratedHigh,
        Case::DirectionalSearch,
    ];

    /// The cases without the lift (`--no-lift`).
    pub const NO_LIFT: [Case; 3] = [
        Case::SogCalibratedNoLift,
        Case::SogUncalibratedNoLift,
        Case::DirectionalSearch,
    ];

    /// The closed-loop settings of this case for `seed`.
    pub fn config(self, seed: u64) -> ClosedLoopConfig {
        ClosedLoopConfig {
            start: StartMode::PrimarySearch,
            calibrated: !matches!(
                self,
                Case::SogUncalibrated | Case::SogUncalibratedNoLift | Case::SogUncalibratedHigh
            ),
            lift: !matches!(
                self,
                Case::SogCalibratedNoLift | Case::SogUncalibratedNoLift | Case::DirectionalSearch
            ),
            lower: !matches!(self, Case::SogCalibratedHigh | Case::SogUncalibratedHigh),
            policy: if self == Case::DirectionalSearch {
                Policy::DirectionalSearch
            } else {
                Policy::Receiver
            },
            ..ClosedLoopConfig::new(seed)
        }
    }

    fn title(self) -> &'static str {
        match self {
            Case::SogCalibrated => {
                "SOG, calibrated step length, receiver lowered to the snow in the fine search"
            }
            Case::SogUncalibrated => {
                "SOG, no step-length calibration, receiver lowered to the snow in the fine search"
            }
            Case::SogCalibratedNoLift => "SOG, calibrated step length, lowered, no lift",
            Case::SogUncalibratedNoLift => "SOG, no step-length calibration, lowered, no lift",
            Case::SogCalibratedHigh => {
                "SOG, calibrated step length, receiver kept 1 m above the snow (before the lowering)"
            }
            Case::SogUncalibratedHigh => {
                "SOG, no step-length calibration, receiver kept 1 m above the snow (before the lowering)"
            }
            Case::DirectionalSearch => "Directional search (DS)",
        }
    }
}

/// One rescue, summarized.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Rescue {
    /// Which search.
    pub case: Case,
    /// Scenario seed.
    pub seed: u64,
    /// Horizontal start distance, m.
    pub start_distance_m: f64,
    /// Burial depth below the snow surface, m.
    pub depth_m: f64,
    /// Transmitter moment magnitude, A·m².
    pub moment_am2: f64,
    /// Horizontal distance at the first received pulse, m (`None`: never heard).
    pub first_rx_distance_m: Option<f64>,
    /// Pulses from the first received one to "probe here".
    pub steps: Option<f64>,
    /// Pulses of the ideal straight walk from the first received pulse.
    pub ideal_steps: Option<f64>,
    /// Pulses from the start to "probe here".
    pub steps_from_start: Option<f64>,
    /// Pulses of the ideal straight walk from the start.
    pub ideal_steps_from_start: f64,
    /// Seconds from the first received pulse to "probe here".
    pub seconds: Option<f64>,
    /// Seconds of the ideal walk from the first received pulse.
    pub ideal_seconds: Option<f64>,
    /// Horizontal path walked after the first received pulse, m.
    pub path_m: f64,
    /// Horizontal error of the probe point (the estimate; DS: the found maximum), m.
    pub error_h_m: Option<f64>,
    /// Horizontal distance of the rescuer's receiver from the victim at the end, m.
    pub stand_h_m: f64,
    /// |shown depth − true burial depth| at "probe here", m.
    pub depth_error_m: Option<f64>,
    /// Mixture re-initializations.
    pub reinitializations: u32,
    /// Never reached "probe here" within 3× the ideal steps.
    pub failed: bool,
    /// Lifts of the receiver made when asked.
    pub lifts: u32,
    /// Lowerings to the snow and raisings of the receiver made when asked.
    pub height_moves: u32,
    /// Transmitter pulses from the first received one to "probe here", per phase of the
    /// search (see [`Phase`]).
    pub phases: [u32; Phase::COUNT],
    /// The receiver's own horizontal uncertainty (largest σ, m) at "probe here".
    pub sigma_h_at_probe_m: Option<f64>,
    /// Dead-reckoning consistency of the displacements between pulses up to "probe
    /// here", per kind of interval (see [`DrKind`]).
    pub dead_reckoning: [DrStats; DrKind::COUNT],
}

/// Kind of interval between two pulses, for the dead-reckoning consistency table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DrKind {
    /// Flux line or walking to the mean (2 m or more to go).
    Walk,
    /// Fine search (less than 2 m to go, over the mean, or standing for a height move):
    /// at least one step counted.
    FineSteps,
    /// Fine search, no step counted (standing, turning on the spot, lowering).
    FineNoStep,
}

impl DrKind {
    /// Number of kinds.
    pub const COUNT: usize = 3;
    /// All kinds, in report order.
    pub const ALL: [DrKind; Self::COUNT] = [DrKind::Walk, DrKind::FineSteps, DrKind::FineNoStep];

    fn label(self) -> &'static str {
        match self {
            DrKind::Walk => "flux line and walk to the mean",
            DrKind::FineSteps => "fine search, steps counted",
            DrKind::FineNoStep => "fine search, no step counted",
        }
    }

    fn of(row: &PulseRow) -> Option<DrKind> {
        match Phase::of(row) {
            Phase::NoSignal => None,
            Phase::FluxLine | Phase::ToMean => Some(DrKind::Walk),
            _ if row.displacement_steps > 0 => Some(DrKind::FineSteps),
            _ => Some(DrKind::FineNoStep),
        }
    }
}

/// χ² (2 degrees of freedom) exceeded with probability 0.1 %.
const CHI2_2_999: f64 = 13.816;

/// Sums over the intervals of one kind: the dead-reckoned horizontal translation against
/// the true one, normalized by the translation covariance the firmware hands the filter.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct DrStats {
    /// Intervals.
    pub n: u32,
    /// Sum of the forward error (m): its mean is the bias along the device's heading.
    pub forward_sum_m: f64,
    /// Sum of the squared horizontal error (m²).
    pub err2_sum_m2: f64,
    /// Sum of the covariance's horizontal trace (m²).
    pub var_sum_m2: f64,
    /// Sum of the normalized squared error `eᵀ C⁻¹ e` (2 on average when consistent).
    pub nees_sum: f64,
    /// Intervals whose `eᵀ C⁻¹ e` exceeds the χ² 99.9 % point (0.1 % when consistent).
    pub over: u32,
}

impl DrStats {
    fn add(&mut self, row: &PulseRow) {
        let [ex, ey] = row.displacement_error_m;
        let [xx, xy, yy] = row.displacement_cov_m2;
        let det = xx * yy - xy * xy;
        if det.is_nan() || det <= 0.0 || !ex.is_finite() || !ey.is_finite() {
            return;
        }
        let nees = (ex * ex * yy - 2.0 * ex * ey * xy + ey * ey * xx) / det;
        self.n += 1;
        self.forward_sum_m += ex;
        self.err2_sum_m2 += ex * ex + ey * ey;
        self.var_sum_m2 += xx + yy;
        self.nees_sum += nees;
        self.over += u32::from(nees > CHI2_2_999);
    }

    fn merge(&mut self, o: &DrStats) {
        self.n += o.n;
        self.forward_sum_m += o.forward_sum_m;
        self.err2_sum_m2 += o.err2_sum_m2;
        self.var_sum_m2 += o.var_sum_m2;
        self.nees_sum += o.nees_sum;
        self.over += o.over;
    }

    /// Per-interval statistics from the dead reckoning of one rescue, up to its
    /// "probe here" (the first row is the start: no displacement before it).
    fn of_rescue(o: &Outcome) -> [DrStats; DrKind::COUNT] {
        let mut st = [DrStats::default(); DrKind::COUNT];
        let upto = o.probe_t.unwrap_or(f64::INFINITY);
        for r in o.rows.iter().skip(1).filter(|r| r.t <= upto) {
            if let Some(k) = DrKind::of(r).and_then(|k| DrKind::ALL.iter().position(|x| *x == k))
                && let Some(s) = st.get_mut(k)
            {
                s.add(r);
            }
        }
        st
    }
}

/// What the display told the rescuer between two pulses (the phase-time breakdown).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Pulse not received, or "no signal".
    NoSignal,
    /// Following the flux line.
    FluxLine,
    /// Localized, walking to the mean (2 m or more to go).
    ToMean,
    /// Fine search, stepping toward the mean (less than 2 m to go, not over it yet).
    FineApproach,
    /// Fine search over the mean (within `max(probe radius, σ_h)`): bracketing, waiting
    /// for the belief to shrink to the probe radius.
    OverMean,
    /// Standing for a lift of the receiver, or to lower or raise it.
    Lift,
}

impl Phase {
    /// Number of phases.
    pub const COUNT: usize = 6;
    /// All phases, in report order.
    pub const ALL: [Phase; Self::COUNT] = [
        Phase::NoSignal,
        Phase::FluxLine,
        Phase::ToMean,
        Phase::FineApproach,
        Phase::OverMean,
        Phase::Lift,
    ];

    fn label(self) -> &'static str {
        match self {
            Phase::NoSignal => "not received / no signal",
            Phase::FluxLine => "flux line",
            Phase::ToMean => "localized, walking to the mean (≥ 2 m)",
            Phase::FineApproach => "fine search, approaching (< 2 m)",
            Phase::OverMean => "fine search, over the mean (bracketing, waiting to probe)",
            Phase::Lift => "lift, lower or raise the receiver (standing)",
        }
    }

    /// The phase shown by one pulse's display.
    fn of(row: &PulseRow) -> Phase {
        let d = &row.display;
        let probe_reach = f64::from(GuidanceConfig::default().probe_reach_m);
        match d.status {
            Status::NoSignal => Phase::NoSignal,
            Status::FluxLine => Phase::FluxLine,
            _ if d.lift || d.height_prompt != HeightPrompt::None => Phase::Lift,
            Status::Localized | Status::Probe => {
                let h = d.horizontal_m.map_or(f64::MAX, f64::from);
                let sig = d.uncertainty_m.map_or(0.0, f64::from);
                let walk = d.walk_m.map_or(f64::MAX, f64::from);
                if h <= probe_reach.max(sig) {
                    Phase::OverMean
                } else if walk < FINE_WALK_M {
                    Phase::FineApproach
                } else {
                    Phase::ToMean
                }
            }
        }
    }

    /// Pulses per phase from the first received pulse to "probe here" (`steps` of them).
    fn breakdown(o: &Outcome) -> [u32; Self::COUNT] {
        let mut n = [0u32; Self::COUNT];
        let Some(t0) = o.first_rx_t else {
            return n;
        };
        // Unfinished: every pulse after the first reception.
        let steps = o
            .pulses_to_probe
            .unwrap_or(((o.end_t - t0) / o.period_s).floor().max(0.0) as u64);
        let mut heard = 0u64;
        for r in o
            .rows
            .iter()
            .take(usize::try_from(steps).unwrap_or(usize::MAX))
        {
            let phase = Phase::of(r);
            if let Some(k) = Phase::ALL.iter().position(|p| *p == phase)
                && let Some(c) = n.get_mut(k)
            {
                *c += 1;
            }
            heard += 1;
        }
        n[0] += u32::try_from(steps.saturating_sub(heard)).unwrap_or(u32::MAX);
        n
    }
}

/// Remaining walk below which the rescuer model goes step by step (m), as in
/// [`ClosedLoopConfig::new`].
const FINE_WALK_M: f64 = 2.0;

impl Rescue {
    /// Summarizes one closed-loop outcome.
    pub fn from_outcome(case: Case, o: &Outcome, moment_am2: f64) -> Self {
        let ideal_first = o.ideal_from_first_rx_m();
        let ideal_steps = ideal_first.map(|d| o.ideal_pulses(d));
        let steps = o.pulses_to_probe.map(|n| n as f64);
        let failed = match (steps, ideal_steps) {
            (Some(s), Some(i)) => s > 3.0 * i.max(1.0),
            _ => true,
        };
        Self {
            case,
            seed: o.seed,
            start_distance_m: o.ideal_path_m,
            depth_m: -o.victim[2],
            moment_am2,
            first_rx_distance_m: ideal_first,
            steps,
            ideal_steps,
            steps_from_start: o.pulses_from_start.map(|n| n as f64),
            ideal_steps_from_start: o.ideal_pulses(o.ideal_path_m),
            seconds: o.probe_t.zip(o.first_rx_t).map(|(p, f)| p - f),
            ideal_seconds: ideal_first.map(|d| d / o.walk_speed_m_s),
            path_m: o.path_m - o.path_at_first_rx_m,
            error_h_m: o.probe_t.and(o.error_h_m),
            stand_h_m: o.miss_h_m,
            depth_error_m: o.depth_shown_m.map(|d| (d + o.victim[2]).abs()),
            reinitializations: o.reinitializations,
            failed,
            lifts: o.lifts,
            height_moves: o.height_moves,
            phases: Phase::breakdown(o),
            sigma_h_at_probe_m: o
                .probe_t
                .and(o.rows.last())
                .and_then(|r| r.display.uncertainty_m)
                .map(f64::from),
            dead_reckoning: DrStats::of_rescue(o),
        }
    }

    fn ratio(a: Option<f64>, b: Option<f64>) -> Option<f64> {
        a.zip(b).map(|(a, b)| a / b.max(1e-9))
    }
}

/// Runs one case's rescue for `seed`.
pub fn run_one(case: Case, seed: u64) -> anyhow::Result<Rescue> {
    run_one_with(case, seed, None)
}

/// [`run_one`] with the receiver's probe radius overridden (m; `None`: the default).
fn run_one_with(case: Case, seed: u64, probe_radius_m: Option<f64>) -> anyhow::Result<Rescue> {
    let cfg = ClosedLoopConfig {
        probe_radius_m,
        ..case.config(seed)
    };
    let o = closed_loop::run(&cfg, &mut |_, _| {})?;
    let moment = o.moment.iter().map(|m| m * m).sum::<f64>().sqrt();
    Ok(Rescue::from_outcome(case, &o, moment))
}

/// Runs `tries` seeded rescues of `case` in parallel (seeds `first..first + tries`).
pub fn run_case(case: Case, first: u64, tries: u64) -> anyhow::Result<Vec<Rescue>> {
    run_case_with(case, first, tries, None)
}

fn run_case_with(
    case: Case,
    first: u64,
    tries: u64,
    probe_radius_m: Option<f64>,
) -> anyhow::Result<Vec<Rescue>> {
    use indicatif::ParallelProgressIterator as _;
    use rayon::prelude::*;
    (first..first + tries)
        .into_par_iter()
        .progress_with(crate::cli::progress::bar(
            tries,
            &format!("{case:?} rescues"),
        ))
        .map(|seed| run_one_with(case, seed, probe_radius_m))
        .collect()
}

/// The calibrated case with each probe radius of `radii`: steps against probe-point
/// error, the two sides of the fine-search targets.
fn probe_tradeoff(args: &Args, radii: &[f64]) -> anyhow::Result<String> {
    let mut s = format!(
        "### Steps against probe-point error: the probe radius (calibrated)\n\n\
\"Probe here\" needs 3σ_h within the probe radius on {} pulses (or a levelled-off σ_h of at \
most half of it, or the 16-pulse timeout over the mean); the firmware's radius is {} m. The \
same scenarios with other radii (`--probe-tradeoff {}`):\n\n\
| probe radius (m) | steps / ideal median | mean | probe-point error median (m) | max | > 0.20 m | failures |\n\
|---|---|---|---|---|---|---|\n",
        GuidanceConfig::default().probe_confirm_pulses,
        GuidanceConfig::default().probe_radius_m,
        radii
            .iter()
            .map(|r| format!("{r}"))
            .collect::<Vec<_>>()
            .join(",")
    );
    for &r in radii {
        let runs = run_case_with(Case::SogCalibrated, args.first_seed, args.tries, Some(r))?;
        let mut ratios: Vec<f64> = runs
            .iter()
            .map(|x| Rescue::ratio(x.steps, x.ideal_steps).unwrap_or(f64::INFINITY))
            .collect();
        let mut errs: Vec<f64> = runs.iter().filter_map(|x| x.error_h_m).collect();
        let n_ratio = ratios.iter().filter(|v| v.is_finite()).count().max(1);
        let mean_ratio = ratios.iter().filter(|v| v.is_finite()).sum::<f64>() / n_ratio as f64;
        ratios.sort_by(f64::total_cmp);
        errs.sort_by(f64::total_cmp);
        let _ = writeln!(
            s,
            "| {r:.2} | {:.3} | {mean_ratio:.3} | {:.3} | {:.3} | {} | {} |",
            median(&ratios),
            median(&errs),
            errs.last().copied().unwrap_or(f64::NAN),
            errs.iter().filter(|e| **e > 0.2).count(),
            runs.iter().filter(|x| x.failed).count()
        );
    }
    s.push('\n');
    Ok(s)
}

/// Prints every pulse of one rescue (diagnostics: where the pulses go).
fn trace(case: Case, seed: u64) -> anyhow::Result<()> {
    let o = closed_loop::run(&case.config(seed), &mut |r, rx| {
        let d = &r.display;
        let e = rx.estimate();
        eprintln!(
            "t {:7.2} {:10} true_d {:6.2} est_h {:>6} sig_h {:>6} walk {:>6} err_h {:>6} \
             ncomp {:2} lift {} hp {:?} height {:.2}/{:.2} scale {:>6} depth {:>5} tilt_err_deg {:.2} {:.2} dr_sig {:.3} dr_steps {}",
            r.t,
            r.status,
            r.true_distance_m,
            d.horizontal_m.map_or("-".into(), |v| format!("{v:.2}")),
            d.uncertainty_m.map_or("-".into(), |v| format!("{v:.3}")),
            d.walk_m.map_or("-".into(), |v| format!("{v:.2}")),
            r.error_h_m.map_or("-".into(), |v| format!("{v:.3}")),
            r.n_components,
            u8::from(d.lift),
            d.height_prompt,
            d.height_m,
            r.rx[2],
            e.map_or("-".into(), |e| format!("{:.3}", e.scale)),
            d.depth_m.map_or("-".into(), |v| format!("{v:.2}")),
            (f64::from(rx.motion().attitude().0.x) - r.true_rpy[0]).to_degrees(),
            (f64::from(rx.motion().attitude().0.y) - r.true_rpy[1]).to_degrees(),
            r.displacement_sigma_h_m,
            r.displacement_steps,
        );
    })?;
    eprintln!(
        "seed {seed}: victim {:?}, first rx {:?} at t {:?}, probe at {:?}, error {:?}",
        o.victim, o.first_rx_p, o.first_rx_t, o.probe_t, o.error_h_m
    );
    Ok(())
}

/// Runs every case and writes the report.
pub fn run(args: &Args, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    use std::io::Write as _;
    if let Some(seed) = args.trace {
        return trace(args.trace_case, seed);
    }
    let tradeoff = if args.probe_tradeoff.is_empty() {
        String::new()
    } else {
        let radii: Vec<String> = args.probe_tradeoff.iter().map(|r| format!("{r}")).collect();
        format!(" --probe-tradeoff {}", radii.join(","))
    };
    let command = format!(
        "cargo sim rescue-report --tries {}{}{tradeoff}",
        args.tries,
        crate::eval::sidecar::first_seed_flag(args.first_seed),
    );
    let mut report = format!("## Closed-loop rescues (`{command}`)\n\n{PROTOCOL}\n\n");
    let mut all = Vec::new();
    let cases: &[Case] = if args.calibrated_only {
        &[Case::SogCalibrated]
    } else if args.no_lift {
        &Case::NO_LIFT
    } else {
        &Case::ALL
    };
    for &case in cases {
        let t0 = Instant::now();
        eprintln!("rescue-report: {case:?}, {} tries …", args.tries);
        let runs = run_case(case, args.first_seed, args.tries)?;
        eprintln!(
            "rescue-report: {case:?} done in {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        report.push_str(&case_report(case, &runs));
        all.extend(runs);
    }
    if !args.probe_tradeoff.is_empty() {
        report.push_str(&probe_tradeoff(args, &args.probe_tradeoff)?);
    }
    if !args.no_lift && !args.calibrated_only {
        report.push_str(&lower_gain(&all));
        report.push_str(&lift_gain(&all));
        report.push_str(READING);
    }
    if let Some(path) = &args.runs {
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        for r in &all {
            writeln!(f, "{}", serde_json::to_string(r)?)?;
        }
    }
    if let Some(path) = &args.out {
        let side = sidecar(&command, args, cases, &all)?;
        crate::eval::sidecar::write(path, &report, side)?;
    }
    out.write_all(report.as_bytes())?;
    Ok(())
}

/// Keys of a [`Rescue`] record that do not come from the code (none today).
const VOLATILE: &[&str] = &[];

/// The report's sidecar: per-case headline numbers and the first seeds' records (every
/// seed of [`crate::eval::sidecar::CHECK_SEEDS`] for the first case, the first seed of the others).
fn sidecar(
    command: &str,
    args: &Args,
    cases: &[Case],
    all: &[Rescue],
) -> anyhow::Result<crate::eval::sidecar::Sidecar> {
    let mut summary = serde_json::Map::new();
    for &case in cases {
        let runs: Vec<&Rescue> = all.iter().filter(|r| r.case == case).collect();
        let ratio = stats(
            runs.iter()
                .map(|r| r.steps.zip(r.ideal_steps).map(|(a, b)| a / b.max(1e-9))),
        );
        summary.insert(
            serde_json::to_value(case)?
                .as_str()
                .unwrap_or("case")
                .to_owned(),
            serde_json::json!({
                "runs": runs.len(),
                "probe_here": runs.iter().filter(|r| r.steps.is_some()).count(),
                "failed": runs.iter().filter(|r| r.failed).count(),
                "error_h_m_max_mean_median": stats(runs.iter().map(|r| r.error_h_m)),
                "steps_over_ideal_max_mean_median": ratio,
            }),
        );
    }
    let first_case = cases.first().copied();
    let check = crate::eval::sidecar::records(
        all.iter().filter(|r| {
            let seeds = if Some(r.case) == first_case {
                crate::eval::sidecar::CHECK_SEEDS
            } else {
                1
            };
            r.seed < args.first_seed + seeds
        }),
        VOLATILE,
    )?;
    Ok(crate::eval::sidecar::Sidecar::new(
        "rescue-report",
        command,
        args.first_seed,
        args.tries,
        serde_json::Value::Object(summary),
        check,
    ))
}

/// Re-runs one sidecar record (its case and seed) with the current code.
pub fn rerun(record: &serde_json::Value) -> anyhow::Result<serde_json::Value> {
    let case: Case = crate::eval::sidecar::field(record, "/case")?;
    let seed = crate::eval::sidecar::seed_of(record, "/seed")?;
    crate::eval::sidecar::record(&run_one(case, seed)?, VOLATILE)
}

#[cfg(test)]
mod tests;
