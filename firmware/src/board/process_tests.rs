//! The processing task on a fake board: ticks and samples in, log records, screens, LED,
//! tones and saved settings out.

use super::*;
use crate::board::REFERENCE;
use crate::board::settings::SearchMode;
use crate::drivers::imu::ImuReading;
use heapless::spsc::{Consumer, Queue};
extern crate std;
use std::boxed::Box;
use std::vec::Vec;

/// ADC samples per IMU tick at the reference rates (8 kSPS, 100 Hz).
const PER_TICK: usize = 80;

/// The board's hardware as the tests see it: inputs set by the test, outputs recorded.
#[derive(Default)]
struct Fake {
    now_ms: u64,
    sound_low: bool,
    mark: bool,
    stuck: bool,
    volts: f32,
    led: bool,
    rearms: u32,
    shows: Vec<View>,
    tones: Vec<Option<(u32, u16)>>,
    rebuilt: Vec<AppConfig>,
}

impl Hardware for Fake {
    fn rearm_adc(&mut self) {
        self.rearms += 1;
    }
    fn write_range(&mut self, _change: &RangeChange) -> bool {
        true
    }
    fn queued_samples(&self) -> usize {
        0
    }
    fn now_ms(&mut self) -> u64 {
        self.now_ms
    }
    fn sound_low(&mut self) -> bool {
        self.sound_low
    }
    fn mark_pressed(&mut self) -> bool {
        core::mem::take(&mut self.mark)
    }
    fn bus(&mut self) -> (bool, BusStats) {
        (self.stuck, BusStats::default())
    }
    fn set_fault_led(&mut self, on: bool) {
        self.led = on;
    }
    fn battery_volts(&mut self) -> f32 {
        self.volts
    }
    fn max_duty(&self) -> u16 {
        1000
    }
    fn buzz(&mut self, play: Option<(u32, u16)>) {
        self.tones.push(play);
    }
    fn show(&mut self, view: View) {
        self.shows.push(view);
    }
    fn rebuild(&mut self, receiver: &mut Receiver, cfg: AppConfig) -> Result<(), AppError> {
        self.rebuilt.push(cfg);
        *receiver = Receiver::new(cfg)?;
        Ok(())
    }
}

/// A receiver at rest and level, in the reference region's field.
fn reading() -> ImuReading {
    ImuReading {
        acc: Vec3::new(0.0, 0.0, 9.81),
        gyr: Vec3::zeros(),
        mag: Vec3::new(20.0, 0.0, -40.0),
        clipped: false,
    }
}

/// The reference board's pipeline with the default settings, sound on.
fn parts() -> (Box<Frontend>, Box<Receiver>) {
    let p = &REFERENCE;
    let s = Settings::DEFAULT;
    let fe = Frontend::new(p.frontend_config(&s.calibration.antenna_or(&p.analog.nominal)));
    let step = s.calibration.step_length_m.or(p.defaults.step_length_m);
    let rx = Receiver::new(p.app_config(s.earth_field(), step));
    (Box::new(fe.unwrap()), Box::new(rx.unwrap()))
}

fn process<'a>(
    counters: &'a Counters,
    log: Producer<'a, LogItem>,
    saves: Producer<'a, Settings>,
    frontend: &'a mut Frontend,
    receiver: &'a mut Receiver,
) -> Process<'a> {
    let rate = frontend.config().sample_rate_hz;
    let shown = receiver.display_model();
    Process {
        profile: &REFERENCE,
        counters,
        log,
        saves,
        frontend,
        receiver,
        rate,
        clock: SampleClock::new(rate, REFERENCE.imu.rate_hz, 0).unwrap(),
        taken: 0,
        last_imu_t: None,
        drawn: None,
        shown,
        sensors: SensorHealth::new(),
        fault: None,
        battery: Battery::new(),
        controls: Controls::new(Settings::DEFAULT, true),
        playing: None,
        mag_cal: None,
        window_ticks: 0,
        window_samples: 0,
        window_errors: 0,
        bus_stats: BusStats::default(),
        reported: Overruns::new(),
        log_overruns: 0,
    }
}

/// One 10 ms period: the ADC's samples (silence, counted as the DRDY task does), then
/// the IMU tick with `reading`.
fn period(p: &mut Process, hw: &mut Fake, reading: Option<Result<ImuReading, ()>>) {
    for _ in 0..PER_TICK {
        p.counters.samples.fetch_add(1, Ordering::Relaxed);
        let s = Sample {
            volts: [0.0; 3],
            clipped: false,
        };
        p.on_sample(s, hw);
    }
    hw.now_ms += 10;
    let queued = p.counters.samples.load(Ordering::Relaxed);
    p.on_tick(ImuRecord { queued, reading }, hw);
}

fn events(log: &mut Consumer<LogItem>) -> Vec<(&'static str, Option<&'static str>, Option<i64>)> {
    core::iter::from_fn(|| log.dequeue())
        .filter_map(|item| match item {
            LogItem::Event {
                kind, why, count, ..
            } => Some((kind, why, count)),
            _ => None,
        })
        .collect()
}

/// The processing task on a fresh fake board (screen up): its counters, the log and
/// settings queues' consumer ends (patterns), and the task `p`.
macro_rules! rig {
    ($counters:ident, $log_out:pat, $saves_out:pat, $p:ident) => {
        let $counters = Counters::new();
        $counters.screen_ok.store(true, Ordering::Relaxed);
        let (mut log_q, mut save_q) = (Queue::<LogItem, 512>::new(), Queue::<Settings, 4>::new());
        let ((log_in, $log_out), (saves_in, $saves_out)) = (log_q.split(), save_q.split());
        let (mut fe, mut rx) = parts();
        let mut $p = process(&$counters, log_in, saves_in, &mut fe, &mut rx);
    };
}

#[test]
fn readings_are_logged_calibrated_and_the_screen_is_redrawn_once_a_second() {
    rig!(counters, mut log_out, _, p);
    let cal = MagCalibration {
        hard_iron: Vec3::new(1.0, 2.0, 3.0),
        ..MagCalibration::identity()
    };
    p.mag_cal = Some(cal);
    let mut hw = Fake {
        volts: 4.0,
        ..Fake::default()
    };
    for _ in 0..250 {
        period(&mut p, &mut hw, Some(Ok(reading())));
    }
    // Ticks at 10 ms … 2.5 s: drawn at the first, then every 1 s without a pulse.
    assert_eq!(hw.shows.len(), 3);
    assert!(
        hw.shows
            .iter()
            .all(|v| v.fault.is_none() && v.menu.is_none())
    );
    assert!(!hw.led && hw.rearms == 0);
    let imu: Vec<_> = core::iter::from_fn(|| log_out.dequeue())
        .filter_map(|item| match item {
            LogItem::Imu { t, mag, .. } => Some((t, mag)),
            _ => None,
        })
        .collect();
    assert_eq!(imu.len(), 250);
    assert!((imu[0].0 - 0.01).abs() < 1e-9 && (imu[249].0 - 2.5).abs() < 1e-9);
    assert_eq!(imu[0].1, cal.apply(&reading().mag));
    assert_ne!(imu[0].1, reading().mag);
}

#[test]
fn a_silent_adc_is_re_armed_shown_as_a_fault_and_logged() {
    rig!(counters, mut log_out, _, p);
    let mut hw = Fake::default();
    for _ in 0..200 {
        hw.now_ms += 10;
        p.on_tick(
            ImuRecord {
                queued: 0,
                reading: Some(Ok(reading())),
            },
            &mut hw,
        );
    }
    assert!(hw.rearms > 0);
    assert!(hw.led);
    assert_eq!(hw.shows.last().map(|v| v.fault), Some(Some(Fault::Adc)));
    let ev = events(&mut log_out);
    assert!(ev.contains(&("fault", Some("ADC FAULT"), None)));
    // The clock ran on the timer: 2 s.
    assert_eq!(p.clock.now().micros(), 2_000_000);
}

#[test]
fn overruns_are_logged_once_per_growth_and_flash_losses_move_the_clock() {
    rig!(counters, mut log_out, _, p);
    let mut hw = Fake::default();
    period(&mut p, &mut hw, Some(Ok(reading())));
    let before = p.clock.now().micros();
    counters.dropped.store(3, Ordering::Relaxed);
    counters.flash_lost.store(800, Ordering::Relaxed);
    period(&mut p, &mut hw, Some(Ok(reading())));
    period(&mut p, &mut hw, Some(Ok(reading())));
    let ev = events(&mut log_out);
    let overruns: Vec<_> = ev.iter().filter(|e| e.0 == "overrun").collect();
    assert_eq!(
        overruns,
        [
            &("overrun", Some("adc_queue"), Some(3)),
            &("overrun", Some("flash"), Some(800))
        ]
    );
    // Two periods (20 ms) and the 800 samples the flash cost (100 ms).
    assert_eq!(p.clock.now().micros() - before, 120_000);
}

#[test]
fn imu_read_failures_are_logged_and_a_stuck_bus_shows() {
    rig!(counters, mut log_out, _, p);
    let mut hw = Fake::default();
    period(&mut p, &mut hw, Some(Err(())));
    hw.stuck = true;
    period(&mut p, &mut hw, Some(Ok(reading())));
    let ev = events(&mut log_out);
    assert_eq!(
        ev,
        [
            ("read_error", Some("imu"), None),
            ("fault", Some("I2C FAULT"), None)
        ]
    );
    assert!(hw.led);
}

#[test]
fn a_mode_chosen_in_the_menu_rebuilds_the_receiver_and_goes_to_be_stored() {
    rig!(counters, mut log_out, mut saves_out, p);
    let mut hw = Fake::default();
    // Sound button: long (menu), short (next item: MODE), long (CLASSIC); then mark: leave.
    for held in [100, 20, 100] {
        hw.sound_low = true;
        for _ in 0..held {
            period(&mut p, &mut hw, Some(Ok(reading())));
        }
        hw.sound_low = false;
        for _ in 0..10 {
            period(&mut p, &mut hw, Some(Ok(reading())));
        }
    }
    assert!(hw.shows.last().is_some_and(|v| v.menu.is_some()));
    hw.mark = true;
    period(&mut p, &mut hw, Some(Ok(reading())));
    assert!(hw.shows.last().is_some_and(|v| v.menu.is_none()));
    assert_eq!(hw.rebuilt.len(), 1);
    assert_eq!(hw.rebuilt[0].mode, SearchMode::Classic.app());
    let saved = saves_out.dequeue().map(|s| s.mode);
    assert_eq!(saved, Some(SearchMode::Classic));
    let items: Vec<_> = core::iter::from_fn(|| log_out.dequeue()).collect();
    assert!(items.iter().any(|i| matches!(i, LogItem::Header { .. })));
    assert!(items.iter().any(|i| matches!(
        i,
        LogItem::Event {
            kind: "settings",
            why: Some("menu"),
            ..
        }
    )));
    // No tone plays without a signal.
    assert!(hw.tones.iter().all(Option::is_none));
}

#[test]
fn a_run_of_failed_imu_reads_shows_an_imu_fault() {
    rig!(counters, mut log_out, _, p);
    let mut hw = Fake::default();
    for _ in 0..crate::board::health::IMU_FAIL_RUN {
        assert!(!hw.led);
        period(&mut p, &mut hw, Some(Err(())));
    }
    // The health is judged at the start of a tick, before its reading: shown at the next.
    period(&mut p, &mut hw, Some(Err(())));
    assert!(hw.led);
    assert_eq!(p.fault, Some(Fault::Imu));
    assert!(events(&mut log_out).contains(&("fault", Some("IMU FAULT"), None)));
    // Good reads clear it (seen at the tick after the first).
    period(&mut p, &mut hw, Some(Ok(reading())));
    period(&mut p, &mut hw, Some(Ok(reading())));
    assert_eq!(p.fault, None);
}
