//! Sensor health and the battery, as the display shows them.
//!
//! A dead antenna ADC looks, to the guidance, exactly like "no victim in range": no pulse.
//! The rescuer must not read a broken receiver as an empty slope, so [`SensorHealth`]
//! watches the sensors and [`draw_overlay`] puts a fault over the status word ("ADC
//! FAULT" in an inverted box where "NO SIGNAL" would be), whatever the guidance says. The
//! board binary logs every change of [`SensorHealth::fault`].
//!
//! Faults, in the order they are shown (one at a time, the first that holds):
//! - **ADC**: it did not pass its boot check (reset, ID, configuration), or it delivered
//!   no sample for [`ADC_STALL_TICKS`] timer ticks in a row (the time base re-arms it
//!   meanwhile), or more than half of the frames of the last one-second window failed
//!   (CRC or bus errors).
//! - **I2C**: the shared bus is stuck and a bus clear did not free it (IMU and display
//!   are then unreachable; the display shows the fault if it still can).
//! - **IMU**: it did not come up (at boot or after a bus clear), or [`IMU_FAIL_RUN`] reads
//!   in a row failed.
//!
//! - **SD card** (not a sensor: the search goes on without it, so no fault box and no
//!   fault tone): no card in the slot, or the card failed at boot or while writing
//!   ([`crate::board::sd_log::SdState`]); its word ("NO SD", "SD ERR") goes in an inverted
//!   box on the bottom line ([`draw_sd_mark`]), and the fault LED is lit.
//!
//! The battery: the Feather divides BAT by two (2 × 100 kΩ) into PA3; [`Battery`] turns
//! the MCU ADC's reading into volts, smooths it, maps it to a charge estimate on a
//! typical LiPo discharge curve ([`LIPO_CURVE`]) and raises a low-battery warning with
//! hysteresis. With USB power and no battery the charger holds BAT near 4.2 V: the gauge
//! then reads full.

use embedded_graphics::mono_font::MonoTextStyleBuilder;
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{PrimitiveStyle, Rectangle};
use embedded_graphics::text::{Baseline, Text};

use crate::timebase::ClockEvent;

/// Timer ticks without an ADC sample that make an ADC fault (1 s at 100 Hz; the time base
/// calls the ADC stalled after 50 ms and re-arms it every 100 ms, so this is ten failed
/// re-arms).
pub const ADC_STALL_TICKS: u32 = 100;
/// IMU reads failing in a row that make an IMU fault (0.1 s at 100 Hz).
pub const IMU_FAIL_RUN: u32 = 10;

/// A sensor fault, as shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fault {
    /// The antenna ADC: no pulses can be received.
    Adc,
    /// The shared I2C bus is stuck: no IMU, maybe no display.
    Bus,
    /// The IMU: no dead reckoning, no heading.
    Imu,
}

impl Fault {
    /// The word on the display.
    pub fn label(self) -> &'static str {
        match self {
            Fault::Adc => "ADC FAULT",
            Fault::Bus => "I2C FAULT",
            Fault::Imu => "IMU FAULT",
        }
    }
}

/// What the board knows about its sensors.
#[derive(Debug, Clone, Default)]
pub struct SensorHealth {
    adc_boot_failed: bool,
    adc_quiet_ticks: u32,
    adc_window_bad: bool,
    imu_down: bool,
    imu_fail_run: u32,
    bus_stuck: bool,
}

impl SensorHealth {
    /// All sensors presumed well until told otherwise.
    pub fn new() -> Self {
        Self::default()
    }

    /// The ADC's boot check (reset, ID, configuration) passed or not.
    pub fn adc_boot(&mut self, ok: bool) {
        self.adc_boot_failed = !ok;
    }

    /// One tick of the sample clock (see [`crate::timebase::SampleClock::tick`]).
    pub fn adc_tick(&mut self, event: ClockEvent) {
        match event {
            ClockEvent::Running | ClockEvent::Resumed => self.adc_quiet_ticks = 0,
            ClockEvent::Stalled { .. } => {
                self.adc_quiet_ticks = self.adc_quiet_ticks.saturating_add(1)
            }
        }
    }

    /// The ADC frames of the last window: `frames` read, `failed` of them with errors.
    pub fn adc_window(&mut self, frames: u32, failed: u32) {
        self.adc_window_bad = u64::from(failed) * 2 > u64::from(frames) && failed > 0;
    }

    /// The IMU came up (`true`) or did not (`false`), at boot or after a bus clear.
    pub fn imu_up(&mut self, up: bool) {
        self.imu_down = !up;
        self.imu_fail_run = 0;
    }

    /// Whether an IMU is up at this tick: a change counts as [`Self::imu_up`]; no change
    /// keeps the run of failed reads counting.
    pub fn imu_present(&mut self, up: bool) {
        if up == self.imu_down {
            self.imu_up(up);
        }
    }

    /// One IMU read succeeded or failed.
    pub fn imu_read(&mut self, ok: bool) {
        self.imu_fail_run = if ok {
            0
        } else {
            self.imu_fail_run.saturating_add(1)
        };
    }

    /// Whether the shared bus is stuck and was not freed.
    pub fn bus_stuck(&mut self, stuck: bool) {
        self.bus_stuck = stuck;
    }

    /// The fault to show, if any (the first of ADC, I2C, IMU that holds).
    pub fn fault(&self) -> Option<Fault> {
        if self.adc_boot_failed || self.adc_quiet_ticks >= ADC_STALL_TICKS || self.adc_window_bad {
            Some(Fault::Adc)
        } else if self.bus_stuck {
            Some(Fault::Bus)
        } else if self.imu_down || self.imu_fail_run >= IMU_FAIL_RUN {
            Some(Fault::Imu)
        } else {
            None
        }
    }
}

/// A typical single-cell LiPo's voltage under a light load against its remaining charge
/// (V, %), ascending; a gauge, not a coulomb count.
pub const LIPO_CURVE: [(f32, f32); 13] = [
    (3.27, 0.0),
    (3.61, 5.0),
    (3.69, 10.0),
    (3.73, 20.0),
    (3.77, 30.0),
    (3.80, 40.0),
    (3.84, 50.0),
    (3.87, 60.0),
    (3.95, 70.0),
    (4.02, 80.0),
    (4.08, 85.0),
    (4.11, 90.0),
    (4.20, 100.0),
];
/// Below this (V, smoothed) the low-battery warning comes on (≈ 10 % left).
pub const LOW_ON_V: f32 = 3.69;
/// Above this (V, smoothed) it goes off again (the hysteresis covers the sag under load).
pub const LOW_OFF_V: f32 = 3.77;
/// Full scale of the MCU ADC (12 bits).
pub const ADC_FULL_SCALE: f32 = 4095.0;
/// Weight of a new reading in the smoothed voltage (one reading a second: ≈ 5 s time
/// constant, long enough to ride out the current steps of a display flush).
pub const SMOOTHING: f32 = 0.2;

/// The battery as shown: smoothed voltage, charge estimate, low warning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryState {
    /// Smoothed battery voltage, V.
    pub volts: f32,
    /// Charge estimate from [`LIPO_CURVE`], % (0–100).
    pub percent: f32,
    /// Low-battery warning.
    pub low: bool,
}

/// The battery gauge.
#[derive(Debug, Clone, Default)]
pub struct Battery {
    state: Option<BatteryState>,
}

/// The charge estimate, %, for a voltage on [`LIPO_CURVE`] (clamped to 0–100).
pub fn lipo_percent(volts: f32) -> f32 {
    if volts.is_nan() {
        return 0.0;
    }
    let mut prev: Option<(f32, f32)> = None;
    for &(v, p) in LIPO_CURVE.iter() {
        if volts <= v {
            return match prev {
                None => p,
                Some((v0, p0)) => p0 + (p - p0) * (volts - v0) / (v - v0),
            };
        }
        prev = Some((v, p));
    }
    100.0
}

/// Battery volts from a 12-bit MCU ADC reading of the divider tap, with the ADC's
/// reference `vref_v` (V) and the divider's ratio.
pub fn battery_volts(raw: u16, vref_v: f32, divider: f32) -> f32 {
    f32::from(raw.min(4095)) / ADC_FULL_SCALE * vref_v * divider
}

impl Battery {
    /// A gauge with no reading yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a reading (V); a reading that is not finite and positive is ignored. Returns
    /// the new state.
    pub fn update(&mut self, volts: f32) -> Option<BatteryState> {
        if !(volts.is_finite() && volts > 0.0) {
            return self.state;
        }
        let (smoothed, was_low) = match self.state {
            None => (volts, false),
            Some(s) => (s.volts + SMOOTHING * (volts - s.volts), s.low),
        };
        let low = if was_low {
            smoothed < LOW_OFF_V
        } else {
            smoothed < LOW_ON_V
        };
        self.state = Some(BatteryState {
            volts: smoothed,
            percent: lipo_percent(smoothed),
            low,
        });
        self.state
    }

    /// The current state (none before the first reading).
    pub fn state(&self) -> Option<BatteryState> {
        self.state
    }
}

/// Where the fault box sits: over the status word (the top row's left part, clear of the
/// overlap mark at x = 98 and the victim list at x ≥ 104).
pub const FAULT_BOX: Rectangle = Rectangle::new(Point::new(0, 0), Size::new(96, 10));
/// The battery icon: bottom left, outside the arrow's reach (the arrow's tip stays within
/// 22 px of (31, 37), the corner is 33 px away).
pub const BATTERY_ICON: Rectangle = Rectangle::new(Point::new(0, 57), Size::new(12, 7));

/// Draws the health overlay over a drawn display model: the fault (if any) in an inverted
/// box over the status word, the battery icon filled to its charge, and "LOW" beside it
/// when the battery is low.
pub fn draw_overlay<D>(
    fault: Option<Fault>,
    battery: Option<BatteryState>,
    target: &mut D,
) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    if let Some(f) = fault {
        FAULT_BOX
            .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
            .draw(target)?;
        let inverted = MonoTextStyleBuilder::new()
            .font(&FONT_6X10)
            .text_color(BinaryColor::Off)
            .build();
        Text::with_baseline(f.label(), Point::new(1, 0), inverted, Baseline::Top).draw(target)?;
    }
    if let Some(b) = battery {
        BATTERY_ICON
            .into_styled(PrimitiveStyle::with_fill(BinaryColor::Off))
            .draw(target)?;
        BATTERY_ICON
            .into_styled(PrimitiveStyle::with_stroke(BinaryColor::On, 1))
            .draw(target)?;
        // The terminal nub.
        Rectangle::new(BATTERY_ICON.top_left + Point::new(12, 2), Size::new(1, 3))
            .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
            .draw(target)?;
        let inner = BATTERY_ICON.size.width - 2;
        let fill = ((b.percent.clamp(0.0, 100.0) / 100.0) * inner as f32 + 0.5) as u32;
        if fill > 0 {
            Rectangle::new(
                BATTERY_ICON.top_left + Point::new(1, 1),
                Size::new(fill.min(inner), BATTERY_ICON.size.height - 2),
            )
            .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
            .draw(target)?;
        }
        if b.low {
            let style = MonoTextStyleBuilder::new()
                .font(&FONT_6X10)
                .text_color(BinaryColor::On)
                .background_color(BinaryColor::Off)
                .build();
            Text::with_baseline("LOW", Point::new(15, 54), style, Baseline::Top).draw(target)?;
        }
    }
    Ok(())
}

/// Where the SD card's word goes: the bottom line, right of the battery's "LOW", left
/// of the uncertainty text (x 66).
pub const SD_MARK: Rectangle = Rectangle::new(Point::new(34, 54), Size::new(31, 10));

/// Draws the SD card's word (`SdState::fault_label`) in an inverted box at [`SD_MARK`];
/// nothing when `label` is `None` (logging). Labels longer than five characters are cut.
pub fn draw_sd_mark<D>(label: Option<&str>, target: &mut D) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    let Some(label) = label else {
        return Ok(());
    };
    let label = label.get(..5).unwrap_or(label);
    SD_MARK
        .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
        .draw(target)?;
    let inverted = MonoTextStyleBuilder::new()
        .font(&FONT_6X10)
        .text_color(BinaryColor::Off)
        .build();
    Text::with_baseline(
        label,
        SD_MARK.top_left + Point::new(1, 0),
        inverted,
        Baseline::Top,
    )
    .draw(target)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::DisplayModel;
    use crate::display::{self, Frame};
    use crate::guidance::Status;
    use embedded_graphics::image::GetPixel;

    fn region(f: &Frame, r: Rectangle) -> Vec<Option<BinaryColor>> {
        r.points().map(|p| f.pixel(p)).collect()
    }

    #[test]
    fn a_dead_adc_never_reads_no_signal() {
        let model = DisplayModel {
            status: Status::NoSignal,
            ..DisplayModel::default()
        };
        let mut shown = Frame::new();
        display::draw(&model, &mut shown).unwrap();
        let mut h = SensorHealth::new();
        h.adc_boot(false);
        draw_overlay(h.fault(), None, &mut shown).unwrap();
        // The status word's place holds exactly the fault box, as drawn on a blank screen.
        let mut fault_alone = Frame::new();
        draw_overlay(Some(Fault::Adc), None, &mut fault_alone).unwrap();
        assert_eq!(region(&shown, FAULT_BOX), region(&fault_alone, FAULT_BOX));
        // …and that is not what "NO SIGNAL" looks like.
        let mut no_signal = Frame::new();
        display::draw(&model, &mut no_signal).unwrap();
        assert_ne!(region(&shown, FAULT_BOX), region(&no_signal, FAULT_BOX));
        // The rest of the screen is the model's.
        let below = Rectangle::new(Point::new(0, 11), Size::new(128, 45));
        assert_eq!(region(&shown, below), region(&no_signal, below));
    }

    #[test]
    fn the_adc_faults_when_it_failed_at_boot_stalls_for_a_second_or_corrupts_frames() {
        let mut h = SensorHealth::new();
        assert_eq!(h.fault(), None);
        h.adc_boot(false);
        assert_eq!(h.fault(), Some(Fault::Adc));
        h.adc_boot(true);
        assert_eq!(h.fault(), None);
        // A stall shorter than a second is the time base's business, not a fault.
        for _ in 0..ADC_STALL_TICKS - 1 {
            h.adc_tick(ClockEvent::Stalled { rearm: false });
        }
        assert_eq!(h.fault(), None);
        h.adc_tick(ClockEvent::Stalled { rearm: true });
        assert_eq!(h.fault(), Some(Fault::Adc));
        h.adc_tick(ClockEvent::Resumed);
        assert_eq!(h.fault(), None);
        h.adc_window(8000, 4000);
        assert_eq!(h.fault(), None, "half the frames bad is not yet a fault");
        h.adc_window(8000, 4001);
        assert_eq!(h.fault(), Some(Fault::Adc));
        h.adc_window(8000, 3);
        assert_eq!(h.fault(), None);
        h.adc_window(0, 0);
        assert_eq!(h.fault(), None, "an empty window is the stall's case");
    }

    #[test]
    fn the_imu_faults_on_a_run_of_failed_reads_and_the_adc_comes_first() {
        let mut h = SensorHealth::new();
        for _ in 0..IMU_FAIL_RUN - 1 {
            h.imu_read(false);
        }
        assert_eq!(h.fault(), None);
        h.imu_read(true);
        for _ in 0..IMU_FAIL_RUN {
            h.imu_read(false);
        }
        assert_eq!(h.fault(), Some(Fault::Imu));
        h.bus_stuck(true);
        assert_eq!(h.fault(), Some(Fault::Bus));
        h.adc_boot(false);
        assert_eq!(h.fault(), Some(Fault::Adc));
        h.adc_boot(true);
        h.bus_stuck(false);
        h.imu_up(true);
        assert_eq!(h.fault(), None, "a re-initialised IMU starts afresh");
        h.imu_up(false);
        assert_eq!(h.fault(), Some(Fault::Imu));
    }

    #[test]
    fn the_charge_follows_the_curve_and_is_clamped() {
        assert_eq!(lipo_percent(4.3), 100.0);
        assert_eq!(lipo_percent(4.2), 100.0);
        assert_eq!(lipo_percent(3.0), 0.0);
        assert_eq!(lipo_percent(f32::NAN), 0.0);
        assert!((lipo_percent(3.84) - 50.0).abs() < 1e-4);
        assert!((lipo_percent(3.82) - 45.0).abs() < 1e-3);
        let mut last = -1.0;
        for i in 0..=120 {
            let p = lipo_percent(3.2 + 0.01 * i as f32);
            assert!(p >= last && (0.0..=100.0).contains(&p));
            last = p;
        }
    }

    #[test]
    fn the_divider_reading_converts_to_battery_volts() {
        // 3.7 V at BAT → 1.85 V at PA3 → 2296 of 4095 at 3.3 V.
        let v = battery_volts(2296, 3.3, 2.0);
        assert!((v - 3.7).abs() < 0.002, "{v}");
        assert_eq!(battery_volts(u16::MAX, 3.3, 2.0), 6.6);
    }

    #[test]
    fn the_low_warning_has_hysteresis_and_ignores_bad_readings() {
        let mut b = Battery::new();
        assert_eq!(b.state(), None);
        assert_eq!(b.update(f32::NAN), None);
        let s = b.update(3.9).unwrap();
        assert!(!s.low && (s.volts - 3.9).abs() < 1e-6);
        // Discharge slowly: the warning comes on below 3.69 V (smoothed).
        let mut v = 3.9;
        while !b.state().unwrap().low {
            v -= 0.005;
            b.update(v);
            assert!(v > 3.5, "warning never came");
        }
        assert!(b.state().unwrap().volts < LOW_ON_V);
        // A small recovery (load removed) does not clear it…
        for _ in 0..30 {
            b.update(3.74);
        }
        assert!(b.state().unwrap().low);
        // …charging does.
        for _ in 0..30 {
            b.update(4.0);
        }
        assert!(!b.state().unwrap().low);
        assert_eq!(b.update(-1.0), b.state(), "a negative reading is ignored");
    }

    #[test]
    fn the_battery_icon_fills_with_the_charge_and_low_is_written() {
        let count = |f: &Frame| {
            BATTERY_ICON
                .points()
                .filter(|p| f.pixel(*p) == Some(BinaryColor::On))
                .count()
        };
        let state = |percent, low| BatteryState {
            volts: 3.8,
            percent,
            low,
        };
        let mut empty = Frame::new();
        draw_overlay(None, Some(state(0.0, false)), &mut empty).unwrap();
        let mut half = Frame::new();
        draw_overlay(None, Some(state(50.0, false)), &mut half).unwrap();
        let mut full = Frame::new();
        draw_overlay(None, Some(state(100.0, false)), &mut full).unwrap();
        let (e, h, f) = (count(&empty), count(&half), count(&full));
        assert!(e < h && h < f, "{e} {h} {f}");
        // Inner area 10 × 5: half adds 25 pixels, full 50.
        assert_eq!((h - e, f - e), (25, 50));
        let mut low = Frame::new();
        draw_overlay(None, Some(state(5.0, true)), &mut low).unwrap();
        let text = Rectangle::new(Point::new(15, 54), Size::new(18, 10));
        assert!(text.points().any(|p| low.pixel(p) == Some(BinaryColor::On)));
        assert!(
            text.points()
                .all(|p| empty.pixel(p) != Some(BinaryColor::On))
        );
    }

    #[test]
    fn the_sd_mark_is_drawn_only_when_not_logging_and_stays_in_its_box() {
        use crate::board::sd_log::{SdError, SdState};
        let screen = Rectangle::new(Point::zero(), Size::new(128, 64));
        let mut f = Frame::new();
        draw_sd_mark(SdState::Logging(3).fault_label(), &mut f).unwrap();
        assert!(screen.points().all(|p| f.pixel(p) != Some(BinaryColor::On)));
        for state in [SdState::NoCard, SdState::Failed(SdError::Card)] {
            let mut f = Frame::new();
            draw_sd_mark(state.fault_label(), &mut f).unwrap();
            let lit_outside = screen
                .points()
                .filter(|p| !SD_MARK.contains(*p))
                .any(|p| f.pixel(p) == Some(BinaryColor::On));
            assert!(!lit_outside, "{state:?} drawn outside its box");
            // Inverted: the box is mostly lit, the word's pixels dark.
            let dark = SD_MARK
                .points()
                .filter(|p| f.pixel(*p) == Some(BinaryColor::Off))
                .count();
            assert!(dark > 20, "{state:?}: no word in the box");
        }
        // Clear of the battery's "LOW" (ends at x 33) and the uncertainty text (x 66).
        const {
            assert!(SD_MARK.top_left.x > 15 + 3 * 6);
            assert!(SD_MARK.top_left.x + SD_MARK.size.width as i32 <= display::UNCERTAINTY_AT.x);
        }
    }
}
