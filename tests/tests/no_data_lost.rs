//! No data lost (issue 10): the board writes every sample to the session log *before* the
//! estimator processes it (`firmware/src/bin/receiver.rs`, `firmware::session_log`), so a
//! crash of the estimator loses nothing already recorded, and a record torn by the crash
//! (or a power loss) mid-line is skipped on reading with a warning.
//!
//! The test runs a seeded search through that loop — write the record with the
//! firmware's writer to an unbuffered file, then give it to `app::Receiver` — and makes
//! the processing crash (a panic, caught with `catch_unwind`) at a seeded record. The log
//! read back with `hal_sim::io::session::read` must hold every record up to and including the
//! one being processed, value for value as the writer's `f32`s.
// Test code: a failed unwrap or a panic is a failed test, the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use firmware::Vec3;
use firmware::app::Receiver;
use firmware::session_log::{self, LogError};
use hal_sim::io::session::{Record, read_file};
use hal_sim::io::sog_replay::app_config;
use hal_sim::stamp;
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};
use std::io::Write as _;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// A UART-like sink: every `write_str` goes straight to the file (no buffer to lose);
/// optionally it dies after `budget` bytes, mid-record (power loss).
struct Uart {
    file: std::fs::File,
    budget: Option<usize>,
}

impl core::fmt::Write for Uart {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let n = self.budget.map_or(s.len(), |b| b.min(s.len()));
        self.file
            .write_all(&s.as_bytes()[..n])
            .map_err(|_| core::fmt::Error)?;
        if let Some(b) = self.budget.as_mut() {
            *b -= n;
            if n < s.len() {
                return Err(core::fmt::Error);
            }
        }
        Ok(())
    }
}

fn v(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// The value the log holds for a session value: what the firmware wrote (f32).
fn as_logged(r: &Record) -> Option<(f64, [f32; 3])> {
    match r {
        Record::Imu(x) => Some((x.t, v(&x.acc).into())),
        Record::Pulse(x) => Some((x.t, v(&x.h).into())),
        Record::Truth(_) => None,
    }
}

/// Runs the board's write-then-process loop over a seeded search into `path`; the
/// processing panics at record `crash_at`. Returns the records handed over.
fn run_until_crash(
    path: &std::path::Path,
    crash_at: usize,
    power_budget: Option<usize>,
) -> Vec<Record> {
    let sim = simulate(&ScenarioConfig::new(Preset::Paper, 5));
    let mut rx = Box::new(Receiver::new(app_config(&sim.session.header, &sim.receiver)).unwrap());
    let mut log = Uart {
        file: std::fs::File::create(path).unwrap(),
        budget: None,
    };
    let h = &sim.session.header;
    let earth = v(&h.earth_field_ut.unwrap());
    session_log::write_header(&mut log, h.imu_hz as f32, &earth, h.sign_ambiguous).unwrap();
    log.budget = power_budget;
    let records: Vec<Record> = sim.session.records.clone();
    let mut handed = Vec::new();
    let crashed = catch_unwind(AssertUnwindSafe(|| {
        for (k, r) in records.iter().enumerate() {
            // 1. Record (as the board does, before anything else touches the sample).
            let written = match r {
                Record::Imu(x) => session_log::write_imu(
                    &mut log,
                    x.t,
                    &v(&x.acc),
                    &v(&x.gyr),
                    x.mag.as_ref().map(v).as_ref(),
                ),
                Record::Pulse(x) => session_log::write_pulse(&mut log, x.t, &v(&x.h), None),
                Record::Truth(_) => continue,
            };
            handed.push(r.clone());
            if written == Err(LogError::Write) {
                panic!("power lost while writing record {k}");
            }
            // 2. Process: the estimator crashes at `crash_at`.
            assert!(k != crash_at, "estimator crash at record {k}");
            match r {
                Record::Imu(x) => {
                    let mag = x.mag.as_ref().map(v);
                    let _ = rx.on_imu(stamp(x.t), &v(&x.acc), &v(&x.gyr), mag.as_ref());
                }
                Record::Pulse(x) => {
                    let _ = rx.on_pulse(stamp(x.t), &v(&x.h), None);
                }
                Record::Truth(_) => {}
            }
        }
    }));
    assert!(crashed.is_err(), "the crash did not happen");
    handed
}

fn check_log(path: &std::path::Path, handed: &[Record], torn: bool) {
    let log = read_file(path).unwrap();
    let got: Vec<(f64, [f32; 3])> = log.records.iter().filter_map(as_logged).collect();
    let want: Vec<(f64, [f32; 3])> = handed.iter().filter_map(as_logged).collect();
    let expect = if torn {
        &want[..want.len() - 1]
    } else {
        &want[..]
    };
    assert_eq!(got.len(), expect.len(), "records in the log");
    for (g, w) in got.iter().zip(expect) {
        assert_eq!(g.1, w.1, "values at t = {}", w.0);
        assert!(
            (g.0 - w.0).abs() <= 1e-9 * w.0.abs().max(1.0),
            "{} vs {}",
            g.0,
            w.0
        );
    }
    let torn_warnings = log
        .warnings
        .iter()
        .filter(|w| w.message.contains("torn"))
        .count();
    assert_eq!(torn_warnings, usize::from(torn));
}

#[test]
fn an_estimator_crash_loses_no_recorded_sample() {
    let dir = tempdir();
    // A pulse record and an IMU record, early and late in the walk (seeded choices).
    for crash_at in [137, 2_503, 4_999] {
        let path = dir.join(format!("crash-{crash_at}.jsonl"));
        let handed = run_until_crash(&path, crash_at, None);
        assert_eq!(handed.len(), crash_at + 1, "records up to the crash");
        check_log(&path, &handed, false);
    }
}

#[test]
fn a_record_torn_by_a_power_loss_is_skipped_and_the_rest_kept() {
    let dir = tempdir();
    // The sink dies after 200,003 bytes: in the middle of some record.
    let path = dir.join("torn.jsonl");
    let handed = run_until_crash(&path, usize::MAX, Some(200_003));
    let bytes = std::fs::read(&path).unwrap();
    assert!(!bytes.ends_with(b"\n"), "the last record must be torn");
    check_log(&path, &handed, true);
}

fn tempdir() -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("no-data-lost-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}
