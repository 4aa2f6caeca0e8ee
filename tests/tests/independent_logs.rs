//! `replay` on session logs that hal-sim did not write: `tests/tools/independent_log.py`
//! generates them from the spec alone (its own walk — a pursuit curve from off-bearing —
//! gait, device pitch, pulse timing, IMU rates of 50–200 Hz, unknown keys and record
//! types, the standard's moment range; a walker who ignores the receiver's prompts). The
//! firmware's pipeline must find the victim from
//! the physics, whatever simulator made the log.
//!
//! Measured when written (`tests/tools/independent_log.py SEED DIR` then `hal-sim replay`,
//! 20 seeds per variant): final 3-D error median 4–5 % of the true distance (≈ 0.2 m at
//! 3–5 m after 25–40 m walks), worst ≈ 15 %; truth inside 3σ in 19–20 of 20.
// Test code: a failed step is a failed test.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hal_sim::io::receiver_config::ReceiverConfig;
use hal_sim::io::replay::{ReplayLine, replay_with_config};
use std::path::Path;
use std::process::Command;

/// One generated log's final estimate against its truth.
struct Scored {
    true_dist: f64,
    err: f64,
    nees: f64,
}

fn generate(seed: u32, dir: &Path, extra: &[&str]) {
    let script = e2e::workspace_root().join("tests/tools/independent_log.py");
    let status = Command::new("python3")
        .arg(script)
        .arg(seed.to_string())
        .arg(dir)
        .args(extra)
        .status()
        .expect("python3 runs (installed by .ci/setup)");
    assert!(status.success(), "generator failed for seed {seed}");
}

/// The truth record (receiver and first victim position in W) at time `t`.
fn truth_at(dir: &Path, t: f64) -> ([f64; 3], [f64; 3]) {
    let text = std::fs::read_to_string(dir.join("truth.jsonl")).unwrap();
    let rec: serde_json::Value = text
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|r| (r["t"].as_f64().unwrap() - t).abs() < 1e-6)
        .expect("a truth record at every pulse");
    let v =
        |x: &serde_json::Value| -> [f64; 3] { core::array::from_fn(|i| x[i].as_f64().unwrap()) };
    (v(&rec["p"]), v(&rec["victims"][0]["p"]))
}

fn replay_and_score(seed: u32, extra: &[&str]) -> Scored {
    let dir = std::env::temp_dir().join(format!("independent-log-{}-{seed}", std::process::id()));
    generate(seed, &dir, extra);
    let session = hal_sim::io::session::read_file(&dir.join("session.jsonl")).unwrap();
    assert!(
        !session.warnings.is_empty(),
        "the unknown record type is skipped with a warning"
    );
    let receiver = ReceiverConfig::read_file(&dir.join("receiver.json")).unwrap();
    let mut out = Vec::new();
    replay_with_config(&session, &receiver, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let last: ReplayLine = text
        .lines()
        .map(|l| serde_json::from_str::<ReplayLine>(l).unwrap())
        .rev()
        .find(|l| !l.victims.is_empty())
        .expect("the estimator initializes");
    let (rx, victim) = truth_at(&dir, last.t);
    let est = &last.victims[0];
    let e: [f64; 3] = core::array::from_fn(|i| est.p[i] - (victim[i] - rx[i]));
    let cov = nalgebra::Matrix3::from_row_slice(&est.cov);
    let ev = nalgebra::Vector3::from(e);
    let nees = cov
        .try_inverse()
        .map_or(f64::INFINITY, |ci| (ev.transpose() * ci * ev)[(0, 0)]);
    let true_dist = (0..3)
        .map(|i| (victim[i] - rx[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    std::fs::remove_dir_all(&dir).ok();
    Scored {
        true_dist,
        err: ev.norm(),
        nees,
    }
}

#[test]
fn replay_finds_the_victim_in_logs_from_an_independent_generator() {
    let cases: [(u32, &[&str]); 7] = [
        (1, &[]),
        (2, &[]),
        (3, &[]),
        (4, &["--imu-hz", "50"]),
        (5, &["--imu-hz", "200"]),
        (6, &["--stand", "3"]),
        // Walks over the victim and 8 m on, never heeding the receiver's prompts (the
        // "lower to snow" prompt shows as it passes): steps still count.
        (7, &["--pass", "--on-bearing"]),
    ];
    let mut rel = Vec::new();
    let mut inside = 0;
    for (seed, extra) in cases {
        let s = replay_and_score(seed, extra);
        println!(
            "seed {seed} {extra:?}: final error {:.3} m at {:.2} m ({:.1} %), NEES {:.2}",
            s.err,
            s.true_dist,
            100.0 * s.err / s.true_dist,
            s.nees
        );
        assert!(s.err.is_finite() && s.nees.is_finite());
        // A broken pipeline (axes, units, sign, timing) is off by the distance itself.
        assert!(
            s.err < 0.25 * s.true_dist,
            "seed {seed}: {:.3} m off at {:.2} m",
            s.err,
            s.true_dist
        );
        rel.push(s.err / s.true_dist);
        // χ²₃ 99.7 % (3σ).
        inside += usize::from(s.nees <= 14.16);
    }
    rel.sort_by(f64::total_cmp);
    let median = rel[rel.len() / 2];
    assert!(median < 0.10, "median relative error {median:.3}");
    assert!(inside >= 6, "truth inside 3σ in {inside} of 7");
}
