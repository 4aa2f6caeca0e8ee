//! The directional search under ICRA 2006 §VI's protocol and the SOGs filter under IROS
//! 2006 §V's, beside the papers' tables, with the measured steps from the common protocol
//! to each paper's (what each difference costs).
//!
//! - ICRA §VI: start 40–70 m away, 1 m/s, one measurement per second, the transmitter's
//!   position, orientation and power random, "the rescuer follows perfectly the flux
//!   lines", and the search guided from the start (the paper's example starts 49 m away
//!   and follows the flux line from there): every pulse is heard. Its power range is not
//!   given.
//! - IROS §V: 100 tries, start 40–60 m away, 1 m/s, one measurement per second, the
//!   search control of III-C (flux line, then the mixture's mean), error of the estimate
//!   at the end.
use crate::accuracy::{self, Case as AccCase, MotionNoise, RunResult, stats};
use crate::closed_loop;
use crate::policies::directional::Reversal;
use crate::rescue_report::{Case, Rescue};
use anyhow::Result;
use std::fmt::Write as _;

/// One directional-search configuration: the common protocol with some of ICRA §VI's
/// conditions.
#[derive(Debug, Clone, Copy)]
pub struct DsVariant {
    /// Row label.
    pub label: &'static str,
    /// Moment range drawn log-uniformly, A·m² (`None`: EN 300 718's, the common one).
    pub moment: Option<[f64; 2]>,
    /// Every pulse received (no 3 σ_bkg reception threshold).
    pub hear_all: bool,
    /// The rescuer follows the policy perfectly (no reaction lag, no heading error).
    pub perfect: bool,
    /// The reversal rule changed from the classical one (`DsConfig::reversal`,
    /// `DsConfig::flip_margin_sigmas`), to measure what the rule costs.
    pub reversal: Option<(Reversal, f64)>,
}

/// Nominal moment (geometric mean of EN 300 718's range), A·m².
const NOMINAL: [f64; 2] = [9.5e-3, 9.5e-3];

/// The rows, from the common protocol to ICRA §VI's.
pub const DS_VARIANTS: [DsVariant; 9] = [
    DsVariant {
        label: "common protocol (EN 300 718 range 3e-3…3e-2 A·m², heard at ≥ 3 σ_bkg, lag 0.5 s, heading σ 5°)",
        moment: None,
        hear_all: false,
        perfect: false,
        reversal: None,
    },
    DsVariant {
        label: "nominal power 9.5e-3 A·m²",
        moment: Some(NOMINAL),
        hear_all: false,
        perfect: false,
        reversal: None,
    },
    DsVariant {
        label: "every pulse heard from the start",
        moment: None,
        hear_all: true,
        perfect: false,
        reversal: None,
    },
    DsVariant {
        label: "follows perfectly (no lag, no heading error)",
        moment: None,
        hear_all: false,
        perfect: true,
        reversal: None,
    },
    DsVariant {
        label: "every pulse heard + follows perfectly",
        moment: None,
        hear_all: true,
        perfect: true,
        reversal: None,
    },
    DsVariant {
        label: "ICRA §VI: nominal power, every pulse heard, follows perfectly",
        moment: Some(NOMINAL),
        hear_all: true,
        perfect: true,
        reversal: None,
    },
    DsVariant {
        label: "ICRA §VI, reversing only at the first flip distance (ICRA §II-A's wording)",
        moment: Some(NOMINAL),
        hear_all: true,
        perfect: true,
        reversal: Some((Reversal::InitialOnly, 0.0)),
    },
    DsVariant {
        label: "ICRA §VI, reversing only on a drop of 3 σ of a reading below the best",
        moment: Some(NOMINAL),
        hear_all: true,
        perfect: true,
        reversal: Some((Reversal::Always, 3.0)),
    },
    DsVariant {
        label: "common protocol, reversing only on a drop of 3 σ of a reading",
        moment: None,
        hear_all: false,
        perfect: false,
        reversal: Some((Reversal::Always, 3.0)),
    },
];

/// The directional search's section: protocol, table, reading.
pub fn ds_section(first: u64, n: u64) -> Result<String> {
    let mut s = String::from(
        "### Directional search under ICRA 2006 §VI's protocol\n\nProtocol (ICRA §VI): 100 tries, start 40–70 m away, 1 m/s, one measurement per second, the transmitter's position, orientation and power random, \"the rescuer follows perfectly the flux lines\", and the search guided by the flux line from the start (their example starts 49 m away): every pulse is heard. The paper gives no power range. Our DS (`policies::directional`, the common protocol's closed loop of `rescue-report`) is run with each of these conditions added alone to the common protocol, then with all of them; same seeds. Steps count from the start, as the paper's (its ideal, 69 / 54 / 53, is the straight walk from the start).\n\n",
    );
    s.push_str(&ds_table(first, n)?);
    s.push_str("\nA failure is a search that never stood on its maximum or took more than 3× the ideal steps from its first received pulse (the common protocol's rule); the paper reports none (its maximum, 128 steps, is under 3× its ideal). Measured: no ICRA condition alone, nor all of them together, brings the failures to the paper's none, and hearing every pulse from the start adds failures (the search then starts on the far, weak pulses). The last three rows change only the reversal rule (`DsConfig::reversal`, `DsConfig::flip_margin_sigmas`): reversing only on a drop of 3 σ of a reading below the best removes every failure under ICRA's conditions (the paper's none) and all but one under the common protocol, at the same found-point error; reversing only at the first flip distance, as ICRA §II-A words it, leaves a few. So the gap to the paper is this implementation's classical reversal on single noisy readings (any reading not above the best turns the rescuer back), not the transmitter's power nor the reception threshold; the rescue reports keep the classical rule as the baseline a receiver without a noise model would follow.\n");
    Ok(s)
}

/// The IROS section: protocol, table, what differs.
pub fn iros_section(first: u64, n: u64, rbpf_open: Option<&[Option<f64>]>) -> String {
    let mut s = String::from(
        "### SOGs filter and RBPF under IROS 2006 §V's protocol\n\nProtocol (IROS §V): 100 tries, start 40–60 m away, 1 m/s, one measurement per second, the transmitter's position, orientation and power random, the search control of §III-C (flux line until the receiver is outside the mixture's 3σ, then to its mean), the error of the estimate at the end. Ours: `accuracy`'s closed-loop case (the same search control, stop at \"probe here\", start drawn 40–70 m: the upper 10 m are the ICRA paper's range), same seeds; the 3-D error at the last pulse. The RBPF has no closed-loop runner here (the closed loop guides by the SOGs mixture's covariance), so its row is the common protocol's open-loop walk.\n\n",
    );
    s.push_str(&iros_table(first, n, rbpf_open));
    s.push_str("\nThe paper's RBPF pattern (a median of decimetres, a quarter of the tries over 1 m) is reproduced; its maximum is not, and is not explained by a measurement here (one 32.5 m try out of 100 under a closed loop we do not run for the RBPF). The SOGs filter's errors are below the paper's in both loops: our pulses carry the noise of ICRA eq. 10 with the firmware's calibrated σ_bkg and k_sen, and the paper does not give its noise levels, so the absolute numbers compare protocols only as far as the noise does.\n");
    s
}

/// One closed-loop directional search of `v` on `seed`.
pub fn run_ds(v: &DsVariant, seed: u64) -> Result<Rescue> {
    let mut c = Case::DirectionalSearch.config(seed);
    if let Some(m) = v.moment {
        c.transmitter.moment_range = m;
    }
    if v.hear_all {
        c.reception_snr = 0.0;
    }
    if v.perfect {
        c.lag_s = 0.0;
        c.heading_noise_deg = 0.0;
    }
    if let Some((reversal, margin)) = v.reversal {
        c.ds.reversal = reversal;
        c.ds.flip_margin_sigmas = margin;
    }
    let o = closed_loop::run(&c, &mut |_, _| {})?;
    let moment = o.moment.iter().map(|m| m * m).sum::<f64>().sqrt();
    Ok(Rescue::from_outcome(Case::DirectionalSearch, &o, moment))
}

fn fmt3(s: Option<[f64; 3]>, digits: usize) -> String {
    match s {
        Some([a, b, c]) => format!("{a:.digits$} / {b:.digits$} / {c:.digits$}"),
        None => "–".into(),
    }
}

/// The directional search's table, one row per variant, seeds `first..first + n`.
pub fn ds_table(first: u64, n: u64) -> Result<String> {
    use rayon::prelude::*;
    let mut s = String::from(
        "| directional search | rescues (found) | failures (> 3× ideal or never) | heard first at, median (m) | steps from the start max / mean / median | ideal steps from the start max / mean / median | found-point error, horizontal, max / mean / median (m) |\n|---|---|---|---|---|---|---|\n",
    );
    for v in &DS_VARIANTS {
        eprintln!("baselines: DS, {} × {n} …", v.label);
        let runs: Vec<Rescue> = (first..first + n)
            .into_par_iter()
            .map(|seed| run_ds(v, seed))
            .collect::<Result<_>>()?;
        let found = runs.iter().filter(|r| r.steps.is_some()).count();
        let failed = runs.iter().filter(|r| r.failed).count();
        let heard = stats(runs.iter().map(|r| r.first_rx_distance_m)).map(|[_, _, m]| m);
        let _ = writeln!(
            s,
            "| {} | {} ({found}) | {failed} | {} | {} | {} | {} |",
            v.label,
            runs.len(),
            heard.map_or("–".into(), |h| format!("{h:.1}")),
            fmt3(stats(runs.iter().map(|r| r.steps_from_start)), 0),
            fmt3(
                stats(runs.iter().map(|r| Some(r.ideal_steps_from_start))),
                0
            ),
            fmt3(stats(runs.iter().map(|r| r.error_h_m)), 2),
        );
    }
    s.push_str("| **ICRA 2006 Table II** (DS, 100 tries) | 100 | 0 (none reported) | – | 128 / 71 / 70 | 69 / 54 / 53 | 2.62 / 0.52 / 0.42 |\n");
    Ok(s)
}

/// The SOGs filter in IROS §V's closed loop (`accuracy`'s `closed-loop` case), seeds
/// `first..first + n`.
pub fn iros_sog_row(first: u64, n: u64) -> String {
    eprintln!("baselines: SOGs, IROS closed loop × {n} …");
    let runs: Vec<RunResult> =
        accuracy::run_case(AccCase::ClosedLoop, first, n, &MotionNoise::default());
    let over = runs
        .iter()
        .filter(|r| r.final_error_m.is_none_or(|e| e > 1.0))
        .count();
    format!(
        "| SOGs filter, IROS §V closed loop (start 40–70 m) | {} | {} | {} | {} | {over} of {} |\n",
        runs.len(),
        fmt3(stats(runs.iter().map(|r| Some(r.start_distance_m))), 1),
        fmt3(
            stats(runs.iter().map(|r| r.steps_to_probe.map(|k| k as f64))),
            0
        ),
        fmt3(stats(runs.iter().map(|r| r.final_error_m)), 2),
        runs.len(),
    )
}

/// The IROS table: the SOGs filter closed loop, the RBPF's common-protocol row (open
/// loop), the paper's Table I.
pub fn iros_table(first: u64, n: u64, rbpf_open: Option<&[Option<f64>]>) -> String {
    let mut s = String::from(
        "| method, protocol | tries | start distance max / mean / median (m) | steps max / mean / median | final error max / mean / median (m) | error > 1 m |\n|---|---|---|---|---|---|\n",
    );
    s.push_str(&iros_sog_row(first, n));
    if let Some(e) = rbpf_open {
        let over = e.iter().filter(|e| e.is_none_or(|e| e > 1.0)).count();
        let _ = writeln!(
            s,
            "| RBPF (5000), open loop on the common protocol's walk (start 40–70 m) | {} | – | – | {} | {over} of {} |",
            e.len(),
            fmt3(stats(e.iter().copied()), 2),
            e.len(),
        );
    }
    s.push_str("| **IROS 2006 Table I**: SOGs (start 40–60 m) | 100 | 60 / 50.4 / 51 | 93 / 62 / 61 | 0.66 / 0.23 / 0.21 | – |\n");
    s.push_str("| **IROS 2006 Table I**: RBPF (5000 particles) | 100 | 60 / 50.4 / 51 | 99 / 64 / 64 | 32.5 / 2.27 / 0.28 | 25 of 100 (their Fig. 5) |\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icra_conditions_hear_every_pulse_from_the_start() {
        let icra = run_ds(&DS_VARIANTS[5], 3).unwrap();
        assert!((icra.moment_am2 - NOMINAL[0]).abs() < 1e-9);
        // Heard at the start: the first received pulse is the start distance.
        let heard = icra.first_rx_distance_m.unwrap();
        assert!(
            (heard - icra.start_distance_m).abs() < 1.5,
            "{heard} vs {}",
            icra.start_distance_m
        );
    }
}
