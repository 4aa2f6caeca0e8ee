//! `hal-sim inspect`: a summary of a session log (duration, pulse count, IMU rate, gaps).
use crate::session::{Record, Session};
use std::collections::BTreeMap;
use std::fmt;

/// What `inspect` reports.
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
    /// IMU gaps longer than 1.5 sample periods: `(start t, length s)`.
    pub imu_gaps: Vec<(f64, f64)>,
    /// Pulses per source (`None`: no `src`).
    pub pulses: BTreeMap<Option<u32>, usize>,
    /// Smallest, median and largest interval between pulses of one source, s.
    pub pulse_interval_s: Option<(f64, f64, f64)>,
    /// Smallest and largest |h|, A/m.
    pub h_range: Option<(f64, f64)>,
    /// Truth records.
    pub truth_count: usize,
    /// Warnings from reading.
    pub warnings: usize,
}

/// Summarizes a session log.
pub fn summarize(s: &Session) -> Summary {
    let span_s = match (s.records.first(), s.records.last()) {
        (Some(a), Some(b)) => Some((a.t(), b.t())),
        _ => None,
    };
    let imu_t: Vec<f64> = s.imu().map(|x| x.t).collect();
    let imu_hz_measured = match (imu_t.first(), imu_t.last()) {
        (Some(a), Some(b)) if b > a => Some((imu_t.len() - 1) as f64 / (b - a)),
        _ => None,
    };
    let limit = 1.5 / s.header.imu_hz;
    let imu_gaps = imu_t
        .windows(2)
        .filter(|w| w[1] - w[0] > limit)
        .map(|w| (w[0], w[1] - w[0]))
        .collect();
    let mut pulses = BTreeMap::new();
    let mut last: BTreeMap<Option<u32>, f64> = BTreeMap::new();
    let mut intervals = Vec::new();
    let mut h_range: Option<(f64, f64)> = None;
    for r in &s.records {
        if let Record::Pulse(p) = r {
            *pulses.entry(p.src).or_insert(0) += 1;
            if let Some(prev) = last.insert(p.src, p.t) {
                intervals.push(p.t - prev);
            }
            let n = p.h.iter().map(|x| x * x).sum::<f64>().sqrt();
            h_range = Some(h_range.map_or((n, n), |(a, b)| (a.min(n), b.max(n))));
        }
    }
    intervals.sort_by(f64::total_cmp);
    let pulse_interval_s = (!intervals.is_empty()).then(|| {
        (
            intervals[0],
            intervals[intervals.len() / 2],
            intervals[intervals.len() - 1],
        )
    });
    Summary {
        imu_hz_header: s.header.imu_hz,
        sign_ambiguous: s.header.sign_ambiguous,
        span_s,
        imu_count: imu_t.len(),
        imu_hz_measured,
        imu_gaps,
        pulses,
        pulse_interval_s,
        h_range,
        truth_count: s.truth().count(),
        warnings: s.warnings.len(),
    }
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
        write!(f, "imu gaps (> 1.5 periods): {}", self.imu_gaps.len())?;
        if let Some((t, len)) = self.imu_gaps.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
            write!(f, ", longest {len:.3} s at t = {t:.3}")?;
        }
        writeln!(f)?;
        writeln!(f, "sign ambiguous: {}", self.sign_ambiguous)?;
        writeln!(f, "truth records: {}", self.truth_count)?;
        writeln!(f, "skipped lines (warnings): {}", self.warnings)
    }
}
