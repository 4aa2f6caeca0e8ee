//! What the end-to-end tests of the `hal-sim` binary share: running it, and a simulated
//! search to replay (its log, receiver.json and truth).
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// Runs `hal-sim` with `args`, waits for it.
pub fn hal_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hal-sim"))
        .args(args)
        .output()
        .unwrap()
}

/// Starts `hal-sim` with `args`, its standard input, output and error piped.
pub fn hal_sim_piped(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_hal-sim"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Runs `hal-sim` with `args` and `input` on its standard input.
pub fn hal_sim_stdin(args: &[&str], input: &[u8]) -> Output {
    let mut child = hal_sim_piped(args);
    let mut stdin = child.stdin.take().unwrap();
    // The child may stop reading early (an error): a closed pipe is its answer.
    let _ = stdin.write_all(input);
    drop(stdin);
    child.wait_with_output().unwrap()
}

/// Bytes as text (lossy).
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// `hal-sim simulate --preset paper --seed <seed> --max-duration-s 40` into `dir`.
pub fn simulate_into(dir: &Path, seed: &str) {
    simulate_paper(dir, seed, "40", &[]);
}

/// `hal-sim simulate --preset paper --seed <seed> --max-duration-s <seconds> <extra…>`
/// into `dir`.
pub fn simulate_paper(dir: &Path, seed: &str, seconds: &str, extra: &[&str]) {
    let mut args = vec![
        "simulate",
        "--preset",
        "paper",
        "--seed",
        seed,
        "--max-duration-s",
        seconds,
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = hal_sim(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
}

/// A 40 s simulated search (seed 3) in `tmp/sim`: (directory, its log lines).
pub fn simulated(tmp: &Path) -> (PathBuf, Vec<String>) {
    let dir = tmp.join("sim");
    simulate_into(&dir, "3");
    let lines = std::fs::read_to_string(dir.join("session.jsonl"))
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    (dir, lines)
}

/// Lines joined with newlines, one after the last.
pub fn joined(lines: &[String]) -> Vec<u8> {
    let mut s = lines.join("\n");
    s.push('\n');
    s.into_bytes()
}

/// Whether a log line is a pulse record.
pub fn is_pulse(l: &str) -> bool {
    l.contains("\"type\":\"pulse\"")
}

/// The `t` of a record line.
pub fn t_of(l: &str) -> f64 {
    let v: serde_json::Value = serde_json::from_str(l).unwrap();
    v["t"].as_f64().unwrap()
}

/// The NEES of the first victim of the last replay line that has one, against the truth
/// records of `truth` (JSON Lines) at that line's time minus `t_shift`; `None` when no
/// line has an estimate. As `tests/tools/score_replay.py`: the true victim position
/// relative to the receiver, interpolated between truth records.
pub fn final_nees(truth: &str, replay: &[String], t_shift: f64) -> Option<f64> {
    let truth: Vec<serde_json::Value> = truth
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["type"] == "truth")
        .collect();
    let last = replay
        .iter()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|v| v["victims"].as_array().is_some_and(|a| !a.is_empty()))?;
    let t = last["t"].as_f64().unwrap() - t_shift;
    let at = |r: &serde_json::Value, k: &str| -> [f64; 3] {
        std::array::from_fn(|i| r[k][i].as_f64().unwrap())
    };
    let later = truth
        .iter()
        .position(|r| r["t"].as_f64().unwrap() >= t)
        .unwrap_or(truth.len() - 1);
    let (a, b) = (&truth[later.saturating_sub(1)], &truth[later]);
    let (ta, tb) = (a["t"].as_f64().unwrap(), b["t"].as_f64().unwrap());
    let u = if tb <= ta {
        0.0
    } else {
        ((t - ta) / (tb - ta)).clamp(0.0, 1.0)
    };
    let (pa, pb, victim) = (at(a, "p"), at(b, "p"), at(&b["victims"][0], "p"));
    let rel: [f64; 3] = std::array::from_fn(|i| victim[i] - (pa[i] + u * (pb[i] - pa[i])));
    let est = &last["victims"][0];
    let e: [f64; 3] = std::array::from_fn(|i| est["p"][i].as_f64().unwrap() - rel[i]);
    let c: [f64; 9] = std::array::from_fn(|i| est["cov"][i].as_f64().unwrap());
    // e' C⁻¹ e by the adjugate (C symmetric positive definite).
    let det = c[0] * (c[4] * c[8] - c[5] * c[7]) - c[1] * (c[3] * c[8] - c[5] * c[6])
        + c[2] * (c[3] * c[7] - c[4] * c[6]);
    let inv = [
        c[4] * c[8] - c[5] * c[7],
        c[2] * c[7] - c[1] * c[8],
        c[1] * c[5] - c[2] * c[4],
        c[5] * c[6] - c[3] * c[8],
        c[0] * c[8] - c[2] * c[6],
        c[2] * c[3] - c[0] * c[5],
        c[3] * c[7] - c[4] * c[6],
        c[1] * c[6] - c[0] * c[7],
        c[0] * c[4] - c[1] * c[3],
    ];
    let mut nees = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            nees += e[i] * inv[3 * i + j] / det * e[j];
        }
    }
    Some(nees)
}

/// χ²(3) at 99.73 %: a NEES at or below it puts the truth inside the reported 3σ
/// ellipsoid (the bound of `tests/tools/score_replay.py`).
pub const NEES_3SIGMA: f64 = 14.16;
