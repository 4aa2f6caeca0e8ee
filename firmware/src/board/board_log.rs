//! The board's session log: one [`Recorder`] writing every record, with `seq`, to the SD
//! card ([`SdSink`]) and, as an option, to the UART stream; the device events a replay
//! needs (the last reset's cause, withheld pulses and why, failed reads, overruns, marks,
//! settings, faults); and the write errors, counted and reported, never dropped.
//!
//! Event kinds and their keys (spec `arva-session` v1: "extra keys carry the details"):
//!
//! | kind | why | extra keys |
//! |---|---|---|
//! | `reset` | `clean`, `panic`, `watchdog` or `hung` | `message` (the crash record's text) |
//! | `settings` | `stored` or `defaults` (boot), `menu` (changed in the menu), `saved` or `not_saved` (the flash write) | boot: the settings' keys, `slot`, `torn`; menu: `count` (volume); save: `slot`, `erased`, `stall_ms` or `error` |
//! | `gain` | `saturated`, `strong` or `weak` (the ranging rule's reason) | `range`, `pga` (the setting asked for: IF range `high`/`low`, PGA gain 1–128), `from_range`, `from_pga` (the setting before), `applied` (false: the PGA write failed, the hardware stays at `from_*`); `t` is the first sample in the new setting |
//! | `withheld` | `overlap`, `saturated`, `truncated` | – |
//! | `read_error` | `imu` or `adc` | `count` (ADC: failed frames in the last second) |
//! | `overrun` | `adc_queue`, `imu_tick`, `imu_queue`, `log_queue` or `flash` | `count` (samples dropped, IMU ticks missed, IMU records or log records lost since the last report; `flash`: ADC samples lost while a settings save stalled the flash) |
//! | `mark` | – | – |
//! | `calibration` | `step_walk` or `mag_cal` (a menu procedure) | `result` (`start`, `cancelled`, `done` or the failure's word), `value` (step length m, or the fit's residual µT RMS) |
//! | `fault` | the fault's word, or `cleared` | – |
//! | `log_error` | `sd` or `uart` | `failed`, `refused` (records lost on every writer, records refused), `sd_lost_bytes`, `sd` (the card's word or `logging`) |
//! | `log_error` | `sd_remount` (the failed card remounted: a new file, after a new header) | `file` (its session number) |

use crate::Vec3;
use crate::board::crash::LastReset;
use crate::board::gain::{GainEvent, if_word, reason_word};
use crate::board::sd_log::{SdSink, SdState};
use crate::board::settings::REGIONS;
use crate::board::settings_store::{Loaded, Saved, StoreError};
use crate::frontend::PulseMeasurement;
use crate::session_log::{Detail, Recorder, RecorderStats, Tee, plain_text};
use crate::timebase::Instant;
use core::fmt::Write;
use embedded_sdmmc::BlockDevice;

/// The board's session log over an SD sink and an optional UART stream `U`.
pub struct BoardLog<D: BlockDevice, U: Write> {
    rec: Recorder<Tee<SdSink<D>, U>>,
    /// What was last reported: records failed and refused, the writers' failed writes.
    reported: (u32, u32, [u32; 2]),
    /// The last header's values, written again at the start of a remounted card's file.
    header: Option<(f32, Vec3, bool)>,
}

/// The `why` of a withheld pulse (`None` for a measured one).
pub fn withheld_why(m: &PulseMeasurement) -> Option<&'static str> {
    match m {
        PulseMeasurement::Field(_) => None,
        PulseMeasurement::Overlap => Some("overlap"),
        PulseMeasurement::Saturated => Some("saturated"),
        PulseMeasurement::Truncated => Some("truncated"),
    }
}

impl<D: BlockDevice, U: Write> BoardLog<D, U> {
    /// A log writing to `sd` and, when given, `uart`.
    pub fn new(sd: SdSink<D>, uart: Option<U>) -> Self {
        Self {
            rec: Recorder::new(Tee::new(sd, uart)),
            reported: (0, 0, [0; 2]),
            header: None,
        }
    }

    /// The header (a segment starts).
    pub fn header(&mut self, imu_hz: f32, earth_field_ut: &Vec3, sign_ambiguous: bool) {
        self.header = Some((imu_hz, *earth_field_ut, sign_ambiguous));
        let _counted = self.rec.header(imu_hz, earth_field_ut, sign_ambiguous);
    }

    /// The last reset's cause, right after the header.
    pub fn reset(&mut self, t: f64, last: &LastReset<'_>) {
        let (why, message) = match last {
            LastReset::Clean => ("clean", None),
            LastReset::Panic(m) => ("panic", Some(*m)),
            LastReset::Starved(m) => ("watchdog", Some(*m)),
            LastReset::WatchdogHung => ("hung", None),
        };
        let mut buf = [0u8; 128];
        match message {
            Some(m) => {
                let m = plain_text(m, &mut buf);
                self.event(t, "reset", Some(why), &[("message", Detail::Text(m))]);
            }
            None => self.event(t, "reset", Some(why), &[]),
        }
    }

    /// An IMU sample.
    pub fn imu(&mut self, t: f64, acc: &Vec3, gyr: &Vec3, mag: Option<&Vec3>) {
        let _counted = self.rec.imu(t, acc, gyr, mag);
    }

    /// A pulse the front end finished: its field, or why it was withheld.
    pub fn pulse(&mut self, t: f64, m: &PulseMeasurement, src: Option<u8>) {
        match (m, withheld_why(m)) {
            (PulseMeasurement::Field(h), _) => {
                let _counted = self.rec.pulse(t, h, src);
            }
            (_, why) => self.event(t, "withheld", why, &[]),
        }
    }

    /// A change of the analog setting (gain ranging), as the board applied it.
    pub fn gain(&mut self, e: &GainEvent) {
        let t = Instant::from_micros(e.t_us).secs_f64();
        let (from, to) = (e.change.from, e.change.to);
        self.event(
            t,
            "gain",
            Some(reason_word(e.change.reason)),
            &[
                ("range", Detail::Text(if_word(to.if_range))),
                ("pga", Detail::Int(i64::from(to.gain.factor()))),
                ("from_range", Detail::Text(if_word(from.if_range))),
                ("from_pga", Detail::Int(i64::from(from.gain.factor()))),
                ("applied", Detail::Flag(e.applied)),
            ],
        );
    }

    /// The settings read at boot (`why` `stored` or `defaults`): each value, the slot
    /// they came from and the newer torn slots; `step_length_m` is the length in use
    /// (`None`: not calibrated, the step detector's default applies).
    pub fn settings_loaded(&mut self, t: f64, loaded: &Loaded, step_length_m: Option<f32>) {
        let s = &loaded.settings;
        let region = REGIONS.get(usize::from(s.region)).map_or("?", |r| r.name);
        let why = if loaded.defaults_because.is_some() {
            "defaults"
        } else {
            "stored"
        };
        self.event(
            t,
            "settings",
            Some(why),
            &[
                (
                    "step_length_m",
                    step_length_m.map_or(Detail::Text("none"), Detail::Num),
                ),
                ("mode", Detail::Text(s.mode.word())),
                ("volume", Detail::Int(i64::from(s.volume))),
                ("region", Detail::Text(region)),
                ("antenna_cal", Detail::Flag(s.calibration.antenna.is_some())),
                ("mag_cal", Detail::Flag(s.calibration.mag.is_some())),
                (
                    "slot",
                    loaded
                        .slot
                        .map_or(Detail::Text("none"), |k| Detail::Int(i64::from(k))),
                ),
                ("torn", Detail::Int(i64::from(loaded.torn))),
            ],
        );
    }

    /// How a settings save went (`why` `saved` or `not_saved`), with the flash's stall.
    pub fn settings_saved(&mut self, t: f64, result: &Result<Saved, StoreError>, stall_ms: u64) {
        let stall = (
            "stall_ms",
            Detail::Int(i64::try_from(stall_ms).unwrap_or(i64::MAX)),
        );
        match result {
            Ok(saved) => self.event(
                t,
                "settings",
                Some("saved"),
                &[
                    ("slot", Detail::Int(i64::from(saved.slot))),
                    ("erased", Detail::Flag(saved.erased)),
                    stall,
                ],
            ),
            Err(e) => self.event(
                t,
                "settings",
                Some("not_saved"),
                &[("error", Detail::Text(e.word())), stall],
            ),
        }
    }

    /// Any event (written with `seq`; errors counted).
    pub fn event(&mut self, t: f64, kind: &str, why: Option<&str>, details: &[(&str, Detail<'_>)]) {
        let _counted = self.rec.event(t, kind, why, details);
    }

    /// Starts the UART stream (e.g. when the card that was logging failed); returns the
    /// UART back if one streams already.
    pub fn attach_uart(&mut self, uart: U) -> Option<U> {
        let b = &mut self.rec.writer().b;
        if b.is_some() {
            return Some(uart);
        }
        *b = Some(uart);
        None
    }

    /// The UART stream's writer, if one streams.
    pub fn uart(&self) -> Option<&U> {
        self.rec.writer_ref().b.as_ref()
    }

    /// The SD side (its state, counts and card).
    pub fn sd(&self) -> &SdSink<D> {
        &self.rec.writer_ref().a
    }

    /// The SD card's state.
    pub fn sd_state(&self) -> SdState {
        self.rec.writer_ref().a.state()
    }

    /// The recorder's counts.
    pub fn stats(&self) -> RecorderStats {
        self.rec.stats()
    }

    /// Once per main-loop tick, between records: flushes the SD card when due, and when
    /// records were refused or a writer failed since the last report, writes a
    /// `log_error` event (it reaches the UART stream when the card is what failed).
    /// Returns the SD state when it changed, and the counts when they changed, for the
    /// debug log.
    pub fn tick(&mut self, t: f64, now_ms: u64) -> (Option<SdState>, Option<LogErrors>) {
        let changed = self.rec.writer().a.poll(now_ms);
        if let Some(SdState::Logging(file)) = changed {
            // A remounted card: its new file starts a segment (the spec's second-header
            // rule; the UART stream gets the header too) and says why.
            if let Some((hz, field, ambiguous)) = self.header {
                let _counted = self.rec.header(hz, &field, ambiguous);
            }
            self.event(
                t,
                "log_error",
                Some("sd_remount"),
                &[("file", Detail::Int(i64::from(file)))],
            );
        }
        let now = self.counts();
        if now == self.reported {
            return (changed, None);
        }
        let (failed, refused, [sd, uart]) = now;
        let errors = LogErrors {
            failed,
            refused,
            sd_write_errors: sd,
            uart_write_errors: uart,
            sd_lost_bytes: self.rec.writer_ref().a.stats().map_or(0, |s| s.lost_bytes),
        };
        let state = self.sd_state().fault_label().unwrap_or("logging");
        let lost = i64::try_from(errors.sd_lost_bytes).unwrap_or(i64::MAX);
        self.event(
            t,
            "log_error",
            Some(if uart > self.reported.2[1] {
                "uart"
            } else {
                "sd"
            }),
            &[
                ("failed", Detail::Int(i64::from(failed))),
                ("refused", Detail::Int(i64::from(refused))),
                ("sd_lost_bytes", Detail::Int(lost)),
                ("sd", Detail::Text(state)),
            ],
        );
        // The report itself may fail (the card is gone): that goes into the next report,
        // not into a report of the report.
        self.reported = self.counts();
        (changed, Some(errors))
    }

    fn counts(&self) -> (u32, u32, [u32; 2]) {
        let s = self.rec.stats();
        (s.failed, s.refused, self.rec.writer_ref().errors())
    }
}

/// The log's error counts, as [`BoardLog::tick`] reports them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LogErrors {
    /// Records lost on every writer.
    pub failed: u32,
    /// Records refused (non-finite values, text needing escaping).
    pub refused: u32,
    /// Failed writes to the card (a record takes several).
    pub sd_write_errors: u32,
    /// Failed writes to the UART.
    pub uart_write_errors: u32,
    /// Bytes the card lost (not flushed when it failed, or given after).
    pub sd_lost_bytes: u64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::crash::{CrashKind, CrashRecord};
    use crate::board::sd_log::{RamCard, SdError, SdLog};
    extern crate std;
    use std::string::String;
    use std::vec;

    #[test]
    fn attached_uart_takes_the_records_from_then_on() {
        let mut log: BoardLog<RamCard<'_>, String> = BoardLog::new(SdSink::new(None), None);
        log.event(1.0, "mark", None, &[]);
        assert_eq!(log.attach_uart(String::from("x")), None);
        log.event(2.0, "mark", None, &[]);
        assert_eq!(log.attach_uart(String::new()), Some(String::new()));
        let uart = log.rec.writer_ref().b.as_deref().unwrap_or("");
        assert!(uart.starts_with("x{\"type\":\"event\",\"t\":2"), "{uart}");
        assert_eq!(uart.lines().count(), 1);
    }

    #[test]
    fn events_and_errors_reach_the_uart_when_the_card_fails() {
        // A card that fails at once: the log is refused at mount.
        let mut blank = vec![0u8; 1 << 20];
        let sd = SdSink::new(Some(
            SdLog::open(RamCard::new(&mut blank), 0).map_err(|(e, _)| e),
        ));
        let mut log = BoardLog::new(sd, Some(String::new()));
        log.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true);
        let crash = CrashRecord::new(CrashKind::Panic, format_args!("index \"7\" out\n@app.rs:3"));
        log.reset(0.0, &LastReset::from_boot(&crash, false));
        log.pulse(1.5, &PulseMeasurement::Overlap, None);
        log.pulse(
            2.5,
            &PulseMeasurement::Field(Vec3::new(1e-6, 0.0, 0.0)),
            Some(1),
        );
        log.imu(2.6, &Vec3::zeros(), &Vec3::zeros(), None);
        assert_eq!(log.sd_state(), SdState::Failed(SdError::Volume));
        let (changed, report) = log.tick(2.6, 1000);
        assert_eq!(changed, None);
        let report = report.unwrap();
        // The UART took every record: none lost, but the card's failures are counted.
        assert_eq!((report.failed, report.refused), (0, 0));
        assert!(report.sd_write_errors >= 5);
        // Nothing more failed: no second report.
        assert_eq!(log.tick(2.7, 1010).1, None);
        let uart = log.rec.into_writer().b.unwrap();
        let lines: std::vec::Vec<&str> = uart.lines().collect();
        assert_eq!(lines.len(), 6);
        assert!(lines[0].contains(r#""type":"header""#) && lines[0].ends_with(r#","seq":0}"#));
        assert_eq!(
            lines[1],
            r#"{"type":"event","t":0,"kind":"reset","why":"panic","message":"index '7' out @app.rs:3","seq":1}"#
        );
        assert_eq!(
            lines[2],
            r#"{"type":"event","t":1.5,"kind":"withheld","why":"overlap","seq":2}"#
        );
        assert!(
            lines[3].starts_with(r#"{"type":"pulse","t":2.5,"#)
                && lines[3].ends_with(r#","src":1,"seq":3}"#)
        );
        assert_eq!(
            lines[5],
            r#"{"type":"event","t":2.6,"kind":"log_error","why":"sd","failed":0,"refused":0,"sd_lost_bytes":0,"sd":"SD ERR","seq":5}"#
        );
    }

    #[test]
    fn settings_events_say_where_they_came_from_and_how_a_save_went() {
        use crate::board::settings::Settings;
        use crate::board::settings_store::LoadError;
        let mut log: BoardLog<RamCard<'_>, String> =
            BoardLog::new(SdSink::new(None), Some(String::new()));
        let stored = Loaded {
            settings: Settings {
                region: 2,
                ..Settings::DEFAULT
            },
            defaults_because: None,
            slot: Some(7),
            used: 9,
            torn: 1,
        };
        log.settings_loaded(0.0, &stored, Some(0.7));
        let defaults = Loaded {
            settings: Settings::DEFAULT,
            defaults_because: Some(LoadError::Store(StoreError::Read)),
            slot: None,
            used: 0,
            torn: 0,
        };
        log.settings_loaded(0.0, &defaults, None);
        let saved = Saved {
            slot: 8,
            erased: false,
            skipped: 0,
            unchanged: false,
        };
        log.settings_saved(5.0, &Ok(saved), 2);
        log.settings_saved(6.0, &Err(StoreError::Verify), 1900);
        let uart = log.uart().cloned().unwrap_or_default();
        let lines: std::vec::Vec<&str> = uart.lines().collect();
        assert_eq!(
            lines,
            [
                r#"{"type":"event","t":0,"kind":"settings","why":"stored","step_length_m":0.7,"mode":"sog","volume":3,"region":"NORWAY","antenna_cal":false,"mag_cal":false,"slot":7,"torn":1,"seq":0}"#,
                r#"{"type":"event","t":0,"kind":"settings","why":"defaults","step_length_m":"none","mode":"sog","volume":3,"region":"ALPS","antenna_cal":false,"mag_cal":false,"slot":"none","torn":0,"seq":1}"#,
                r#"{"type":"event","t":5,"kind":"settings","why":"saved","slot":8,"erased":false,"stall_ms":2,"seq":2}"#,
                r#"{"type":"event","t":6,"kind":"settings","why":"not_saved","error":"verify","stall_ms":1900,"seq":3}"#,
            ]
        );
    }

    #[test]
    fn without_a_card_the_uart_alone_takes_the_log_and_nothing_counts_as_failed() {
        let mut log: BoardLog<RamCard<'_>, String> =
            BoardLog::new(SdSink::new(None), Some(String::new()));
        log.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true);
        log.reset(0.0, &LastReset::Clean);
        log.event(0.5, "mark", None, &[]);
        assert_eq!(log.tick(0.5, 600), (None, None));
        assert_eq!(log.stats().written, 3);
        assert_eq!(log.sd_state(), SdState::NoCard);
    }
}
