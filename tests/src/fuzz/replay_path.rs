//! Fuzz harnesses of the input side of `hal-sim replay`: `receiver.json` and the whole
//! replay path (reader, replay adapter, the firmware's application).
use super::Bytes;

// --- receiver_json ----------------------------------------------------------------------

/// The keys of `receiver.json` the structured mode of [`receiver_json`] fills, with the
/// order of magnitude of a plausible value.
const RECEIVER_KEYS: &[(&str, f32)] = &[
    ("m_min", 3e-3),
    ("m_max", 3e-2),
    ("m_nom", 1e-2),
    ("pulse_noise.sigma_bkg_A_per_m", 3e-9),
    ("pulse_noise.k_sen", 0.03),
    ("imu.hz", 100.0),
    ("imu.gyr_noise_rad_s", 5e-3),
    ("imu.gyr_bias_max_rad_s", 1e-2),
    ("imu.acc_noise_m_s2", 0.05),
    ("imu.mag_noise_uT", 0.3),
    ("receiver_height_m", 1.0),
    ("pdr.step_length_m", 0.7),
];

/// A JSON value decoded from fuzz bytes: mostly a number of magnitude `scale`, else
/// another kind (bool, string, array, null, object) to reach the type checks.
fn json_value(b: &mut Bytes, scale: f32) -> serde_json::Value {
    use serde_json::Value;
    match b.u8() % 10 {
        0 => Value::Bool(b.bool()),
        1 => Value::String("x".into()),
        2 => Value::Array(vec![json_value(b, scale), json_value(b, scale)]),
        3 => Value::Null,
        4 => Value::Object(serde_json::Map::new()),
        // Non-finite values cannot be written as JSON numbers: they become null.
        _ => {
            serde_json::Number::from_f64(f64::from(b.f32(scale))).map_or(Value::Null, Value::Number)
        }
    }
}

/// A `receiver.json` text from fuzz bytes: either the bytes themselves (first byte odd)
/// or an object of known keys with fuzzed values of fuzzed kinds.
fn receiver_text(b: &mut Bytes) -> String {
    use serde_json::{Map, Value};
    if b.bool() {
        let mut raw = Vec::new();
        while !b.is_empty() {
            raw.push(b.u8());
        }
        return String::from_utf8_lossy(&raw).into_owned();
    }
    let mut root = Map::new();
    for (key, scale) in RECEIVER_KEYS {
        if !b.bool() {
            continue;
        }
        let v = json_value(b, *scale);
        match key.split_once('.') {
            None => {
                root.insert((*key).into(), v);
            }
            Some((outer, inner)) => {
                let o = root
                    .entry(outer)
                    .or_insert_with(|| Value::Object(Map::new()));
                if let Value::Object(m) = o {
                    m.insert(inner.into(), v);
                }
            }
        }
    }
    if b.bool() {
        root.insert("sign_ambiguous".into(), json_value(b, 1.0));
    }
    if b.bool() {
        let (lo, hi) = (json_value(b, 1.0), json_value(b, 3.0));
        root.insert("victim_depth_range_m".into(), Value::Array(vec![lo, hi]));
    }
    Value::Object(root).to_string()
}

/// `hal_sim::io::receiver_config::ReceiverConfig::from_json` on arbitrary text (raw bytes, or
/// an object of the known keys with fuzzed values and kinds). Checks: no panic; an
/// accepted configuration validates, survives a write/read round trip, and the firmware's
/// pipeline accepts it (a configuration the checks let through must be runnable).
pub fn receiver_json(data: &[u8]) {
    use hal_sim::io::receiver_config::ReceiverConfig;
    let mut b = Bytes::new(data);
    let text = receiver_text(&mut b);
    let Ok(c) = ReceiverConfig::from_json(&text) else {
        return;
    };
    assert_eq!(c.validate(), Ok(()), "{text}");
    let back = ReceiverConfig::from_json(&c.to_json()).expect("re-reading what was written");
    assert_eq!(back, c, "{text}");
    let header = hal_sim::io::session::Header::new(100.0, [20.0, -1.0, -44.0], c.sign_ambiguous);
    if let Err(e) = hal_sim::io::sog_replay::SogReplay::new(&header, &c) {
        panic!("a validated receiver.json is refused by the firmware: {e}\n{text}");
    }
}

// --- replay -----------------------------------------------------------------------------

/// Size at which [`replay_log`] stops generating: 32 KiB ≈ 260 IMU records (2.6 s of log at
/// 100 Hz, more than the 2 s reorder window; the time-jump op adds seconds) and up to a
/// few dozen pulses. Without it a 4 KB input
/// expanded to up to 600 runs of 50 records (≈ 3 MB of text), and the run spent ≈ 80 % of
/// its time writing and parsing JSON (`perf`, 2026-11-28), ≈ 110 inputs/s. The reader
/// alone is fuzzed on arbitrary bytes by `session_log_reader`.
const MAX_LOG_BYTES: usize = 32 * 1024;

/// A session log from fuzz bytes: a header (fuzzed rate, earth field, sign flag), then a
/// stream of IMU runs (plausible, walking, with fuzzed perturbations, a saturated or absent
/// magnetometer), pulses (fuzzed field, time, source), repeated pulses, marks, `seq`
/// gaps, garbage, torn lines and second headers — text the reader must survive. At most
/// about [`MAX_LOG_BYTES`] (the op that crosses it is finished).
fn replay_log(b: &mut Bytes) -> Vec<u8> {
    use std::fmt::Write as _;
    fn num(x: f32) -> String {
        // JSON has no NaN or ∞: such values are written as out-of-range numbers.
        if x.is_finite() {
            format!("{x}")
        } else {
            "1e999".into()
        }
    }
    let header = |b: &mut Bytes| {
        let hz = if b.bool() { 100.0 } else { b.f32(100.0) };
        format!(
            r#"{{"type":"header","format":"arva-session","version":1,"imu_hz":{},"earth_field_uT":[20,-1,-44],"sign_ambiguous":{}}}"#,
            num(hz),
            b.u8() & 3 != 0
        )
    };
    let mut s = String::new();
    let _ = writeln!(s, "{}", header(b));
    let (mut t, mut seq) = (0.0f32, 0u64);
    let mut ops = 0;
    while !b.is_empty() && ops < 600 && s.len() < MAX_LOG_BYTES {
        ops += 1;
        let op = b.u8();
        let seq_text = if op & 0x20 != 0 {
            seq += 1 + u64::from(b.u8() % 4);
            format!(r#""seq":{seq},"#)
        } else {
            String::new()
        };
        match op % 16 {
            0..=7 => {
                let n = 1 + usize::from(b.u8() % 50);
                let da = b.vec3(1.0);
                let dg = b.vec3(0.2);
                let mag = match op & 0xC0 {
                    0x00 => String::new(),
                    0x40 => r#","mag":[5000,0,-44]"#.to_string(),
                    _ => r#","mag":[20,-1,-44]"#.to_string(),
                };
                for i in 0..n {
                    t += 0.01;
                    let w = ((i as f32) * 0.9).sin();
                    let _ = writeln!(
                        s,
                        r#"{{"type":"imu",{seq_text}"t":{},"acc":[{},{},{}],"gyr":[{},{},{}]{mag}}}"#,
                        num(t),
                        num(da.x * w),
                        num(da.y * w),
                        num(9.81 + da.z * w),
                        num(dg.x * w),
                        num(dg.y * w),
                        num(dg.z * w)
                    );
                }
            }
            8..=10 => {
                let h = b.vec3(1e-5);
                let tp = if op & 0x80 != 0 {
                    t + b.f32(1.0)
                } else {
                    t - 0.2
                };
                let src = if b.bool() {
                    format!(r#","src":{}"#, u64::from(b.u16()) * 70_000)
                } else {
                    String::new()
                };
                let line = format!(
                    r#"{{"type":"pulse",{seq_text}"t":{},"h":[{},{},{}]{src}}}"#,
                    num(tp),
                    num(h.x),
                    num(h.y),
                    num(h.z)
                );
                let copies = if op & 0x40 != 0 { 1 + b.u8() % 4 } else { 1 };
                for _ in 0..copies {
                    let _ = writeln!(s, "{line}");
                }
            }
            11 => {
                let _ = writeln!(
                    s,
                    r#"{{"type":"event",{seq_text}"t":{},"kind":"mark"}}"#,
                    num(t)
                );
            }
            12 => {
                // Garbage bytes, maybe without a newline before the next record.
                let n = usize::from(b.u8() % 24);
                for _ in 0..n {
                    s.push(char::from(b.u8() % 128));
                }
                if b.bool() {
                    s.push('\n');
                }
            }
            13 => {
                // A torn record: its first part only.
                let rec = format!(
                    r#"{{"type":"imu","t":{},"acc":[0,0,9.81],"gyr":[0,0,0]}}"#,
                    num(t)
                );
                let cut = usize::from(b.u8()) % rec.len();
                s.push_str(&rec[..cut]);
                s.push('\n');
            }
            14 => {
                s.push('\u{feff}');
                let _ = writeln!(s, "{}", header(b));
                t = b.f32(100.0).abs().min(1e6);
            }
            _ => {
                // Time jumps: a gap, or a damaged time stamp.
                t += b.f32(3.0);
                if !t.is_finite() {
                    t = 0.0;
                }
            }
        }
    }
    s.into_bytes()
}

/// The whole replay path — `hal_sim::io::session::Reader` + the replay adapter + the firmware's
/// application — on a fuzzed log (structured, see `replay_log`, or raw bytes after the
/// first byte when it is odd) with the default `receiver.json` or a fuzzed one. Checks: no
/// panic; exactly one output line per pulse answered; every line is valid replay JSON with
/// finite numbers (serde_json writes NaN as `null`, which fails to parse back as `f64`).
pub fn replay(data: &[u8]) {
    use hal_sim::io::receiver_config::ReceiverConfig;
    use hal_sim::io::replay::{ReplayLine, StreamOptions, replay_stream};
    let mut b = Bytes::new(data);
    let mode = b.u8();
    let receiver = if mode & 2 != 0 {
        ReceiverConfig::from_json(&receiver_text(&mut Bytes::new(&b.array::<24>())))
            .unwrap_or_default()
    } else {
        ReceiverConfig::default()
    };
    let log = if mode & 1 != 0 {
        let mut raw = Vec::new();
        while !b.is_empty() {
            raw.push(b.u8());
        }
        raw
    } else {
        replay_log(&mut b)
    };
    let opts = StreamOptions {
        strict: mode & 4 != 0,
        live: mode & 8 != 0,
    };
    let mut out = Vec::new();
    let Ok(summary) = replay_stream(log.as_slice(), &receiver, &mut out, opts, |_| {}, |_| {})
    else {
        return;
    };
    let text = String::from_utf8(out).expect("replay output is UTF-8");
    let mut n = 0u64;
    for line in text.lines() {
        let l: ReplayLine = serde_json::from_str(line)
            .unwrap_or_else(|e| panic!("replay line {line} does not parse back: {e}"));
        assert!(l.t.is_finite(), "{line}");
        n += 1;
    }
    assert_eq!(n, summary.lines);
    assert_eq!(
        summary.lines,
        summary.read.pulses + summary.late_pulses,
        "one line per pulse record: {summary}"
    );
}
