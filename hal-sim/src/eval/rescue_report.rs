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

/// Options of `hal-sim rescue-report`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Seeded rescues per case (seeds 1..=tries).
    #[arg(long, default_value_t = 100)]
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
    /// As [`Case::SogCalibrated`], the receiver never asking for a lift.
    SogCalibratedNoLift,
    /// As [`Case::SogUncalibrated`], the receiver never asking for a lift.
    SogUncalibratedNoLift,
    /// As [`Case::SogCalibrated`], the receiver never asking to be lowered to the snow
    /// (the whole fine search 1 m above the snow).
    SogCalibratedHigh,
    /// As [`Case::SogUncalibrated`], the receiver never asking to be lowered.
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

/// Median of sorted values (NaN when empty).
fn median(sorted: &[f64]) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

fn fmt3(s: Option<[f64; 3]>, digits: usize) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.digits$} | {b:.digits$} | {c:.digits$}"),
        None => "– | – | –".into(),
    }
}

/// The papers' Table II (ICRA 2006): (row, max, mean, median).
const PAPER: [(&str, [f64; 3]); 5] = [
    ("DS error", [2.62, 0.52, 0.42]),
    ("SOG error", [0.07, 0.02, 0.02]),
    ("Steps DS", [128.0, 71.0, 70.0]),
    ("Steps SOG", [100.0, 63.0, 62.0]),
    ("Steps Ideal", [69.0, 54.0, 53.0]),
];

fn paper(row: &str) -> String {
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
fn phase_table(runs: &[Rescue]) -> String {
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
fn fine_search_at_walking_pace(runs: &[&Rescue]) -> Option<[f64; 2]> {
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
fn dead_reckoning_table(runs: &[Rescue]) -> String {
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
type Metric = fn(&Rescue) -> Option<f64>;

/// The gain of the lowering to the snow: the default cases against the receiver kept at
/// the walking height.
fn lower_gain(all: &[Rescue]) -> String {
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
fn compare(all: &[Rescue], head: &str, pairs: [(Case, Case); 2], extra: (&str, Metric)) -> String {
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
fn lift_gain(all: &[Rescue]) -> String {
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
        "cargo run -p hal-sim --release -- rescue-report --tries {}{}{tradeoff}",
        args.tries,
        if args.first_seed == 1 {
            String::new()
        } else {
            format!(" --first-seed {}", args.first_seed)
        },
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
    let check = all
        .iter()
        .filter(|r| {
            let seeds = if Some(r.case) == first_case {
                crate::eval::sidecar::CHECK_SEEDS
            } else {
                1
            };
            r.seed < args.first_seed + seeds
        })
        .map(|r| crate::eval::sidecar::record(r, VOLATILE))
        .collect::<anyhow::Result<_>>()?;
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
    let case: Case = serde_json::from_value(record["case"].clone())?;
    let seed = crate::eval::sidecar::seed_of(record, "/seed")?;
    crate::eval::sidecar::record(&run_one(case, seed)?, VOLATILE)
}

/// How to read the phase tables and follow one rescue; the constants they justify are
/// recorded in `docs/decisions/fine-search-guidance.md`.
const READING: &str = "\
### Reading the tables

The phase tables split the pulses from the first reception to \"probe here\" by what the \
display showed; each ends with the bound the fine search would give if it took only the \
pulses of walking its 2 m at the ideal pace, so the gap between that bound and the measured \
steps / ideal is the fine search's stop-and-go, lowering and confirming pulses. \
`hal-sim rescue-report --trace SEED [--trace-case sog-uncalibrated]` prints one rescue pulse \
by pulse; `--first-seed 1000` runs a separate range of scenarios. The search control's tuned \
constants (probe radius, flux-line rules, bracketing, lowering) and what was measured for \
each are in `docs/decisions/fine-search-guidance.md`.\n";

const PROTOCOL: &str = "\
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_phases_account_for_every_pulse_to_probe() {
        let r = run_one(Case::SogCalibrated, 2).expect("run");
        let steps = r.steps.expect("reached probe here");
        let total: u32 = r.phases.iter().sum();
        assert_eq!(f64::from(total), steps, "{:?}", r.phases);
        // A rescue goes through the flux line, the walk to the mean and the fine search.
        assert!(r.phases[1] > 0 && r.phases[2] > 0, "{:?}", r.phases);
        assert!(r.phases[3] + r.phases[4] > 0, "{:?}", r.phases);
        let table = phase_table(std::slice::from_ref(&r));
        assert!(table.contains("| flux line |"), "{table}");
        // The bound replaces the fine-search pulses by the walk of its 2 m.
        let [first, start] = fine_search_at_walking_pace(&[&r]).expect("one run");
        let fine = f64::from(r.phases[3] + r.phases[4] + r.phases[5]);
        let ideal = r.ideal_steps.expect("ideal");
        let walk = FINE_WALK_M * ideal / r.first_rx_distance_m.expect("first pulse");
        assert!(
            (first - (steps - fine + walk) / ideal).abs() < 1e-9,
            "{first}"
        );
        let from_start = r.steps_from_start.expect("from start");
        let expected = (from_start - fine + walk) / r.ideal_steps_from_start;
        assert!((start - expected).abs() < 1e-9, "{start}");
        assert!(
            table.contains("any fine-search policy could take"),
            "{table}"
        );
    }

    #[test]
    fn weak_beacons_at_the_edge_of_reception_are_reached() {
        // Seeds 19 and 80: weak transmitters heard from ≈ 37 m, whose pulses come and go
        // on the flux line. Before the receiver reversed the flux line on a lost weak
        // signal, the rescuer walked in and out at the edge of reception for minutes
        // (4.6× and 3.1× the ideal steps, the report's two failures); now 1.3× and 1.6×.
        // Seed 80 still loses the signal on the way (the reversal is exercised); seed 19
        // no longer does since a horizontal field within the noise keeps the rescuer
        // walking straight (`GuidanceConfig::flux_min_snr`).
        for seed in [19, 80] {
            let r = run_one(Case::SogCalibrated, seed).expect("run");
            assert!(
                seed != 80 || r.phases[0] > 0,
                "seed {seed}: the signal was lost on the way"
            );
            let steps = r.steps.expect("reached probe here");
            let ratio = steps / r.ideal_steps.expect("ideal steps");
            assert!(ratio < 2.0, "seed {seed}: {steps} steps, {ratio:.2}× ideal");
            assert!(
                r.error_h_m.is_some_and(|e| e < 0.2),
                "seed {seed}: {:?}",
                r.error_h_m
            );
        }
    }

    #[test]
    fn a_noisy_horizontal_field_does_not_walk_the_rescuer_in_circles() {
        // Seed 3025: a near-vertical moment heard from 43 m near its equator, where the
        // field is nearly vertical and its horizontal part below the noise. Following each
        // pulse's noisy horizontal direction walked the rescuer in circles for 170 pulses
        // (4.4× the ideal steps, a failure); holding the direction until the horizontal
        // field is significant (`GuidanceConfig::flux_min_snr`) reaches it in 1.5×.
        let r = run_one(Case::SogCalibrated, 3025).expect("run");
        let steps = r.steps.expect("reached probe here");
        let ratio = steps / r.ideal_steps.expect("ideal steps");
        assert!(ratio < 2.0, "{steps} steps, {ratio:.2}× ideal");
    }

    #[test]
    fn a_lowering_started_after_the_steps_under_way_is_measured() {
        // Seeds 1012 and 1037: "LOWER TO SNOW" came while the rescuer was finishing
        // steps; the prompt ran out before the lowering, which went unmeasured, and the
        // firmware took the receiver for 0.8 m higher than it was (probe 0.38 / 0.28 m
        // off). The prompt now waits for the rescuer to stand.
        for seed in [1012, 1037] {
            let mut worst: f64 = 0.0;
            let o = closed_loop::run(&Case::SogCalibrated.config(seed), &mut |r, _| {
                worst = worst.max((f64::from(r.display.height_m) - r.rx[2]).abs());
            })
            .expect("run");
            // The hand's bob is a few centimetres; an unmeasured lowering is 0.8 m.
            assert!(worst < 0.15, "seed {seed}: tracked height {worst:.2} m off");
            assert!(
                o.error_h_m.is_some_and(|e| e < 0.25),
                "seed {seed}: {:?}",
                o.error_h_m
            );
        }
    }

    #[test]
    fn median_and_the_probe_tradeoff_table() {
        assert_eq!(median(&[1.0, 2.0, 3.0]), 2.0);
        assert_eq!(median(&[1.0, 2.0, 3.0, 4.0]), 2.5);
        assert!(median(&[]).is_nan());
        let args = Args {
            tries: 1,
            out: None,
            runs: None,
            no_lift: false,
            first_seed: 2,
            calibrated_only: true,
            trace: None,
            trace_case: Case::SogCalibrated,
            probe_tradeoff: vec![0.3, 0.6],
        };
        let table = probe_tradeoff(&args, &args.probe_tradeoff).expect("runs");
        // One row per radius; the default radius reproduces the calibrated case.
        assert_eq!(table.lines().filter(|l| l.starts_with("| 0.")).count(), 2);
        let r = run_one(Case::SogCalibrated, 2).expect("run");
        let row = format!(
            "| 0.30 | {:.3} |",
            Rescue::ratio(r.steps, r.ideal_steps).expect("reached probe here")
        );
        assert!(table.contains(&row), "{table}\n{row}");
    }

    #[test]
    fn the_walk_dead_reckoning_is_consistent_and_the_fine_search_is_counted() {
        let r = run_one(Case::SogCalibrated, 2).expect("run");
        let [walk, steps, no_step] = r.dead_reckoning;
        // Every interval up to the probe is classified (the first received pulse has no
        // displacement before it).
        let counted: u32 = r.dead_reckoning.iter().map(|s| s.n).sum();
        let heard = r.phases.iter().sum::<u32>() - r.phases[0];
        assert!(
            counted + 1 >= heard && counted <= heard,
            "{counted} vs {heard}"
        );
        // Walking, the PDR's covariance covers its error (a frame or sign slip in the
        // comparison would give metre errors against a decimetre σ).
        let n = f64::from(walk.n);
        assert!(walk.n > 20, "{walk:?}");
        assert!(walk.nees_sum / n < 3.0, "{walk:?}");
        assert!((walk.err2_sum_m2 / n).sqrt() < 0.3, "{walk:?}");
        assert!(steps.n + no_step.n > 0, "{steps:?} {no_step:?}");
        let table = dead_reckoning_table(&[r]);
        assert!(
            table.contains("| fine search, no step counted |"),
            "{table}"
        );
    }
}
