//! The board's time base: ADC samples counted by the data-ready interrupt, with a watchdog
//! for an antenna ADC that stops delivering.
//!
//! Time on the board is the number of antenna samples taken over the ADC's sample rate,
//! so the DSP's pulse times and the IMU's sample times share one clock. The ADS131M04's
//! DRDY line is edge-triggered: if one frame is not read (a bus error, an interrupt held
//! off too long), DRDY can stay low, no further falling edge comes, and the count stops
//! for good — with it the IMU's time, so dead reckoning and the display would freeze.
//! [`SampleClock`] is ticked by an independent timer (the 100 Hz IMU tick): when no sample
//! arrives for [`STALL_TICKS`] ticks it declares the ADC stalled, keeps time running from
//! the timer, and asks the caller every [`REARM_TICKS`] ticks to re-arm the ADC (one frame
//! read clears DRDY). Pulse times from the DSP, which counts only real samples, are moved
//! onto the board clock with [`SampleClock::offset_s`].

/// Timer ticks without a sample before the ADC counts as stalled (50 ms at 100 Hz: 400
/// samples at 8 kSPS should have arrived).
pub const STALL_TICKS: u32 = 5;
/// While stalled, ticks between requests to re-arm the ADC.
pub const REARM_TICKS: u32 = 10;

/// What one timer tick found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockEvent {
    /// Samples are arriving.
    Running,
    /// No sample for [`STALL_TICKS`] ticks or more; `rearm`: re-arm the ADC now.
    Stalled {
        /// Whether the caller should re-arm the ADC at this tick.
        rearm: bool,
    },
    /// Samples arrive again after a stall.
    Resumed,
}

/// Why a clock could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockError {
    /// A rate was not finite and positive, or the tick is not slower than a sample.
    #[error("rate not finite and positive, or tick not slower than a sample")]
    BadRate,
}

/// Board time from the ADC's sample count, kept running by a timer when the ADC stalls.
#[derive(Debug, Clone)]
pub struct SampleClock {
    rate_hz: f64,
    samples_per_tick: f64,
    /// Time counted in samples: real samples plus the timer's stand-ins during stalls.
    samples: f64,
    /// Stand-in samples added during stalls (the DSP never saw them).
    stand_in: f64,
    last_count: u32,
    quiet_ticks: u32,
}

impl SampleClock {
    /// A clock for an ADC at `sample_rate_hz` ticked at `tick_hz`, starting at 0 s with
    /// `samples_so_far` already counted by the interrupt.
    pub fn new(sample_rate_hz: f32, tick_hz: f32, samples_so_far: u32) -> Result<Self, ClockError> {
        let ok = |x: f32| x.is_finite() && x > 0.0;
        if !ok(sample_rate_hz) || !ok(tick_hz) || tick_hz >= sample_rate_hz {
            return Err(ClockError::BadRate);
        }
        Ok(Self {
            rate_hz: f64::from(sample_rate_hz),
            samples_per_tick: f64::from(sample_rate_hz) / f64::from(tick_hz),
            samples: f64::from(samples_so_far),
            stand_in: 0.0,
            last_count: samples_so_far,
            quiet_ticks: 0,
        })
    }

    /// One timer tick; `count` is the interrupt's running sample count (it may wrap).
    pub fn tick(&mut self, count: u32) -> ClockEvent {
        let new = count.wrapping_sub(self.last_count);
        self.last_count = count;
        if new > 0 {
            self.samples += f64::from(new);
            let was_stalled = self.quiet_ticks >= STALL_TICKS;
            self.quiet_ticks = 0;
            return if was_stalled {
                ClockEvent::Resumed
            } else {
                ClockEvent::Running
            };
        }
        self.quiet_ticks = self.quiet_ticks.saturating_add(1);
        if self.quiet_ticks < STALL_TICKS {
            // A short hole (the interrupt held off): time waits for the samples.
            return ClockEvent::Running;
        }
        // Stalled: the timer carries time, including the quiet ticks before the verdict.
        let ticks = if self.quiet_ticks == STALL_TICKS {
            STALL_TICKS
        } else {
            1
        };
        let add = f64::from(ticks) * self.samples_per_tick;
        self.samples += add;
        self.stand_in += add;
        ClockEvent::Stalled {
            rearm: self
                .quiet_ticks
                .saturating_sub(STALL_TICKS)
                .is_multiple_of(REARM_TICKS),
        }
    }

    /// Board time now, s.
    pub fn now_s(&self) -> f32 {
        (self.samples / self.rate_hz) as f32
    }

    /// Time the DSP did not see (stalls so far), s: add it to a DSP pulse time.
    pub fn offset_s(&self) -> f32 {
        (self.stand_in / self.rate_hz) as f32
    }

    /// Whether the ADC currently counts as stalled.
    pub fn stalled(&self) -> bool {
        self.quiet_ticks >= STALL_TICKS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock() -> SampleClock {
        SampleClock::new(8000.0, 100.0, 0).unwrap()
    }

    #[test]
    fn samples_set_the_time() {
        let mut c = clock();
        let mut count = 0u32;
        for _ in 0..100 {
            count += 80;
            assert_eq!(c.tick(count), ClockEvent::Running);
        }
        assert!((c.now_s() - 1.0).abs() < 1e-6);
        assert_eq!(c.offset_s(), 0.0);
        assert!(!c.stalled());
    }

    #[test]
    fn a_short_hole_waits_for_the_samples() {
        let mut c = clock();
        c.tick(80);
        for _ in 0..STALL_TICKS - 1 {
            assert_eq!(c.tick(80), ClockEvent::Running);
        }
        // The held-off samples arrive: no time was invented.
        assert_eq!(c.tick(80 * (STALL_TICKS + 1)), ClockEvent::Running);
        assert!((c.now_s() - 0.01 * (STALL_TICKS + 1) as f32).abs() < 1e-6);
        assert_eq!(c.offset_s(), 0.0);
    }

    #[test]
    fn a_stall_keeps_time_running_and_asks_to_rearm() {
        let mut c = clock();
        c.tick(80);
        let mut rearms = 0;
        let mut last = c.now_s();
        for k in 1..=60u32 {
            let e = c.tick(80);
            if k >= STALL_TICKS {
                assert!(matches!(e, ClockEvent::Stalled { .. }), "{k}: {e:?}");
                assert!(c.now_s() > last, "time moves on while stalled");
                last = c.now_s();
            }
            if e == (ClockEvent::Stalled { rearm: true }) {
                rearms += 1;
            }
        }
        // 60 ticks = 0.6 s of timer time after the first 10 ms.
        assert!((c.now_s() - 0.61).abs() < 1e-5, "{}", c.now_s());
        assert!((c.offset_s() - 0.6).abs() < 1e-5);
        // At the verdict and every REARM_TICKS ticks after it: ticks 5, 15, …, 55.
        assert_eq!(rearms, 6);
        // Samples return: time goes on from there, never backwards.
        assert_eq!(c.tick(160), ClockEvent::Resumed);
        assert!(c.now_s() > last);
        assert_eq!(c.tick(240), ClockEvent::Running);
        // A DSP pulse time (real samples only) lands on the board clock with the offset.
        let dsp_t = 240.0 / 8000.0;
        assert!((dsp_t + c.offset_s() - c.now_s()).abs() < 1e-5);
    }

    #[test]
    fn the_count_may_wrap() {
        let start = u32::MAX - 100;
        let mut c = SampleClock::new(8000.0, 100.0, start).unwrap();
        assert_eq!(c.tick(start.wrapping_add(160)), ClockEvent::Running);
        assert!((c.now_s() - (f64::from(start) + 160.0) as f32 / 8000.0).abs() < 1e-3);
    }

    #[test]
    fn bad_rates_are_refused() {
        for (r, t) in [
            (0.0, 100.0),
            (f32::NAN, 100.0),
            (8000.0, f32::INFINITY),
            (8000.0, -1.0),
            (100.0, 8000.0),
        ] {
            assert_eq!(
                SampleClock::new(r, t, 0).map(|_| ()),
                Err(ClockError::BadRate),
                "{r} {t}"
            );
        }
    }
}
