//! `hal-sim replay`: runs an estimator over a session log and writes the spec's replay
//! JSON Lines, one line per pulse.
//!
//! The estimator is a plug-in behind [`Estimator`]; [`estimator_for`] is the single place
//! that chooses it: the firmware's pipeline. [`NoEstimator`] (empty `victims`) remains for
//! tests of the output format.
use crate::io::receiver_config::ReceiverConfig;
use crate::io::session::{
    Event, Header, Imu, Item, Pulse, ReadOptions, ReadStats, Reader, Record, Session, Warning,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::{BufRead, Write};

/// One victim in a replay line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VictimEstimate {
    /// Estimated position relative to the receiver in G_k (north, west, up), m.
    pub p: [f64; 3],
    /// Covariance of `p`, row-major, m².
    pub cov: [f64; 9],
    /// Straight-line distance to the estimate, m.
    pub dist_m: f64,
    /// Horizontal bearing of the estimate relative to the device's yaw, positive to the
    /// left, degrees in (-180, 180].
    pub dir_deg: f64,
}

impl VictimEstimate {
    /// Fills `dist_m` and `dir_deg` from `p` and the device's yaw (rad).
    pub fn new(p: [f64; 3], cov: [f64; 9], yaw_rad: f64) -> Self {
        let dist_m = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let dir = crate::world::rescuer::wrap_pi(p[1].atan2(p[0]) - yaw_rad).to_degrees();
        Self {
            p,
            cov,
            dist_m,
            dir_deg: if dir <= -180.0 { 180.0 } else { dir },
        }
    }
}

/// One line of replay output (one processed pulse).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayLine {
    /// Time of the pulse, s.
    pub t: f64,
    /// Number of mixture components alive.
    pub n_components: u32,
    /// Guidance arrow, degrees, positive to the left.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrow_deg: Option<f64>,
    /// Display status word.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
    /// What the display asks the rescuer to do now (`"probe here"`, `"lower to snow"`,
    /// `"raise"`, `"lift"`); absent when nothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prompt: Option<String>,
    /// Current estimate per victim; empty before initialization.
    pub victims: Vec<VictimEstimate>,
}

/// An estimator fed by a replayed log.
pub trait Estimator {
    /// Consumes an IMU sample.
    fn on_imu(&mut self, imu: &Imu);
    /// Consumes a pulse and reports the state after it.
    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine;
    /// Consumes an event record (`"mark"` presses the mark button); others are ignored.
    fn on_event(&mut self, _event: &Event) {}
    /// The current state for a pulse that is answered without being processed (`status`
    /// says why, e.g. `"late"`).
    fn state_line(&mut self, t: f64, status: &str) -> ReplayLine {
        ReplayLine {
            t,
            n_components: 0,
            arrow_deg: None,
            status: Some(status.to_string()),
            prompt: None,
            victims: Vec::new(),
        }
    }
    /// Inputs refused so far, by reason (for the summary).
    fn refusals(&self) -> Vec<(&'static str, u64)> {
        Vec::new()
    }
}

/// The placeholder estimator: no estimate, empty `victims`.
#[derive(Debug, Default, Clone)]
pub struct NoEstimator;

impl Estimator for NoEstimator {
    fn on_imu(&mut self, _imu: &Imu) {}

    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine {
        ReplayLine {
            t: pulse.t,
            n_components: 0,
            arrow_deg: None,
            status: None,
            prompt: None,
            victims: Vec::new(),
        }
    }
}

/// The estimator `replay` uses for a log with this header and receiver configuration:
/// the firmware's motion + SOGs pipeline ([`crate::io::sog_replay::SogReplay`]).
pub fn estimator_for(
    header: &Header,
    receiver: &ReceiverConfig,
) -> anyhow::Result<Box<dyn Estimator>> {
    Ok(Box::new(crate::io::sog_replay::SogReplay::new(
        header, receiver,
    )?))
}

/// Replays `session` through the estimator [`estimator_for`] picks for it and `receiver`,
/// writing the replay JSON Lines to `out`. Returns the number of lines written.
pub fn replay_with_config(
    session: &Session,
    receiver: &ReceiverConfig,
    out: &mut impl Write,
) -> anyhow::Result<usize> {
    let mut estimator = estimator_for(&session.header, receiver)?;
    replay(session, estimator.as_mut(), out, |_| {})
}

/// Feeds every record of `session` to `estimator` in order and writes one JSON line per
/// pulse to `out`; `on_record` is called after each record (for progress). Truth records
/// are never passed on. Returns the number of lines written.
pub fn replay(
    session: &Session,
    estimator: &mut dyn Estimator,
    out: &mut impl Write,
    mut on_record: impl FnMut(usize),
) -> anyhow::Result<usize> {
    let mut lines = 0;
    for (i, r) in session.records.iter().enumerate() {
        match r {
            Record::Imu(x) => estimator.on_imu(x),
            Record::Pulse(p) => {
                let line = estimator.on_pulse(p);
                serde_json::to_writer(&mut *out, &line)?;
                out.write_all(b"\n")?;
                lines += 1;
            }
            Record::Truth(_) => {}
        }
        on_record(i);
    }
    out.flush()?;
    Ok(lines)
}

/// How a streamed replay reads its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StreamOptions {
    /// Stop at the first malformed line (exit status 1) instead of skipping it.
    pub strict: bool,
    /// Live input: no reordering window (each record is processed as it arrives) and each
    /// line is flushed as soon as it is written.
    pub live: bool,
}

/// What a streamed replay read, skipped, refused and wrote.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReplaySummary {
    /// The reader's counts.
    pub read: ReadStats,
    /// Lines written (one per pulse record).
    pub lines: u64,
    /// Pulses answered without being processed because they came too late.
    pub late_pulses: u64,
    /// Inputs the estimator refused, by reason, summed over the segments.
    pub refused: Vec<(&'static str, u64)>,
}

impl ReplaySummary {
    fn add_refusals(&mut self, r: Vec<(&'static str, u64)>) {
        for (why, n) in r {
            match self.refused.iter_mut().find(|(w, _)| *w == why) {
                Some((_, m)) => *m += n,
                None => self.refused.push((why, n)),
            }
        }
    }
}

impl std::fmt::Display for ReplaySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.read;
        writeln!(
            f,
            "replay summary: {} lines read in {} segment(s); records: {} imu, {} pulse, {} event, {} truth; {} replay lines written",
            r.lines, r.segments, r.imu, r.pulses, r.events, r.truth, self.lines
        )?;
        writeln!(
            f,
            "  skipped: {} malformed ({} resynchronized within the line), {} over {} bytes, {} before the first header, {} of unknown type, {} out of t order beyond {} s ({} of them pulses, answered as \"late\")",
            r.malformed,
            r.resynchronized,
            r.too_long,
            crate::io::session::MAX_LINE_BYTES,
            r.before_header,
            r.unknown_type,
            r.late,
            crate::io::session::REORDER_WINDOW_S,
            self.late_pulses
        )?;
        writeln!(
            f,
            "  seq: {} gap(s), {} record(s) lost",
            r.seq_gaps, r.seq_lost
        )?;
        write!(f, "  refused by the firmware:")?;
        if self.refused.iter().all(|(_, n)| *n == 0) {
            write!(f, " none")?;
        }
        for (why, n) in self.refused.iter().filter(|(_, n)| *n > 0) {
            write!(f, " {n} {why};")?;
        }
        writeln!(f)
    }
}

/// Warnings shown on the terminal before only their number is kept: a log of a million
/// garbage lines would otherwise print a million lines (the summary counts them all).
pub const WARNINGS_SHOWN: u64 = 20;

/// Writes reading warnings for the log `name`: the first `limit` in full, then only a
/// count, reported by [`WarningCap::finish`].
#[derive(Debug, Clone)]
pub struct WarningCap {
    name: String,
    limit: u64,
    seen: u64,
}

impl WarningCap {
    /// A cap of `limit` warnings for the log `name`.
    pub fn new(name: &str, limit: u64) -> Self {
        Self {
            name: name.to_string(),
            limit,
            seen: 0,
        }
    }

    /// Writes `w` to `out` unless `limit` warnings were written already.
    pub fn warn(&mut self, w: &Warning, out: &mut impl Write) {
        self.seen += 1;
        if self.seen <= self.limit {
            // A closed stderr is no reason to stop a replay.
            let _ = writeln!(out, "warning: {}: {w}", self.name);
        }
    }

    /// The line telling how many warnings were not shown, if any.
    pub fn finish(&self) -> Option<String> {
        (self.seen > self.limit).then(|| {
            format!(
                "warning: {}: {} more warning(s) not shown ({} in all)",
                self.name,
                self.seen - self.limit,
                self.seen
            )
        })
    }
}

/// Streams a session log from `input` through the firmware's pipeline configured by
/// `receiver` (a fresh one per segment), writing one JSON line per pulse record to `out`
/// in file order. Warnings go to `on_warning` as they come; `on_progress` gets the bytes
/// read so far. Errors: reading or writing failed, an unusable header, the estimator
/// refused its configuration, and in strict mode the first malformed line.
pub fn replay_stream(
    input: impl BufRead,
    receiver: &ReceiverConfig,
    out: &mut impl Write,
    opts: StreamOptions,
    on_warning: impl FnMut(&Warning),
    on_progress: impl FnMut(u64),
) -> anyhow::Result<ReplaySummary> {
    replay_stream_with(
        input,
        |h| estimator_for(h, receiver),
        out,
        opts,
        on_warning,
        on_progress,
    )
}

/// Replays a whole log held in memory strictly (as `replay --strict`), the check that a
/// writer's log reads back cleanly: the first malformed line, and any warning (a `seq`
/// gap, a record too late, an unknown type), is an error. The replay lines are dropped.
pub fn replay_clean(log: &[u8], receiver: &ReceiverConfig) -> anyhow::Result<ReplaySummary> {
    let mut warnings = Vec::new();
    let opts = StreamOptions {
        strict: true,
        live: false,
    };
    let summary = replay_stream(
        log,
        receiver,
        &mut std::io::sink(),
        opts,
        |w| warnings.push(w.to_string()),
        |_| {},
    )?;
    anyhow::ensure!(
        warnings.is_empty(),
        "the log replays with warnings: {}",
        warnings.join("; ")
    );
    Ok(summary)
}

/// Writes one replay line; an output error stays an [`std::io::Error`] (a closed pipe is
/// recognized by its kind).
fn write_line(out: &mut impl Write, l: &ReplayLine) -> anyhow::Result<()> {
    let mut text = serde_json::to_vec(l)?;
    text.push(b'\n');
    out.write_all(&text)?;
    Ok(())
}

/// Whether `e` is a write to a closed pipe (`replay … | head -1`): the reader of the
/// output has all it wanted, not a failure.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// [`replay_stream`] with the estimator of each segment made by `make`.
pub fn replay_stream_with(
    input: impl BufRead,
    mut make: impl FnMut(&Header) -> anyhow::Result<Box<dyn Estimator>>,
    out: &mut impl Write,
    opts: StreamOptions,
    mut on_warning: impl FnMut(&Warning),
    mut on_progress: impl FnMut(u64),
) -> anyhow::Result<ReplaySummary> {
    let read_opts = ReadOptions {
        strict: opts.strict,
        window_s: if opts.live {
            0.0
        } else {
            crate::io::session::REORDER_WINDOW_S
        },
    };
    let mut reader = Reader::new(input, read_opts);
    let mut summary = ReplaySummary::default();
    let mut estimator: Option<Box<dyn Estimator>> = None;
    // Answers waiting for an earlier pulse record still in the reordering window, by line.
    let mut done: BTreeMap<usize, ReplayLine> = BTreeMap::new();
    let mut records = 0u64;
    loop {
        let next = reader.next_item();
        for w in reader.take_warnings() {
            on_warning(&w);
        }
        let Some((line, item)) = next? else { break };
        match item {
            Item::Header(h) => {
                if let Some(e) = estimator.take() {
                    summary.add_refusals(e.refusals());
                }
                estimator = Some(make(&h)?);
            }
            Item::Record(r) => {
                let Some(e) = estimator.as_mut() else {
                    continue;
                };
                match &r {
                    Record::Imu(x) => e.on_imu(x),
                    Record::Pulse(p) => {
                        done.insert(line, e.on_pulse(p));
                    }
                    Record::Truth(_) => {}
                }
            }
            Item::Event(ev) => {
                if let Some(e) = estimator.as_mut() {
                    e.on_event(&ev);
                }
            }
            Item::Late(p) => {
                if let Some(e) = estimator.as_mut() {
                    summary.late_pulses += 1;
                    done.insert(line, e.state_line(p.t, "late"));
                }
            }
        }
        // Answers go out in file order: up to the first pulse not yet processed.
        if !done.is_empty() {
            let first = reader.first_pending_pulse_line().unwrap_or(usize::MAX);
            while let Some(entry) = done.first_entry() {
                if *entry.key() >= first {
                    break;
                }
                write_line(out, &entry.remove())?;
                summary.lines += 1;
                if opts.live {
                    out.flush()?;
                }
            }
        }
        records += 1;
        if records.is_multiple_of(4096) {
            on_progress(reader.stats().bytes);
        }
    }
    for l in done.into_values() {
        write_line(out, &l)?;
        summary.lines += 1;
    }
    out.flush()?;
    if let Some(e) = estimator.take() {
        summary.add_refusals(e.refusals());
    }
    summary.read = *reader.stats();
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warnings_beyond_the_cap_are_counted_not_shown() {
        let mut cap = WarningCap::new("x.jsonl", 2);
        let mut out = Vec::new();
        for line in 1..=5 {
            let w = Warning {
                line,
                message: "bad".into(),
            };
            cap.warn(&w, &mut out);
        }
        let text = String::from_utf8(out).unwrap();
        assert_eq!(
            text,
            "warning: x.jsonl: line 1: bad\nwarning: x.jsonl: line 2: bad\n"
        );
        assert_eq!(
            cap.finish().as_deref(),
            Some("warning: x.jsonl: 3 more warning(s) not shown (5 in all)")
        );
        assert_eq!(WarningCap::new("y", 2).finish(), None);
    }

    #[test]
    fn a_clean_replay_refuses_a_log_with_warnings() {
        let mut log = Vec::new();
        let header = Header::new(100.0, [20.0, 0.0, -40.0], false);
        Session::new(header).write(&mut log).unwrap();
        let summary = replay_clean(&log, &ReceiverConfig::default()).unwrap();
        assert_eq!((summary.read.segments, summary.lines), (1, 0));
        log.extend_from_slice(b"{\"type\":\"chirp\",\"t\":0.5}\n");
        let e = replay_clean(&log, &ReceiverConfig::default()).unwrap_err();
        assert!(e.to_string().contains("unknown record type"), "{e}");
    }

    #[test]
    fn direction_convention() {
        // Victim to the west while facing north: 90° to the left.
        let v = VictimEstimate::new([0.0, 10.0, 0.0], [0.0; 9], 0.0);
        assert!((v.dir_deg - 90.0).abs() < 1e-9 && (v.dist_m - 10.0).abs() < 1e-12);
        // Facing west, a victim to the north is 90° to the right.
        let v = VictimEstimate::new([5.0, 0.0, -1.0], [0.0; 9], std::f64::consts::FRAC_PI_2);
        assert!((v.dir_deg + 90.0).abs() < 1e-9);
        let v = VictimEstimate::new([-5.0, 0.0, 0.0], [0.0; 9], 0.0);
        assert_eq!(v.dir_deg, 180.0);
    }
}
