//! Session logs (`arva-session` version 1, `docs/session-log.md`): record types, a
//! streaming [`Reader`] (bounded memory, the 2 s reordering window for late pulses,
//! segments, malformed lines reported by number and skipped, `seq` gaps, byte-order mark),
//! a whole-log [`read`] on top of it, and a writer.
//!
//! Numbers are written with serde_json's shortest round-trip representation of `f64` and
//! keys in the order of the spec, so parsing a log this crate wrote and writing it again
//! gives the same bytes.
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::io::{BufRead, Write};
use std::path::Path;

mod reader;
pub use reader::*;

/// The value of the header's `format` key.
pub const FORMAT: &str = "arva-session";
/// The format version this crate reads and writes.
pub const VERSION: u32 = 1;

/// The first line of a session log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Always `"arva-session"`.
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// Nominal IMU sample rate, Hz.
    #[serde(default = "default_imu_hz")]
    pub imu_hz: f64,
    /// Local geomagnetic field in W, µT.
    #[serde(
        rename = "earth_field_uT",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub earth_field_ut: Option<[f64; 3]>,
    /// Whether the overall sign of each pulse's `h` is arbitrary.
    #[serde(default = "default_true")]
    pub sign_ambiguous: bool,
}

fn default_imu_hz() -> f64 {
    100.0
}

fn default_true() -> bool {
    true
}

/// Plausible IMU sample rates, Hz.
pub const IMU_HZ_RANGE: [f64; 2] = [1.0, 10_000.0];
/// Plausible magnitudes of the geomagnetic field, µT (≈ 22 to 67 µT on Earth).
pub const EARTH_FIELD_UT_RANGE: [f64; 2] = [15.0, 80.0];

/// `v` for a message: plain between 1e-4 and 1e6, else in scientific notation (Rust's
/// `{}` would print 1e308 with 309 digits).
pub(crate) fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `Ok` when `v` lies in `[lo, hi]`, else the message naming `key` and the range.
pub(crate) fn check_range(key: &str, v: f64, [lo, hi]: [f64; 2], unit: &str) -> Result<(), String> {
    if v >= lo && v <= hi {
        Ok(())
    } else {
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Err(format!(
            "{key} = {} is outside [{lo}, {hi}]{unit}",
            number(v)
        ))
    }
}

impl Header {
    /// `Ok` when this reader can replay the segment: this format, version 1, and every
    /// value physically plausible; else a message naming the key and its allowed range.
    pub fn validate(&self) -> Result<(), String> {
        if self.format != FORMAT {
            return Err(format!(
                "format is \"{}\", expected \"{FORMAT}\"",
                self.format
            ));
        }
        if self.version != VERSION {
            return Err(format!(
                "unsupported version {} (this reader reads {VERSION})",
                self.version
            ));
        }
        check_range("imu_hz", self.imu_hz, IMU_HZ_RANGE, "Hz")?;
        if let Some(e) = self.earth_field_ut {
            let norm = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
            check_range("|earth_field_uT|", norm, EARTH_FIELD_UT_RANGE, "µT")?;
        }
        Ok(())
    }

    /// A version-1 header.
    pub fn new(imu_hz: f64, earth_field_ut: [f64; 3], sign_ambiguous: bool) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            imu_hz,
            earth_field_ut: Some(earth_field_ut),
            sign_ambiguous,
        }
    }
}

/// One IMU sample in the body frame R.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Imu {
    /// Time, s.
    pub t: f64,
    /// Specific force `R_WRᵀ (a_W − g_W)`, m/s² (level and at rest: `[0, 0, +9.81]`).
    pub acc: [f64; 3],
    /// Angular rate of R relative to W, in R, rad/s.
    pub gyr: [f64; 3],
    /// Magnetic flux density in R, µT (absent when the IMU has no magnetometer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mag: Option<[f64; 3]>,
}

/// One received beacon pulse.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pulse {
    /// Time of the pulse centre, s.
    pub t: f64,
    /// Field strength at the receiver in R, A/m (overall sign arbitrary when the header
    /// says `sign_ambiguous`).
    pub h: [f64; 3],
    /// Transmitter the front end attributed the pulse to; absent for a single transmitter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub src: Option<u32>,
}

/// One victim in a truth record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthVictim {
    /// Transmitter position in W, m.
    pub p: [f64; 3],
    /// Magnetic moment in W, A·m².
    pub m: [f64; 3],
}

/// Ground truth at one instant (kept in a separate file, never fed to the estimator).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// Time, s.
    pub t: f64,
    /// Receiver position in W, m.
    pub p: [f64; 3],
    /// Receiver roll, pitch, yaw, rad.
    pub rpy: [f64; 3],
    /// The transmitters.
    pub victims: Vec<TruthVictim>,
}

/// A user or device event (`"mark"`: the user marked the victim searched for; device
/// events such as `"withheld"`, `"gain"`, `"reset"` carry their details in extra keys).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// Time, s.
    pub t: f64,
    /// What happened.
    pub kind: String,
    /// The other keys, kept as read.
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

/// A record after the header.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// An IMU sample.
    Imu(Imu),
    /// A beacon pulse.
    Pulse(Pulse),
    /// A ground-truth record.
    Truth(Truth),
}

impl Record {
    /// The record's time, s.
    pub fn t(&self) -> f64 {
        match self {
            Record::Imu(r) => r.t,
            Record::Pulse(r) => r.t,
            Record::Truth(r) => r.t,
        }
    }
}

/// A non-fatal problem found while reading.
#[derive(Debug, Clone, PartialEq)]
pub struct Warning {
    /// 1-based line number.
    pub line: usize,
    /// What was wrong.
    pub message: String,
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.message)
    }
}

/// Why a session log could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// A line is not a valid record.
    #[error("line {line}: {message}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// What was wrong.
        message: String,
    },
    /// The log has no header line.
    #[error("empty session log: no header line")]
    Empty,
    /// Reading failed.
    #[error("reading the session log: {0}")]
    Io(#[from] std::io::Error),
}

/// A parsed session log.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    /// The header line.
    pub header: Header,
    /// The records after the header, in `t` order.
    pub records: Vec<Record>,
    /// The event records, in `t` order.
    pub events: Vec<Event>,
    /// Lines that were skipped, with the reason.
    pub warnings: Vec<Warning>,
}

#[derive(Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum Tagged<'a> {
    Header(&'a Header),
    Imu(&'a Imu),
    Pulse(&'a Pulse),
    Truth(&'a Truth),
    Event(&'a Event),
}

impl Session {
    /// An empty session with this header.
    pub fn new(header: Header) -> Self {
        Self {
            header,
            records: Vec::new(),
            events: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// Writes the log: the header line, then one line per record, the events among the
    /// records by `t` (an event after the records of its own `t`).
    pub fn write(&self, out: &mut impl Write) -> std::io::Result<()> {
        write_line(out, &Tagged::Header(&self.header))?;
        let mut events = self.events.iter().peekable();
        for r in &self.records {
            while let Some(e) = events.next_if(|e| e.t < r.t()) {
                write_line(out, &Tagged::Event(e))?;
            }
            write_record(out, r)?;
        }
        for e in events {
            write_line(out, &Tagged::Event(e))?;
        }
        Ok(())
    }

    /// The IMU samples.
    pub fn imu(&self) -> impl Iterator<Item = &Imu> {
        self.records.iter().filter_map(|r| match r {
            Record::Imu(x) => Some(x),
            _ => None,
        })
    }

    /// The beacon pulses.
    pub fn pulses(&self) -> impl Iterator<Item = &Pulse> {
        self.records.iter().filter_map(|r| match r {
            Record::Pulse(x) => Some(x),
            _ => None,
        })
    }

    /// The truth records.
    pub fn truth(&self) -> impl Iterator<Item = &Truth> {
        self.records.iter().filter_map(|r| match r {
            Record::Truth(x) => Some(x),
            _ => None,
        })
    }
}

/// Writes one record as a line.
pub fn write_record(out: &mut impl Write, r: &Record) -> std::io::Result<()> {
    match r {
        Record::Imu(x) => write_line(out, &Tagged::Imu(x)),
        Record::Pulse(x) => write_line(out, &Tagged::Pulse(x)),
        Record::Truth(x) => write_line(out, &Tagged::Truth(x)),
    }
}

fn write_line(out: &mut impl Write, v: &Tagged<'_>) -> std::io::Result<()> {
    serde_json::to_writer(&mut *out, v)?;
    out.write_all(b"\n")
}

/// Writes `session` as a receiver writes it (the spec's writer rules): each pulse record
/// when its front end finished it — `written_t[k]` for the k-th pulse, at or after its
/// own `t`, i.e. after the records up to then — instead of sorted by `t`; each of the
/// device's `events` (`t` in s, and the line as the device's writer wrote it, without
/// `seq`, in `t` order) when it happened, after the records before its `t`; every record
/// after the header numbered by `seq` (0, 1, …) in file order. Other records keep their
/// `t` order; `session.events` are not written (a simulation has none).
pub fn write_as_written(
    session: &Session,
    written_t: &[f64],
    events: &[(f64, String)],
    out: &mut impl Write,
) -> std::io::Result<()> {
    write_line(out, &Tagged::Header(&session.header))?;
    let mut seq = 0u64;
    let mut held: VecDeque<(f64, &Record)> = VecDeque::new();
    let mut events = events.iter().peekable();
    let mut k = 0;
    for r in &session.records {
        if let Record::Pulse(p) = r {
            let w = written_t.get(k).copied().unwrap_or(p.t).max(p.t);
            k += 1;
            held.push_back((w, r));
            continue;
        }
        flush_written(out, &mut seq, &mut held, &mut events, r.t())?;
        put_record(out, &mut seq, r)?;
    }
    flush_written(out, &mut seq, &mut held, &mut events, f64::INFINITY)
}

/// Writes one line (`{"type":…`) as `{"seq":n,"type":…` and counts it.
fn put_numbered(out: &mut impl Write, seq: &mut u64, line: &[u8]) -> std::io::Result<()> {
    out.write_all(format!("{{\"seq\":{seq},").as_bytes())?;
    out.write_all(line.get(1..).unwrap_or_default())?;
    *seq += 1;
    Ok(())
}

fn put_record(out: &mut impl Write, seq: &mut u64, r: &Record) -> std::io::Result<()> {
    let mut line = Vec::new();
    write_record(&mut line, r)?;
    put_numbered(out, seq, &line)
}

/// Writes, in time order, the held pulses written by `until` and the events before it.
fn flush_written<'a>(
    out: &mut impl Write,
    seq: &mut u64,
    held: &mut VecDeque<(f64, &Record)>,
    events: &mut std::iter::Peekable<impl Iterator<Item = &'a (f64, String)>>,
    until: f64,
) -> std::io::Result<()> {
    loop {
        let p = held.front().map(|(w, _)| *w).filter(|w| *w <= until);
        let e = events.peek().map(|(t, _)| *t).filter(|t| *t < until);
        let event_first = match (p, e) {
            (Some(w), Some(te)) => te < w,
            (Some(_), None) => false,
            (None, Some(_)) => true,
            (None, None) => return Ok(()),
        };
        if event_first {
            if let Some((_, line)) = events.next() {
                put_numbered(out, seq, format!("{line}\n").as_bytes())?;
            }
        } else if let Some((_, r)) = held.pop_front() {
            put_record(out, seq, r)?;
        }
    }
}

/// Reads a whole single-segment session log from a file (see [`read`]).
pub fn read_file(path: &Path) -> Result<Session, SessionError> {
    let f = std::fs::File::open(path)?;
    read(std::io::BufReader::new(f))
}

/// Reads a whole session log into memory through a lenient [`Reader`]: malformed lines,
/// unknown record types, records out of the reordering window and `seq` gaps become
/// [`Session::warnings`]; records come in `t` order. A log of several segments (a second
/// header) is an error here: [`Reader`] streams them one after the other.
pub fn read(input: impl BufRead) -> Result<Session, SessionError> {
    let mut reader = Reader::new(input, ReadOptions::default());
    let mut session: Option<Session> = None;
    while let Some((line, item)) = reader.next_item()? {
        let warnings = reader.take_warnings();
        match (&mut session, item) {
            (None, Item::Header(h)) => session = Some(Session::new(h)),
            (Some(_), Item::Header(_)) => {
                return Err(SessionError::Line {
                    line,
                    message: "a second header (a new segment): read it with session::Reader".into(),
                });
            }
            (Some(s), Item::Record(r)) => s.records.push(r),
            (Some(s), Item::Event(e)) => s.events.push(e),
            (Some(_), Item::Late(_)) | (None, _) => {}
        }
        if let Some(s) = session.as_mut() {
            s.warnings.extend(warnings);
        }
    }
    let mut s = session.ok_or(SessionError::Empty)?;
    s.warnings.extend(reader.take_warnings());
    Ok(s)
}

/// Writes a value as one JSON line to a file path, creating or truncating it.
pub fn create_file(path: &Path) -> std::io::Result<std::io::BufWriter<std::fs::File>> {
    Ok(std::io::BufWriter::new(std::fs::File::create(path)?))
}

#[cfg(test)]
mod tests;
