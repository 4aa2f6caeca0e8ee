//! The bad-input suite (issue 22): `hal-sim replay` (and `inspect`) on damaged logs,
//! implausible headers and receiver configurations, one table row per case with the
//! expected exit code, the messages on stderr, the number of replay lines and, for the
//! logs that are answered, the truth inside the reported 3σ at the end.
//!
//! Every case starts from one 40 s simulated search (`common::simulated`) and damages it.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;
#[path = "bad_input/config.rs"]
mod config;
#[path = "bad_input/log_lines.rs"]
mod log_lines;
#[path = "bad_input/records.rs"]
mod records;

use common::{NEES_3SIGMA, final_nees, hal_sim, hal_sim_stdin, is_pulse, joined, t_of, text};
use std::path::PathBuf;
use std::sync::OnceLock;

/// The simulated search every case damages.
struct Sim {
    dir: PathBuf,
    lines: Vec<String>,
    truth: String,
    /// Pulse records in the log.
    pulses: usize,
}

fn sim() -> &'static Sim {
    static SIM: OnceLock<Sim> = OnceLock::new();
    SIM.get_or_init(|| {
        let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bad_input");
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).unwrap();
        let (dir, lines) = common::simulated(&tmp);
        let truth = std::fs::read_to_string(dir.join("truth.jsonl")).unwrap();
        let pulses = lines.iter().filter(|l| is_pulse(l)).count();
        assert!(pulses >= 10, "{pulses} pulses");
        Sim {
            dir,
            lines,
            truth,
            pulses,
        }
    })
}

/// Where the log comes from.
#[derive(Clone, Copy)]
enum Input {
    /// A file holding the damaged log.
    File,
    /// The damaged log on standard input (`replay -`, live mode).
    Stdin,
    /// A path that does not exist.
    Missing,
    /// A directory.
    Dir,
}

/// One bad input and what `hal-sim` must answer.
struct Case {
    name: &'static str,
    /// `replay` or `inspect` (which gets no receiver.json; its lines are not counted).
    cmd: &'static str,
    /// The log, from the simulated log's lines.
    log: fn(&[String]) -> Vec<u8>,
    input: Input,
    /// receiver.json text; `None`: the simulation's own.
    receiver: Option<&'static str>,
    /// Extra arguments (`--strict`).
    args: &'static [&'static str],
    /// Expected exit status.
    exit: i32,
    /// Texts stderr must contain.
    stderr: &'static [&'static str],
    /// Texts stdout must contain.
    stdout: &'static [&'static str],
    /// Expected replay lines: `k × pulses + d`.
    lines: (usize, isize),
    /// `Some(shift)`: the truth (at the replay time minus `shift`) lies inside the final
    /// estimate's 3σ.
    truth: Option<f64>,
}

const OK: Case = Case {
    name: "",
    cmd: "replay",
    log: |l| joined(l),
    input: Input::File,
    receiver: None,
    args: &[],
    exit: 0,
    stderr: &["summary"],
    stdout: &[],
    lines: (1, 0),
    truth: Some(0.0),
};

/// An error exit with no replay line.
const FAIL: Case = Case {
    exit: 1,
    lines: (0, 0),
    truth: None,
    stderr: &[],
    ..OK
};

fn owned(l: &[String]) -> Vec<String> {
    l.to_vec()
}

/// Index of the first line past the middle that is a record of `ty`.
fn middle(l: &[String], ty: &str) -> usize {
    let pat = format!("\"type\":\"{ty}\"");
    (l.len() / 2..l.len())
        .find(|&i| l[i].contains(&pat))
        .unwrap()
}

/// Replaces the first occurrence of `from` by `to` in line `i`.
fn edit(l: &[String], i: usize, from: &str, to: &str) -> Vec<u8> {
    let mut v = owned(l);
    assert!(v[i].contains(from), "{} has no {from}", v[i]);
    v[i] = v[i].replacen(from, to, 1);
    joined(&v)
}

/// Line `i`'s array `key` with its first element's text replaced by `v`.
fn set_first(l: &[String], i: usize, key: &str, v: &str) -> Vec<u8> {
    let mut w = owned(l);
    let at = w[i].find(&format!("\"{key}\":[")).unwrap() + key.len() + 4;
    let end = at + w[i][at..].find(',').unwrap();
    w[i].replace_range(at..end, v);
    joined(&w)
}

/// The header line replaced by `h`.
fn with_header(l: &[String], h: &str) -> Vec<u8> {
    let mut v = owned(l);
    v[0] = h.to_string();
    joined(&v)
}

/// Each IMU record's `mag` replaced by `f(old)` (`None`: removed).
fn map_mag(l: &[String], f: fn(&str) -> Option<String>) -> Vec<u8> {
    let v: Vec<String> = l
        .iter()
        .map(|x| match x.find(",\"mag\":[") {
            Some(i) if x.contains("\"type\":\"imu\"") => {
                let end = i + x[i..].find(']').unwrap() + 1;
                let arr = &x[i + 7..end];
                match f(arr) {
                    Some(m) => format!("{},\"mag\":{m}{}", &x[..i], &x[end..]),
                    None => format!("{}{}", &x[..i], &x[end..]),
                }
            }
            _ => x.clone(),
        })
        .collect();
    joined(&v)
}

/// The pulse lines repeated `k` times in place.
fn repeat_pulses(l: &[String], k: usize) -> Vec<u8> {
    let mut v = Vec::new();
    for x in l {
        let n = if is_pulse(x) { k } else { 1 };
        v.extend(std::iter::repeat_n(x.clone(), n));
    }
    joined(&v)
}

/// Each pulse written `late` s after its time (after the records up to then).
fn pulses_late(l: &[String], late: f64) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    let mut held: Vec<String> = Vec::new();
    for x in l {
        if is_pulse(x) {
            held.push(x.clone());
            continue;
        }
        if x.contains("\"t\":") {
            let t = t_of(x);
            while held.first().is_some_and(|p| t_of(p) + late <= t) {
                out.push(held.remove(0));
            }
        }
        out.push(x.clone());
    }
    out.append(&mut held);
    out
}

/// Every record's `t` shifted by `dt` (header untouched).
fn shift_t(l: &[String], dt: f64) -> Vec<u8> {
    let v: Vec<String> = l
        .iter()
        .map(|x| {
            let mut r: serde_json::Value = serde_json::from_str(x).unwrap();
            if let Some(t) = r["t"].as_f64() {
                r["t"] = (t + dt).into();
            }
            r.to_string()
        })
        .collect();
    joined(&v)
}

/// Every pulse record given `"src": s`.
fn with_src(l: &[String], s: &str) -> Vec<u8> {
    let v: Vec<String> = l
        .iter()
        .map(|x| {
            if is_pulse(x) {
                x.replacen('{', &format!("{{\"src\":{s},"), 1)
            } else {
                x.clone()
            }
        })
        .collect();
    joined(&v)
}

/// Every record given a `seq` (its line number), then `f` applied.
fn with_seq(l: &[String], f: fn(&mut Vec<String>)) -> Vec<u8> {
    let mut v: Vec<String> = l
        .iter()
        .enumerate()
        .map(|(i, x)| x.replacen('{', &format!("{{\"seq\":{i},"), 1))
        .collect();
    f(&mut v);
    joined(&v)
}

/// `item` inserted before line `i`.
fn insert(l: &[String], i: usize, item: &str) -> Vec<u8> {
    let mut v = owned(l);
    v.insert(i, item.to_string());
    joined(&v)
}

const HEADER: &str = r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100.0,"earth_field_uT":[21.8,0.0,-42.8],"sign_ambiguous":true}"#;

fn cases() -> Vec<Case> {
    [log_lines::cases(), records::cases(), config::cases()]
        .into_iter()
        .flatten()
        .collect()
}

/// Runs `case`; returns the failures found (empty: passed).
fn run(case: &Case, sim: &Sim, n: usize) -> Vec<String> {
    let dir = sim.dir.join(format!("case{n:03}"));
    std::fs::create_dir_all(&dir).unwrap();
    let log_bytes = (case.log)(&sim.lines);
    let log = match case.input {
        Input::File | Input::Stdin => dir.join("session.jsonl"),
        Input::Missing => dir.join("missing.jsonl"),
        Input::Dir => dir.clone(),
    };
    if matches!(case.input, Input::File) {
        std::fs::write(&log, &log_bytes).unwrap();
    }
    let receiver = match case.receiver {
        Some(t) => {
            let p = dir.join("receiver.json");
            std::fs::write(&p, t).unwrap();
            p
        }
        None => sim.dir.join("receiver.json"),
    };
    let log_arg = match case.input {
        Input::Stdin => "-".to_string(),
        _ => log.to_str().unwrap().to_string(),
    };
    let mut args = vec![case.cmd, &log_arg];
    if case.cmd == "replay" {
        args.extend(["--receiver", receiver.to_str().unwrap()]);
    }
    args.extend_from_slice(case.args);
    let out = match case.input {
        Input::Stdin => hal_sim_stdin(&args, &log_bytes),
        _ => hal_sim(&args),
    };
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    let lines: Vec<String> = stdout.lines().map(String::from).collect();
    let mut fails = Vec::new();
    if out.status.code() != Some(case.exit) {
        fails.push(format!(
            "exit {:?}, expected {}",
            out.status.code(),
            case.exit
        ));
    }
    for want in case.stderr {
        if !stderr.contains(want) {
            fails.push(format!("stderr lacks {want:?}"));
        }
    }
    for want in case.stdout {
        if !stdout.contains(want) {
            fails.push(format!("stdout lacks {want:?}"));
        }
    }
    let expected = (case.lines.0 * sim.pulses) as isize + case.lines.1;
    let replay = case.cmd == "replay";
    if replay && lines.len() as isize != expected {
        fails.push(format!("{} replay lines, expected {expected}", lines.len()));
    }
    if stderr.contains("panicked") || stdout.contains("null") {
        fails.push("a panic or a non-finite number".into());
    }
    if let Some(shift) = case.truth.filter(|_| replay) {
        match final_nees(&sim.truth, &lines, shift) {
            Some(nees) if nees <= NEES_3SIGMA => {}
            Some(nees) => fails.push(format!("truth outside 3σ at the end (NEES {nees:.2})")),
            None => fails.push("no estimate at the end".into()),
        }
    }
    if !fails.is_empty() {
        let head: String = stderr.lines().take(12).collect::<Vec<_>>().join("\n  ");
        fails.push(format!("stderr (first lines):\n  {head}"));
    }
    fails
}

#[test]
fn every_bad_input_gets_its_answer() {
    let sim = sim();
    let cases = cases();
    assert!(cases.len() >= 50, "{} cases", cases.len());
    let only = std::env::var("BAD_INPUT_CASE").ok();
    let mut failed = Vec::new();
    for (n, case) in cases.iter().enumerate() {
        if only.as_deref().is_some_and(|o| !case.name.contains(o)) {
            continue;
        }
        let fails = run(case, sim, n);
        if !fails.is_empty() {
            failed.push(format!("{}:\n  {}", case.name, fails.join("\n  ")));
        }
    }
    assert!(
        failed.is_empty(),
        "{} case(s) failed:\n{}",
        failed.len(),
        failed.join("\n")
    );
}
