//! The board's session-log records on their way from the processing task to the log
//! writer (the idle loop): [`LogItem`], queued by value, written by
//! [`BoardLog::write_item`]; and the overrun counts ([`Overruns`]) turned into `overrun`
//! events once per tick. The event kinds and keys: [`crate::board::board_log`].

use crate::Vec3;
use crate::board::board_log::BoardLog;
use crate::board::gain::GainEvent;
use crate::frontend::PulseMeasurement;
use crate::session_log::Detail;
use crate::timebase::Instant;
use core::fmt::Write;
use embedded_sdmmc::BlockDevice;

/// A session-log record, formatted and written by the log writer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LogItem {
    /// An IMU sample (magnetometer calibrated).
    Imu {
        /// Board time, s.
        t: f64,
        /// Specific force, m/s².
        acc: Vec3,
        /// Angular rate, rad/s.
        gyr: Vec3,
        /// Magnetic field (calibrated), µT.
        mag: Vec3,
    },
    /// A pulse the front end finished (or why it was withheld).
    Pulse {
        /// Board time of the pulse's centre, s.
        t: f64,
        /// Its field, or why there is none.
        m: PulseMeasurement,
        /// The front end's track.
        src: Option<u8>,
    },
    /// A change of the analog setting (gain ranging) as applied.
    Gain(GainEvent),
    /// A new segment: the receiver was rebuilt (mode, region or step length changed in
    /// the menu).
    Header {
        /// IMU rate, Hz.
        imu_hz: f32,
        /// The new earth field, µT.
        earth_ut: Vec3,
    },
    /// A menu procedure started or ended.
    Calibration {
        /// Board time, s.
        t: f64,
        /// `step_walk` or `mag_cal`.
        what: &'static str,
        /// `start`, `cancelled`, or the outcome's word.
        result: &'static str,
        /// The step length (m) or the fit's residual (µT RMS), when done.
        value: Option<f32>,
    },
    /// An event with an optional count.
    Event {
        /// Board time, s.
        t: f64,
        /// The spec's event kind.
        kind: &'static str,
        /// Its cause.
        why: Option<&'static str>,
        /// The `count` key.
        count: Option<i64>,
    },
}

impl<D: BlockDevice, U: Write> BoardLog<D, U> {
    /// Writes one queued record; returns its time (s), `None` for a header.
    pub fn write_item(&mut self, item: &LogItem) -> Option<f64> {
        match *item {
            LogItem::Imu { t, acc, gyr, mag } => {
                self.imu(t, &acc, &gyr, Some(&mag));
                Some(t)
            }
            LogItem::Pulse { t, m, src } => {
                self.pulse(t, &m, src);
                Some(t)
            }
            LogItem::Gain(e) => {
                self.gain(&e);
                Some(Instant::from_micros(e.t_us).secs_f64())
            }
            LogItem::Header { imu_hz, earth_ut } => {
                self.header(imu_hz, &earth_ut, true);
                None
            }
            LogItem::Calibration {
                t,
                what,
                result,
                value,
            } => {
                let result = ("result", Detail::Text(result));
                match value {
                    Some(v) => self.event(
                        t,
                        "calibration",
                        Some(what),
                        &[result, ("value", Detail::Num(v))],
                    ),
                    None => self.event(t, "calibration", Some(what), &[result]),
                }
                Some(t)
            }
            LogItem::Event {
                t,
                kind,
                why,
                count,
            } => {
                match count {
                    Some(c) => self.event(t, kind, why, &[("count", Detail::Int(c))]),
                    None => self.event(t, kind, why, &[]),
                }
                Some(t)
            }
        }
    }
}

/// The overrun kinds, in the order of the counts handed to [`Overruns::report`]: ADC
/// samples dropped (sample queue full), IMU ticks missed, IMU records lost (queue full),
/// log records lost (queue full), ADC samples lost while a settings save stalled the
/// flash.
pub const OVERRUN_KINDS: [&str; 5] = ["adc_queue", "imu_tick", "imu_queue", "log_queue", "flash"];

/// What was last reported of each (wrapping) overrun count.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Overruns {
    reported: [u32; 5],
}

impl Overruns {
    /// Nothing reported yet (the counts start at 0).
    pub fn new() -> Self {
        Self::default()
    }

    /// The kinds whose count grew since the last call, with how much (counts may wrap).
    pub fn report(&mut self, now: [u32; 5]) -> heapless::Vec<(&'static str, u32), 5> {
        let mut out = heapless::Vec::new();
        for ((n, last), why) in now.iter().zip(self.reported.iter()).zip(OVERRUN_KINDS) {
            let new = n.wrapping_sub(*last);
            if new > 0 {
                // At most 5 entries: the capacity.
                let _fits = out.push((why, new));
            }
        }
        self.reported = now;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::sd_log::{RamCard, SdSink};
    use crate::frontend::{Range, RangeChange, RangeReason};
    extern crate std;
    use std::string::String;
    use std::vec::Vec;

    #[test]
    fn every_item_becomes_one_line_and_the_writer_learns_its_time() {
        let mut log: BoardLog<RamCard<'_>, String> =
            BoardLog::new(SdSink::new(None), Some(String::new()));
        let v = Vec3::new(1.0, 2.0, 3.0);
        let items = [
            LogItem::Header {
                imu_hz: 100.0,
                earth_ut: Vec3::new(21.0, 0.0, -42.0),
            },
            LogItem::Imu {
                t: 0.01,
                acc: v,
                gyr: v,
                mag: v,
            },
            LogItem::Pulse {
                t: 0.5,
                m: PulseMeasurement::Saturated,
                src: None,
            },
            LogItem::Gain(GainEvent {
                t_us: 600_000,
                change: RangeChange {
                    t_s: 0.6,
                    from: Range::MOST_SENSITIVE,
                    to: Range::HIGH_G1,
                    reason: RangeReason::Saturated,
                },
                applied: true,
            }),
            LogItem::Calibration {
                t: 0.7,
                what: "step_walk",
                result: "done",
                value: Some(0.75),
            },
            LogItem::Calibration {
                t: 0.8,
                what: "mag_cal",
                result: "cancelled",
                value: None,
            },
            LogItem::Event {
                t: 0.9,
                kind: "overrun",
                why: Some("flash"),
                count: Some(12),
            },
            LogItem::Event {
                t: 1.0,
                kind: "mark",
                why: None,
                count: None,
            },
        ];
        let times: Vec<Option<f64>> = items.iter().map(|i| log.write_item(i)).collect();
        assert_eq!(
            times,
            [
                None,
                Some(0.01),
                Some(0.5),
                Some(0.6),
                Some(0.7),
                Some(0.8),
                Some(0.9),
                Some(1.0)
            ]
        );
        let uart = log.uart().cloned().unwrap_or_default();
        let lines: Vec<&str> = uart.lines().collect();
        assert_eq!(lines.len(), items.len());
        assert!(lines[0].starts_with(r#"{"type":"header""#));
        assert!(lines[1].starts_with(r#"{"type":"imu","t":0.01,"#));
        assert_eq!(
            lines[2],
            r#"{"type":"event","t":0.5,"kind":"withheld","why":"saturated","seq":2}"#
        );
        assert!(lines[3].contains(r#""kind":"gain","why":"saturated","range":"high","pga":1,"from_range":"high","from_pga":128,"applied":true"#), "{}", lines[3]);
        assert_eq!(
            lines[4],
            r#"{"type":"event","t":0.7,"kind":"calibration","why":"step_walk","result":"done","value":0.75,"seq":4}"#
        );
        assert_eq!(
            lines[5],
            r#"{"type":"event","t":0.8,"kind":"calibration","why":"mag_cal","result":"cancelled","seq":5}"#
        );
        assert_eq!(
            lines[6],
            r#"{"type":"event","t":0.9,"kind":"overrun","why":"flash","count":12,"seq":6}"#
        );
        assert_eq!(lines[7], r#"{"type":"event","t":1,"kind":"mark","seq":7}"#);
    }

    #[test]
    fn overruns_are_reported_once_by_kind_across_a_wrap() {
        let mut o = Overruns::new();
        assert!(o.report([0; 5]).is_empty());
        let r = o.report([3, 0, 0, 1, 0]);
        assert_eq!(r.as_slice(), [("adc_queue", 3), ("log_queue", 1)]);
        // Unchanged counts: nothing again.
        assert!(o.report([3, 0, 0, 1, 0]).is_empty());
        // A count that wrapped past u32::MAX.
        let mut o = Overruns::new();
        o.report([0, 0, 0, 0, u32::MAX - 1]);
        assert_eq!(o.report([0, 0, 0, 0, 2]).as_slice(), [("flash", 4)]);
    }
}
