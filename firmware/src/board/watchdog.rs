//! Feeding the independent watchdog only while the main work progresses.
//!
//! A watchdog fed from a timer interrupt, or at the top of a loop that runs whatever
//! happens, resets nothing when the work itself is stuck (an ADC queue never drained, IMU
//! ticks never handled) while the loop still spins. [`ProgressWatch`] keeps, for each piece
//! of work, when it last progressed; the board binary feeds the IWDG only when
//! [`ProgressWatch::verdict`] says every piece progressed within its limit. When one
//! stalls the feeding stops, the IWDG resets the MCU within its period, and the verdict
//! names the stalled work so that it can be stored (see [`super::crash`]) and shown after
//! the reset. A loop stuck inside a call (a bus transfer that never ends) stops feeding
//! by itself.
//!
//! Time is a monotonic millisecond count from [`MonotonicMs`], which extends the Cortex-M
//! cycle counter (32 bits, wraps every 25.6 s at 168 MHz) to 64 bits, so a progress stamp
//! compares correctly after any uptime.

/// The main loop's pieces of work that must keep progressing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Work {
    /// The ADC sample queue is drained (the main loop caught up with the DRDY interrupt).
    Samples = 0,
    /// A tick of the 100 Hz IMU timer was handled (IMU read, buttons, redraw).
    Ticks = 1,
}

impl Work {
    /// Every piece of work, in index order.
    pub const ALL: [Work; 2] = [Work::Samples, Work::Ticks];

    /// A short name for logs and the crash record.
    pub fn name(self) -> &'static str {
        match self {
            Work::Samples => "ADC sample queue not drained",
            Work::Ticks => "IMU ticks not handled",
        }
    }
}

/// Whether the watchdog may be fed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Every piece of work progressed within its limit: feed.
    Feed,
    /// This work has not progressed for `for_ms` (more than its limit): do not feed.
    Stalled {
        /// The stalled work.
        work: Work,
        /// How long since it last progressed, ms.
        for_ms: u64,
    },
}

/// Last progress of each piece of work against its limit.
#[derive(Debug, Clone)]
pub struct ProgressWatch {
    last_ms: [u64; 2],
    limit_ms: [u64; 2],
}

impl ProgressWatch {
    /// A watch started at `now_ms` (every work counts as just progressed) with the given
    /// limits, ms, indexed by [`Work`].
    pub fn new(limit_ms: [u64; 2], now_ms: u64) -> Self {
        Self {
            last_ms: [now_ms; 2],
            limit_ms,
        }
    }

    /// Records that `work` progressed at `now_ms`. A stamp older than the last one kept
    /// (a clock read out of order) is ignored.
    pub fn progress(&mut self, work: Work, now_ms: u64) {
        if let Some(t) = self.last_ms.get_mut(work as usize) {
            *t = (*t).max(now_ms);
        }
    }

    /// Whether every work progressed within its limit at `now_ms`; the first stalled one
    /// otherwise.
    pub fn verdict(&self, now_ms: u64) -> Verdict {
        for w in Work::ALL {
            let i = w as usize;
            let (Some(last), Some(limit)) = (self.last_ms.get(i), self.limit_ms.get(i)) else {
                continue;
            };
            let since = now_ms.saturating_sub(*last);
            if since > *limit {
                return Verdict::Stalled {
                    work: w,
                    for_ms: since,
                };
            }
        }
        Verdict::Feed
    }
}

/// A 64-bit monotonic count from a wrapping 32-bit cycle counter, read at least once per
/// wrap (25.6 s at 168 MHz; the main loop reads it at every pass).
#[derive(Debug, Clone)]
pub struct MonotonicMs {
    cycles_per_ms: u32,
    last: u32,
    total_cycles: u64,
}

impl MonotonicMs {
    /// A clock of `cycles_per_ms` (≥ 1) cycles per millisecond starting at the counter
    /// value `now_cycles` (time 0).
    pub fn new(cycles_per_ms: u32, now_cycles: u32) -> Self {
        Self {
            cycles_per_ms: cycles_per_ms.max(1),
            last: now_cycles,
            total_cycles: 0,
        }
    }

    /// Milliseconds since the start, given the counter's current value.
    pub fn now_ms(&mut self, now_cycles: u32) -> u64 {
        self.total_cycles += u64::from(now_cycles.wrapping_sub(self.last));
        self.last = now_cycles;
        self.total_cycles / u64::from(self.cycles_per_ms)
    }
}

/// Counts a periodic interrupt's lost releases from the cycle counter: ticks due since
/// the first one (rounded, so a late tick followed by an early one is no loss) against
/// ticks handled. The NVIC keeps one pending bit, so a handler that starts more than a
/// period late has lost a release.
#[derive(Debug, Clone)]
pub struct TickMisses {
    period_cycles: u32,
    last: u32,
    elapsed: u64,
    handled: u64,
}

impl TickMisses {
    /// A counter for a tick every `period_cycles` (≥ 1) cycles.
    pub fn new(period_cycles: u32) -> Self {
        Self {
            period_cycles: period_cycles.max(1),
            last: 0,
            elapsed: 0,
            handled: 0,
        }
    }

    /// A tick handled at the counter value `now_cycles` (a wrapping 32-bit counter, read
    /// at least once per wrap): the ticks lost since the last one.
    pub fn on_tick(&mut self, now_cycles: u32) -> u32 {
        if self.handled > 0 {
            self.elapsed += u64::from(now_cycles.wrapping_sub(self.last));
        }
        self.last = now_cycles;
        let p = u64::from(self.period_cycles);
        let due = (self.elapsed + p / 2) / p + 1;
        self.handled += 1;
        let missed = due.saturating_sub(self.handled);
        self.handled = self.handled.max(due);
        u32::try_from(missed).unwrap_or(u32::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_misses_counts_lost_releases_not_jitter() {
        const P: u32 = 1_680_000;
        let mut m = TickMisses::new(P);
        // Start near the counter's wrap; jitter up to 40 % of a period, late then early.
        let t0 = u32::MAX - 3 * P;
        let mut lost = 0;
        for k in 0..5_000u32 {
            let jitter = if k % 2 == 0 { P / 5 * 2 } else { 0 };
            lost += m.on_tick(t0.wrapping_add(k.wrapping_mul(P)).wrapping_add(jitter));
        }
        assert_eq!(lost, 0);
        // Skip one, then three releases: counted once each, then back to none.
        let mut m = TickMisses::new(P);
        let ticks = [0u32, 1, 2, 4, 5, 9, 10, 11];
        let lost: Vec<u32> = ticks
            .iter()
            .map(|&k| m.on_tick(t0.wrapping_add(k * P)))
            .collect();
        assert_eq!(lost, [0, 0, 0, 1, 0, 3, 0, 0]);
    }

    const LIMITS: [u64; 2] = [1000, 500];

    #[test]
    fn feeds_while_everything_progresses() {
        let mut w = ProgressWatch::new(LIMITS, 0);
        for t in (10..20_000).step_by(10) {
            w.progress(Work::Samples, t);
            w.progress(Work::Ticks, t);
            assert_eq!(w.verdict(t + 5), Verdict::Feed);
        }
    }

    #[test]
    fn a_stalled_piece_of_work_stops_the_feeding_and_is_named() {
        let mut w = ProgressWatch::new(LIMITS, 0);
        // The loop keeps spinning and the samples drain, but the ticks stopped at 1 s.
        for t in (0..=1000).step_by(10) {
            w.progress(Work::Ticks, t);
        }
        for t in (1000..=1500).step_by(10) {
            w.progress(Work::Samples, t);
            assert_eq!(w.verdict(t), Verdict::Feed, "t = {t}");
        }
        w.progress(Work::Samples, 1510);
        assert_eq!(
            w.verdict(1510),
            Verdict::Stalled {
                work: Work::Ticks,
                for_ms: 510
            }
        );
        // Progress resumes: feeding resumes.
        w.progress(Work::Ticks, 1520);
        assert_eq!(w.verdict(1520), Verdict::Feed);
    }

    #[test]
    fn each_limit_is_its_own() {
        let w = ProgressWatch::new(LIMITS, 0);
        assert_eq!(w.verdict(500), Verdict::Feed);
        assert_eq!(
            w.verdict(501),
            Verdict::Stalled {
                work: Work::Ticks,
                for_ms: 501
            }
        );
        let mut w = ProgressWatch::new(LIMITS, 0);
        w.progress(Work::Ticks, 900);
        assert_eq!(
            w.verdict(1001),
            Verdict::Stalled {
                work: Work::Samples,
                for_ms: 1001
            }
        );
    }

    #[test]
    fn an_out_of_order_stamp_does_not_move_progress_back() {
        let mut w = ProgressWatch::new(LIMITS, 0);
        w.progress(Work::Ticks, 400);
        w.progress(Work::Ticks, 100);
        assert_eq!(w.verdict(900), Verdict::Feed);
    }

    #[test]
    fn the_millisecond_clock_survives_counter_wraps_over_ten_days() {
        // 168 MHz: the 32-bit counter wraps every 25.57 s; read it every 10 s of cycles.
        let cpm = 168_000u32;
        let start = 0xFFFF_0000u32;
        let mut clock = MonotonicMs::new(cpm, start);
        let step = 10 * 1000 * u64::from(cpm); // 10 s of cycles
        let mut cycles: u64 = 0;
        let ten_days_s = 10 * 24 * 3600u64;
        for _ in 0..ten_days_s / 10 {
            cycles += step;
            let counter = (u64::from(start) + cycles) as u32;
            let ms = clock.now_ms(counter);
            assert_eq!(ms, cycles / u64::from(cpm));
        }
        assert_eq!(
            clock.now_ms((u64::from(start) + cycles) as u32),
            ten_days_s * 1000
        );
        // And a watch on it still judges 10 days in.
        let now = ten_days_s * 1000;
        let mut w = ProgressWatch::new(LIMITS, now - 10_000);
        w.progress(Work::Samples, now - 5);
        w.progress(Work::Ticks, now - 5);
        assert_eq!(w.verdict(now), Verdict::Feed);
    }
}
