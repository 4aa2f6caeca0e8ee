//! `hal-sim inspect`: a summary of a session log per segment (duration, pulse count, IMU
//! rate, gaps), read as a stream (bounded memory: counts, the longest gap, and one time
//! per pulse for the interval median).
use crate::io::session::{
    Header, Item, ReadOptions, ReadStats, Reader, Record, Session, SessionError, Warning,
};
use std::collections::BTreeMap;
use std::fmt;
use std::io::BufRead;

/// What `inspect` reports for one segment (a header and the records after it).
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Header's IMU rate, Hz.
    pub imu_hz_header: f64,
    /// Whether pulse signs are ambiguous.
    pub sign_ambiguous: bool,
    /// First and last record time, s.
    pub span_s: Option<(f64, f64)>,
    /// Number of IMU samples.
    pub imu_count: usize,
    /// Measured IMU rate (samples − 1 over their time span), Hz.
    pub imu_hz_measured: Option<f64>,
    /// IMU gaps longer than 1.5 sample periods.
    pub imu_gaps: usize,
    /// The longest of them: `(start t, length s)`.
    pub longest_gap: Option<(f64, f64)>,
    /// Pulses per source (`None`: no `src`).
    pub pulses: BTreeMap<Option<u32>, usize>,
    /// Smallest, median and largest interval between pulses of one source, s.
    pub pulse_interval_s: Option<(f64, f64, f64)>,
    /// Smallest and largest |h|, A/m.
    pub h_range: Option<(f64, f64)>,
    /// Truth records.
    pub truth_count: usize,
    /// Event records.
    pub event_count: usize,
    /// Warnings from reading (all segments for a whole-log [`summarize`]).
    pub warnings: usize,
}

/// Builds a [`Summary`] record by record (records in `t` order).
#[derive(Debug, Clone)]
pub struct Builder {
    s: Summary,
    first_imu: Option<f64>,
    last_imu: Option<f64>,
    last_pulse: BTreeMap<Option<u32>, f64>,
    intervals: Vec<f64>,
}

impl Builder {
    /// A segment that starts with `header`.
    pub fn new(header: &Header) -> Self {
        Self {
            s: Summary {
                imu_hz_header: header.imu_hz,
                sign_ambiguous: header.sign_ambiguous,
                span_s: None,
                imu_count: 0,
                imu_hz_measured: None,
                imu_gaps: 0,
                longest_gap: None,
                pulses: BTreeMap::new(),
                pulse_interval_s: None,
                h_range: None,
                truth_count: 0,
                event_count: 0,
                warnings: 0,
            },
            first_imu: None,
            last_imu: None,
            last_pulse: BTreeMap::new(),
            intervals: Vec::new(),
        }
    }

    fn time(&mut self, t: f64) {
        self.s.span_s = Some(self.s.span_s.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
    }

    /// Adds a record.
    pub fn record(&mut self, r: &Record) {
        self.time(r.t());
        match r {
            Record::Imu(x) => {
                self.s.imu_count += 1;
                if let Some(prev) = self.last_imu {
                    let dt = x.t - prev;
                    if dt > 1.5 / self.s.imu_hz_header {
                        self.s.imu_gaps += 1;
                        if self.s.longest_gap.is_none_or(|(_, l)| dt > l) {
                            self.s.longest_gap = Some((prev, dt));
                        }
                    }
                }
                self.first_imu.get_or_insert(x.t);
                self.last_imu = Some(x.t);
            }
            Record::Pulse(p) => {
                *self.s.pulses.entry(p.src).or_insert(0) += 1;
                if let Some(prev) = self.last_pulse.insert(p.src, p.t) {
                    self.intervals.push(p.t - prev);
                }
                let n = p.h.iter().map(|x| x * x).sum::<f64>().sqrt();
                self.s.h_range = Some(self.s.h_range.map_or((n, n), |(a, b)| (a.min(n), b.max(n))));
            }
            Record::Truth(_) => self.s.truth_count += 1,
        }
    }

    /// Adds an event record.
    pub fn event(&mut self, t: f64) {
        self.time(t);
        self.s.event_count += 1;
    }

    /// The summary of what was added.
    pub fn finish(mut self) -> Summary {
        if let (Some(a), Some(b)) = (self.first_imu, self.last_imu)
            && b > a
        {
            self.s.imu_hz_measured = Some((self.s.imu_count - 1) as f64 / (b - a));
        }
        let v = &mut self.intervals;
        v.sort_by(f64::total_cmp);
        if let (Some(a), Some(b)) = (v.first(), v.last()) {
            self.s.pulse_interval_s = Some((*a, v[v.len() / 2], *b));
        }
        self.s
    }
}

/// Summarizes a session log read whole (one segment).
pub fn summarize(s: &Session) -> Summary {
    let mut b = Builder::new(&s.header);
    for r in &s.records {
        b.record(r);
    }
    let mut out = b.finish();
    out.warnings = s.warnings.len();
    out
}

/// What `inspect` reports for a whole log: each segment with the line of its header, and
/// the reader's counts.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    /// The segments: (header line, summary).
    pub segments: Vec<(usize, Summary)>,
    /// What was read and skipped.
    pub stats: ReadStats,
}

/// Streams a log from `input` and summarizes each segment; warnings go to `on_warning`
/// as they come. Errors: reading failed, no header, an unusable header.
pub fn inspect_stream(
    input: impl BufRead,
    mut on_warning: impl FnMut(&Warning),
) -> Result<Report, SessionError> {
    let mut reader = Reader::new(input, ReadOptions::default());
    let mut segments = Vec::new();
    let mut current: Option<(usize, Builder, usize)> = None;
    let close = |c: Option<(usize, Builder, usize)>, segments: &mut Vec<(usize, Summary)>| {
        if let Some((line, b, warnings)) = c {
            let mut s = b.finish();
            s.warnings = warnings;
            segments.push((line, s));
        }
    };
    loop {
        let next = reader.next_item();
        let warnings = reader.take_warnings();
        if let Some((_, _, n)) = current.as_mut() {
            *n += warnings.len();
        }
        for w in &warnings {
            on_warning(w);
        }
        let Some((line, item)) = next? else { break };
        match item {
            Item::Header(h) => {
                close(current.take(), &mut segments);
                current = Some((line, Builder::new(&h), 0));
            }
            Item::Record(r) => {
                if let Some((_, b, _)) = current.as_mut() {
                    b.record(&r);
                }
            }
            Item::Event(e) => {
                if let Some((_, b, _)) = current.as_mut() {
                    b.event(e.t);
                }
            }
            // Late pulses are counted in the reader's stats (and warned about).
            Item::Late(_) => {}
        }
    }
    close(current.take(), &mut segments);
    Ok(Report {
        segments,
        stats: *reader.stats(),
    })
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.span_s {
            Some((a, b)) => writeln!(f, "duration: {:.2} s ({a:.2} … {b:.2})", b - a)?,
            None => writeln!(f, "duration: no records")?,
        }
        let total: usize = self.pulses.values().sum();
        write!(f, "pulses: {total}")?;
        for (src, n) in &self.pulses {
            match src {
                Some(s) => write!(f, "  [src {s}: {n}]")?,
                None => write!(f, "  [no src: {n}]")?,
            }
        }
        writeln!(f)?;
        if let Some((a, m, b)) = self.pulse_interval_s {
            writeln!(
                f,
                "pulse interval: min {a:.3} s, median {m:.3} s, max {b:.3} s"
            )?;
        }
        if let Some((a, b)) = self.h_range {
            writeln!(f, "|h|: {a:.3e} … {b:.3e} A/m")?;
        }
        write!(
            f,
            "imu: {} samples, header {} Hz",
            self.imu_count, self.imu_hz_header
        )?;
        match self.imu_hz_measured {
            Some(hz) => writeln!(f, ", measured {hz:.3} Hz")?,
            None => writeln!(f)?,
        }
        write!(f, "imu gaps (> 1.5 periods): {}", self.imu_gaps)?;
        if let Some((t, len)) = self.longest_gap {
            write!(f, ", longest {len:.3} s at t = {t:.3}")?;
        }
        writeln!(f)?;
        writeln!(f, "sign ambiguous: {}", self.sign_ambiguous)?;
        writeln!(f, "truth records: {}", self.truth_count)?;
        writeln!(f, "event records: {}", self.event_count)?;
        writeln!(f, "skipped lines (warnings): {}", self.warnings)
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let many = self.segments.len() > 1;
        for (k, (line, s)) in self.segments.iter().enumerate() {
            if many {
                writeln!(f, "segment {} (header at line {line}):", k + 1)?;
            }
            write!(f, "{s}")?;
        }
        let r = &self.stats;
        writeln!(
            f,
            "lines: {} in {} segment(s); skipped: {} malformed, {} over {} bytes, {} before the first header, {} of unknown type, {} late; seq: {} record(s) lost",
            r.lines,
            r.segments,
            r.malformed,
            r.too_long,
            crate::io::session::MAX_LINE_BYTES,
            r.before_header,
            r.unknown_type,
            r.late,
            r.seq_lost
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_are_summarized_apart_and_as_a_stream() {
        let header = r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100.0}"#;
        let imu = |t: f64| format!(r#"{{"type":"imu","t":{t},"acc":[0,0,9.8],"gyr":[0,0,0]}}"#);
        let pulse =
            |t: f64, s: u32| format!(r#"{{"type":"pulse","t":{t},"h":[3e-6,4e-6,0],"src":{s}}}"#);
        let mut log = format!("{header}\n");
        for k in 0..300 {
            log += &format!("{}\n", imu(f64::from(k) * 0.01));
        }
        // A pulse written 0.2 s late (the board's order), a gap of 0.5 s, garbage.
        log += &format!("{}\n{}\n{}\n", pulse(2.8, 7), imu(3.5), "{torn");
        log += &format!("{}\n", pulse(3.4, 7));
        log += &format!("\u{feff}{header}\n{}\n{}\n", imu(0.0), imu(0.01));
        let mut warned = Vec::new();
        let r = inspect_stream(log.as_bytes(), |w| warned.push(w.line)).unwrap();
        assert_eq!(r.segments.len(), 2);
        let (line, a) = &r.segments[0];
        assert_eq!(*line, 1);
        assert_eq!(a.imu_count, 301);
        assert_eq!(a.imu_gaps, 1);
        let (t, len) = a.longest_gap.unwrap();
        assert!(
            (t - 2.99).abs() < 1e-9 && (len - 0.51).abs() < 1e-9,
            "{t} {len}"
        );
        assert_eq!(a.pulses.get(&Some(7)), Some(&2));
        let (lo, med, hi) = a.pulse_interval_s.unwrap();
        assert!((lo - 0.6).abs() < 1e-9 && med == lo && hi == lo);
        assert!((a.h_range.unwrap().0 - 5e-6).abs() < 1e-15);
        assert_eq!(a.warnings, 1);
        assert_eq!(warned, vec![304]);
        let (line, b) = &r.segments[1];
        assert_eq!((*line, b.imu_count, b.warnings), (306, 2, 0));
        let text = r.to_string();
        assert!(text.contains("segment 2 (header at line 306)"), "{text}");
        assert!(
            text.contains("in 2 segment(s); skipped: 1 malformed"),
            "{text}"
        );
        // The whole-log summary agrees with the stream's first segment.
        let first: String = log.lines().take(305).map(|l| format!("{l}\n")).collect();
        let s = crate::io::session::read(first.as_bytes()).unwrap();
        assert_eq!(summarize(&s), *a);
    }
}
