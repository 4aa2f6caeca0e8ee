use super::*;

const LOG: &str = r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100.0,"earth_field_uT":[21.0,0.0,-42.0],"sign_ambiguous":true}
{"type":"imu","t":12.34,"acc":[0.1,-0.2,9.9],"gyr":[0.01,0.0,-0.02],"mag":[20.5,1.0,-41.7]}
{"type":"pulse","t":12.5,"h":[1.2e-6,-3.4e-7,8.0e-8],"src":0}
{"type":"truth","t":12.5,"p":[3.0,-1.0,1.0],"rpy":[0.02,-0.1,1.3],"victims":[{"p":[40.0,12.0,-1.5],"m":[0.0,0.5,0.1]}]}
"#;

#[test]
fn reads_the_spec_examples() {
    let s = read(LOG.as_bytes()).unwrap();
    assert_eq!(s.header.earth_field_ut, Some([21.0, 0.0, -42.0]));
    assert_eq!(s.records.len(), 3);
    assert_eq!(s.pulses().next().unwrap().src, Some(0));
    assert_eq!(s.truth().next().unwrap().victims[0].p[2], -1.5);
    assert!(s.warnings.is_empty());
}

#[test]
fn unknown_keys_ignored_unknown_types_warned() {
    let log = format!(
        "{}{}\n{}\n",
        LOG,
        r#"{"type":"battery","t":13.0,"volts":3.7}"#,
        r#"{"type":"imu","t":13.0,"acc":[0,0,9.8],"gyr":[0,0,0],"extra":{"a":[1,2]}}"#
    );
    let s = read(log.as_bytes()).unwrap();
    assert_eq!(s.records.len(), 4);
    assert_eq!(s.warnings.len(), 1);
    assert_eq!(s.warnings[0].line, 5);
}

#[test]
fn a_torn_last_line_is_skipped_with_a_warning() {
    let whole = read(LOG.as_bytes()).unwrap();
    for torn in [
        "{\"type\":\"imu\",\"t\":1",
        "{",
        "{\"type\":\"pulse\",\"t\":20.0,\"h\":[1e-6,",
    ] {
        let s = read(format!("{LOG}{torn}").as_bytes()).unwrap();
        assert_eq!(s.records, whole.records);
        assert_eq!(s.warnings.len(), whole.warnings.len() + 1);
        assert!(s.warnings.last().unwrap().message.contains("torn"));
    }
}

/// Every item a lenient reader hands on, with the warnings and the stats.
fn read_all(text: &[u8], opts: ReadOptions) -> (Vec<(usize, Item)>, Vec<Warning>, ReadStats) {
    let mut r = Reader::new(text, opts);
    let mut items = Vec::new();
    let mut warnings = Vec::new();
    while let Some(x) = r.next_item().unwrap() {
        items.push(x);
        warnings.extend(r.take_warnings());
    }
    warnings.extend(r.take_warnings());
    (items, warnings, *r.stats())
}

fn times(items: &[(usize, Item)]) -> Vec<f64> {
    items
        .iter()
        .filter_map(|(_, i)| match i {
            Item::Record(r) => Some(r.t()),
            Item::Event(e) => Some(e.t),
            _ => None,
        })
        .collect()
}

const HEADER: &str = r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100.0,"earth_field_uT":[21.0,0.0,-42.0],"sign_ambiguous":true}"#;

fn imu(t: f64) -> String {
    format!(r#"{{"type":"imu","t":{t},"acc":[0,0,9.8],"gyr":[0,0,0]}}"#)
}

fn pulse(t: f64) -> String {
    format!(r#"{{"type":"pulse","t":{t},"h":[1e-6,0,0]}}"#)
}

#[test]
fn malformed_lines_are_reported_by_number_and_skipped() {
    let bad = [
        "{\"type\":\"imu\",\"t\":1".to_string(),
        "{\"type\":\"pulse\",\"t\":20.0}".to_string(),
        "{\"t\":20.0}".to_string(),
        "[1,2]".to_string(),
        "\u{0}\u{ff}".to_string(),
        "garbage garbage".to_string(),
    ];
    for b in &bad {
        let text = format!("{LOG}{b}\n{}\n", imu(13.0));
        let s = read(text.as_bytes()).unwrap();
        assert_eq!(s.records.len(), 4, "{b}: the record after it is kept");
        assert_eq!(s.warnings.len(), 1, "{b}");
        assert_eq!(s.warnings[0].line, 5, "{b}");
        // Strict mode stops there instead.
        let mut r = Reader::new(
            text.as_bytes(),
            ReadOptions {
                strict: true,
                ..ReadOptions::default()
            },
        );
        let err = loop {
            match r.next_item() {
                Ok(Some(_)) => {}
                Ok(None) => panic!("{b}: strict mode read to the end"),
                Err(e) => break e,
            }
        };
        assert!(
            matches!(err, SessionError::Line { line: 5, .. }),
            "{b}: {err}"
        );
    }
    // Bytes that are not UTF-8.
    let mut text = LOG.as_bytes().to_vec();
    text.extend_from_slice(&[0xff, 0xfe, b'\n']);
    text.extend_from_slice(imu(13.0).as_bytes());
    let (_, w, st) = read_all(&text, ReadOptions::default());
    assert_eq!((w.len(), w[0].line, st.malformed, st.imu), (1, 5, 1, 2));
    // What no reader can replay is an error.
    for (text, line) in [
        (
            "{\"type\":\"header\",\"format\":\"arva-session\",\"version\":2}\n".to_string(),
            1,
        ),
        (
            "\n\n{\"type\":\"header\",\"format\":\"x\",\"version\":1}\n".to_string(),
            3,
        ),
    ] {
        match read(text.as_bytes()) {
            Err(SessionError::Line { line: l, message }) => {
                assert_eq!(l, line, "{message}");
                assert!(message.starts_with("header: "), "{message}");
            }
            other => panic!("expected a line error, got {other:?}"),
        }
    }
    assert!(matches!(read(&b""[..]), Err(SessionError::Empty)));
    // Records without any header: skipped, and then no header at all.
    let (r, st) = {
        let text = format!("{}\n{}\n", imu(1.0), pulse(1.0));
        let mut r = Reader::new(text.as_bytes(), ReadOptions::default());
        let r2 = r.next_item();
        (r2.map(|x| x.is_some()), *r.stats())
    };
    assert!(matches!(r, Err(SessionError::Empty)));
    assert_eq!(st.before_header, 2);
}

#[test]
fn a_byte_order_mark_is_ignored() {
    let mut text = b"\xEF\xBB\xBF".to_vec();
    text.extend_from_slice(LOG.as_bytes());
    let s = read(&text[..]).unwrap();
    assert_eq!(s, read(LOG.as_bytes()).unwrap());
    // A log appended to another may bring its own mark: a new segment all the same.
    let mut two = text.clone();
    two.extend_from_slice(&text);
    let (items, w, st) = read_all(&two, ReadOptions::default());
    assert!(w.is_empty(), "{w:?}");
    assert_eq!((st.segments, st.imu, st.pulses, st.truth), (2, 2, 2, 2));
    assert_eq!(items.len(), 8);
}

#[test]
fn a_line_over_one_mib_is_refused_without_being_kept() {
    let long = format!(
        r#"{{"type":"imu","t":13.0,"acc":[0,0,9.8],"gyr":[0,0,0],"pad":"{}"}}"#,
        "x".repeat(MAX_LINE_BYTES)
    );
    let text = format!("{LOG}{long}\n{}\n", imu(13.5));
    let mut r = Reader::new(text.as_bytes(), ReadOptions::default());
    let mut n = 0;
    while r.next_item().unwrap().is_some() {
        n += 1;
        assert!(r.buf.capacity() <= 2 * MAX_LINE_BYTES);
    }
    let st = *r.stats();
    let w = r.take_warnings();
    assert_eq!((n, st.too_long, st.imu), (5, 1, 2));
    assert_eq!(w.len(), 1);
    assert_eq!(w[0].line, 5);
    assert!(w[0].message.contains("longer than"), "{}", w[0].message);
    // A line just under the limit is read.
    let pad = MAX_LINE_BYTES - imu(13.0).len() - 20;
    let fits = format!(
        r#"{{"type":"imu","t":13.0,"acc":[0,0,9.8],"gyr":[0,0,0],"p":"{}"}}"#,
        "x".repeat(pad)
    );
    assert!(fits.len() <= MAX_LINE_BYTES);
    let s = read(format!("{LOG}{fits}\n").as_bytes()).unwrap();
    assert_eq!((s.records.len(), s.warnings.len()), (4, 0));
}

#[test]
fn a_second_header_starts_a_new_segment() {
    let text = format!(
        "{HEADER}\n{}\n{}\n{}\n{HEADER}\n{}\n{}\n",
        imu(100.0),
        pulse(100.1),
        imu(100.2),
        imu(0.5),
        pulse(0.6)
    );
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert!(w.is_empty(), "{w:?}");
    assert_eq!(st.segments, 2);
    let headers: Vec<usize> = items
        .iter()
        .filter(|(_, i)| matches!(i, Item::Header(_)))
        .map(|(l, _)| *l)
        .collect();
    assert_eq!(headers, [1, 5]);
    // Time restarts: nothing of the second segment is late.
    assert_eq!(times(&items), [100.0, 100.1, 100.2, 0.5, 0.6]);
    // The whole-log reader does not join segments.
    assert!(matches!(
        read(text.as_bytes()),
        Err(SessionError::Line { line: 5, .. })
    ));
}

#[test]
fn seq_gaps_are_reported() {
    let text = format!(
        "{}\n{}\n{}\n{}\n{}\n",
        HEADER.replace("\"type\"", "\"seq\":0,\"type\""),
        imu(1.0).replace("\"type\"", "\"seq\":1,\"type\""),
        imu(1.01).replace("\"type\"", "\"seq\":5,\"type\""),
        imu(1.02).replace("\"type\"", "\"seq\":6,\"type\""),
        imu(1.03).replace("\"type\"", "\"seq\":2,\"type\""),
    );
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!(times(&items).len(), 4, "records are kept");
    assert_eq!((st.seq_gaps, st.seq_lost), (2, 3));
    assert_eq!(w.len(), 2);
    assert_eq!(w[0].line, 3);
    assert!(w[0].message.contains("3 records lost"), "{}", w[0].message);
    assert_eq!(w[1].line, 5);
    assert!(w[1].message.contains("goes back"), "{}", w[1].message);
}

#[test]
fn late_pulses_within_the_window_are_put_in_order() {
    // The board's order: a pulse written when it has ended, after IMU samples up to
    // 0.3 s later than its centre.
    let mut text = format!("{HEADER}\n");
    for k in 0..400 {
        let t = f64::from(k) * 0.01;
        text.push_str(&imu(t));
        text.push('\n');
        if k % 100 == 30 && k > 30 {
            text.push_str(&pulse(t - 0.3));
            text.push('\n');
        }
    }
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert!(w.is_empty(), "{w:?}");
    assert_eq!((st.imu, st.pulses, st.late), (400, 3, 0));
    let t = times(&items);
    assert!(t.windows(2).all(|p| p[0] <= p[1]), "in t order");
    // A pulse at the time of an IMU sample comes after it (file order for ties).
    let i = items
        .iter()
        .position(|(_, i)| matches!(i, Item::Record(Record::Pulse(_))))
        .unwrap();
    assert!(matches!(&items[i - 1].1, Item::Record(Record::Imu(x)) if x.t == 1.0));
    // Without a window (live input) the file order is kept.
    let (items, _, _) = read_all(
        text.as_bytes(),
        ReadOptions {
            window_s: 0.0,
            ..ReadOptions::default()
        },
    );
    assert!(!times(&items).windows(2).all(|p| p[0] <= p[1]));
}

#[test]
fn records_later_than_the_window_are_reported_and_skipped() {
    let text = format!(
        "{HEADER}\n{}\n{}\n{}\n{}\n{}\n{}\n",
        imu(10.0),
        imu(11.0),
        imu(12.5),
        pulse(10.1),
        imu(10.2),
        imu(12.6)
    );
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!(times(&items), [10.0, 11.0, 12.5, 12.6]);
    assert_eq!(st.late, 2);
    assert_eq!(w.iter().map(|w| w.line).collect::<Vec<_>>(), [5, 6]);
    // The late pulse is still handed on, to be answered.
    assert!(
        items
            .iter()
            .any(|(l, i)| *l == 5 && matches!(i, Item::Late(p) if p.t == 10.1))
    );
}

#[test]
fn one_record_jumping_ahead_does_not_lose_the_rest() {
    // "t":11.34 with its '.' dropped reads 1134.
    let text = format!(
        "{HEADER}\n{}\n{}\n{}\n{}\n",
        imu(11.33),
        imu(1134.0),
        imu(11.35),
        imu(11.36)
    );
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!(times(&items), [11.33, 11.35, 11.36]);
    assert_eq!((st.late, w.len(), w[0].line), (1, 1, 3));
    // A real gap is kept: the next record confirms it.
    let text = format!("{HEADER}\n{}\n{}\n{}\n", imu(1.0), imu(30.0), imu(30.01));
    let (items, w, _) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!((times(&items), w.len()), (vec![1.0, 30.0, 30.01], 0));
    // And so is a gap at the very end.
    let text = format!("{HEADER}\n{}\n{}\n", imu(1.0), imu(30.0));
    let (items, _, _) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!(times(&items), [1.0, 30.0]);
}

#[test]
fn a_torn_record_glued_to_the_next_is_resynchronized() {
    // Power loss mid-line, then the restarted writer's header on the same line.
    let text = format!(
        "{HEADER}\n{}\n{{\"type\":\"imu\",\"t\":1.0,\"acc\":[0,{HEADER}\n{}\n",
        imu(0.99),
        imu(0.01)
    );
    let (items, w, st) = read_all(text.as_bytes(), ReadOptions::default());
    assert_eq!((st.segments, st.malformed, st.resynchronized), (2, 1, 1));
    assert_eq!(times(&items), [0.99, 0.01]);
    assert_eq!(w[0].line, 3);
}

#[test]
fn memory_stays_bounded_on_a_long_log() {
    // An hour at 100 Hz with a late pulse a second: the window never holds more than
    // its 2 s of records.
    struct Gen {
        k: u64,
        line: Vec<u8>,
        pos: usize,
    }
    impl std::io::Read for Gen {
        fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
            if self.pos == self.line.len() {
                if self.k == 360_000 {
                    return Ok(0);
                }
                let t = self.k as f64 * 0.01;
                self.line = if self.k == 0 {
                    format!("{HEADER}\n")
                } else if self.k % 100 == 50 {
                    format!("{}\n{}\n", imu(t), pulse(t - 0.2))
                } else {
                    format!("{}\n", imu(t))
                }
                .into_bytes();
                self.pos = 0;
                self.k += 1;
            }
            let n = out.len().min(self.line.len() - self.pos);
            out[..n].copy_from_slice(&self.line[self.pos..self.pos + n]);
            self.pos += n;
            Ok(n)
        }
    }
    let source = Gen {
        k: 0,
        line: Vec::new(),
        pos: 0,
    };
    let mut r = Reader::new(std::io::BufReader::new(source), ReadOptions::default());
    let mut most = 0;
    while r.next_item().unwrap().is_some() {
        most = most.max(r.window.len() + r.out.len());
    }
    assert!(most <= 210, "{most} records held");
    assert_eq!(r.stats().pulses, 3600);
    assert!(r.take_warnings().is_empty());
}

#[test]
fn events_are_read_in_order_and_written_back() {
    let text = format!(
        "{HEADER}\n{}\n{}\n{}\n",
        imu(1.0),
        r#"{"type":"event","t":1.005,"kind":"mark","seq":3,"note":"x"}"#,
        imu(1.01)
    );
    let s = read(text.as_bytes()).unwrap();
    assert_eq!(s.events.len(), 1);
    assert_eq!(s.events[0].kind, "mark");
    assert_eq!(s.events[0].extra.get("note"), Some(&serde_json::json!("x")));
    assert!(!s.events[0].extra.contains_key("type"));
    let mut out = Vec::new();
    s.write(&mut out).unwrap();
    let again = read(&out[..]).unwrap();
    assert_eq!(again.events, s.events);
    let lines: Vec<&str> = std::str::from_utf8(&out).unwrap().lines().collect();
    assert!(lines[2].contains("\"kind\":\"mark\""), "{}", lines[2]);
}

#[test]
fn implausible_headers_are_refused_by_key_and_range() {
    for (h, key) in [
        (HEADER.replace("100.0", "1e308"), "imu_hz"),
        (HEADER.replace("100.0", "0.0"), "imu_hz"),
        (
            HEADER.replace("[21.0,0.0,-42.0]", "[0.0,0.0,0.0]"),
            "earth_field_uT",
        ),
        (
            HEADER.replace("[21.0,0.0,-42.0]", "[2100.0,0.0,-42.0]"),
            "earth_field_uT",
        ),
    ] {
        match read(format!("{h}\n").as_bytes()) {
            Err(SessionError::Line { line: 1, message }) => {
                assert!(message.contains(key) && message.contains('['), "{message}");
            }
            other => panic!("{h}: {other:?}"),
        }
    }
}

#[test]
fn never_panics_on_garbage() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let alphabet = b"{}[]\":,.-+eE0123456789 typehadrimulsnfxtv\n\\";
    for _ in 0..2000 {
        let mut text = LOG.as_bytes().to_vec();
        let n = rng.random_range(0..120);
        for _ in 0..n {
            text.push(alphabet[rng.random_range(0..alphabet.len())]);
        }
        let cut = rng.random_range(0..text.len());
        let _ = read(&text[cut..]);
    }
}

#[test]
fn write_then_read_round_trips() {
    let s = read(LOG.as_bytes()).unwrap();
    let mut out = Vec::new();
    s.write(&mut out).unwrap();
    let again = read(&out[..]).unwrap();
    assert_eq!(s, again);
    let mut out2 = Vec::new();
    again.write(&mut out2).unwrap();
    assert_eq!(out, out2);
}
