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
//! onto the board clock with [`SampleClock::offset_us`].
//!
//! Time stamps are integers ([`Instant`], µs since boot); the pipeline computes in `f32`
//! seconds from an [`Epoch`] that follows the present.

/// A device time stamp: whole microseconds since boot.
///
/// Integer, so it does not lose resolution with uptime (u64 µs wraps after 584 000
/// years). The pipeline does not compute in it: [`crate::app::Receiver`] turns it into
/// `f32` seconds relative to a recent epoch (see [`Epoch`]); the session log writes it as
/// `f64` seconds ([`Instant::secs_f64`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(u64);

impl Instant {
    /// Boot.
    pub const ZERO: Instant = Instant(0);

    /// `us` microseconds since boot.
    pub const fn from_micros(us: u64) -> Self {
        Self(us)
    }

    /// `s` seconds since boot rounded to the microsecond (hosts, session logs); `None`
    /// when `s` is NaN, infinite, negative or beyond the range.
    pub fn from_secs_f64(s: f64) -> Option<Self> {
        let us = libm::round(s * 1e6);
        // 2^64 µs: every value below converts to u64 exactly or by rounding down.
        (0.0..18_446_744_073_709_551_616.0)
            .contains(&us)
            .then_some(Self(us as u64))
    }

    /// Microseconds since boot.
    pub const fn micros(self) -> u64 {
        self.0
    }

    /// Seconds since boot (exact below 2^53 µs ≈ 285 years; the session log's `t`).
    pub fn secs_f64(self) -> f64 {
        self.0 as f64 / 1e6
    }

    /// This instant plus `us` microseconds (saturating).
    pub const fn plus_micros(self, us: u64) -> Self {
        Self(self.0.saturating_add(us))
    }
}

/// Time of a pulse's centre in whole µs since the front end's first sample, from the
/// pulse's first sample index and its duration ([`crate::frontend::Pulse::start_sample`],
/// `duration_s`) at `rate_hz` samples per second: integer, unlike the pulse's `t_s`.
pub fn pulse_centre_us(start_sample: u64, duration_s: f32, rate_hz: f32) -> u64 {
    let s = start_sample as f64 / f64::from(rate_hz) + 0.5 * f64::from(duration_s);
    Instant::from_secs_f64(s).map_or(0, Instant::micros)
}

/// Re-based seconds: a device [`Instant`] as `f32` seconds from an epoch kept within
/// [`Epoch::REBASE_AT_S`] of the present, so the resolution of the times the estimator
/// and dead reckoning compute with stays ≤ 2⁻¹⁴ s (61 µs; 2⁻¹⁵ s ≈ 31 µs after the first
/// re-base) at any uptime, where `f32` seconds since boot reach 2⁻⁷ s (8 ms) after 36 h
/// and skip 100 Hz IMU ticks as "not later" after 1.5 days.
///
/// The epoch starts at the first stamp seen, rounded down to a whole second (so a stream
/// shifted by whole seconds gives the very same relative times). When a relative time
/// reaches [`Epoch::REBASE_AT_S`], [`Epoch::rebase_due`] says how far to move the epoch
/// (whole multiples of [`Epoch::STEP_S`], which `f32` holds exactly); the owner shifts every
/// stored time stamp by that much in the same call ([`Epoch::advance`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Epoch {
    origin: Option<Instant>,
}

impl Epoch {
    /// Relative time at which the epoch moves on, s (`f32` resolution 2⁻¹⁴ s below it).
    pub const REBASE_AT_S: f32 = 512.0;
    /// The epoch moves in whole steps of this, s: relative times land in [256, 512) s.
    pub const STEP_S: f32 = 256.0;
    const STEP_US: u64 = 256_000_000;

    /// No epoch yet: the first stamp converted sets it.
    pub const fn new() -> Self {
        Self { origin: None }
    }

    /// The epoch, once set.
    pub fn origin(&self) -> Option<Instant> {
        self.origin
    }

    /// `t` in seconds from the epoch (set to `t`'s whole second if there is none yet).
    /// Stamps before the epoch give negative times.
    pub fn seconds(&mut self, t: Instant) -> f32 {
        let origin = *self.origin.get_or_insert(Instant(t.0 - t.0 % 1_000_000));
        Self::between(origin, t)
    }

    /// `t` in seconds from the epoch without setting it (from `t`'s whole second when
    /// there is none yet, as [`Epoch::seconds`] would set it).
    pub fn peek(&self, t: Instant) -> f32 {
        let origin = self.origin.unwrap_or(Instant(t.0 - t.0 % 1_000_000));
        Self::between(origin, t)
    }

    /// `t − origin` in seconds, rounded once to `f32`.
    fn between(origin: Instant, t: Instant) -> f32 {
        let d = i128::from(t.0) - i128::from(origin.0);
        // i128 → f64 rounds only beyond 2^53 µs; f64 / 1e6 and → f32 round once each (the
        // f64 quotient is exact to 2^-53, far below the f32 rounding).
        (d as f64 / 1e6) as f32
    }

    /// The epoch's time `rel` s after it, as an instant (rounded to the µs; `None` before
    /// the epoch is set or for a time before boot).
    pub fn instant(&self, rel: f32) -> Option<Instant> {
        let o = self.origin?;
        let us = libm::round(f64::from(rel) * 1e6);
        // |rel| ≤ f32::MAX s would overflow i64 µs: refuse beyond ±2^62 µs.
        if !us.is_finite() || us.abs() >= 4.6e18 {
            return None;
        }
        o.0.checked_add_signed(us as i64).map(Instant)
    }

    /// Seconds since boot of the time `rel` s after the epoch (the epoch's origin in f64
    /// plus `rel`; `rel` itself before the epoch is set).
    pub fn secs_f64(&self, rel: f32) -> f64 {
        self.origin.map_or(0.0, Instant::secs_f64) + f64::from(rel)
    }

    /// How far (s, a multiple of [`Epoch::STEP_S`]) the epoch must move so that the
    /// relative time `rel` falls below [`Epoch::REBASE_AT_S`]; 0 when it does already.
    pub fn rebase_due(&self, rel: f32) -> f32 {
        if self.origin.is_none() || !rel.is_finite() || rel < Self::REBASE_AT_S {
            return 0.0;
        }
        // Steps that leave rel in [STEP_S, 2·STEP_S).
        libm::floorf(rel / Self::STEP_S) * Self::STEP_S - Self::STEP_S
    }

    /// Moves the epoch `shift` s later (a value from [`Epoch::rebase_due`]); the caller
    /// subtracts `shift` from every time stamp it keeps.
    pub fn advance(&mut self, shift: f32) {
        if let Some(o) = self.origin.as_mut() {
            let steps = libm::roundf(shift / Self::STEP_S);
            if steps >= 1.0 {
                o.0 =
                    o.0.saturating_add((steps as u64).saturating_mul(Self::STEP_US));
            }
        }
    }
}

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

    /// Board time now as an integer time stamp (µs, from the sample count: exact while
    /// the count stays below 2^53 samples).
    pub fn now(&self) -> Instant {
        Instant::from_micros(libm::round(self.samples * 1e6 / self.rate_hz) as u64)
    }

    /// `n` samples the ADC took that were never read (no interrupt could run: a flash
    /// erase stalls instruction fetch): time moves on by them, and like a stall's
    /// stand-ins they shift the DSP's later pulse times.
    pub fn skip(&mut self, n: u32) {
        self.samples += f64::from(n);
        self.stand_in += f64::from(n);
    }

    /// Time the DSP did not see (stalls so far) in whole µs: add it to a DSP pulse's
    /// time stamp.
    pub fn offset_us(&self) -> u64 {
        libm::round(self.stand_in * 1e6 / self.rate_hz) as u64
    }

    /// Whether the ADC currently counts as stalled.
    pub fn stalled(&self) -> bool {
        self.quiet_ticks >= STALL_TICKS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secs(t: Instant) -> f32 {
        t.secs_f64() as f32
    }

    fn clock() -> SampleClock {
        SampleClock::new(8000.0, 100.0, 0).unwrap()
    }

    #[test]
    fn skipped_samples_move_time_and_the_pulse_offset_on() {
        let mut c = clock();
        assert_eq!(c.tick(800), ClockEvent::Running);
        // A 2 s flash erase: 16 000 samples never read, then the count goes on.
        c.skip(16_000);
        assert_eq!(c.now(), Instant::from_micros(2_100_000));
        assert_eq!(c.offset_us(), 2_000_000);
        assert_eq!(c.tick(880), ClockEvent::Running);
        assert_eq!(c.now(), Instant::from_micros(2_110_000));
    }

    #[test]
    fn samples_set_the_time() {
        let mut c = clock();
        let mut count = 0u32;
        for _ in 0..100 {
            count += 80;
            assert_eq!(c.tick(count), ClockEvent::Running);
        }
        assert!((secs(c.now()) - 1.0).abs() < 1e-6);
        assert_eq!((c.offset_us() as f32 / 1e6), 0.0);
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
        assert!((secs(c.now()) - 0.01 * (STALL_TICKS + 1) as f32).abs() < 1e-6);
        assert_eq!((c.offset_us() as f32 / 1e6), 0.0);
    }

    #[test]
    fn a_stall_keeps_time_running_and_asks_to_rearm() {
        let mut c = clock();
        c.tick(80);
        let mut rearms = 0;
        let mut last = secs(c.now());
        for k in 1..=60u32 {
            let e = c.tick(80);
            if k >= STALL_TICKS {
                assert!(matches!(e, ClockEvent::Stalled { .. }), "{k}: {e:?}");
                assert!(secs(c.now()) > last, "time moves on while stalled");
                last = secs(c.now());
            }
            if e == (ClockEvent::Stalled { rearm: true }) {
                rearms += 1;
            }
        }
        // 60 ticks = 0.6 s of timer time after the first 10 ms.
        assert!((secs(c.now()) - 0.61).abs() < 1e-5, "{}", secs(c.now()));
        assert!(((c.offset_us() as f32 / 1e6) - 0.6).abs() < 1e-5);
        // At the verdict and every REARM_TICKS ticks after it: ticks 5, 15, …, 55.
        assert_eq!(rearms, 6);
        // Samples return: time goes on from there, never backwards.
        assert_eq!(c.tick(160), ClockEvent::Resumed);
        assert!(secs(c.now()) > last);
        assert_eq!(c.tick(240), ClockEvent::Running);
        // A DSP pulse time (real samples only) lands on the board clock with the offset.
        let dsp_t = 240.0 / 8000.0;
        assert!((dsp_t + (c.offset_us() as f32 / 1e6) - secs(c.now())).abs() < 1e-5);
    }

    #[test]
    fn the_count_may_wrap() {
        let start = u32::MAX - 100;
        let mut c = SampleClock::new(8000.0, 100.0, start).unwrap();
        assert_eq!(c.tick(start.wrapping_add(160)), ClockEvent::Running);
        assert!((secs(c.now()) - (f64::from(start) + 160.0) as f32 / 8000.0).abs() < 1e-3);
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

    #[test]
    fn instants_convert_to_and_from_seconds() {
        let t = Instant::from_secs_f64(864_000.000_125).unwrap();
        assert_eq!(t.micros(), 864_000_000_125);
        assert_eq!(t.secs_f64(), 864_000.000_125);
        for bad in [f64::NAN, f64::INFINITY, -1.0, 2e13] {
            assert_eq!(Instant::from_secs_f64(bad), None, "{bad}");
        }
        assert_eq!(Instant::ZERO.plus_micros(5).micros(), 5);
        assert_eq!(
            Instant::from_micros(u64::MAX).plus_micros(1).micros(),
            u64::MAX
        );
        // 10 days of IMU ticks stay distinct and evenly spaced; f32 seconds since boot
        // cannot tell one tick from the next there.
        let a = Instant::from_micros(864_000_000_000);
        let b = a.plus_micros(10_000);
        assert!(b > a);
        assert_eq!(864_000.0f32 + 0.01, 864_000.0f32);
        assert_eq!(
            pulse_centre_us(8000 * 864_000, 0.004, 8000.0),
            864_000_002_000
        );
    }

    #[test]
    fn the_epoch_starts_at_the_first_whole_second_and_follows_the_present() {
        let mut e = Epoch::new();
        assert_eq!(e.rebase_due(1e6), 0.0, "no epoch yet: nothing to move");
        let t0 = Instant::from_micros(864_000_250_000);
        assert_eq!(e.seconds(t0), 0.25);
        assert_eq!(e.origin(), Some(Instant::from_micros(864_000_000_000)));
        // Same relative times as a stream starting at boot.
        let mut boot = Epoch::new();
        for us in [250_000u64, 1_000_010_000, 511_999_990_000] {
            let rel = e.seconds(Instant::from_micros(864_000_000_000 + us));
            assert_eq!(rel, boot.seconds(Instant::from_micros(us)), "{us}");
            assert_eq!(e.peek(Instant::from_micros(864_000_000_000 + us)), rel);
        }
        // Before the epoch: negative.
        assert_eq!(e.seconds(Instant::from_micros(863_999_000_000)), -1.0);
        assert_eq!(e.rebase_due(511.99), 0.0);
        // At 512 s the epoch moves a whole number of 256 s steps: rel lands in [256, 512).
        for (rel, shift) in [
            (512.0, 256.0),
            (700.0, 256.0),
            (768.5, 512.0),
            (10_000.0, 9728.0),
        ] {
            assert_eq!(e.rebase_due(rel), shift, "{rel}");
            assert!((Epoch::STEP_S..Epoch::REBASE_AT_S).contains(&(rel - shift)));
        }
        let t = Instant::from_micros(864_000_000_000 + 700_000_123);
        let rel = e.seconds(t);
        e.advance(e.rebase_due(rel));
        assert_eq!(e.origin(), Some(Instant::from_micros(864_256_000_000)));
        // After the move the time has the resolution of [256, 512) s: 2^-15 s.
        let after = e.seconds(t);
        assert!(
            (f64::from(after) - 444.000_123).abs() <= 1.0 / 65536.0,
            "{after}"
        );
        assert_eq!(
            e.instant(after)
                .map(|i| i.micros().abs_diff(t.micros()) <= 16),
            Some(true)
        );
        assert!((e.secs_f64(after) - t.secs_f64()).abs() < 16e-6);
        assert_eq!(Epoch::new().instant(1.0), None);
        assert_eq!(e.instant(-1e30), None);
    }
}
