//! Session logs (`arva-session` version 1, `shared/spec/session-log.md`): record types,
//! a reader that reports malformed lines by number and skips unknown record types with a
//! warning, and a writer.
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

impl Header {
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
    /// The records after the header, in file order.
    pub records: Vec<Record>,
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
}

#[derive(Deserialize)]
struct TypeOnly {
    #[serde(rename = "type")]
    ty: Option<String>,
}

impl Session {
    /// An empty session with this header.
    pub fn new(header: Header) -> Self {
        Self {
            header,
            records: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// Writes the log: the header line, then one line per record.
    pub fn write(&self, out: &mut impl Write) -> std::io::Result<()> {
        write_line(out, &Tagged::Header(&self.header))?;
        for r in &self.records {
            write_record(out, r)?;
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

/// Reads a session log from a file.
pub fn read_file(path: &Path) -> Result<Session, SessionError> {
    let f = std::fs::File::open(path)?;
    read(std::io::BufReader::new(f))
}

/// Reads a session log. Blank lines are ignored; unknown keys are ignored; unknown
/// record types are skipped with a warning, and so is a torn last line (no newline, not
/// a whole JSON value: the writer stopped mid-record); anything else that is wrong (bad JSON, a
/// missing or mistyped field, no header first, a second header, an unsupported version,
/// time going backwards) is an error naming the line.
pub fn read(mut input: impl BufRead) -> Result<Session, SessionError> {
    let mut buf = Vec::new();
    let mut line_no = 0usize;
    let mut session: Option<Session> = None;
    let mut last_t = f64::NEG_INFINITY;
    loop {
        buf.clear();
        if input.read_until(b'\n', &mut buf)? == 0 {
            break;
        }
        line_no += 1;
        let err = |message: String| SessionError::Line {
            line: line_no,
            message,
        };
        // A last line without its newline that is not a whole JSON value was torn by a
        // crash or power loss while it was written: the records before it are kept.
        if !buf.ends_with(b"\n")
            && serde_json::from_slice::<serde_json::Value>(&buf).is_err()
            && let Some(s) = session.as_mut()
        {
            s.warnings.push(Warning {
                line: line_no,
                message: format!("torn last line ({} bytes) ignored", buf.len()),
            });
            break;
        }
        let text = std::str::from_utf8(&buf).map_err(|e| err(format!("not UTF-8: {e}")))?;
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        let tag: TypeOnly = serde_json::from_str(text).map_err(|e| err(json_message(&e)))?;
        let ty = tag
            .ty
            .ok_or_else(|| err("record has no \"type\" key".into()))?;
        let Some(s) = session.as_mut() else {
            if ty != "header" {
                return Err(err(format!(
                    "the first record must be the header, found type \"{ty}\""
                )));
            }
            let h: Header = parse(text, &ty).map_err(err)?;
            if h.format != FORMAT {
                return Err(err(format!(
                    "format is \"{}\", expected \"{FORMAT}\"",
                    h.format
                )));
            }
            if h.version != VERSION {
                return Err(err(format!("unsupported version {}", h.version)));
            }
            if h.imu_hz.is_nan() || h.imu_hz <= 0.0 {
                return Err(err(format!("imu_hz must be positive, got {}", h.imu_hz)));
            }
            session = Some(Session::new(h));
            continue;
        };
        let record = match ty.as_str() {
            "imu" => Record::Imu(parse(text, &ty).map_err(err)?),
            "pulse" => Record::Pulse(parse(text, &ty).map_err(err)?),
            "truth" => Record::Truth(parse(text, &ty).map_err(err)?),
            "header" => return Err(err("a second header".into())),
            other => {
                s.warnings.push(Warning {
                    line: line_no,
                    message: format!("unknown record type \"{other}\" skipped"),
                });
                continue;
            }
        };
        let t = record.t();
        if t < last_t {
            return Err(err(format!(
                "t = {t} is earlier than the previous record's t = {last_t}"
            )));
        }
        last_t = t;
        s.records.push(record);
    }
    session.ok_or(SessionError::Empty)
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
        // The same bytes with their newline are a malformed line, not a torn one.
        assert!(read(format!("{LOG}{{\"type\":\"imu\",\"t\":1\n").as_bytes()).is_err());
    }

    #[test]
    fn malformed_lines_name_their_number() {
        let cases = [
            (format!("{LOG}{{\"type\":\"imu\",\"t\":1\n"), 5),
            (format!("{LOG}{{\"type\":\"pulse\",\"t\":20.0}}\n"), 5),
            (
                format!("{LOG}{{\"type\":\"pulse\",\"t\":1.0,\"h\":[1,2,3]}}\n"),
                5,
            ),
            (format!("{LOG}{{\"t\":20.0}}\n"), 5),
            (
                format!("{LOG}{{\"type\":\"header\",\"format\":\"arva-session\",\"version\":1}}\n"),
                5,
            ),
            (format!("{LOG}[1,2]\n"), 5),
            (
                "{\"type\":\"imu\",\"t\":0,\"acc\":[0,0,0],\"gyr\":[0,0,0]}\n".to_string(),
                1,
            ),
            (
                "{\"type\":\"header\",\"format\":\"arva-session\",\"version\":2}\n".to_string(),
                1,
            ),
            (
                "\n\n{\"type\":\"header\",\"format\":\"x\",\"version\":1}\n".to_string(),
                3,
            ),
            (format!("{LOG}\u{0}\u{ff}\n"), 5),
        ];
        for (text, line) in cases {
            match read(text.as_bytes()) {
                Err(SessionError::Line { line: l, message }) => {
                    assert_eq!(l, line, "{message}");
                    assert!(!message.is_empty());
                }
                other => panic!("expected a line error, got {other:?}"),
            }
        }
        assert!(matches!(read(&b""[..]), Err(SessionError::Empty)));
        let mut bad = LOG.as_bytes().to_vec();
        bad.extend_from_slice(&[0xff, 0xfe, b'\n']);
        assert!(matches!(
            read(&bad[..]),
            Err(SessionError::Line { line: 5, .. })
        ));
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
