//! Session logs (`arva-session` version 1, `docs/session-log.md`): record types, a
//! streaming [`Reader`] (bounded memory, the 2 s reordering window for late pulses,
//! segments, malformed lines reported by number and skipped, `seq` gaps, byte-order mark),
//! a whole-log [`read`] on top of it, and a writer.
//!
//! Numbers are written with serde_json's shortest round-trip representation of `f64` and
//! keys in the order of the spec, so parsing a log this crate wrote and writing it again
//! gives the same bytes.
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::Path;

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
/// own `t`, i.e. after the records up to then — instead of sorted by `t`, and every
/// record after the header numbered by `seq` (0, 1, …) in file order. Records other than
/// pulses keep their `t` order; events are not written (a simulation has none).
pub fn write_as_written(
    session: &Session,
    written_t: &[f64],
    out: &mut impl Write,
) -> std::io::Result<()> {
    write_line(out, &Tagged::Header(&session.header))?;
    let mut seq = 0u64;
    let mut put = |out: &mut dyn Write, r: &Record| -> std::io::Result<()> {
        let mut line = Vec::new();
        write_record(&mut line, r)?;
        // `{"type":…` → `{"seq":n,"type":…`
        out.write_all(format!("{{\"seq\":{seq},").as_bytes())?;
        out.write_all(line.get(1..).unwrap_or_default())?;
        seq += 1;
        Ok(())
    };
    let mut held: std::collections::VecDeque<(f64, &Record)> = Default::default();
    let mut k = 0;
    for r in &session.records {
        if let Record::Pulse(p) = r {
            let w = written_t.get(k).copied().unwrap_or(p.t).max(p.t);
            k += 1;
            held.push_back((w, r));
            continue;
        }
        while let Some((_, p)) = held.front().filter(|(w, _)| *w <= r.t()).copied() {
            put(out, p)?;
            held.pop_front();
        }
        put(out, r)?;
    }
    for (_, p) in held {
        put(out, p)?;
    }
    Ok(())
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

/// The longest line a reader keeps, bytes (the spec: readers refuse lines over 1 MiB).
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// How much later (s) than its own `t` the records before a pulse record may be (the
/// spec's reordering window: a receiver writes a pulse when it has ended).
pub const REORDER_WINDOW_S: f64 = 2.0;

/// How a [`Reader`] treats damage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadOptions {
    /// Stop with an error at the first malformed or over-long line instead of skipping it.
    pub strict: bool,
    /// Reordering window, s: a record is released once a record this much later has been
    /// read. 0 hands every record on as soon as it is read, in file order (live input,
    /// where the writer waits for the answer to each pulse).
    pub window_s: f64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            strict: false,
            window_s: REORDER_WINDOW_S,
        }
    }
}

/// What a [`Reader`] hands on.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// A header: a segment starts (the first one too); replay from a fresh state.
    Header(Header),
    /// A record, in `t` order within the segment.
    Record(Record),
    /// A user or device event, in `t` order with the records.
    Event(Event),
    /// A pulse record that came more than the window after later records: not in `t`
    /// order, so not replayed, but a replay still answers it (reported as a warning too).
    Late(Pulse),
}

/// Counts of what a [`Reader`] read and skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReadStats {
    /// Lines read (blank ones included).
    pub lines: u64,
    /// Bytes read.
    pub bytes: u64,
    /// Segments (headers).
    pub segments: u64,
    /// IMU records handed on.
    pub imu: u64,
    /// Pulse records handed on in order.
    pub pulses: u64,
    /// Event records handed on.
    pub events: u64,
    /// Truth records handed on.
    pub truth: u64,
    /// Malformed lines skipped (not UTF-8, not JSON, a missing or mistyped field).
    pub malformed: u64,
    /// Lines over [`MAX_LINE_BYTES`] refused.
    pub too_long: u64,
    /// Records before the first header, skipped.
    pub before_header: u64,
    /// Records of an unknown `type`, skipped.
    pub unknown_type: u64,
    /// Records out of `t` order beyond the window, skipped (pulses among them are handed on
    /// as [`Item::Late`]).
    pub late: u64,
    /// Malformed lines in which a record was found after the damage.
    pub resynchronized: u64,
    /// Gaps in `seq`.
    pub seq_gaps: u64,
    /// Records lost according to `seq`.
    pub seq_lost: u64,
}

/// A record waiting in the reordering window.
#[derive(Debug)]
struct Pending {
    t: f64,
    line: usize,
    item: Item,
}

/// A line parsed on its own.
enum Parsed {
    Header(Header),
    Item(f64, Item),
    Unknown(String),
}

/// Streaming reader of session logs: one line in memory (at most [`MAX_LINE_BYTES`]) and
/// the records of the reordering window. Hands on [`Item`]s with the line they came from;
/// what it skipped is in [`Reader::take_warnings`] and [`Reader::stats`].
pub struct Reader<R> {
    input: R,
    opts: ReadOptions,
    buf: Vec<u8>,
    line_no: usize,
    in_segment: bool,
    /// Released items, in order.
    out: std::collections::VecDeque<(usize, Item)>,
    /// The reordering window, sorted by (t, line).
    window: std::collections::VecDeque<Pending>,
    /// Latest `t` placed in the window in this segment.
    max_t: f64,
    /// A record whose `t` jumped more than the window ahead, waiting for the next record
    /// to confirm it.
    suspect: Option<Pending>,
    last_seq: Option<u64>,
    warnings: Vec<Warning>,
    stats: ReadStats,
    /// An error to hand on once the items released before it are.
    failed: Option<SessionError>,
    done: bool,
}

#[derive(Deserialize)]
struct Meta {
    #[serde(rename = "type")]
    ty: Option<String>,
    #[serde(default)]
    seq: Option<u64>,
}

impl<R: BufRead> Reader<R> {
    /// A reader of `input`.
    pub fn new(input: R, opts: ReadOptions) -> Self {
        Self {
            input,
            opts,
            buf: Vec::new(),
            line_no: 0,
            in_segment: false,
            out: Default::default(),
            window: Default::default(),
            max_t: f64::NEG_INFINITY,
            suspect: None,
            last_seq: None,
            warnings: Vec::new(),
            stats: ReadStats::default(),
            failed: None,
            done: false,
        }
    }

    /// What was read and skipped so far.
    pub fn stats(&self) -> &ReadStats {
        &self.stats
    }

    /// The warnings since the last call (each names its line).
    pub fn take_warnings(&mut self) -> Vec<Warning> {
        std::mem::take(&mut self.warnings)
    }

    /// The first line of the pulse records read but not yet handed on (a replay that
    /// answers pulses in file order waits for them).
    pub fn first_pending_pulse_line(&self) -> Option<usize> {
        let queued = self
            .out
            .iter()
            .filter(|(_, i)| matches!(i, Item::Record(Record::Pulse(_)) | Item::Late(_)))
            .map(|(l, _)| *l);
        self.window
            .iter()
            .chain(self.suspect.as_ref())
            .filter(|p| matches!(p.item, Item::Record(Record::Pulse(_))))
            .map(|p| p.line)
            .chain(queued)
            .min()
    }

    /// The next item with its line number; `None` at the end. Errors: reading failed,
    /// no header at all, a header that is not version 1 of this format or holds an
    /// implausible value, and (strict mode) a malformed or over-long line.
    pub fn next_item(&mut self) -> Result<Option<(usize, Item)>, SessionError> {
        loop {
            if let Some(x) = self.out.pop_front() {
                return Ok(Some(x));
            }
            // An error comes after what was released before it (the records of a
            // segment ended by an unusable header are still handed on).
            if let Some(e) = self.failed.take() {
                self.done = true;
                return Err(e);
            }
            if self.done {
                return Ok(None);
            }
            if let Err(e) = self.read_one() {
                self.failed = Some(e);
            }
        }
    }

    fn warn(&mut self, line: usize, message: String) {
        self.warnings.push(Warning { line, message });
    }

    /// A line that cannot be used: an error in strict mode, else a warning.
    fn skip(&mut self, message: String) -> Result<(), SessionError> {
        if self.opts.strict {
            return Err(SessionError::Line {
                line: self.line_no,
                message,
            });
        }
        self.warn(self.line_no, message);
        Ok(())
    }

    /// Reads the next line into `buf` (without its newline, at most [`MAX_LINE_BYTES`]):
    /// `None` at the end of the input, else (over-long, ended by a newline).
    fn read_line(&mut self) -> std::io::Result<Option<(bool, bool)>> {
        self.buf.clear();
        let (mut any, mut too_long, mut newline) = (false, false, false);
        while !newline {
            let avail = match self.input.fill_buf() {
                Ok(b) => b,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if avail.is_empty() {
                break;
            }
            any = true;
            let (chunk, found) = match avail.iter().position(|&b| b == b'\n') {
                Some(i) => (&avail[..i], true),
                None => (avail, false),
            };
            // Past the limit the rest of the line is consumed without being kept.
            if !too_long {
                if self.buf.len() + chunk.len() > MAX_LINE_BYTES {
                    too_long = true;
                    self.buf.clear();
                } else {
                    self.buf.extend_from_slice(chunk);
                }
            }
            let used = chunk.len() + usize::from(found);
            self.input.consume(used);
            self.stats.bytes += used as u64;
            newline = found;
        }
        Ok(any.then_some((too_long, newline)))
    }

    /// Reads one line and files what it holds.
    fn read_one(&mut self) -> Result<(), SessionError> {
        let Some((too_long, newline)) = self.read_line()? else {
            self.end_segment();
            self.done = true;
            if self.stats.segments == 0 {
                return Err(SessionError::Empty);
            }
            return Ok(());
        };
        self.line_no += 1;
        self.stats.lines += 1;
        if too_long {
            self.stats.too_long += 1;
            return self.skip(format!("line longer than {MAX_LINE_BYTES} bytes refused"));
        }
        // A byte-order mark (at the start of the log, or of a log appended to another).
        let bytes = self.buf.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&self.buf);
        let text = match std::str::from_utf8(bytes) {
            Ok(t) => t.trim().to_owned(),
            Err(e) => {
                self.stats.malformed += 1;
                return self.skip(format!("not UTF-8 ({e}); line skipped"));
            }
        };
        if text.is_empty() {
            return Ok(());
        }
        let parsed = match parse_line(&text) {
            Ok(p) => p,
            Err(message) => {
                // A torn record followed by a whole one on the same line (power loss,
                // then the restarted writer): resynchronize at the whole one.
                let found = text
                    .match_indices("{\"type\"")
                    .filter(|(i, _)| *i > 0)
                    .find_map(|(i, _)| parse_line(&text[i..]).ok().map(|p| (i, p)));
                self.stats.malformed += 1;
                let message = if newline {
                    format!("malformed line skipped: {message}")
                } else {
                    format!(
                        "torn last line ({} bytes) skipped: {message}",
                        self.buf.len()
                    )
                };
                match found {
                    Some((i, p)) => {
                        self.stats.resynchronized += 1;
                        self.skip(format!(
                            "{message}; a record found after {i} damaged bytes is kept"
                        ))?;
                        p
                    }
                    None => return self.skip(message),
                }
            }
        };
        self.file(parsed)
    }

    fn check_seq(&mut self, seq: Option<u64>) {
        let Some(seq) = seq else { return };
        if let Some(last) = self.last_seq {
            if seq > last.saturating_add(1) {
                let lost = seq - last - 1;
                self.stats.seq_gaps += 1;
                self.stats.seq_lost += lost;
                self.warn(
                    self.line_no,
                    format!("seq jumps from {last} to {seq}: {lost} records lost"),
                );
            } else if seq <= last {
                self.stats.seq_gaps += 1;
                self.warn(self.line_no, format!("seq goes back from {last} to {seq}"));
            }
        }
        self.last_seq = Some(seq);
    }

    fn file(&mut self, parsed: (Option<u64>, Parsed)) -> Result<(), SessionError> {
        let (seq, parsed) = parsed;
        let line = self.line_no;
        if let Parsed::Header(h) = parsed {
            // The segment before ends either way: its records are good.
            self.end_segment();
            h.validate().map_err(|message| SessionError::Line {
                line,
                message: format!("header: {message}"),
            })?;
            self.in_segment = true;
            self.stats.segments += 1;
            self.last_seq = seq;
            self.out.push_back((line, Item::Header(h)));
            return Ok(());
        }
        if !self.in_segment {
            self.stats.before_header += 1;
            return self.skip("a record before the first header skipped".into());
        }
        self.check_seq(seq);
        match parsed {
            Parsed::Header(_) => Ok(()),
            Parsed::Unknown(ty) => {
                self.stats.unknown_type += 1;
                self.warn(line, format!("unknown record type \"{ty}\" skipped"));
                Ok(())
            }
            Parsed::Item(t, item) => {
                self.admit(Pending { t, line, item });
                Ok(())
            }
        }
    }

    /// A record whose `t` jumps more than the window ahead is held until the next one
    /// tells whether the clock really moved on (a gap) or the jump is damage.
    fn admit(&mut self, p: Pending) {
        let w = self.opts.window_s;
        if let Some(s) = self.suspect.take() {
            if p.t >= s.t - w {
                self.place(s);
            } else {
                self.refuse_late(
                    s,
                    "jumps ahead of the records around it (damaged?)".to_string(),
                );
            }
        }
        if w > 0.0 && self.max_t.is_finite() && p.t > self.max_t + w {
            self.suspect = Some(p);
        } else {
            self.place(p);
        }
    }

    fn refuse_late(&mut self, p: Pending, why: String) {
        self.stats.late += 1;
        self.warn(p.line, format!("t = {} {why}; record skipped", p.t));
        if let Item::Record(Record::Pulse(x)) = p.item {
            self.out.push_back((p.line, Item::Late(x)));
        }
    }

    fn place(&mut self, p: Pending) {
        let w = self.opts.window_s;
        if w <= 0.0 {
            // No window: file order, the consumer judges the times.
            self.release(p);
            return;
        }
        if p.t < self.max_t - w {
            let why = format!(
                "is more than {w} s earlier than a record before it (t = {})",
                self.max_t
            );
            self.refuse_late(p, why);
            return;
        }
        self.max_t = self.max_t.max(p.t);
        // Mostly in order: search from the back.
        let at = self
            .window
            .iter()
            .rposition(|q| (q.t, q.line) <= (p.t, p.line))
            .map_or(0, |i| i + 1);
        self.window.insert(at, p);
        while self.window.front().is_some_and(|q| q.t <= self.max_t - w) {
            if let Some(q) = self.window.pop_front() {
                self.release(q);
            }
        }
    }

    fn release(&mut self, q: Pending) {
        match &q.item {
            Item::Record(Record::Imu(_)) => self.stats.imu += 1,
            Item::Record(Record::Pulse(_)) => self.stats.pulses += 1,
            Item::Record(Record::Truth(_)) => self.stats.truth += 1,
            Item::Event(_) => self.stats.events += 1,
            Item::Header(_) | Item::Late(_) => {}
        }
        self.out.push_back((q.line, q.item));
    }

    /// Releases the whole window (a new header or the end of the input).
    fn end_segment(&mut self) {
        if let Some(s) = self.suspect.take() {
            self.place(s);
        }
        while let Some(q) = self.window.pop_front() {
            self.release(q);
        }
        self.max_t = f64::NEG_INFINITY;
        self.last_seq = None;
        self.in_segment = false;
    }
}

/// Parses one non-blank line: its `seq` and what it holds.
fn parse_line(text: &str) -> Result<(Option<u64>, Parsed), String> {
    let meta: Meta = serde_json::from_str(text).map_err(|e| json_message(&e))?;
    let ty = meta
        .ty
        .ok_or_else(|| "record has no \"type\" key".to_string())?;
    let item = |r: Record| Parsed::Item(r.t(), Item::Record(r));
    let parsed = match ty.as_str() {
        "header" => {
            let h: Header = parse(text, &ty)?;
            Parsed::Header(h)
        }
        "imu" => item(Record::Imu(parse(text, &ty)?)),
        "pulse" => item(Record::Pulse(parse(text, &ty)?)),
        "truth" => item(Record::Truth(parse(text, &ty)?)),
        "event" => {
            let mut e: Event = parse(text, &ty)?;
            e.extra.remove("type");
            e.extra.remove("seq");
            Parsed::Item(e.t, Item::Event(e))
        }
        _ => Parsed::Unknown(ty),
    };
    Ok((meta.seq, parsed))
}

fn parse<T: serde::de::DeserializeOwned>(text: &str, ty: &str) -> Result<T, String> {
    serde_json::from_str(text).map_err(|e| format!("{ty} record: {}", json_message(&e)))
}

/// serde_json's message with its position given as a column of the line (each line is
/// parsed on its own, so its "line 1" would mislead).
fn json_message(e: &serde_json::Error) -> String {
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    match full.strip_suffix(&suffix) {
        Some(msg) => format!("{msg} (column {})", e.column()),
        None => full,
    }
}

/// Writes a value as one JSON line to a file path, creating or truncating it.
pub fn create_file(path: &Path) -> std::io::Result<std::io::BufWriter<std::fs::File>> {
    Ok(std::io::BufWriter::new(std::fs::File::create(path)?))
}

#[cfg(test)]
mod tests {
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
}
