//! Cases of the log as lines: intact and reordered logs, encodings, torn lines and garbage,
//! numbers.

use super::*;

/// The cases of this group.
pub(super) fn cases() -> Vec<Case> {
    vec![
        // --- intact and reordered logs ---------------------------------------------------
        Case {
            name: "intact log",
            stderr: &["refused by the firmware: none"],
            ..OK
        },
        Case {
            name: "board order: pulses written 0.25 s late",
            log: |l| joined(&pulses_late(l, 0.25)),
            ..OK
        },
        Case {
            name: "pulses written 1.9 s late (inside the window)",
            log: |l| joined(&pulses_late(l, 1.9)),
            ..OK
        },
        Case {
            name: "one pulse written 3 s late (beyond the window)",
            log: |l| {
                let i = middle(l, "pulse");
                let t = t_of(&l[i]);
                let mut v = owned(l);
                let p = v.remove(i);
                let j = (i..v.len()).find(|&j| t_of(&v[j]) > t + 3.0).unwrap();
                v.insert(j, p);
                joined(&v)
            },
            stderr: &["is more than 2 s earlier", "answered as \"late\""],
            stdout: &["\"status\":\"late\""],
            ..OK
        },
        Case {
            name: "live mode on standard input",
            input: Input::Stdin,
            ..OK
        },
        Case {
            name: "live mode, board order (no window: late pulses processed as they come)",
            input: Input::Stdin,
            log: |l| joined(&pulses_late(l, 0.25)),
            truth: None,
            ..OK
        },
        Case {
            name: "times as Unix seconds (t ≈ 1.8e9)",
            log: |l| shift_t(l, 1.8e9),
            truth: Some(1.8e9),
            ..OK
        },
        Case {
            name: "negative times",
            log: |l| shift_t(l, -1000.0),
            truth: Some(-1000.0),
            ..OK
        },
        Case {
            name: "CRLF line ends and blank lines",
            log: |l| {
                let mut s = l.join("\r\n\r\n");
                s.push_str("\r\n");
                s.into_bytes()
            },
            ..OK
        },
        Case {
            name: "no newline after the last record",
            log: |l| l.join("\n").into_bytes(),
            ..OK
        },
        Case {
            name: "unknown record types and keys",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                v.insert(i, r#"{"type":"note","t":1.0,"text":"x"}"#.into());
                v[1] = v[1].replacen('{', "{\"future\":[1,{}],", 1);
                joined(&v)
            },
            stderr: &["unknown record type \"note\" skipped", "1 of unknown type"],
            ..OK
        },
        Case {
            name: "events: mark, withheld, unknown kind",
            log: |l| {
                let i = middle(l, "imu");
                let t = t_of(&l[i]);
                let mut v = owned(l);
                v.insert(i, format!(r#"{{"type":"event","t":{t},"kind":"mark"}}"#));
                v.insert(
                    i,
                    format!(r#"{{"type":"event","t":{t},"kind":"withheld","why":"saturated"}}"#),
                );
                v.insert(
                    i,
                    format!(r#"{{"type":"event","t":{t},"kind":"gain","stage":2}}"#),
                );
                joined(&v)
            },
            stderr: &["3 event"],
            ..OK
        },
        // --- encoding ----------------------------------------------------------------------
        Case {
            name: "UTF-8 byte-order mark at the start",
            log: |l| [b"\xEF\xBB\xBF".as_slice(), &joined(l)].concat(),
            ..OK
        },
        Case {
            name: "byte-order mark in the middle (appended log)",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                v[i] = format!("\u{feff}{}", v[i]);
                joined(&v)
            },
            ..OK
        },
        Case {
            name: "a line that is not UTF-8",
            log: |l| {
                let i = middle(l, "imu");
                let mut b = joined(&l[..i]);
                b.extend_from_slice(b"{\"type\":\"imu\",\xff\xfe}\n");
                b.extend_from_slice(&joined(&l[i..]));
                b
            },
            stderr: &["not UTF-8", "1 malformed"],
            ..OK
        },
        Case {
            name: "UTF-16 text",
            log: |l| {
                let s = String::from_utf8(joined(l)).unwrap();
                s.encode_utf16().flat_map(|u| u.to_le_bytes()).collect()
            },
            exit: 1,
            stderr: &["no header"],
            ..FAIL
        },
        // --- torn lines and garbage ----------------------------------------------------------
        Case {
            name: "torn IMU line in the middle",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let n = v[i].len() / 2;
                v[i].truncate(n);
                joined(&v)
            },
            stderr: &["malformed line skipped", "1 malformed"],
            ..OK
        },
        Case {
            name: "torn pulse line in the middle",
            log: |l| {
                let i = middle(l, "pulse");
                let mut v = owned(l);
                let n = v[i].len() / 2;
                v[i].truncate(n);
                joined(&v)
            },
            stderr: &["malformed line skipped"],
            lines: (1, -1),
            ..OK
        },
        Case {
            name: "torn record followed by a whole one on the same line (power loss)",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let torn = v[i - 1][..v[i - 1].len() / 3].to_string();
                v[i] = format!("{torn}{}", v[i]);
                joined(&v)
            },
            stderr: &["a record found after", "1 resynchronized"],
            ..OK
        },
        Case {
            name: "torn last line without newline",
            log: |l| {
                let mut b = joined(l);
                b.extend_from_slice(br#"{"type":"imu","t":99.0,"acc":[0,0"#);
                b
            },
            stderr: &["torn last line"],
            ..OK
        },
        Case {
            name: "block of binary garbage",
            log: |l| {
                let i = middle(l, "imu");
                let mut b = joined(&l[..i]);
                b.extend((0u32..3000).map(|k| (k.wrapping_mul(2_654_435_761) >> 13) as u8));
                b.push(b'\n');
                b.extend_from_slice(&joined(&l[i..]));
                b
            },
            stderr: &["malformed"],
            ..OK
        },
        Case {
            name: "lines of ASCII garbage",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                for g in [
                    "garbage{{{\"",
                    "]]]",
                    "null",
                    "42",
                    "\"imu\"",
                    "{}",
                    "[{\"type\":\"imu\"}]",
                ] {
                    v.insert(i, g.into());
                }
                joined(&v)
            },
            stderr: &["7 malformed"],
            ..OK
        },
        Case {
            name: "garbage before the header",
            log: |l| insert(l, 0, "AT+OK\u{7}noise"),
            stderr: &["malformed"],
            ..OK
        },
        Case {
            name: "records before the header",
            log: |l| {
                let mut v = owned(l);
                v.swap(0, 1);
                joined(&v)
            },
            stderr: &["a record before the first header skipped"],
            ..OK
        },
        Case {
            name: "a line over 1 MiB",
            log: |l| {
                let i = middle(l, "imu");
                insert(
                    l,
                    i,
                    &format!("{{\"type\":\"note\",\"x\":\"{}\"}}", "a".repeat(1 << 21)),
                )
            },
            stderr: &["longer than 1048576 bytes refused", "1 over 1048576 bytes"],
            ..OK
        },
        Case {
            name: "a last line over 1 MiB without newline",
            log: |l| {
                let mut b = joined(l);
                b.extend(std::iter::repeat_n(b'7', 3 << 20));
                b
            },
            stderr: &["longer than 1048576 bytes refused"],
            ..OK
        },
        Case {
            name: "strict mode: a torn line stops the replay",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                v[i].truncate(10);
                joined(&v)
            },
            args: &["--strict"],
            stderr: &["malformed line skipped"],
            ..FAIL
        },
        Case {
            name: "strict mode on an intact log",
            args: &["--strict"],
            ..OK
        },
        // --- numbers -------------------------------------------------------------------------
        Case {
            name: "NaN as a number",
            log: |l| {
                let i = middle(l, "imu");
                edit(l, i, "\"acc\":[", "\"acc\":[NaN,")
            },
            stderr: &["malformed line skipped"],
            ..OK
        },
        Case {
            name: "infinity as an out-of-range number (1e999)",
            log: |l| {
                let i = middle(l, "pulse");
                edit(l, i, "\"h\":[", "\"h\":[1e999,")
            },
            stderr: &["number out of range"],
            lines: (1, -1),
            ..OK
        },
        Case {
            name: "a pulse field beyond f32 (1e300 A/m)",
            log: |l| {
                let i = middle(l, "pulse");
                set_first(l, i, "h", "1e300")
            },
            stderr: &["1 pulses (non-finite or refused by the estimator)"],
            stdout: &["\"status\":\"refused\""],
            ..OK
        },
        Case {
            name: "an IMU sample beyond f32 (1e300 m/s²)",
            log: |l| {
                let i = middle(l, "imu");
                set_first(l, i, "acc", "1e300")
            },
            stderr: &["1 IMU samples (implausible or out of order)"],
            ..OK
        },
        Case {
            name: "a zero pulse field",
            log: |l| {
                let i = middle(l, "pulse");
                let mut v = owned(l);
                let t = t_of(&v[i]);
                v[i] = format!(r#"{{"type":"pulse","t":{t},"h":[0,0,0]}}"#);
                joined(&v)
            },
            ..OK
        },
        Case {
            name: "a time stamp damaged far ahead (t + 1e6 s)",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                let t = t_of(&v[i]);
                v[i] = v[i].replacen(&format!("\"t\":{t}"), &format!("\"t\":{}", t + 1e6), 1);
                joined(&v)
            },
            stderr: &["jumps ahead of the records around it"],
            ..OK
        },
        Case {
            name: "repeated IMU records (same t twice)",
            log: |l| {
                let mut v = Vec::new();
                for x in l {
                    v.push(x.clone());
                    if x.contains("\"type\":\"imu\"") {
                        v.push(x.clone());
                    }
                }
                joined(&v)
            },
            ..OK
        },
    ]
}
