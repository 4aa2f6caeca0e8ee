//! The streaming reader of the spec: bounded lines, the window for late pulses,
//! resynchronization after bad lines, segments, seq gaps, and the counts of what was read and
//! skipped.

use super::*;

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
pub(super) struct Pending {
    t: f64,
    line: usize,
    item: Item,
}

/// A line parsed on its own.
pub(super) enum Parsed {
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
    pub(super) buf: Vec<u8>,
    line_no: usize,
    in_segment: bool,
    /// Released items, in order.
    pub(super) out: std::collections::VecDeque<(usize, Item)>,
    /// The reordering window, sorted by (t, line).
    pub(super) window: std::collections::VecDeque<Pending>,
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
pub(super) struct Meta {
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
pub(super) fn parse_line(text: &str) -> Result<(Option<u64>, Parsed), String> {
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

pub(super) fn parse<T: serde::de::DeserializeOwned>(text: &str, ty: &str) -> Result<T, String> {
    serde_json::from_str(text).map_err(|e| format!("{ty} record: {}", json_message(&e)))
}

/// serde_json's message with its position given as a column of the line (each line is
/// parsed on its own, so its "line 1" would mislead).
pub(super) fn json_message(e: &serde_json::Error) -> String {
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    match full.strip_suffix(&suffix) {
        Some(msg) => format!("{msg} (column {})", e.column()),
        None => full,
    }
}
