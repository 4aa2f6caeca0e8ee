//! The `hal-sim` binary end to end.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use common::{hal_sim, simulate_into, text};

#[test]
fn simulate_inspect_replay() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    simulate_into(&a, "5");
    simulate_into(&b, "5");
    for f in [
        "session.jsonl",
        "truth.jsonl",
        "receiver.json",
        "scenario.json",
    ] {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(
            !x.is_empty() && x == y,
            "{f} differs between identical runs"
        );
    }
    let log = a.join("session.jsonl");
    let out = hal_sim(&["inspect", log.to_str().unwrap()]);
    assert!(out.status.success());
    let summary = text(&out.stdout);
    assert!(
        summary.contains("duration: 40.00 s") && summary.contains("measured 100.000 Hz"),
        "{summary}"
    );
    assert!(summary.contains("imu gaps (> 1.5 periods): 0"), "{summary}");

    let receiver = a.join("receiver.json");
    let out = hal_sim(&[
        "replay",
        log.to_str().unwrap(),
        "--receiver",
        receiver.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let session = hal_sim::io::session::read_file(&log).unwrap();
    let lines: Vec<String> = text(&out.stdout).lines().map(String::from).collect();
    assert_eq!(lines.len(), session.pulses().count());
    let mut initialized = false;
    for (line, pulse) in lines.iter().zip(session.pulses()) {
        let v: hal_sim::io::replay::ReplayLine = serde_json::from_str(line).unwrap();
        assert_eq!(v.t, pulse.t);
        // Once the estimator holds a belief it reports one victim on every later pulse.
        assert!(v.victims.len() <= 1);
        assert!(
            !initialized || v.victims.len() == 1,
            "estimate lost at t = {}",
            v.t
        );
        initialized |= !v.victims.is_empty();
        assert_eq!(v.n_components == 0, v.victims.is_empty());
    }
    assert!(initialized, "the estimator never initialized");
}

#[test]
fn a_malformed_line_is_reported_and_skipped_or_stops_strict_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("bad.jsonl");
    std::fs::write(
        &log,
        concat!(
            r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100.0,"sign_ambiguous":true}"#,
            "\n",
            r#"{"type":"imu","t":0.0,"acc":[0,0,9.8],"gyr":[0,0,0],"mag":[20,0,-40]}"#,
            "\n",
            r#"{"type":"note","t":0.0,"text":"unknown types are skipped"}"#,
            "\n",
            r#"{"type":"pulse","t":0.5,"h":[1e-6,2e-6]}"#,
            "\n",
            r#"{"type":"pulse","t":0.6,"h":[1e-6,2e-6,0]}"#,
            "\n",
        ),
    )
    .unwrap();
    for cmd in ["replay", "inspect"] {
        let out = hal_sim(&[cmd, log.to_str().unwrap()]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let err = text(&out.stderr);
        assert!(err.contains("line 4:") && err.contains("line 3:"), "{err}");
    }
    let out = hal_sim(&["replay", log.to_str().unwrap()]);
    assert_eq!(
        text(&out.stdout).lines().count(),
        1,
        "the intact pulse answered"
    );
    let err = text(&out.stderr);
    assert!(
        err.contains("replay summary: 5 lines read") && err.contains("1 malformed"),
        "{err}"
    );
    let out = hal_sim(&["replay", "--strict", log.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("line 4:"));
    assert!(out.stdout.is_empty());
    let out = hal_sim(&[
        "inspect",
        tmp.path().join("missing.jsonl").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
}

#[test]
fn help_explains_the_options() {
    let out = hal_sim(&["simulate", "--help"]);
    assert!(out.status.success());
    let help = text(&out.stdout);
    for word in [
        "--preset",
        "--seed",
        "--count",
        "--sigma-bkg",
        "flux-line",
        "zigzag",
    ] {
        assert!(help.contains(word), "{word} missing from:\n{help}");
    }
    let out = hal_sim(&["--help"]);
    for word in ["simulate", "replay", "inspect", "field-map"] {
        assert!(text(&out.stdout).contains(word));
    }
}

/// The seeded reports share one vocabulary: `--tries` (at least 1) and `--first-seed`.
const SEEDED_REPORTS: [&str; 7] = [
    "accuracy",
    "rescue-report",
    "multi-report",
    "classic-report",
    "baselines-report",
    "sensing-report",
    "consistency",
];

#[test]
fn every_seeded_report_takes_tries_and_first_seed_and_refuses_zero_tries() {
    for cmd in SEEDED_REPORTS {
        let out = hal_sim(&[cmd, "--help"]);
        assert!(out.status.success(), "{cmd} --help");
        let help = text(&out.stdout);
        for flag in ["--tries", "--first-seed", "--out"] {
            assert!(help.contains(flag), "{cmd}: {flag} missing from\n{help}");
        }
        let out = hal_sim(&[cmd, "--tries", "0"]);
        assert_eq!(out.status.code(), Some(2), "{cmd} --tries 0 was accepted");
        let err = text(&out.stderr);
        assert!(err.contains("--tries") && err.contains("0"), "{cmd}: {err}");
    }
}

#[test]
fn help_is_wrapped_and_has_no_rustdoc_links() {
    let out = hal_sim(&["--help"]);
    let top = text(&out.stdout);
    let mut commands: Vec<String> = top
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .filter(|c| c != "help")
        .collect();
    assert!(commands.len() > 10, "{top}");
    commands.push(String::new());
    for cmd in &commands {
        for flag in ["-h", "--help"] {
            let args: Vec<&str> = [cmd.as_str(), flag]
                .into_iter()
                .filter(|a| !a.is_empty())
                .collect();
            let out = hal_sim(&args);
            assert!(out.status.success(), "{args:?}");
            let help = text(&out.stdout);
            for line in help.lines() {
                assert!(
                    line.chars().count() <= 100,
                    "{args:?}: a help line over 100 columns:\n{line}"
                );
                assert!(
                    !line.contains("[`") && !line.contains("`]"),
                    "{args:?}: a rustdoc link in the help:\n{line}"
                );
            }
        }
    }
}
