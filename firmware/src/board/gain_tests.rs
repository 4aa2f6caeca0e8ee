//! Gain ranging on the board: a synthetic analog chain (one coil signal per channel,
//! clipping at the hardware's full scale) whose setting follows only what the board's
//! write closure accepted; every change becomes one `gain` record in the session log.

use super::*;
use crate::board::board_log::BoardLog;
use crate::board::sd_log::{RamCard, SdSink};
use crate::frontend::{Calibration, FrontendConfig, RangingConfig};
extern crate std;
use std::string::String;
use std::vec::Vec;

const FS: f64 = 8000.0;
const IF: f64 = 2000.0;
/// High-range coil gain, A/m per V (the reference board's 4 mA/m per V).
const GAIN: f64 = 4.0e-3;
const LOW_RATIO: f64 = 64.0;

fn frontend() -> Frontend {
    let cfg = FrontendConfig {
        calibration: Calibration {
            gain_a_per_m_per_v: [GAIN as f32; 3],
            offset_v: [0.0; 3],
            phase_rad: [0.0; 3],
            low_range_ratio: [LOW_RATIO as f32; 3],
            low_range_phase_rad: [0.0; 3],
        },
        range: Range::MOST_SENSITIVE,
        ranging: Some(RangingConfig::default()),
        ..FrontendConfig::default()
    };
    match Frontend::new(cfg) {
        Ok(fe) => fe,
        Err(e) => panic!("config refused: {e}"),
    }
}

/// Pulses of 80 ms every 0.95 s from 0.4 s, `h` A/m on each coil until `until_s`.
fn field(t: f64, h: f64, until_s: f64) -> f64 {
    let k = ((t - 0.4) / 0.95).floor();
    let start = 0.4 + k * 0.95;
    if t < 0.4 || t >= until_s || t - start >= 0.08 {
        return 0.0;
    }
    h * (2.0 * core::f64::consts::PI * IF * t).cos()
}

/// What a run saw: the events, the sample index each took effect at, the hardware's
/// setting at the end.
struct Run {
    events: Vec<(u64, GainEvent)>,
    hw: Range,
    fe: Frontend,
}

/// Feeds `dur_s` s of the chain; `accept(n)` says whether the `n`-th write succeeds.
/// The hardware's setting changes only on an accepted write (as the board's PGA).
fn run(h: f64, until_s: f64, dur_s: f64, accept: impl Fn(usize) -> bool) -> Run {
    let mut fe = frontend();
    let mut hw = fe.range();
    let mut events = Vec::new();
    let offset_us = 1_500_000;
    for k in 0..(dur_s * FS) as u64 {
        let t = k as f64 / FS;
        let ratio = match hw.if_range {
            IfRange::High => 1.0,
            IfRange::Low => LOW_RATIO,
        };
        let fs = f64::from(hw.full_scale_v());
        let volts = field(t, h, until_s) / (GAIN * ratio);
        let clipped = volts.abs() >= fs;
        let v = volts.clamp(-fs, fs) as f32;
        if let Err(e) = fe.push([v, 0.5 * v, -v], clipped) {
            panic!("sample refused: {e}");
        }
        let n = events.len();
        let e = apply_change(&mut fe, 0, FS as f32, offset_us, |c| {
            assert_eq!(c.from, hw, "a change starts from the hardware's setting");
            let ok = accept(n);
            if ok {
                hw = c.to;
            }
            ok
        });
        if let Some(e) = e {
            assert_eq!(
                fe.range(),
                hw,
                "the DSP calibrates for what the hardware measures"
            );
            assert_eq!(e.now_in(), hw);
            events.push((k + 1, e));
        }
    }
    Run { events, hw, fe }
}

#[test]
fn a_strong_beacon_ranges_down_and_each_change_is_stamped_at_its_first_sample() {
    // 0.05 A/m: 1300× the most sensitive full scale (3.75e-5 A/m at PGA 128).
    let r = run(0.05, 6.0, 6.0, |_| true);
    assert!(!r.events.is_empty(), "no change of setting");
    assert!(r.events.len() <= 6, "{} changes", r.events.len());
    assert_eq!(r.fe.stats().range_changes as usize, r.events.len());
    for (k, e) in &r.events {
        assert!(e.applied);
        // Sample k at 8 kSPS, plus the stalled time handed in.
        assert_eq!(e.t_us, k * 125 + 1_500_000);
    }
    let first = r.events[0].1;
    assert_eq!(first.change.from, Range::MOST_SENSITIVE);
    assert_eq!(first.change.reason, RangeReason::Saturated);
    // The last setting no longer clips: 0.05 A/m fits its full scale.
    let full_scale = f64::from(r.hw.full_scale_v())
        * GAIN
        * if r.hw.if_range == IfRange::Low {
            LOW_RATIO
        } else {
            1.0
        };
    assert!(full_scale > 0.05, "{:?}: {full_scale} A/m", r.hw);
}

#[test]
fn a_failed_write_keeps_the_hardware_and_the_dsp_on_the_old_setting() {
    // The first write fails, later ones succeed.
    let r = run(0.05, 6.0, 6.0, |n| n > 0);
    let (_, first) = r.events[0];
    assert!(!first.applied);
    assert_eq!(first.now_in(), Range::MOST_SENSITIVE);
    // The next pulse clips again and asks again, from the setting the hardware kept.
    let (_, second) = r.events[1];
    assert!(second.applied);
    assert_eq!(second.change.from, Range::MOST_SENSITIVE);
}

#[test]
fn nothing_pending_calls_no_write() {
    let mut fe = frontend();
    let mut called = false;
    let e = apply_change(&mut fe, 0, 8000.0, 0, |_| {
        called = true;
        true
    });
    assert_eq!(e, None);
    assert!(!called);
}

#[test]
fn every_change_is_one_gain_record_in_the_log() {
    // Strong pulses for 4 s, then silence: the setting goes down, then back up.
    let r = run(0.05, 4.0, 12.0, |n| n != 1);
    assert!(
        r.events
            .iter()
            .any(|(_, e)| e.change.reason == RangeReason::Weak)
    );
    let mut log: BoardLog<RamCard<'_>, String> =
        BoardLog::new(SdSink::new(None), Some(String::new()));
    for (_, e) in &r.events {
        log.gain(e);
    }
    let uart = log.uart().cloned().unwrap_or_default();
    let lines: Vec<&str> = uart.lines().collect();
    assert_eq!(lines.len(), r.events.len());
    for (seq, (line, (_, e))) in lines.iter().zip(&r.events).enumerate() {
        let c = e.change;
        let want = std::format!(
            r#"{{"type":"event","t":{},"kind":"gain","why":"{}","range":"{}","pga":{},"from_range":"{}","from_pga":{},"applied":{},"seq":{seq}}}"#,
            Instant::from_micros(e.t_us).secs_f64(),
            reason_word(c.reason),
            if_word(c.to.if_range),
            c.to.gain.factor(),
            if_word(c.from.if_range),
            c.from.gain.factor(),
            e.applied,
        );
        assert_eq!(*line, want);
    }
    // The failed write is in the log as such.
    assert!(lines[1].contains(r#""applied":false"#), "{}", lines[1]);
}
