//! The sidecar of `baselines.md` (`baselines.json`, see [`crate::eval::sidecar`]): the command,
//! the headline numbers of every table, and the records of a few cheap runs of the first
//! seed that `hal-sim/tests/report_sidecars.rs` re-runs to catch a stale report.
use super::paper::search::{DS_VARIANTS, ICRA_MARGIN, run_ds};
use super::report::Args;
use super::{Method, MethodRuns, run_open};
use crate::eval::accuracy::{MotionNoise, stats};
use crate::eval::sidecar::{Sidecar, record, seed_of};
use anyhow::{Result, anyhow};

/// The open-loop methods whose first-seed run is stored for the staleness check: the
/// cheap ones (the particle filters take minutes per run in a debug build).
pub const CHECK_METHODS: [Method; 3] = [Method::SingleEkf, Method::Rls, Method::Histogram];

/// Keys of a record that depend on the machine, not on the code.
const VOLATILE: &[&str] = &["host_us_per_step"];

/// The report's sidecar: headline numbers per method (and `paper`, the paper-protocol
/// sections'), the first seed's runs of [`CHECK_METHODS`] and of the directional search
/// under ICRA §VI's conditions with the 3 σ rule.
pub fn sidecar(
    command: &str,
    args: &Args,
    all: &[MethodRuns],
    paper: serde_json::Map<String, serde_json::Value>,
) -> Result<Sidecar> {
    let mut methods = serde_json::Map::new();
    for r in all {
        methods.insert(
            r.method.name().into(),
            serde_json::json!({
                "open_loop_final_error_m_max_mean_median":
                    stats(r.open.iter().map(|o| o.final_error_m)),
                "open_loop_over_1m": r.open.iter().filter(|o| o.final_error_m.is_none_or(|e| e > 1.0)).count(),
                "closed_loop_error_h_m_max_mean_median":
                    stats(r.closed.iter().map(|c| c.error_h_m)),
                "closed_loop_failed": r.closed.iter().filter(|c| c.failed).count(),
            }),
        );
    }
    let mut summary = serde_json::Map::new();
    summary.insert("common_protocol".into(), methods.into());
    summary.extend(paper);
    let mut check = Vec::new();
    for r in all.iter().filter(|r| CHECK_METHODS.contains(&r.method)) {
        if let Some(run) = r.open.iter().find(|o| o.seed == args.first_seed) {
            check.push(serde_json::json!({
                "kind": "open_loop",
                "method": r.method,
                "run": record(run, VOLATILE)?,
            }));
        }
    }
    if !args.no_paper_protocols {
        check.push(ds_record(args.first_seed)?);
    }
    Ok(Sidecar::new(
        "baselines-report",
        command,
        args.first_seed,
        args.tries,
        serde_json::Value::Object(summary),
        check,
    ))
}

/// The directional search under ICRA §VI's conditions with the 3 σ rule on `seed`.
fn ds_record(seed: u64) -> Result<serde_json::Value> {
    let v = DS_VARIANTS
        .get(ICRA_MARGIN)
        .ok_or_else(|| anyhow!("no DS variant {ICRA_MARGIN}"))?;
    Ok(serde_json::json!({
        "kind": "directional_search_icra",
        "variant": v.label,
        "rescue": record(&run_ds(v, seed)?, VOLATILE)?,
    }))
}

/// Re-runs one sidecar record with the current code.
pub fn rerun(rec: &serde_json::Value) -> Result<serde_json::Value> {
    match rec["kind"].as_str() {
        Some("open_loop") => {
            let method: Method = serde_json::from_value(rec["method"].clone())?;
            let seed = seed_of(rec, "/run/seed")?;
            let run = run_open(method, seed, &MotionNoise::default())
                .ok_or_else(|| anyhow!("{method:?} does not run open loop"))?;
            Ok(serde_json::json!({
                "kind": "open_loop",
                "method": method,
                "run": record(&run, VOLATILE)?,
            }))
        }
        Some("directional_search_icra") => ds_record(seed_of(rec, "/rescue/seed")?),
        other => Err(anyhow!("unknown baselines record kind {other:?}")),
    }
}
