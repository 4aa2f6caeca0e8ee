//! The board binary's processing task without its hardware: ADC samples through the
//! pulse front end and the estimator, the 100 Hz tick (clock, sensor health, battery,
//! buttons and menu, tones, the IMU sample), the session-log records it produces and the
//! overruns it reports. The pins, timers, locks and the display hand-over are behind
//! [`Hardware`], so the task's logic runs on the host too.

use crate::Vec3;
use crate::app::{AppConfig, AppError, Receiver};
use crate::board::BoardProfile;
use crate::board::controls::{Closed, Controls, Response};
use crate::board::gain;
use crate::board::health::{Battery, Fault, SensorHealth};
use crate::board::i2c_bus::BusStats;
use crate::board::log_item::{LogItem, Overruns};
use crate::board::sd_log::SdState;
use crate::board::settings::Settings;
use crate::board::sound;
use crate::board::view::View;
use crate::display::DisplayModel;
use crate::drivers::imu::ImuReading;
use crate::frontend::{Frontend, PulseMeasurement, RangeChange};
use crate::motion::MagCalibration;
use crate::timebase::{ClockEvent, Instant, SampleClock, pulse_centre_us};
use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, Ordering};
use heapless::spsc::Producer;

/// Longest time (µs) the screen goes without a redraw when no pulse redraws it.
pub const REDRAW_MAX_US: u64 = 1_000_000;

/// One simultaneous sample of the three coils.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The coils' voltages, V.
    pub volts: [f32; 3],
    /// A coil saturated (or the frame was corrupt).
    pub clipped: bool,
}

/// One IMU tick's result, stamped with the samples queued before it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuRecord {
    /// ADC samples queued when the IMU was read (the processing task takes the record
    /// after those samples: time order).
    pub queued: u32,
    /// The reading (`None`: no IMU up; `Some(Err)`: the read failed).
    pub reading: Option<Result<ImuReading, ()>>,
}

/// Counters and flags the board's tasks share (statics of the binary, lock-free).
#[derive(Debug, Default)]
pub struct Counters {
    /// ADC samples taken (DRDY edges).
    pub samples: AtomicU32,
    /// ADC samples queued.
    pub queued: AtomicU32,
    /// ADC samples dropped (sample queue full).
    pub dropped: AtomicU32,
    /// ADC frames that failed their check.
    pub frame_errors: AtomicU32,
    /// IMU ticks missed (TIM2 released again before its last release ran).
    pub missed_ticks: AtomicU32,
    /// ADC samples lost while the flash stalled every task (a settings save): the
    /// processing task moves its clock on by them and logs an overrun.
    pub flash_lost: AtomicU32,
    /// IMU records lost to a full queue.
    pub imu_overruns: AtomicU32,
    /// Sample-queue drains of the processing task (progress, for the watchdog's feeder).
    pub drains: AtomicU32,
    /// IMU records handled by the processing task (progress, for the feeder).
    pub ticks: AtomicU32,
    /// The display took its last write.
    pub screen_ok: AtomicBool,
    /// A bus clear asks the display task to re-initialise the display.
    pub screen_reinit: AtomicBool,
    /// The SD card's state for the display: 0 logging, 1 no card, 2 failed.
    pub sd_mark: AtomicU8,
}

impl Counters {
    /// All zero, the display not (yet) working.
    pub const fn new() -> Self {
        Self {
            samples: AtomicU32::new(0),
            queued: AtomicU32::new(0),
            dropped: AtomicU32::new(0),
            frame_errors: AtomicU32::new(0),
            missed_ticks: AtomicU32::new(0),
            flash_lost: AtomicU32::new(0),
            imu_overruns: AtomicU32::new(0),
            drains: AtomicU32::new(0),
            ticks: AtomicU32::new(0),
            screen_ok: AtomicBool::new(false),
            screen_reinit: AtomicBool::new(false),
            sd_mark: AtomicU8::new(0),
        }
    }

    /// Publishes the SD card's state for the display and the fault LED.
    pub fn set_sd(&self, state: &SdState) {
        let mark = match state {
            SdState::Logging(_) => 0,
            SdState::NoCard => 1,
            SdState::Failed(_) => 2,
        };
        self.sd_mark.store(mark, Ordering::Relaxed);
    }

    /// The SD card's word for the display (published by the idle loop).
    pub fn sd_label(&self) -> Option<&'static str> {
        match self.sd_mark.load(Ordering::Relaxed) {
            0 => None,
            1 => SdState::NoCard.fault_label(),
            _ => Some("SD ERR"),
        }
    }

    /// The overrun counts in the order of `log_item::OVERRUN_KINDS`, with the log
    /// records lost counted by the processing task.
    fn overruns(&self, log_overruns: u32) -> [u32; 5] {
        [
            self.dropped.load(Ordering::Relaxed),
            self.missed_ticks.load(Ordering::Relaxed),
            self.imu_overruns.load(Ordering::Relaxed),
            log_overruns,
            self.flash_lost.load(Ordering::Relaxed),
        ]
    }
}

/// What the processing task drives on the board: the ADC (under the DRDY task's lock),
/// the IF range switch, the buttons, the bus status, the fault LED, the battery input,
/// the buzzer, the display hand-over and the receiver's rebuild in place.
pub trait Hardware {
    /// Re-arms a stalled ADC's DRDY: reads one frame (DRDY stays low until the frame is
    /// read, so no further edge would come) and clears the pin's pending interrupt.
    fn rearm_adc(&mut self);
    /// Writes a change of analog setting: the coils' PGA gain, then the IF range switch
    /// (left at `change.from` after a failed gain write). True when the PGA took it.
    fn write_range(&mut self, change: &RangeChange) -> bool;
    /// ADC samples waiting in the sample queue (taken in the setting before a change).
    fn queued_samples(&self) -> usize;
    /// Monotonic milliseconds since boot.
    fn now_ms(&mut self) -> u64;
    /// Whether the sound button's pin reads low (pressed).
    fn sound_low(&mut self) -> bool;
    /// The mark button's debounced poll: true once per press.
    fn mark_pressed(&mut self) -> bool;
    /// Whether the I2C bus is stuck, and its counters.
    fn bus(&mut self) -> (bool, BusStats);
    /// Lights (`true`) or darkens the fault LED.
    fn set_fault_led(&mut self, on: bool);
    /// The battery's voltage, V (one conversion).
    fn battery_volts(&mut self) -> f32;
    /// The buzzer's full-scale duty.
    fn max_duty(&self) -> u16;
    /// Plays a tone at (frequency Hz, duty); `None` is silence.
    fn buzz(&mut self, play: Option<(u32, u16)>);
    /// Hands the display task the newest screen and wakes it.
    fn show(&mut self, view: View);
    /// Builds a new receiver for `cfg` in the place of `receiver` (never on the stack);
    /// the old one is left as it was when `cfg` is refused.
    fn rebuild(&mut self, receiver: &mut Receiver, cfg: AppConfig) -> Result<(), AppError>;
}

/// What the processing task owns besides its hardware and its input queues.
pub struct Process<'a> {
    /// The board this runs on (rates, defaults, the receiver's configuration).
    pub profile: &'a BoardProfile,
    /// The counters shared with the other tasks.
    pub counters: &'a Counters,
    /// Session-log records to the idle loop.
    pub log: Producer<'a, LogItem>,
    /// Settings to store (the idle loop writes the flash).
    pub saves: Producer<'a, Settings>,
    /// The pulse front end.
    pub frontend: &'a mut Frontend,
    /// The application.
    pub receiver: &'a mut Receiver,
    /// The ADC's sample rate, Hz.
    pub rate: f32,
    /// Board time from the ADC's sample count.
    pub clock: SampleClock,
    /// Samples taken from the queue.
    pub taken: u32,
    /// Time of the last IMU sample processed.
    pub last_imu_t: Option<Instant>,
    /// Time of the last redraw.
    pub drawn: Option<Instant>,
    /// The search screen's model shown.
    pub shown: DisplayModel,
    /// The sensors' health.
    pub sensors: SensorHealth,
    /// The sensor fault shown.
    pub fault: Option<Fault>,
    /// The battery gauge.
    pub battery: Battery,
    /// The buttons, the menu, its procedures and the tone (`board::controls`).
    pub controls: Controls,
    /// The tone playing and its duty.
    pub playing: Option<(u32, u16)>,
    /// The magnetometer calibration applied to every reading.
    pub mag_cal: Option<MagCalibration>,
    /// Ticks into the current second.
    pub window_ticks: u32,
    /// ADC samples taken at the start of the current second.
    pub window_samples: u32,
    /// ADC frame errors at the start of the current second.
    pub window_errors: u32,
    /// The I2C bus's counters last logged.
    pub bus_stats: BusStats,
    /// Overruns counted so far, by kind, and what was last logged.
    pub reported: Overruns,
    /// Session-log records lost to a full queue.
    pub log_overruns: u32,
}

impl Process<'_> {
    /// Queues a session-log record; a full queue loses it (counted, logged later).
    fn log(&mut self, item: LogItem) {
        if self.log.enqueue(item).is_err() {
            self.log_overruns = self.log_overruns.wrapping_add(1);
        }
    }

    /// An event record now.
    fn event(&mut self, kind: &'static str, why: Option<&'static str>, count: Option<i64>) {
        let t = self.clock.now().secs_f64();
        self.log(LogItem::Event {
            t,
            kind,
            why,
            count,
        });
    }

    /// Hands the display the newest model.
    fn redraw(&mut self, hw: &mut impl Hardware) {
        self.drawn = Some(self.clock.now());
        let v = View {
            model: self.shown,
            fault: self.fault,
            battery: self.battery.state(),
            menu: self.controls.open_menu(),
            procedure: self
                .controls
                .procedure(self.receiver.motion().total_steps()),
            outcome: self.controls.outcome(),
        };
        hw.show(v);
    }

    /// One ADC sample through the front end; a finished pulse through the estimator.
    pub fn on_sample(&mut self, sample: Sample, hw: &mut impl Hardware) {
        self.taken = self.taken.wrapping_add(1);
        match self.frontend.push(sample.volts, sample.clipped) {
            Ok(Some(pulse)) => {
                // The DSP counts only the samples it saw: stalls are added back.
                let t_pulse = Instant::from_micros(
                    pulse_centre_us(pulse.start_sample, pulse.duration_s, self.rate)
                        + self.clock.offset_us(),
                );
                // Logged before it is processed: a fault in the estimator loses no record.
                self.log(LogItem::Pulse {
                    t: t_pulse.secs_f64(),
                    m: pulse.measurement,
                    src: pulse.src,
                });
                let model = match pulse.measurement {
                    PulseMeasurement::Field(h) => {
                        self.receiver.on_pulse(t_pulse, &h, pulse.src).ok()
                    }
                    // Overlap, clipping, truncation: held out of the estimators.
                    _ => Some(self.receiver.on_withheld(t_pulse)),
                };
                if let Some(model) = model {
                    self.shown = model;
                    self.redraw(hw);
                }
            }
            Ok(None) => {}
            Err(_) => log_warn!("front end refused a sample"),
        }
        // A change of gain: to the hardware, then to the log (the replay's `gain` event).
        let (queued, offset_us) = (hw.queued_samples(), self.clock.offset_us());
        if let Some(e) = gain::apply_change(self.frontend, queued, self.rate, offset_us, |c| {
            hw.write_range(c)
        }) {
            let c = e.change;
            if e.applied {
                log_info!("range {} -> {} ({})", c.from, c.to, c.reason);
            } else {
                log_warn!("PGA write failed: staying at {}", c.from);
            }
            self.log(LogItem::Gain(e));
        }
    }

    /// One 100 Hz tick: the clock, health, battery, buttons, tones and the IMU sample.
    pub fn on_tick(&mut self, record: ImuRecord, hw: &mut impl Hardware) {
        let event = self.clock.tick(self.taken);
        self.sensors.adc_tick(watch_adc(event, hw));
        self.window_ticks += 1;
        if self.window_ticks >= self.profile.imu.rate_hz as u32 {
            self.window_ticks = 0;
            self.second(hw);
        }
        // The buttons (the mark button debounced over 3 ticks by its own poll).
        let now_ms = hw.now_ms();
        let steps = self.receiver.motion().total_steps();
        let low = hw.sound_low();
        let sound = self.controls.sound_button(low, now_ms, steps);
        let mut redraw = self.respond(sound, hw);
        if hw.mark_pressed() {
            let r = self.controls.mark_button(steps);
            redraw |= self.respond(r, hw);
        }
        let t = self.clock.now();
        // A fault shows at once and is logged when it comes and goes.
        let (stuck, stats) = hw.bus();
        self.sensors.bus_stuck(stuck);
        if stats != self.bus_stats {
            log_warn!(
                "I2C bus: {=u32} errors, {=u32} stuck, {=u32} cleared, {=u32} clears failed",
                stats.errors,
                stats.stuck,
                stats.recoveries,
                stats.failed_recoveries
            );
            self.bus_stats = stats;
        }
        self.sensors.imu_present(record.reading.is_some());
        let now_fault = self.sensors.fault();
        if now_fault != self.fault {
            match now_fault {
                Some(f) => log_error!("sensor fault: {=str}", f.label()),
                None => log_info!("sensor fault cleared"),
            }
            self.event(
                "fault",
                Some(now_fault.map_or("cleared", Fault::label)),
                None,
            );
            self.fault = now_fault;
            redraw = true;
        }
        let screen_ok = self.counters.screen_ok.load(Ordering::Relaxed);
        let led = self.fault.is_some() || !screen_ok || self.counters.sd_label().is_some();
        hw.set_fault_led(led);
        // Pulses redraw the screen; without them it is redrawn at least every
        // REDRAW_MAX_US, so that "NO SIGNAL" and the arrow to a silent victim show.
        if redraw
            || self
                .drawn
                .is_none_or(|d| t.micros().saturating_sub(d.micros()) >= REDRAW_MAX_US)
        {
            self.shown = self.receiver.display_model();
            self.redraw(hw);
        }
        self.tone(hw);
        // A short hole in the ADC's samples holds the clock: skip that tick's sample.
        if let Some(reading) = record
            .reading
            .filter(|_| self.last_imu_t.is_none_or(|l| t > l))
        {
            self.last_imu_t = Some(t);
            match reading {
                Ok(r) => self.on_imu(t, &r),
                Err(()) => {
                    log_warn!("IMU read failed");
                    self.event("read_error", Some("imu"), None);
                    self.sensors.imu_read(false);
                }
            }
        }
        self.overruns();
        self.counters.ticks.fetch_add(1, Ordering::Relaxed);
    }

    /// One IMU reading at `t`: to the calibration procedure (raw), the log and the
    /// receiver (calibrated magnetometer).
    fn on_imu(&mut self, t: Instant, r: &ImuReading) {
        // The calibration fits the raw readings.
        self.controls.on_mag(&r.mag);
        let mag: Vec3 = self.mag_cal.map_or(r.mag, |c| c.apply(&r.mag));
        self.log(LogItem::Imu {
            t: t.secs_f64(),
            acc: r.acc,
            gyr: r.gyr,
            mag,
        });
        if self.receiver.on_imu(t, &r.acc, &r.gyr, Some(&mag)).is_err() {
            log_warn!("IMU sample refused");
        }
        self.sensors.imu_read(true);
    }

    /// Once a second: the ADC's health window and the battery.
    fn second(&mut self, hw: &mut impl Hardware) {
        let (n, e) = (
            self.counters.samples.load(Ordering::Relaxed),
            self.counters.frame_errors.load(Ordering::Relaxed),
        );
        let failed = e.wrapping_sub(self.window_errors);
        self.sensors
            .adc_window(n.wrapping_sub(self.window_samples), failed);
        if failed > 0 {
            self.event("read_error", Some("adc"), Some(i64::from(failed)));
        }
        (self.window_samples, self.window_errors) = (n, e);
        let was_low = self.battery.state().is_some_and(|b| b.low);
        let volts = hw.battery_volts();
        if let Some(b) = self.battery.update(volts).filter(|b| b.low != was_low) {
            if b.low {
                log_warn!("battery low: {=f32} V", b.volts);
            } else {
                log_info!("battery no longer low: {=f32} V", b.volts);
            }
        }
    }

    /// Carries out what the buttons asked for (`board::controls`): log records, a victim
    /// marked, the closed menu's settings applied and stored. True when the screen
    /// changed.
    fn respond(&mut self, r: Response, hw: &mut impl Hardware) -> bool {
        if let Some(muted) = r.muted {
            log_info!("sound {=str}", if muted { "off" } else { "on" });
        }
        if let Some((what, result, value)) = r.calibration {
            log_info!("{=str}: {=str}", what, result);
            let t = self.clock.now().secs_f64();
            self.log(LogItem::Calibration {
                t,
                what,
                result,
                value,
            });
        }
        if r.mark_victim {
            self.event("mark", None, None);
            match self.receiver.mark() {
                Ok(n) => log_info!("victim {=u8} marked", n),
                Err(_) => log_info!("mark: no victim to mark"),
            }
            self.shown = self.receiver.display_model();
        }
        if let Some(c) = r.closed {
            self.close_menu(c, hw);
        }
        r.redraw || r.mark_victim
    }

    /// The receiver rebuilt in place for `s` (a new search): mode, earth field, step
    /// length; the log starts a new segment with the new earth field.
    fn rebuild_receiver(&mut self, s: &Settings, hw: &mut impl Hardware) {
        let step = s
            .calibration
            .step_length_m
            .or(self.profile.defaults.step_length_m);
        let mut cfg = self.profile.app_config(s.earth_field(), step);
        cfg.mode = s.mode.app();
        match hw.rebuild(self.receiver, cfg) {
            Ok(()) => {
                self.controls.rebuilt(s);
                self.last_imu_t = None;
                self.shown = self.receiver.display_model();
                self.log(LogItem::Header {
                    imu_hz: self.profile.imu.rate_hz,
                    earth_ut: s.earth_field(),
                });
                log_info!("receiver rebuilt: mode {=str}", s.mode.word());
            }
            Err(e) => log_error!("new settings refused by the receiver: {}", e),
        }
    }

    /// The menu closed with changed settings: they apply from now on (a new mode, region
    /// or step length rebuilds the receiver: a new search), are logged and go to the idle
    /// loop to be stored in flash (it stalls every task while it writes).
    fn close_menu(&mut self, c: Closed, hw: &mut impl Hardware) {
        let s = c.settings;
        self.mag_cal = s.calibration.mag;
        if c.rebuild {
            self.rebuild_receiver(&s, hw);
        }
        let why = if self.saves.enqueue(s).is_ok() {
            log_info!("settings changed (volume {=u8}); saving", s.volume);
            "menu"
        } else {
            log_warn!("settings changed; not stored (saves pending)");
            "menu_not_saved"
        };
        self.event("settings", Some(why), Some(i64::from(s.volume)));
    }

    /// The tone of the moment (10 ms edges at the tick) at its volume.
    fn tone(&mut self, hw: &mut impl Hardware) {
        let now_ms = hw.now_ms();
        let max_duty = hw.max_duty();
        let play = self
            .controls
            .tone(&self.shown, self.fault, now_ms)
            .map(|(hz, volume)| (hz, sound::duty(max_duty, volume)));
        if play != self.playing {
            hw.buzz(play);
            self.playing = play;
        }
    }

    /// Logs each kind of overrun whose count grew: samples dropped (queue full), IMU
    /// ticks missed, IMU records lost (queue full), log records lost (queue full; logged
    /// once the queue has room again), samples lost while the flash stalled (a settings
    /// save: the clock moves on by them).
    fn overruns(&mut self) {
        let now = self.counters.overruns(self.log_overruns);
        for (why, new) in self.reported.report(now) {
            if why == "flash" {
                self.clock.skip(new);
            }
            log_warn!("overrun {=str}: {=u32}", why, new);
            self.event("overrun", Some(why), Some(i64::from(new)));
        }
    }
}

/// Reacts to the sample clock's verdict: a stalled ADC's DRDY is re-armed.
fn watch_adc(event: ClockEvent, hw: &mut impl Hardware) -> ClockEvent {
    match event {
        ClockEvent::Running => {}
        ClockEvent::Resumed => log_info!("antenna ADC delivering again"),
        ClockEvent::Stalled { rearm: false } => {}
        ClockEvent::Stalled { rearm: true } => {
            log_warn!("antenna ADC stalled: re-arming DRDY");
            hw.rearm_adc();
        }
    }
    event
}

#[cfg(test)]
#[path = "process_tests.rs"]
mod tests;
