//! `hal-sim replay` on damaged and reordered logs, end to end: a simulated log in the
//! board's order, with a byte-order mark, torn, with garbage, concatenated, with lost
//! records (`seq`), piped into `head`, and fed live on standard input; a bus-level
//! simulation written as the board writes (pulses late, `seq`); a log without
//! magnetometer (never "localized").
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use common::{
    NEES_3SIGMA, final_nees, hal_sim, hal_sim_piped, is_pulse, joined, simulate_paper, simulated,
    t_of, text,
};
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// Replays `log` (bytes) with the simulation's receiver.json: (stdout lines, stderr, ok).
fn replay(dir: &Path, name: &str, log: &[u8], extra: &[&str]) -> (Vec<String>, String, bool) {
    let path = dir.join(name);
    std::fs::write(&path, log).unwrap();
    let receiver = dir.join("receiver.json");
    let mut args = vec![
        "replay",
        path.to_str().unwrap(),
        "--receiver",
        receiver.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = hal_sim(&args);
    let lines = text(&out.stdout).lines().map(String::from).collect();
    (lines, text(&out.stderr), out.status.success())
}

#[test]
fn damaged_logs_replay_every_intact_pulse() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, lines) = simulated(tmp.path());
    let pulses = lines.iter().filter(|l| is_pulse(l)).count();
    assert!(pulses >= 10, "{pulses} pulses");
    let (reference, err, ok) = replay(&dir, "plain.jsonl", &joined(&lines), &[]);
    assert!(ok, "{err}");
    assert_eq!(reference.len(), pulses);
    assert!(err.contains("replay summary"), "{err}");
    assert!(err.contains(&format!("{pulses} pulse")), "{err}");

    // The board's order: each pulse written 0.25 s after its centre.
    let mut board: Vec<String> = Vec::new();
    let mut held: Vec<String> = Vec::new();
    for l in &lines {
        if is_pulse(l) {
            held.push(l.clone());
            continue;
        }
        if l.contains("\"t\":") {
            let t = t_of(l);
            while held.first().is_some_and(|p| t_of(p) + 0.25 <= t) {
                board.push(held.remove(0));
            }
        }
        board.push(l.clone());
    }
    board.append(&mut held);
    assert_ne!(board, lines);
    let (out, err, ok) = replay(&dir, "board.jsonl", &joined(&board), &[]);
    assert!(ok, "{err}");
    assert_eq!(
        out, reference,
        "the board's order replays as the sorted log"
    );
    assert!(!err.contains("warning"), "{err}");

    // A byte-order mark.
    let mut bom = b"\xEF\xBB\xBF".to_vec();
    bom.extend_from_slice(&joined(&lines));
    let (out, err, ok) = replay(&dir, "bom.jsonl", &bom, &[]);
    assert!(ok && out == reference, "{err}");

    // Concatenated captures: two segments, each replayed from a fresh state.
    let mut twice = joined(&lines);
    twice.extend_from_slice(&joined(&lines));
    let (out, err, ok) = replay(&dir, "twice.jsonl", &twice, &[]);
    assert!(ok, "{err}");
    assert_eq!(out.len(), 2 * pulses);
    assert_eq!(out[..pulses], reference[..]);
    assert_eq!(out[pulses..], reference[..]);
    assert!(err.contains("in 2 segment(s)"), "{err}");

    // A torn IMU line in the middle and a block of garbage: reported by line number,
    // every pulse still answered.
    let mut damaged = lines.clone();
    let k = (1..damaged.len())
        .find(|&i| i > damaged.len() / 2 && !is_pulse(&damaged[i]))
        .unwrap();
    let half = damaged[k].len() / 2;
    damaged[k].truncate(half);
    damaged.insert(k + 10, "\u{1}\u{2}garbage{{{\"".into());
    damaged.insert(k + 11, "]]]".into());
    let (out, err, ok) = replay(&dir, "damaged.jsonl", &joined(&damaged), &[]);
    assert!(ok, "{err}");
    assert_eq!(out.len(), pulses);
    for line in [k + 1, k + 11, k + 12] {
        assert!(err.contains(&format!("line {line}:")), "line {line}: {err}");
    }
    assert!(err.contains("3 malformed"), "{err}");
    let (out, err, ok) = replay(&dir, "damaged.jsonl", &joined(&damaged), &["--strict"]);
    assert!(!ok && out.is_empty(), "{err}");
    assert!(err.contains(&format!("line {}:", k + 1)), "{err}");

    // Lost records, as `seq` tells.
    let mut seq: Vec<String> = lines
        .iter()
        .enumerate()
        .map(|(i, l)| l.replacen('{', &format!("{{\"seq\":{i},"), 1))
        .collect();
    seq.drain(100..103);
    let (out, err, ok) = replay(&dir, "seq.jsonl", &joined(&seq), &[]);
    assert!(ok, "{err}");
    assert!(
        err.contains("seq jumps from 99 to 103: 3 records lost"),
        "{err}"
    );
    assert!(out.len() >= pulses - 3);
}

#[test]
fn a_closed_pipe_ends_quietly() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = simulated(tmp.path());
    let mut child = hal_sim_piped(&["replay", dir.join("session.jsonl").to_str().unwrap()]);
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert!(first.starts_with("{\"t\":"), "{first}");
    // `head -1` has what it wanted and closes the pipe.
    let out = child.wait_with_output().unwrap();
    let err = text(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.to_lowercase().contains("broken pipe"), "{err}");
}

#[test]
fn live_mode_answers_each_pulse_as_it_arrives() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, lines) = simulated(tmp.path());
    let mut child = hal_sim_piped(&[
        "replay",
        "-",
        "--receiver",
        dir.join("receiver.json").to_str().unwrap(),
    ]);
    let mut stdin = child.stdin.take().unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut answered = 0;
    for l in &lines {
        writeln!(stdin, "{l}").unwrap();
        if is_pulse(l) {
            stdin.flush().unwrap();
            // The answer comes before the next record is written: the loop can close.
            let mut answer = String::new();
            stdout.read_line(&mut answer).unwrap();
            let v: serde_json::Value = serde_json::from_str(&answer).unwrap();
            assert_eq!(v["t"].as_f64(), Some(t_of(l)));
            assert!(v["status"].is_string());
            answered += 1;
        }
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(out.stdout.is_empty());
    assert!(answered >= 10, "{answered} answered");
}

#[test]
fn a_bus_level_log_is_written_in_the_boards_order_and_replays() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bus");
    simulate_paper(&dir, "3", "80", &["--bus"]);
    let log = std::fs::read_to_string(dir.join("session.jsonl")).unwrap();
    let lines: Vec<&str> = log.lines().collect();
    // Every record numbered in file order.
    for (k, l) in lines[1..].iter().enumerate() {
        assert!(l.starts_with(&format!("{{\"seq\":{k},\"type\":")), "{l}");
    }
    // Each pulse after the records up to when the front end finished it: later than its
    // own t, within the spec's 2 s window.
    let mut latest = f64::NEG_INFINITY;
    let mut late = 0;
    for l in &lines[1..] {
        let t = t_of(l);
        if is_pulse(l) && t < latest {
            assert!(latest - t <= 2.0, "{l} written at {latest}");
            late += 1;
        }
        latest = latest.max(t);
    }
    let pulses = lines.iter().filter(|l| is_pulse(l)).count();
    assert!(
        pulses >= 5 && late > 0,
        "{late} of {pulses} pulses after later records"
    );
    let (out, err, ok) = replay(&dir, "session.jsonl", log.as_bytes(), &[]);
    assert!(ok && !err.contains("warning"), "{err}");
    assert_eq!(out.len(), pulses);
    // The same records sorted by t replay the same.
    let mut sorted: Vec<String> = lines[1..].iter().map(|l| l.to_string()).collect();
    sorted.sort_by(|a, b| t_of(a).total_cmp(&t_of(b)));
    sorted.insert(0, lines[0].to_string());
    let (again, err, ok) = replay(&dir, "sorted.jsonl", &joined(&sorted), &[]);
    assert!(ok, "{err}");
    assert_eq!(again, out);
}

/// Issue 22 item 5: "when the inputs cannot support a belief, the covariance says so and
/// the status is not localized". Without a magnetometer the heading is unknown: the
/// position in G_k is declared unknown by its covariance (truth inside 3σ at the end) and
/// the display never sends the rescuer to it (`guidance::heading_supports`), while the
/// same search with its magnetometer is localized.
#[test]
fn without_a_magnetometer_the_display_is_never_localized() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("sim");
    simulate_paper(&dir, "3", "120", &[]);
    let log = std::fs::read_to_string(dir.join("session.jsonl")).unwrap();
    let truth = std::fs::read_to_string(dir.join("truth.jsonl")).unwrap();
    let status = |lines: &[String], s: &str| {
        let word = format!("\"status\":\"{s}\"");
        lines.iter().filter(|l| l.contains(&word)).count()
    };
    let (with_mag, err, ok) = replay(&dir, "with_mag.jsonl", log.as_bytes(), &[]);
    assert!(ok, "{err}");
    assert!(
        status(&with_mag, "localized") > 0,
        "with its magnetometer: localized"
    );
    let no_mag: Vec<String> = log
        .lines()
        .map(|l| {
            let mut r: serde_json::Value = serde_json::from_str(l).unwrap();
            if r["type"] == "imu" {
                r.as_object_mut().unwrap().remove("mag");
            }
            r.to_string()
        })
        .collect();
    let (lines, err, ok) = replay(&dir, "no_mag.jsonl", &joined(&no_mag), &[]);
    assert!(ok, "{err}");
    assert_eq!(lines.len(), with_mag.len());
    assert_eq!(status(&lines, "localized") + status(&lines, "probe"), 0);
    assert!(status(&lines, "flux-line") > 0);
    let nees = final_nees(&truth, &lines, 0.0).expect("an estimate at the end");
    assert!(
        nees <= NEES_3SIGMA,
        "truth outside 3σ at the end: NEES {nees:.2}"
    );
}
