//! The board's own records replay (issue 21 item 4, issue 22 item 3): a seeded search
//! written through the board's log path (`firmware::board::log_item::LogItem` →
//! `BoardLog::write_item`) with the device events the board adds — `gain` events from gain
//! ranging, a magnetometer calibration, a flash overrun, a withheld pulse — and a second
//! header where the menu rebuilt the receiver (a new segment), read back by `hal-sim`'s
//! strict streaming replay: no malformed line, no `seq` gap, two segments, every event
//! counted, one answer per pulse.
// Test code: a failed unwrap or a panic is a failed test, the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use firmware::Vec3;
use firmware::board::board_log::BoardLog;
use firmware::board::gain::GainEvent;
use firmware::board::log_item::LogItem;
use firmware::board::sd_log::{RamCard, SdSink};
use firmware::frontend::{PulseMeasurement, Range, RangeChange, RangeReason};
use hal_sim::io::receiver_config::ReceiverConfig;
use hal_sim::io::replay::replay_clean;
use hal_sim::io::session::Record;
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};

fn v(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

#[test]
fn a_board_log_with_gain_calibration_and_rebuild_events_replays_strictly() {
    let sim = simulate(&ScenarioConfig::new(Preset::Paper, 7));
    let h = &sim.session.header;
    let earth = v(&h.earth_field_ut.unwrap());
    let mut log: BoardLog<RamCard<'_>, String> =
        BoardLog::new(SdSink::new(None), Some(String::new()));
    let mut items = vec![LogItem::Header {
        imu_hz: h.imu_hz as f32,
        earth_ut: earth,
    }];
    let (mut pulses, mut events) = (0u64, 0u64);
    let rebuild_at = sim.session.records.len() / 2;
    // The board's "now": the latest time written (a gain event is stamped with the DSP's
    // current sample, never before what was logged already).
    let mut now = 0.0f64;
    for (k, r) in sim.session.records.iter().enumerate() {
        if k == rebuild_at {
            // The menu changed the mode: a new segment, after the calibration's events.
            let t = r.t();
            items.push(LogItem::Calibration {
                t,
                what: "mag_cal",
                result: "done",
                value: Some(0.31),
            });
            items.push(LogItem::Event {
                t,
                kind: "settings",
                why: Some("menu"),
                count: Some(2),
            });
            items.push(LogItem::Header {
                imu_hz: h.imu_hz as f32,
                earth_ut: earth,
            });
            items.push(LogItem::Event {
                t,
                kind: "overrun",
                why: Some("flash"),
                count: Some(16),
            });
            events += 3;
        }
        now = now.max(r.t());
        match r {
            Record::Imu(x) => items.push(LogItem::Imu {
                t: x.t,
                acc: v(&x.acc),
                gyr: v(&x.gyr),
                mag: x.mag.as_ref().map(v).unwrap(),
            }),
            Record::Pulse(x) => {
                pulses += 1;
                items.push(LogItem::Pulse {
                    t: x.t,
                    m: PulseMeasurement::Field(v(&x.h)),
                    src: None,
                });
                // Every third pulse the gain steps, alternating down and up (the board
                // logs it at the pulse's end, stamped with the first sample in the new
                // setting: the DSP's present).
                if pulses % 3 == 0 {
                    let down = pulses % 6 == 0;
                    let (from, to) = if down {
                        (Range::MOST_SENSITIVE, Range::rung(1).unwrap())
                    } else {
                        (Range::rung(1).unwrap(), Range::MOST_SENSITIVE)
                    };
                    items.push(LogItem::Gain(GainEvent {
                        t_us: (now * 1e6).ceil() as u64,
                        change: RangeChange {
                            t_s: now as f32,
                            from,
                            to,
                            reason: if down {
                                RangeReason::Strong
                            } else {
                                RangeReason::Weak
                            },
                        },
                        applied: pulses % 9 != 0,
                    }));
                    events += 1;
                }
            }
            Record::Truth(_) => {}
        }
    }
    // One pulse the front end withheld (an event, not a pulse record).
    let t_end = sim.session.records.last().map_or(0.0, Record::t);
    items.push(LogItem::Pulse {
        t: t_end,
        m: PulseMeasurement::Overlap,
        src: None,
    });
    events += 1;
    for item in &items {
        log.write_item(item);
    }
    assert_eq!(log.stats().refused + log.stats().failed, 0);
    let text = log.uart().cloned().unwrap();
    assert!(text.contains(r#""kind":"gain","why":"strong","range":"high","pga":64,"from_range":"high","from_pga":128,"applied":true"#));

    let summary = replay_clean(text.as_bytes(), &ReceiverConfig::default()).unwrap();
    let read = summary.read;
    assert_eq!((read.segments, read.malformed, read.seq_gaps), (2, 0, 0));
    assert_eq!((read.pulses, read.events), (pulses, events));
    assert_eq!(summary.lines, pulses);
    eprintln!(
        "{} records, {pulses} pulses, {events} events (gain, calibration, settings, overrun, withheld), 2 segments",
        items.len()
    );
}
