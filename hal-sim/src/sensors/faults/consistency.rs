//! Consistency of the whole pipeline (`hal-sim consistency`): NEES of the application's
//! estimate (IMU → attitude and PDR → SOGs filter, [`firmware::app::Receiver`]) over
//! seeded simulated searches, as slides 002 test it: the fraction of pulses with the
//! position NEES `eᵀP⁻¹e` inside the 95 % χ²(3) bound, and the mean NEES (3 when
//! consistent). Unlike `hal-sim accuracy` (true displacement plus declared noise), the
//! displacement here is the firmware's own dead reckoning from the simulated IMU.
use super::drive::{PulseStep, drive};
use crate::eval::accuracy::CHI2_3DOF_95;
use crate::world::physics::{M3, V3};
use crate::world::scenario::{Preset, ScenarioConfig, simulate};

/// Seeded searches per preset (seeds 1..=tries), and the report's destination.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Seeded searches per preset.
    #[arg(long, default_value_t = 50)]
    pub tries: u64,
    /// Write the markdown section here (default: stdout only).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
}

/// Pooled NEES figures.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Nees {
    /// Pulses with an estimate and a truth.
    pub evaluated: usize,
    /// Of those, inside the 95 % bound.
    pub inside_95: usize,
    /// Sum of the NEES.
    pub sum: f64,
    /// Searches whose last estimate is more than 1 m off.
    pub final_over_1m: usize,
    /// Searches run.
    pub runs: usize,
}

impl Nees {
    /// Fraction of the evaluated pulses inside the bound.
    pub fn fraction(&self) -> f64 {
        self.inside_95 as f64 / self.evaluated.max(1) as f64
    }

    fn add(&mut self, o: &Nees) {
        self.evaluated += o.evaluated;
        self.inside_95 += o.inside_95;
        self.sum += o.sum;
        self.final_over_1m += o.final_over_1m;
        self.runs += o.runs;
    }
}

/// The position NEES of one pulse's estimate against its truth.
pub fn nees(p: &PulseStep) -> Option<f64> {
    let (e, t) = (p.estimate.as_ref()?, p.truth.as_ref()?);
    let d = V3::new(e.p.x.into(), e.p.y.into(), e.p.z.into()) - t;
    let cov = M3::from_fn(|i, j| f64::from(e.cov[(i, j)]));
    let inv = cov.try_inverse()?;
    Some((d.transpose() * inv * d)[(0, 0)])
}

/// NEES over one seeded search of `preset`.
pub fn run_one(preset: Preset, seed: u64) -> anyhow::Result<Nees> {
    let sim = simulate(&ScenarioConfig::new(preset, seed));
    let trace = drive(&sim.session, &sim.receiver, Some(&sim.truth), f64::INFINITY)?;
    let mut n = Nees {
        runs: 1,
        ..Nees::default()
    };
    for x in trace.pulses.iter().filter_map(nees) {
        n.evaluated += 1;
        n.sum += x;
        n.inside_95 += usize::from(x <= CHI2_3DOF_95);
    }
    n.final_over_1m = usize::from(trace.final_error_m().is_none_or(|e| e > 1.0));
    Ok(n)
}

/// Runs `tries` searches of each preset and writes the markdown section.
pub fn run(args: &Args, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    use rayon::prelude::*;
    use std::fmt::Write as _;
    let presets = [Preset::Paper, Preset::Line, Preset::Arc, Preset::FluxLine];
    let mut s = format!(
        "| preset | searches | pulses evaluated | NEES inside 95 % bound ({CHI2_3DOF_95}) | mean NEES | final error > 1 m |\n|---|---:|---:|---:|---:|---:|\n"
    );
    let mut all = Nees::default();
    for preset in presets {
        let runs: Vec<Nees> = (1..=args.tries)
            .into_par_iter()
            .map(|seed| run_one(preset, seed))
            .collect::<anyhow::Result<_>>()?;
        let mut n = Nees::default();
        runs.iter().for_each(|r| n.add(r));
        all.add(&n);
        let _ = writeln!(
            s,
            "| {preset:?} | {} | {} | {:.1} % | {:.2} | {} |",
            n.runs,
            n.evaluated,
            100.0 * n.fraction(),
            n.sum / n.evaluated.max(1) as f64,
            n.final_over_1m
        );
    }
    let _ = writeln!(
        s,
        "| all | {} | {} | {:.1} % | {:.2} | {} |",
        all.runs,
        all.evaluated,
        100.0 * all.fraction(),
        all.sum / all.evaluated.max(1) as f64,
        all.final_over_1m
    );
    if let Some(path) = &args.out {
        std::fs::write(path, &s)?;
    }
    out.write_all(s.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seeded_search_is_mostly_consistent() {
        // Fails if the NEES is computed wrongly (e.g. with the covariance not inverted) or
        // if the pipeline is grossly overconfident on a plain search.
        let n = run_one(Preset::Paper, 4).unwrap();
        assert!(n.evaluated > 20);
        assert!(n.fraction() > 0.6, "NEES inside on {:.2}", n.fraction());
        let mean = n.sum / n.evaluated as f64;
        assert!(mean > 0.3 && mean < 10.0, "mean NEES {mean}");
    }
}
