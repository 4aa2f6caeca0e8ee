//! A checked-in report cannot silently go stale: each report's sidecar (`X.json` beside
//! `X.md`, written by the report's own command) names the markdown it was written with and
//! stores the per-run records of its first seeds. This test checks the markdown against the
//! sidecar's hash, re-runs those seeds with the current code and compares every record.
//! When it fails, regenerate the report with the command it prints.

#![allow(clippy::panic, clippy::unwrap_used, clippy::expect_used)]

use hal_sim::eval::sidecar::{self, Sidecar};
use std::path::{Path, PathBuf};

/// The reports that carry a sidecar.
const REPORTS: &[&str] = &[
    "accuracy.md",
    "classic.md",
    "multi.md",
    "rescue.md",
    "rescue-seeds1000.md",
    "baselines.md",
    "sensing.md",
    "team.md",
    "consistency.md",
];

fn reports_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("reports")
}

fn load(name: &str) -> (String, Sidecar) {
    let md_path = reports_dir().join(name);
    let md =
        std::fs::read_to_string(&md_path).unwrap_or_else(|e| panic!("{}: {e}", md_path.display()));
    let side = sidecar::read(&sidecar::path_for(&md_path)).unwrap_or_else(|e| {
        panic!("{name} has no readable sidecar ({e:#}): regenerate it with its command")
    });
    (md, side)
}

fn rerun(side: &Sidecar, record: &serde_json::Value) -> serde_json::Value {
    let result = match side.report.as_str() {
        "accuracy" => hal_sim::eval::accuracy::rerun(record),
        "classic-report" => hal_sim::sim::classic_loop::rerun(record),
        "multi-report" => hal_sim::eval::multi_report::rerun(record),
        "rescue-report" => hal_sim::eval::rescue_report::rerun(record),
        "baselines-report" => hal_sim::eval::baselines::record::rerun(record),
        "sensing-report" => hal_sim::eval::sensing_report::rerun(record),
        "team-report" => hal_sim::team::report::rerun(record),
        "consistency" => hal_sim::sensors::faults::consistency::rerun(record),
        other => panic!("unknown report kind {other}"),
    };
    result.unwrap_or_else(|e| panic!("{}: re-running {record}: {e:#}", side.report))
}

fn check_report(name: &str) {
    let (md, side) = load(name);
    assert_eq!(
        sidecar::fnv64(md.as_bytes()),
        side.markdown_fnv64,
        "{name} differs from what its command wrote (edited by hand, or regenerated \
         without its sidecar): regenerate with `{}`",
        side.command
    );
    assert!(!side.check.is_empty(), "{name}: the sidecar holds no run");
    for record in &side.check {
        let now = rerun(&side, record);
        assert_eq!(
            &now, record,
            "{name} is stale: the current code gives another result for this run; \
             regenerate with `{}`",
            side.command
        );
    }
}

#[test]
fn accuracy_report_is_current() {
    check_report(REPORTS[0]);
}

#[test]
fn classic_report_is_current() {
    check_report(REPORTS[1]);
}

#[test]
fn multi_report_is_current() {
    check_report(REPORTS[2]);
}

#[test]
fn rescue_report_is_current() {
    check_report(REPORTS[3]);
}

#[test]
fn rescue_report_on_the_second_seed_range_is_current() {
    check_report(REPORTS[4]);
}

#[test]
fn baselines_report_is_current() {
    check_report(REPORTS[5]);
}

#[test]
fn sensing_report_is_current() {
    check_report(REPORTS[6]);
}

#[test]
fn team_report_is_current() {
    check_report(REPORTS[7]);
}

#[test]
fn consistency_report_is_current() {
    check_report(REPORTS[8]);
}

/// `reliability.md` is written by hand but quotes the consistency table: it must quote
/// the one `consistency.md` holds (whose sidecar the test above checks).
#[test]
fn reliability_quotes_the_current_consistency_table() {
    let (generated, side) = load(REPORTS[8]);
    let path = reports_dir().join("reliability.md");
    let reliability =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let table: Vec<&str> = generated.lines().filter(|l| l.starts_with('|')).collect();
    assert!(table.len() > 2, "consistency.md holds no table");
    assert!(
        reliability.contains(&table.join("\n")),
        "reliability.md does not quote consistency.md's table: copy it from there (regenerated \
         with `{}`)",
        side.command
    );
}
