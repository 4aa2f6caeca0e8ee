//! Writer of the session log (`arva-session` version 1, `../shared/spec/session-log.md`):
//! the board streams what its sensors delivered, one JSON object per line, so that a field
//! test can be replayed on a PC with `hal-sim replay`.
//!
//! Records are written to any [`core::fmt::Write`] (a UART, an RTT channel, a buffer)
//! *before* the estimator processes them, so a crash of the estimator never loses a
//! recorded sample. Non-finite values are refused with [`LogError::NonFinite`] (JSON has
//! no NaN) before anything is written, so a refused record never leaves half a line.
//! Units and frames are the spec's: `acc` m/s² specific force, `gyr` rad/s, `mag` µT,
//! `h` A/m, all in the body frame R (x forward, y left, z up); `t` in seconds.

use crate::Vec3;
use core::fmt::Write;

/// Why a record was not written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LogError {
    /// A value was NaN or infinite; nothing was written.
    #[error("value NaN or infinite: nothing written")]
    NonFinite,
    /// A text value that would need escaping in JSON; nothing was written.
    #[error("text that would need escaping: nothing written")]
    Invalid,
    /// The underlying writer failed (the line may be incomplete: readers tolerate a torn
    /// last line).
    #[error("the log writer failed")]
    Write,
}

impl From<core::fmt::Error> for LogError {
    fn from(_: core::fmt::Error) -> Self {
        LogError::Write
    }
}

fn check(values: &[f32]) -> Result<(), LogError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(LogError::NonFinite)
    }
}

/// Writes `[x,y,z]`; `exp` selects exponent notation (for fields spanning 1e-9…1e-3).
fn write_vec(w: &mut impl Write, v: &Vec3, exp: bool) -> Result<(), LogError> {
    if exp {
        write!(w, "[{:e},{:e},{:e}]", v.x, v.y, v.z)?;
    } else {
        write!(w, "[{},{},{}]", v.x, v.y, v.z)?;
    }
    Ok(())
}

/// Ends a record: the optional `seq` key, then `}` and the newline.
fn end(w: &mut impl Write, seq: Option<u64>) -> Result<(), LogError> {
    if let Some(n) = seq {
        write!(w, ",\"seq\":{n}")?;
    }
    writeln!(w, "}}")?;
    Ok(())
}

/// The header line: IMU rate (Hz), the local earth field in the geographic frame (µT)
/// and whether pulse signs are ambiguous.
pub fn write_header(
    w: &mut impl Write,
    imu_hz: f32,
    earth_field_ut: &Vec3,
    sign_ambiguous: bool,
) -> Result<(), LogError> {
    header(w, imu_hz, earth_field_ut, sign_ambiguous, None)
}

fn header(
    w: &mut impl Write,
    imu_hz: f32,
    earth_field_ut: &Vec3,
    sign_ambiguous: bool,
    seq: Option<u64>,
) -> Result<(), LogError> {
    check(&[imu_hz, earth_field_ut.x, earth_field_ut.y, earth_field_ut.z])?;
    write!(
        w,
        "{{\"type\":\"header\",\"format\":\"arva-session\",\"version\":1,\"imu_hz\":{imu_hz},\"earth_field_uT\":"
    )?;
    write_vec(w, earth_field_ut, false)?;
    write!(w, ",\"sign_ambiguous\":{sign_ambiguous}")?;
    end(w, seq)
}

/// One IMU sample at time `t` (s); `mag` may be absent (magnetometer not read).
pub fn write_imu(
    w: &mut impl Write,
    t: f64,
    acc: &Vec3,
    gyr: &Vec3,
    mag: Option<&Vec3>,
) -> Result<(), LogError> {
    imu(w, t, acc, gyr, mag, None)
}

fn imu(
    w: &mut impl Write,
    t: f64,
    acc: &Vec3,
    gyr: &Vec3,
    mag: Option<&Vec3>,
    seq: Option<u64>,
) -> Result<(), LogError> {
    check(acc.as_slice())?;
    check(gyr.as_slice())?;
    if let Some(m) = mag {
        check(m.as_slice())?;
    }
    if !t.is_finite() {
        return Err(LogError::NonFinite);
    }
    write!(w, "{{\"type\":\"imu\",\"t\":{t},\"acc\":")?;
    write_vec(w, acc, false)?;
    write!(w, ",\"gyr\":")?;
    write_vec(w, gyr, false)?;
    if let Some(m) = mag {
        write!(w, ",\"mag\":")?;
        write_vec(w, m, false)?;
    }
    end(w, seq)
}

/// One beacon pulse at time `t` (s) with field `h` (A/m, body frame) and, when the front
/// end separates several transmitters, its track `src`.
pub fn write_pulse(w: &mut impl Write, t: f64, h: &Vec3, src: Option<u8>) -> Result<(), LogError> {
    pulse(w, t, h, src, None)
}

fn pulse(
    w: &mut impl Write,
    t: f64,
    h: &Vec3,
    src: Option<u8>,
    seq: Option<u64>,
) -> Result<(), LogError> {
    check(h.as_slice())?;
    if !t.is_finite() {
        return Err(LogError::NonFinite);
    }
    write!(w, "{{\"type\":\"pulse\",\"t\":{t},\"h\":")?;
    write_vec(w, h, true)?;
    if let Some(s) = src {
        write!(w, ",\"src\":{s}")?;
    }
    end(w, seq)
}

/// An event record at time `t` (s): `kind` is one of the spec's kinds (`"mark"`,
/// `"withheld"`, `"gain"`, `"overrun"`, `"read_error"`, `"reset"`, `"settings"`) and `why`
/// an optional detail. Both are written as JSON strings; a `"` or `\` in them, or a control
/// character, is refused with [`LogError::Invalid`] before anything is written.
pub fn write_event(
    w: &mut impl Write,
    t: f64,
    kind: &str,
    why: Option<&str>,
) -> Result<(), LogError> {
    event(w, t, kind, why, &[], None)
}

/// A value of an event's extra key (the spec: "extra keys carry the details").
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Detail<'a> {
    /// A JSON string (refused like `why` when it would need escaping).
    Text(&'a str),
    /// A JSON integer (counts, ids).
    Int(i64),
    /// A JSON number (refused when not finite).
    Num(f32),
    /// A JSON boolean.
    Flag(bool),
}

/// Whether `s` can be written as a JSON string without escaping.
fn plain(s: &str) -> bool {
    !s.chars().any(|c| c == '"' || c == '\\' || c.is_control())
}

/// `s` made writable as a JSON string without escaping, in `buf`: a `"` becomes `'`, a
/// `\` or a control character (a newline) a space; cut at a character boundary when
/// `buf` is too small. For texts from outside (a panic message) before they go into an
/// event.
pub fn plain_text<'a>(s: &str, buf: &'a mut [u8]) -> &'a str {
    let mut n = 0;
    for c in s.chars() {
        let c = match c {
            '"' => '\'',
            '\\' => ' ',
            c if c.is_control() => ' ',
            c => c,
        };
        let mut tmp = [0u8; 4];
        let bytes = c.encode_utf8(&mut tmp).as_bytes();
        let Some(dst) = buf.get_mut(n..n + bytes.len()) else {
            break;
        };
        dst.copy_from_slice(bytes);
        n += bytes.len();
    }
    buf.get(..n)
        .and_then(|b| core::str::from_utf8(b).ok())
        .unwrap_or("")
}

/// An event record with extra keys `details` (key, value) after `kind` and `why`; keys and
/// text values are checked like `kind`, numbers for finiteness, all before anything is
/// written.
pub fn write_event_with(
    w: &mut impl Write,
    t: f64,
    kind: &str,
    why: Option<&str>,
    details: &[(&str, Detail<'_>)],
) -> Result<(), LogError> {
    event(w, t, kind, why, details, None)
}

fn event(
    w: &mut impl Write,
    t: f64,
    kind: &str,
    why: Option<&str>,
    details: &[(&str, Detail<'_>)],
    seq: Option<u64>,
) -> Result<(), LogError> {
    if !t.is_finite() {
        return Err(LogError::NonFinite);
    }
    if !plain(kind) || !why.is_none_or(plain) {
        return Err(LogError::Invalid);
    }
    for (key, value) in details {
        let reserved = matches!(*key, "type" | "t" | "kind" | "why" | "seq");
        match value {
            _ if reserved || !plain(key) => return Err(LogError::Invalid),
            Detail::Text(s) if !plain(s) => return Err(LogError::Invalid),
            Detail::Num(x) if !x.is_finite() => return Err(LogError::NonFinite),
            _ => {}
        }
    }
    write!(w, "{{\"type\":\"event\",\"t\":{t},\"kind\":\"{kind}\"")?;
    if let Some(why) = why {
        write!(w, ",\"why\":\"{why}\"")?;
    }
    for (key, value) in details {
        match value {
            Detail::Text(s) => write!(w, ",\"{key}\":\"{s}\"")?,
            Detail::Int(n) => write!(w, ",\"{key}\":{n}")?,
            Detail::Num(x) => write!(w, ",\"{key}\":{x}")?,
            Detail::Flag(b) => write!(w, ",\"{key}\":{b}")?,
        }
    }
    end(w, seq)
}

/// What a [`Recorder`] did with the records it was given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecorderStats {
    /// Records written whole.
    pub written: u64,
    /// Records refused before anything was written (non-finite value, text needing
    /// escaping): they take no `seq` number.
    pub refused: u32,
    /// Records the writer failed on (lost or torn): each took its `seq` number, so a reader
    /// sees the gap.
    pub failed: u32,
}

/// The board's session log: writes every record with `seq` (+1 per record, restarting at
/// 0 with each header, as the spec's readers expect) and counts what was refused and what
/// the writer failed on, so that no error is dropped silently.
#[derive(Debug)]
pub struct Recorder<W> {
    w: W,
    seq: u64,
    stats: RecorderStats,
}

impl<W: Write> Recorder<W> {
    /// A recorder writing to `w`; the first record should be a [`Recorder::header`].
    pub fn new(w: W) -> Self {
        Self {
            w,
            seq: 0,
            stats: RecorderStats::default(),
        }
    }

    /// Counts the outcome of one record; a write failure still uses up its `seq`.
    fn count(&mut self, r: Result<(), LogError>) -> Result<(), LogError> {
        match r {
            Ok(()) => {
                self.seq += 1;
                self.stats.written += 1;
            }
            Err(LogError::Write) => {
                self.seq += 1;
                self.stats.failed = self.stats.failed.saturating_add(1);
            }
            Err(_) => self.stats.refused = self.stats.refused.saturating_add(1),
        }
        r
    }

    /// The header (starts a segment: `seq` restarts at 0).
    pub fn header(
        &mut self,
        imu_hz: f32,
        earth_field_ut: &Vec3,
        sign_ambiguous: bool,
    ) -> Result<(), LogError> {
        self.seq = 0;
        let r = header(&mut self.w, imu_hz, earth_field_ut, sign_ambiguous, Some(0));
        self.count(r)
    }

    /// An IMU sample (see [`write_imu`]).
    pub fn imu(
        &mut self,
        t: f64,
        acc: &Vec3,
        gyr: &Vec3,
        mag: Option<&Vec3>,
    ) -> Result<(), LogError> {
        let r = imu(&mut self.w, t, acc, gyr, mag, Some(self.seq));
        self.count(r)
    }

    /// A pulse (see [`write_pulse`]).
    pub fn pulse(&mut self, t: f64, h: &Vec3, src: Option<u8>) -> Result<(), LogError> {
        let r = pulse(&mut self.w, t, h, src, Some(self.seq));
        self.count(r)
    }

    /// An event (see [`write_event_with`]).
    pub fn event(
        &mut self,
        t: f64,
        kind: &str,
        why: Option<&str>,
        details: &[(&str, Detail<'_>)],
    ) -> Result<(), LogError> {
        let r = event(&mut self.w, t, kind, why, details, Some(self.seq));
        self.count(r)
    }

    /// The counts so far.
    pub fn stats(&self) -> RecorderStats {
        self.stats
    }

    /// The writer (to flush it, check its health or swap its medium).
    pub fn writer(&mut self) -> &mut W {
        &mut self.w
    }

    /// The writer, to look at.
    pub fn writer_ref(&self) -> &W {
        &self.w
    }

    /// Gives the writer back.
    pub fn into_writer(self) -> W {
        self.w
    }
}

/// Writes to two writers (the SD card and the UART stream) and counts each one's failed
/// writes. With a second writer it fails only when both fail, so that a dead card does
/// not tear the UART's lines (a record's `write!` stops at its first error); with one
/// writer it fails when that one fails.
#[derive(Debug)]
pub struct Tee<A, B> {
    /// The first writer.
    pub a: A,
    /// The second writer (`None`: not used).
    pub b: Option<B>,
    errors: [u32; 2],
}

impl<A, B> Tee<A, B> {
    /// Writes to `a` and, when given, `b`.
    pub fn new(a: A, b: Option<B>) -> Self {
        Self {
            a,
            b,
            errors: [0; 2],
        }
    }

    /// Failed writes of the first and of the second writer.
    pub fn errors(&self) -> [u32; 2] {
        self.errors
    }
}

impl<A: Write, B: Write> Write for Tee<A, B> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let ra = self.a.write_str(s);
        let [ea, eb] = &mut self.errors;
        if ra.is_err() {
            *ea = ea.saturating_add(1);
        }
        let Some(b) = self.b.as_mut() else {
            return ra;
        };
        let rb = b.write_str(s);
        if rb.is_err() {
            *eb = eb.saturating_add(1);
        }
        ra.or(rb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::string::String;

    #[test]
    fn lines_follow_the_spec() {
        let mut s = String::new();
        write_header(&mut s, 100.0, &Vec3::new(21.0, 0.0, -42.0), true).unwrap();
        write_imu(
            &mut s,
            12.34,
            &Vec3::new(0.1, -0.2, 9.9),
            &Vec3::new(0.01, 0.0, -0.02),
            Some(&Vec3::new(20.5, 1.0, -41.7)),
        )
        .unwrap();
        write_pulse(&mut s, 12.5, &Vec3::new(1.2e-6, -3.4e-7, 8.0e-8), Some(2)).unwrap();
        let lines: std::vec::Vec<&str> = s.lines().collect();
        assert_eq!(
            lines[0],
            r#"{"type":"header","format":"arva-session","version":1,"imu_hz":100,"earth_field_uT":[21,0,-42],"sign_ambiguous":true}"#
        );
        assert_eq!(
            lines[1],
            r#"{"type":"imu","t":12.34,"acc":[0.1,-0.2,9.9],"gyr":[0.01,0,-0.02],"mag":[20.5,1,-41.7]}"#
        );
        assert_eq!(
            lines[2],
            r#"{"type":"pulse","t":12.5,"h":[1.2e-6,-3.4e-7,8e-8],"src":2}"#
        );
    }

    #[test]
    fn events_follow_the_spec() {
        let mut s = String::new();
        write_event(&mut s, 80.2, "mark", None).unwrap();
        write_event(&mut s, 81.0, "withheld", Some("overlap")).unwrap();
        let lines: std::vec::Vec<&str> = s.lines().collect();
        assert_eq!(lines[0], r#"{"type":"event","t":80.2,"kind":"mark"}"#);
        assert_eq!(
            lines[1],
            r#"{"type":"event","t":81,"kind":"withheld","why":"overlap"}"#
        );
        let before = s.clone();
        assert_eq!(
            write_event(&mut s, 1.0, "a\"b", None),
            Err(LogError::Invalid)
        );
        assert_eq!(
            write_event(&mut s, 1.0, "gain", Some("x\ny")),
            Err(LogError::Invalid)
        );
        assert_eq!(
            write_event(&mut s, f64::NAN, "mark", None),
            Err(LogError::NonFinite)
        );
        assert_eq!(s, before);
    }

    #[test]
    fn non_finite_values_write_nothing() {
        let mut s = String::new();
        assert_eq!(
            write_pulse(&mut s, 1.0, &Vec3::new(f32::NAN, 0.0, 0.0), None),
            Err(LogError::NonFinite)
        );
        assert_eq!(
            write_imu(&mut s, f64::INFINITY, &Vec3::zeros(), &Vec3::zeros(), None),
            Err(LogError::NonFinite)
        );
        assert_eq!(
            write_header(&mut s, f32::NAN, &Vec3::zeros(), true),
            Err(LogError::NonFinite)
        );
        assert!(s.is_empty());
    }

    /// A writer that fails from its `n`-th write on.
    struct FailAfter {
        out: String,
        left: usize,
    }

    impl Write for FailAfter {
        fn write_str(&mut self, s: &str) -> core::fmt::Result {
            if self.left == 0 {
                return Err(core::fmt::Error);
            }
            self.left -= 1;
            self.out.push_str(s);
            Ok(())
        }
    }

    #[test]
    fn recorder_numbers_records_and_counts_failures() {
        let mut r = Recorder::new(String::new());
        r.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true).unwrap();
        r.imu(0.01, &Vec3::zeros(), &Vec3::zeros(), None).unwrap();
        assert_eq!(
            r.pulse(0.5, &Vec3::new(f32::NAN, 0.0, 0.0), None),
            Err(LogError::NonFinite)
        );
        r.event(
            0.6,
            "read_error",
            Some("imu"),
            &[("count", Detail::Int(3)), ("ok", Detail::Flag(false))],
        )
        .unwrap();
        assert_eq!(
            r.event(0.7, "gain", None, &[("seq", Detail::Int(1))]),
            Err(LogError::Invalid)
        );
        assert_eq!(
            r.event(0.7, "gain", None, &[("db", Detail::Num(f32::INFINITY))]),
            Err(LogError::NonFinite)
        );
        r.event(
            0.8,
            "gain",
            None,
            &[("range", Detail::Text("low")), ("db", Detail::Num(-6.5))],
        )
        .unwrap();
        assert_eq!(
            r.stats(),
            RecorderStats {
                written: 4,
                refused: 3,
                failed: 0
            }
        );
        let text = r.into_writer();
        let lines: std::vec::Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4);
        assert!(lines[0].ends_with(r#","sign_ambiguous":true,"seq":0}"#));
        assert_eq!(
            lines[1],
            r#"{"type":"imu","t":0.01,"acc":[0,0,0],"gyr":[0,0,0],"seq":1}"#
        );
        assert_eq!(
            lines[2],
            r#"{"type":"event","t":0.6,"kind":"read_error","why":"imu","count":3,"ok":false,"seq":2}"#
        );
        assert_eq!(
            lines[3],
            r#"{"type":"event","t":0.8,"kind":"gain","range":"low","db":-6.5,"seq":3}"#
        );

        // A failing writer: the record is counted as failed and its number is used up, so
        // the next record read shows the gap.
        let mut r = Recorder::new(FailAfter {
            out: String::new(),
            left: 1000,
        });
        r.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true).unwrap();
        r.writer().left = 0;
        assert_eq!(
            r.imu(0.01, &Vec3::zeros(), &Vec3::zeros(), None),
            Err(LogError::Write)
        );
        assert_eq!(r.stats().failed, 1);
        r.writer().left = 100;
        r.event(0.02, "mark", None, &[]).unwrap();
        assert!(r.into_writer().out.ends_with(
            r#""kind":"mark","seq":2}
"#
        ));
    }

    #[test]
    fn outside_text_is_made_plain_and_cut_on_a_character() {
        let mut buf = [0u8; 16];
        let t = plain_text("bad \"x\"\n@a\\b.rs:3", &mut buf);
        assert_eq!(t, "bad 'x' @a b.rs:");
        let mut s = String::new();
        write_event(&mut s, 1.0, "reset", Some(t)).unwrap();
        let mut small = [0u8; 5];
        assert_eq!(plain_text("abcdé", &mut small), "abcd");
    }

    #[test]
    fn tee_writes_both_and_fails_only_when_both_fail() {
        let mut t = Tee::new(
            String::new(),
            Some(FailAfter {
                out: String::new(),
                left: 1,
            }),
        );
        t.write_str("ab").unwrap();
        t.write_str("cd").unwrap();
        assert_eq!(t.a, "abcd");
        assert_eq!(t.errors(), [0, 1]);
        let mut t = Tee::new(
            FailAfter {
                out: String::new(),
                left: 0,
            },
            Some(FailAfter {
                out: String::new(),
                left: 0,
            }),
        );
        assert!(t.write_str("x").is_err());
        assert_eq!(t.errors(), [1, 1]);
        let mut t: Tee<FailAfter, String> = Tee::new(
            FailAfter {
                out: String::new(),
                left: 0,
            },
            None,
        );
        assert!(t.write_str("x").is_err());
        assert_eq!(t.errors(), [1, 0]);
    }
}
