//! `hal-sim demo` end to end, and the display fields in `replay`'s output.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use common::{hal_sim, text};

#[test]
fn demo_prints_screens_and_writes_pngs() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("demo");
    let out = hal_sim(&[
        "demo",
        "--seed",
        "2",
        "--every",
        "20",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let screens = text(&out.stdout);
    assert!(screens.contains("PROBE HERE"), "{screens}");
    assert!(
        screens.contains('█') && screens.contains("[flux-line]"),
        "{screens}"
    );
    for f in ["demo.png", "display.png"] {
        let bytes = std::fs::read(dir.join(f)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{f}");
    }
    let quiet = hal_sim(&[
        "demo",
        "--seed",
        "2",
        "--quiet",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let q = text(&quiet.stdout);
    assert!(
        quiet.status.success() && !q.contains('█') && q.contains("seed 2"),
        "{q}"
    );
}

#[test]
fn replay_reports_the_display_status() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let out = hal_sim(&["simulate", "--seed", "3", "--out", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let log = dir.join("session.jsonl");
    let rec = dir.join("receiver.json");
    let out = hal_sim(&[
        "replay",
        log.to_str().unwrap(),
        "--receiver",
        rec.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let mut statuses = std::collections::BTreeSet::new();
    for line in text(&out.stdout).lines() {
        let v: hal_sim::io::replay::ReplayLine = serde_json::from_str(line).unwrap();
        let s = v.status.expect("status on every line");
        assert!(["searching", "flux-line", "localized", "probe"].contains(&s.as_str()));
        if s != "searching" {
            let a = v.arrow_deg.expect("an arrow");
            assert!(a > -180.0 && a <= 180.0);
        }
        statuses.insert(s);
    }
    assert!(statuses.contains("localized"), "{statuses:?}");
}
