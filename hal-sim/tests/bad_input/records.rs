//! Cases of the records: missing fields and wrong types, the magnetometer, sources, repeated
//! and lost records, headers.

use super::*;

/// The cases of this group.
pub(super) fn cases() -> Vec<Case> {
    vec![
        // --- missing fields, wrong types -------------------------------------------------------
        Case {
            name: "pulse without h",
            log: |l| {
                let i = middle(l, "pulse");
                let mut v = owned(l);
                v[i] = format!(r#"{{"type":"pulse","t":{}}}"#, t_of(&v[i]));
                joined(&v)
            },
            stderr: &["pulse record: missing field `h`"],
            lines: (1, -1),
            ..OK
        },
        Case {
            name: "IMU record without t",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let t = t_of(&v[i]);
                v[i] = v[i].replacen(&format!("\"t\":{t},"), "", 1);
                joined(&v)
            },
            stderr: &["imu record: missing field `t`"],
            ..OK
        },
        Case {
            name: "record without type",
            log: |l| {
                let i = middle(l, "imu");
                edit(l, i, "\"type\":\"imu\",", "")
            },
            stderr: &["record has no \"type\" key"],
            ..OK
        },
        Case {
            name: "h as a string",
            log: |l| {
                let i = middle(l, "pulse");
                let mut v = owned(l);
                v[i] = format!(r#"{{"type":"pulse","t":{},"h":"1e-6,0,0"}}"#, t_of(&v[i]));
                joined(&v)
            },
            stderr: &["pulse record: invalid type"],
            lines: (1, -1),
            ..OK
        },
        Case {
            name: "h with two components",
            log: |l| {
                let i = middle(l, "pulse");
                let mut v = owned(l);
                v[i] = format!(r#"{{"type":"pulse","t":{},"h":[1e-6,0]}}"#, t_of(&v[i]));
                joined(&v)
            },
            stderr: &["pulse record: invalid length 2"],
            lines: (1, -1),
            ..OK
        },
        Case {
            name: "t as a string",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let t = t_of(&v[i]);
                v[i] = v[i].replacen(&format!("\"t\":{t}"), &format!("\"t\":\"{t}\""), 1);
                joined(&v)
            },
            stderr: &["imu record: invalid type: string"],
            ..OK
        },
        // --- magnetometer ----------------------------------------------------------------------
        Case {
            name: "no magnetometer in the whole log",
            log: |l| map_mag(l, |_| None),
            ..OK
        },
        Case {
            name: "magnetometer saturated on one axis throughout",
            log: |l| {
                map_mag(l, |m| {
                    let v: Vec<f64> = serde_json::from_str(m).unwrap();
                    Some(format!("[4912,{},{}]", v[1], v[2]))
                })
            },
            stderr: &["magnetometer readings at full scale (sample kept without them)"],
            ..OK
        },
        Case {
            name: "magnetometer with two components",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let at = v[i].find("\"mag\":[").unwrap() + 7;
                v[i].insert_str(at, "1e-3],\"x\":[");
                joined(&v)
            },
            stderr: &["imu record: invalid length"],
            ..OK
        },
        // --- sources ---------------------------------------------------------------------------
        Case {
            name: "src 1000 (beyond a byte)",
            log: |l| with_src(l, "1000"),
            ..OK
        },
        Case {
            name: "src u32::MAX",
            log: |l| with_src(l, "4294967295"),
            ..OK
        },
        Case {
            name: "src beyond u32 (refused)",
            log: |l| with_src(l, "4294967296"),
            stderr: &["malformed line skipped"],
            lines: (0, 0),
            truth: None,
            ..OK
        },
        Case {
            name: "negative src (refused)",
            log: |l| with_src(l, "-1"),
            stderr: &["malformed line skipped"],
            lines: (0, 0),
            truth: None,
            ..OK
        },
        Case {
            name: "300 distinct sources",
            log: |l| {
                let mut k = 0;
                let v: Vec<String> = l
                    .iter()
                    .map(|x| {
                        if is_pulse(x) {
                            k += 1;
                            x.replacen('{', &format!("{{\"src\":{},", k * 7), 1)
                        } else {
                            x.clone()
                        }
                    })
                    .collect();
                joined(&v)
            },
            truth: None,
            ..OK
        },
        // --- repeated records, lost records, segments -------------------------------------------
        Case {
            name: "every pulse repeated 100 times",
            log: |l| repeat_pulses(l, 100),
            lines: (100, 0),
            stdout: &["\"status\":\"duplicate\""],
            stderr: &["repeated pulse records"],
            ..OK
        },
        Case {
            name: "seq gap (3 records lost)",
            log: |l| with_seq(l, |v| drop(v.drain(100..103))),
            stderr: &[
                "seq jumps from 99 to 103: 3 records lost",
                "1 gap(s), 3 record(s) lost",
            ],
            ..OK
        },
        Case {
            name: "seq goes back (records swapped)",
            log: |l| with_seq(l, |v| v.swap(100, 101)),
            stderr: &["seq goes back from 101 to 100"],
            ..OK
        },
        Case {
            name: "two captures concatenated (second header)",
            log: |l| [joined(l), joined(l)].concat(),
            lines: (2, 0),
            stderr: &["in 2 segment(s)"],
            ..OK
        },
        Case {
            name: "reboot mid-log: a header, then times restarting",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(&l[..i]);
                v.extend_from_slice(l);
                joined(&v)
            },
            lines: (1, 0),
            stderr: &["in 2 segment(s)"],
            ..OK
        },
        // --- headers ---------------------------------------------------------------------------
        Case {
            name: "empty file",
            log: |_| Vec::new(),
            stderr: &["no header"],
            ..FAIL
        },
        Case {
            name: "only blank lines",
            log: |_| b"\n\n\r\n".to_vec(),
            stderr: &["no header"],
            ..FAIL
        },
        Case {
            name: "header only",
            log: |l| joined(&l[..1]),
            lines: (0, 0),
            truth: None,
            ..OK
        },
        Case {
            name: "no header at all",
            log: |l| joined(&l[1..]),
            stderr: &["a record before the first header skipped", "no header"],
            ..FAIL
        },
        Case {
            name: "header of another format",
            log: |l| with_header(l, r#"{"type":"header","format":"csv","version":1}"#),
            stderr: &["line 1", "format is \"csv\", expected \"arva-session\""],
            ..FAIL
        },
        Case {
            name: "header version 2",
            log: |l| with_header(l, &HEADER.replace("\"version\":1", "\"version\":2")),
            stderr: &["unsupported version 2"],
            ..FAIL
        },
        Case {
            name: "header imu_hz 1e308",
            log: |l| with_header(l, &HEADER.replace("100.0", "1e308")),
            stderr: &["line 1: header: imu_hz = 1e308 is outside [1, 10000] Hz"],
            ..FAIL
        },
        Case {
            name: "header imu_hz 0",
            log: |l| with_header(l, &HEADER.replace("100.0", "0")),
            stderr: &["imu_hz = 0 is outside [1, 10000] Hz"],
            ..FAIL
        },
        Case {
            name: "header with a zero earth field",
            log: |l| with_header(l, &HEADER.replace("[21.8,0.0,-42.8]", "[0,0,0]")),
            stderr: &["|earth_field_uT| = 0 is outside [15, 80] µT"],
            ..FAIL
        },
        Case {
            name: "header without the optional keys (defaults)",
            log: |l| {
                with_header(
                    l,
                    r#"{"type":"header","format":"arva-session","version":1}"#,
                )
            },
            ..OK
        },
        Case {
            name: "a second header with an implausible rate",
            log: |l| {
                let mut b = joined(l);
                b.extend_from_slice(&with_header(l, &HEADER.replace("100.0", "-5")));
                b
            },
            stderr: &["header: imu_hz = -5 is outside [1, 10000] Hz"],
            exit: 1,
            ..OK
        },
    ]
}
