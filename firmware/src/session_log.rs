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

/// The header line: IMU rate (Hz), the local earth field in the geographic frame (µT)
/// and whether pulse signs are ambiguous.
pub fn write_header(
    w: &mut impl Write,
    imu_hz: f32,
    earth_field_ut: &Vec3,
    sign_ambiguous: bool,
) -> Result<(), LogError> {
    check(&[imu_hz, earth_field_ut.x, earth_field_ut.y, earth_field_ut.z])?;
    write!(
        w,
        "{{\"type\":\"header\",\"format\":\"arva-session\",\"version\":1,\"imu_hz\":{imu_hz},\"earth_field_uT\":"
    )?;
    write_vec(w, earth_field_ut, false)?;
    writeln!(w, ",\"sign_ambiguous\":{sign_ambiguous}}}")?;
    Ok(())
}

/// One IMU sample at time `t` (s); `mag` may be absent (magnetometer not read).
pub fn write_imu(
    w: &mut impl Write,
    t: f64,
    acc: &Vec3,
    gyr: &Vec3,
    mag: Option<&Vec3>,
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
    writeln!(w, "}}")?;
    Ok(())
}

/// One beacon pulse at time `t` (s) with field `h` (A/m, body frame) and, when the front
/// end separates several transmitters, its track `src`.
pub fn write_pulse(w: &mut impl Write, t: f64, h: &Vec3, src: Option<u8>) -> Result<(), LogError> {
    check(h.as_slice())?;
    if !t.is_finite() {
        return Err(LogError::NonFinite);
    }
    write!(w, "{{\"type\":\"pulse\",\"t\":{t},\"h\":")?;
    write_vec(w, h, true)?;
    if let Some(s) = src {
        write!(w, ",\"src\":{s}")?;
    }
    writeln!(w, "}}")?;
    Ok(())
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
    if !t.is_finite() {
        return Err(LogError::NonFinite);
    }
    let plain = |s: &str| !s.chars().any(|c| c == '"' || c == '\\' || c.is_control());
    if !plain(kind) || !why.is_none_or(plain) {
        return Err(LogError::Invalid);
    }
    write!(w, "{{\"type\":\"event\",\"t\":{t},\"kind\":\"{kind}\"")?;
    if let Some(why) = why {
        write!(w, ",\"why\":\"{why}\"")?;
    }
    writeln!(w, "}}")?;
    Ok(())
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
}
