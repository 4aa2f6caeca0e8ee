//! The board's real-time schedule as a model: the board binary's tasks, their fixed
//! priorities, their worst costs and the queues between them, simulated event by event on
//! one 168 MHz core with preemption by priority and the I2C bus shared under the
//! priority-ceiling protocol (RTIC's resource locks). [`simulate`] returns the deepest
//! each queue got and every overrun; [`margin`] the factor by which the tasks' costs could
//! grow before any queue overflows. The task table and where each cost comes from:
//! `docs/board.md` ("Real-time structure").
//!
//! | task | priority | released by | work | queue it fills |
//! |---|---|---|---|---|
//! | ADC data ready | 4 | DRDY edge, 8 kSPS | SPI frame, CRC, volts | samples ([`SAMPLE_QUEUE`]) |
//! | IMU tick | 3 | TIM2, 100 Hz | BMI160 + LSM303AGR over I2C, buttons | IMU records ([`IMU_QUEUE`]) |
//! | process | 2 | a sample or IMU record queued | DSP per sample, estimator per pulse, IMU step | log bytes ([`LOG_QUEUE`]), the display's model |
//! | display | 1 | a new model (each pulse, else every second) | draw, flush over I2C | – (the newest model wins) |
//! | log writer | 0 (idle) | log bytes queued | UART stream, SD block writes and flushes | – |
//!
//! An interrupt whose previous release has not started yet loses the new one (the NVIC
//! keeps one pending bit): a lost DRDY is a dropped sample, a lost TIM2 update a missed
//! IMU tick. The display's flush sends 16-byte I2C transactions, each under the bus lock
//! (ceiling = the IMU tick's priority), so the IMU tick waits at most one transaction.

/// The core clock, Hz (one cycle is the model's time unit).
pub const SYSCLK_HZ: u64 = 168_000_000;
/// Priority of the ADC's data-ready interrupt (the highest).
pub const PRIO_DRDY: u8 = 4;
/// Priority of the IMU tick (TIM2), also the I2C bus's ceiling.
pub const PRIO_IMU: u8 = 3;
/// Priority of the processing task (DSP, estimator, guidance).
pub const PRIO_PROCESS: u8 = 2;
/// Priority of the display task (draws the newest model and flushes it over I2C).
pub const PRIO_DISPLAY: u8 = 1;
/// Priority of the log writer (the idle loop).
pub const PRIO_LOG: u8 = 0;
/// Capacity of the ADC sample queue, samples (256 ms at 8 kSPS).
pub const SAMPLE_QUEUE: u32 = 2048;
/// Capacity of the IMU record queue, records (320 ms at 100 Hz).
pub const IMU_QUEUE: u32 = 32;
/// Capacity of the session log's record queue between the processing task and the writer
/// (records, formatted by the writer; 1.2 s of IMU records).
pub const LOG_QUEUE: u32 = 128;
/// Largest IMU record queue the model tracks.
const MAX_IMU_QUEUE: usize = 256;
/// Largest log record queue the model tracks.
const MAX_LOG_QUEUE: usize = 256;

/// The board's worst costs. Instructions measured under QEMU (`netduinoplus2`,
/// `-icount shift=0`, release build); wire times from the bus clocks. Sources:
/// `docs/board.md` ("Real-time structure").
pub const BOARD_COSTS: Costs = Costs {
    // `cargo qemu --bin qemu_board`: "board drdy_isr 947" (frame read and CRC, volts,
    // enqueue), + 100 for the exception entry and exit and the EXTI flag.
    drdy_instr: 947 + 100,
    // 6 words × 24 bit at 8 MHz = 18 µs, + 0.3 µs per byte of the HAL's byte loop.
    drdy_bus_ns: 18_000 + 18 * 300,
    // "board imu_read 214" + 200 for the entry, the timer flag, the stamp and the enqueue.
    imu_instr: 214 + 200,
    // BMI160 burst (addr, reg, addr, 12 B) + LSM303AGR (addr, reg, addr, 6 B): 24 bytes
    // × 9 bit + start/stop ≈ 220 bit at 400 kHz = 550 µs, + 2 µs per byte of HAL loop.
    imu_bus_ns: 550_000 + 24 * 2_000,
    // budget.md: the DSP's 0.5 s window (4 000 samples) 832 k → 208 per sample, on top
    // of the pulse's worst single sample below (its analysis counted twice).
    sample_instr: 208,
    // budget.md: worst end-of-pulse sample 301 k + worst estimator step 7 177 727
    // (240 components; the board's victims hold 80).
    pulse_instr: 301_000 + 7_177_727,
    // qemu_soak's worst IMU step 27 333 + 2 000 for the buttons, the tone, the health
    // checks and the record's copy into the log queue.
    imu_step_instr: 27_333 + 2_000,
    // "board log_imu 11297", "board log_pulse 6298", rounded up.
    imu_record_instr: 12_000,
    pulse_record_instr: 7_000,
    // "board render 486042": the model, the fault box, the gauge and the SD mark
    // (rounded up).
    render_instr: 500_000,
    // 1 024 B in 16-byte data writes (64) + the draw-area commands (2).
    flush_chunks: 66,
    // One write: addr + control + 16 B = 18 × 9 bit + start/stop ≈ 164 bit at 400 kHz.
    chunk_bus_ns: 410_000,
    // "board log_imu … 153", "board log_pulse … 99" (bytes with the newline, a day into
    // the session), rounded up for signs and longer numbers.
    imu_record_bytes: 170,
    pulse_record_bytes: 110,
    // The UART stream is off while the card logs (see `UART_ONLY`): with both, the
    // writer's byte loop and the card's worst busy times do not fit beside the others.
    uart_byte_ns: 0,
    // A 512 B block over 4-bit SDIO at 24 MHz (43 µs) + the card's typical program time.
    sd_block_ns: 1_000_000,
    // The SD specification's write busy limit, once per flush.
    sd_stall_ns: 250_000_000,
    sd_stall_every_ms: 500,
    flush_extra_blocks: 2,
    flush_every_ms: 500,
};

/// The log writer without a card: the UART stream only (921 600 Bd, 10 bit per byte,
/// the writer waits for each byte), no card times.
pub const UART_ONLY: Costs = Costs {
    uart_byte_ns: 10_851,
    sd_block_ns: 0,
    sd_stall_ns: 0,
    flush_extra_blocks: 0,
    ..BOARD_COSTS
};

/// The worst arrival pattern: four beacons at the standard's shortest period (1 s − 30 %),
/// their pulses back to back at the shortest pulse the DSP accepts (50 ms), 10 s.
pub const WORST_LOAD: Load = Load {
    duration_ms: 10_000,
    sample_hz: 8_000,
    imu_hz: 100,
    beacons: 4,
    pulse_period_ms: 700,
    pulse_spacing_ms: 50,
    first_pulse_ms: 300,
    redraw_ms: 1_000,
};

/// The board's queue capacities.
pub const BOARD_CAPACITIES: Capacities = Capacities {
    samples: SAMPLE_QUEUE,
    imu: IMU_QUEUE,
    log_items: LOG_QUEUE,
};

/// The tasks' worst costs: instructions (scaled by [`Scale::cpu`], one cycle each at
/// [`SYSCLK_HZ`]) and bus or device waits in ns (scaled by [`Scale::bus`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Costs {
    /// DRDY interrupt: instructions per sample (frame read, CRC, conversion, enqueue).
    pub drdy_instr: u64,
    /// DRDY interrupt: the SPI frame on the wire, ns.
    pub drdy_bus_ns: u64,
    /// IMU tick: instructions (driver, enqueue, buttons).
    pub imu_instr: u64,
    /// IMU tick: the I2C reads (acc + gyr, mag) on the wire, ns.
    pub imu_bus_ns: u64,
    /// Processing one ADC sample between pulses (the DSP's per-sample work), instructions.
    pub sample_instr: u64,
    /// A pulse's end: the DSP's analysis and the estimator step, instructions.
    pub pulse_instr: u64,
    /// One IMU record: the application's IMU step, the buttons, the tone, instructions.
    pub imu_step_instr: u64,
    /// Formatting one IMU record for the session log (by the writer), instructions.
    pub imu_record_instr: u64,
    /// Formatting one pulse record (by the writer), instructions.
    pub pulse_record_instr: u64,
    /// Drawing the screen into the display's buffer, instructions.
    pub render_instr: u64,
    /// I2C transactions of one display flush.
    pub flush_chunks: u64,
    /// One flush transaction on the wire (under the bus lock), ns.
    pub chunk_bus_ns: u64,
    /// Session-log bytes of one IMU record.
    pub imu_record_bytes: u32,
    /// Session-log bytes of one pulse record.
    pub pulse_record_bytes: u32,
    /// UART stream: wire time per byte, ns (the writer waits for it).
    pub uart_byte_ns: u64,
    /// The card's busy time after one 512-byte block, ns (wall clock: the writer polls,
    /// preempted or not, until the card is done).
    pub sd_block_ns: u64,
    /// The card's worst busy time, ns, once every [`Costs::sd_stall_every_ms`] (wall clock).
    pub sd_stall_ns: u64,
    /// How often the card stalls, ms (the log's flush period: directory and FAT writes).
    pub sd_stall_every_ms: u64,
    /// Blocks a flush writes besides the data (FAT and directory entry).
    pub flush_extra_blocks: u64,
    /// The SD log's flush period, ms.
    pub flush_every_ms: u64,
}

/// What arrives: rates and the pulse pattern.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Load {
    /// Simulated time, ms.
    pub duration_ms: u64,
    /// ADC sample rate, Hz.
    pub sample_hz: u64,
    /// IMU tick rate, Hz.
    pub imu_hz: u64,
    /// Beacons in range (each ends a pulse every [`Load::pulse_period_ms`]).
    pub beacons: u64,
    /// A beacon's pulse period, ms.
    pub pulse_period_ms: u64,
    /// Time between the pulse ends of consecutive beacons, ms.
    pub pulse_spacing_ms: u64,
    /// The first pulse's end, ms.
    pub first_pulse_ms: u64,
    /// The longest the screen goes without a redraw, ms (pulses redraw it too).
    pub redraw_ms: u64,
}

/// Queue capacities.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capacities {
    /// ADC samples.
    pub samples: u32,
    /// IMU records (at most 256 in the model).
    pub imu: u32,
    /// Session-log records (at most 256 in the model).
    pub log_items: u32,
}

/// Where the board binary's tasks run. [`Priorities::BOARD`] is the board's structure;
/// others let a test compare designs (e.g. the IMU at the processing task's level).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Priorities {
    /// ADC data ready.
    pub drdy: u8,
    /// IMU tick (and the bus's ceiling).
    pub imu: u8,
    /// Processing.
    pub process: u8,
    /// Display.
    pub display: u8,
    /// Log writer.
    pub log: u8,
}

impl Priorities {
    /// The board binary's priorities.
    pub const BOARD: Self = Self {
        drdy: PRIO_DRDY,
        imu: PRIO_IMU,
        process: PRIO_PROCESS,
        display: PRIO_DISPLAY,
        log: PRIO_LOG,
    };
}

/// Growth factors applied to the costs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    /// Multiplies every instruction count (cycles per instruction, or a slower step).
    pub cpu: f64,
    /// Multiplies every bus and device time.
    pub bus: f64,
}

impl Scale {
    /// The costs as given.
    pub const ONE: Self = Self { cpu: 1.0, bus: 1.0 };
}

/// What a simulation saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outcome {
    /// Deepest the sample queue got.
    pub max_samples: u32,
    /// Deepest the IMU record queue got.
    pub max_imu: u32,
    /// Deepest the log record queue got.
    pub max_log_items: u32,
    /// Samples lost: the queue full, or a DRDY release while the previous one waited.
    pub dropped_samples: u64,
    /// IMU ticks lost: a TIM2 release while the previous one waited.
    pub missed_ticks: u64,
    /// IMU records lost to a full queue.
    pub imu_overruns: u64,
    /// Log records lost to a full queue.
    pub log_overruns: u64,
    /// Longest from a DRDY release to its sample queued, cycles.
    pub worst_drdy_cycles: u64,
    /// Longest from a TIM2 release to its record queued, cycles.
    pub worst_imu_cycles: u64,
    /// Pulses the processing task finished.
    pub pulses: u64,
    /// IMU records the processing task finished.
    pub imu_records: u64,
    /// Screens drawn and flushed.
    pub frames: u64,
    /// Longest from a redraw request to its flush's end, cycles.
    pub worst_frame_cycles: u64,
    /// Cycles each task was busy: DRDY, IMU, process, display, log writer.
    pub busy_cycles: [u64; 5],
    /// Simulated cycles.
    pub cycles: u64,
}

impl Outcome {
    /// Whether nothing was lost anywhere.
    pub fn lossless(&self) -> bool {
        self.sensors_lossless() && self.log_overruns == 0
    }

    /// Whether every ADC sample and IMU tick got through (log records may have been lost).
    pub fn sensors_lossless(&self) -> bool {
        self.dropped_samples == 0 && self.missed_ticks == 0 && self.imu_overruns == 0
    }
}

/// Cycles of `ns` nanoseconds, scaled.
fn ns_cycles(ns: u64, scale: f64) -> u64 {
    libm::ceil(ns as f64 * scale * SYSCLK_HZ as f64 / 1e9) as u64
}

/// Cycles of `instr` instructions, scaled.
fn instr_cycles(instr: u64, scale: f64) -> u64 {
    libm::ceil(instr as f64 * scale) as u64
}

/// Cycles of `ms` milliseconds.
const fn ms_cycles(ms: u64) -> u64 {
    ms * (SYSCLK_HZ / 1000)
}

/// A released interrupt: one pending bit plus the job in progress.
#[derive(Clone, Copy, Default)]
struct Irq {
    /// Released, not started (release time).
    pending: Option<u64>,
    /// Started: cycles left and its release time.
    running: Option<(u64, u64)>,
}

impl Irq {
    /// A release at `t`: false when it is lost (one already pending).
    fn release(&mut self, t: u64) -> bool {
        if self.pending.is_some() {
            return false;
        }
        self.pending = Some(t);
        true
    }

    /// Whether it has work.
    fn ready(&self) -> bool {
        self.pending.is_some() || self.running.is_some()
    }

    /// Starts the pending job if none runs.
    fn start(&mut self, cost: u64) {
        if self.running.is_none()
            && let Some(t) = self.pending.take()
        {
            self.running = Some((cost, t));
        }
    }
}

/// A display job: drawing, then the flush's I2C transactions, each holding the bus.
#[derive(Clone, Copy, Default)]
struct Frame {
    /// CPU cycles of drawing left.
    cpu: u64,
    /// Transactions left after the one in progress.
    chunks: u64,
    /// Cycles left of the transaction in progress (it holds the bus).
    chunk: u64,
    /// When the redraw was asked for.
    asked: u64,
}

/// The pulse ends of the beacons, in order.
struct Pulses {
    next: [u64; 8],
    n: usize,
    period: u64,
}

impl Pulses {
    fn new(load: &Load) -> Self {
        let mut next = [u64::MAX; 8];
        let n = usize::try_from(load.beacons).unwrap_or(8).min(8);
        for (b, slot) in next.iter_mut().enumerate().take(n) {
            *slot = ms_cycles(load.first_pulse_ms + b as u64 * load.pulse_spacing_ms);
        }
        Self {
            next,
            n,
            period: ms_cycles(load.pulse_period_ms).max(1),
        }
    }

    /// Whether a pulse ends at or before `t` (and if so, moves past it).
    fn take_until(&mut self, t: u64) -> bool {
        let period = self.period;
        match self
            .next
            .iter_mut()
            .take(self.n)
            .filter(|e| **e <= t)
            .min_by_key(|e| **e)
        {
            Some(e) => {
                *e = e.saturating_add(period);
                true
            }
            None => false,
        }
    }
}

/// Simulates `load` through the task set with `costs` × `scale`, the queue capacities
/// `caps` and the priorities `prio`.
pub fn simulate(
    costs: &Costs,
    load: &Load,
    caps: &Capacities,
    prio: &Priorities,
    scale: Scale,
) -> Outcome {
    let ts = (SYSCLK_HZ / load.sample_hz.max(1)).max(1);
    let ti = (SYSCLK_HZ / load.imu_hz.max(1)).max(1);
    let end = ms_cycles(load.duration_ms);
    let cpu = |instr: u64| instr_cycles(instr, scale.cpu);
    let bus = |ns: u64| ns_cycles(ns, scale.bus);
    let drdy_cost = (cpu(costs.drdy_instr) + bus(costs.drdy_bus_ns)).max(1);
    let imu_cost = (cpu(costs.imu_instr) + bus(costs.imu_bus_ns)).max(1);
    let (sample_cost, pulse_cost) = (cpu(costs.sample_instr), cpu(costs.pulse_instr));
    let (imu_step, render) = (cpu(costs.imu_step_instr), cpu(costs.render_instr));
    let chunk = bus(costs.chunk_bus_ns).max(1);
    let (uart_byte, sd_block, sd_stall) = (
        bus(costs.uart_byte_ns),
        bus(costs.sd_block_ns),
        bus(costs.sd_stall_ns),
    );
    let stall_every = ms_cycles(costs.sd_stall_every_ms.max(1));
    let flush_every = ms_cycles(costs.flush_every_ms.max(1));
    let redraw_every = ms_cycles(load.redraw_ms.max(1));
    let imu_cap = (caps.imu as usize).min(MAX_IMU_QUEUE);
    let log_cap = (caps.log_items as usize).min(MAX_LOG_QUEUE);
    let (imu_record, pulse_record) = (cpu(costs.imu_record_instr), cpu(costs.pulse_record_instr));

    let mut out = Outcome::default();
    let mut pulses = Pulses::new(load);
    let (mut drdy, mut imu) = (Irq::default(), Irq::default());
    // The queues: samples (a count), IMU records (the samples queued before each), log bytes.
    let (mut samples, mut queued_total, mut taken) = (0u32, 0u64, 0u64);
    let mut imu_q: heapless::Deque<u64, MAX_IMU_QUEUE> = heapless::Deque::new();
    // Log records: the writer's cycles to format and send each, and its bytes.
    let mut log_q: heapless::Deque<(u64, u32), MAX_LOG_QUEUE> = heapless::Deque::new();
    // The processing task's item in progress (CPU cycles left, the log record it queues).
    let mut job: Option<(u64, Option<(u64, u32)>)> = None;
    // The display: the newest request (its time) and the frame in progress.
    let (mut asked, mut frame): (Option<u64>, Option<Frame>) = (None, None);
    let mut last_redraw: u64 = 0;
    // The log writer: CPU cycles left of the record in progress (formatting, the UART
    // stream) and its bytes; the bytes in the card's block buffer; the card's busy time
    // after a block, on the wall clock (the card programs while the writer is preempted).
    let (mut writer, mut writer_bytes, mut block_bytes) = (0u64, 0u32, 0u32);
    let mut card_until: Option<u64> = None;
    let (mut next_flush, mut flush_due, mut next_stall) = (flush_every, false, 0u64);
    let (mut next_drdy, mut next_imu) = (0u64, ti / 2);
    let mut t: u64 = 0;

    while t < end {
        // Releases and timers at t.
        if t >= next_drdy {
            if !drdy.release(next_drdy) {
                out.dropped_samples += 1;
            }
            next_drdy += ts;
        }
        if t >= next_imu {
            if !imu.release(next_imu) {
                out.missed_ticks += 1;
            }
            next_imu += ti;
        }
        if t >= next_flush {
            flush_due = true;
            next_flush += flush_every;
        }
        if card_until.is_some_and(|u| t >= u) {
            card_until = None;
        }
        let writing = writer > 0 || card_until.is_some();
        if flush_due && !writing && block_bytes == 0 && log_q.is_empty() {
            flush_due = false;
        }

        // Who runs: the highest level with work; a flush transaction holds the bus at its
        // ceiling (the IMU tick's level), and a started job keeps the core against its level.
        let in_chunk = frame.is_some_and(|f| f.chunk > 0);
        let display_level = if in_chunk {
            prio.imu.max(prio.display)
        } else {
            prio.display
        };
        let log_ready = writing || !log_q.is_empty() || (flush_due && block_bytes > 0);
        let mut tasks: [(u8, bool, usize, bool); 5] = [
            (prio.drdy, drdy.running.is_some(), 0, drdy.ready()),
            (prio.imu, imu.running.is_some(), 1, imu.ready()),
            (
                prio.process,
                job.is_some(),
                2,
                job.is_some() || samples > 0 || !imu_q.is_empty(),
            ),
            (
                display_level,
                frame.is_some(),
                3,
                frame.is_some() || asked.is_some(),
            ),
            (prio.log, writing, 4, log_ready),
        ];
        tasks.sort_unstable_by_key(|&(p, started, k, _)| (core::cmp::Reverse(p), !started, k));
        let runner = tasks.iter().find(|c| c.3).map(|c| c.2);

        // A task that is about to run takes its work.
        match runner {
            Some(0) => drdy.start(drdy_cost),
            Some(1) => imu.start(imu_cost),
            Some(2) if job.is_none() => {
                // In time order: an IMU record before the samples queued after it.
                let imu_first = imu_q.front().is_some_and(|&q| q <= taken || samples == 0);
                if imu_first {
                    imu_q.pop_front();
                    out.imu_records += 1;
                    job = Some((imu_step, Some((imu_record, costs.imu_record_bytes))));
                    if t.saturating_sub(last_redraw) >= redraw_every {
                        asked = asked.or(Some(t));
                        last_redraw = t;
                    }
                } else {
                    samples -= 1;
                    taken += 1;
                    job = Some((sample_cost, None));
                    // The pulse ends with the sample taken at its end.
                    if pulses.take_until(taken * ts) {
                        out.pulses += 1;
                        job = Some((
                            sample_cost + pulse_cost,
                            Some((pulse_record, costs.pulse_record_bytes)),
                        ));
                        asked = asked.or(Some(t));
                        last_redraw = t;
                    }
                }
            }
            Some(3) if frame.is_none() => {
                frame = asked.take().map(|a| Frame {
                    cpu: render,
                    chunks: costs.flush_chunks,
                    chunk: 0,
                    asked: a,
                });
            }
            Some(4) if !writing => {
                let stall = |next_stall: &mut u64| {
                    if t >= *next_stall {
                        *next_stall = t + stall_every;
                        sd_stall
                    } else {
                        0
                    }
                };
                if let Some((instr, bytes)) = log_q.pop_front() {
                    writer = (instr + u64::from(bytes) * uart_byte).max(1);
                    writer_bytes = bytes;
                } else {
                    // Flush: the partial block, the FAT and the directory entry.
                    flush_due = false;
                    block_bytes = 0;
                    let wait = (1 + costs.flush_extra_blocks) * sd_block + stall(&mut next_stall);
                    card_until = Some(t + wait.max(1));
                }
            }
            _ => {}
        }
        if let Some(f) = frame
            .as_mut()
            .filter(|f| runner == Some(3) && f.cpu == 0 && f.chunk == 0 && f.chunks > 0)
        {
            f.chunks = f.chunks.saturating_sub(1);
            f.chunk = chunk;
        }

        // Run until the next release or timer, or the runner's segment ends.
        let left = match runner {
            Some(0) => drdy.running.map_or(1, |r| r.0),
            Some(1) => imu.running.map_or(1, |r| r.0),
            Some(2) => job.map_or(1, |j| j.0),
            Some(3) => frame.map_or(1, |f| if f.cpu > 0 { f.cpu } else { f.chunk }),
            Some(_) if writer > 0 => writer,
            Some(_) => card_until.map_or(1, |u| u.saturating_sub(t)),
            None => u64::MAX,
        };
        let next = card_until
            .unwrap_or(u64::MAX)
            .min(next_drdy)
            .min(next_imu)
            .min(next_flush)
            .min(end)
            .min(t.saturating_add(left.max(1)));
        let dt = next.max(t + 1) - t;
        t += dt;
        let spend = |left: &mut u64| {
            *left -= dt.min(*left);
            *left == 0
        };
        match runner {
            Some(0) => {
                out.busy_cycles[0] += dt;
                if let Some((left, rel)) = drdy.running.as_mut()
                    && spend(left)
                {
                    out.worst_drdy_cycles = out.worst_drdy_cycles.max(t - *rel);
                    drdy.running = None;
                    if samples < caps.samples {
                        samples += 1;
                        queued_total += 1;
                        out.max_samples = out.max_samples.max(samples);
                    } else {
                        out.dropped_samples += 1;
                    }
                }
            }
            Some(1) => {
                out.busy_cycles[1] += dt;
                if let Some((left, rel)) = imu.running.as_mut()
                    && spend(left)
                {
                    out.worst_imu_cycles = out.worst_imu_cycles.max(t - *rel);
                    imu.running = None;
                    if imu_q.len() < imu_cap && imu_q.push_back(queued_total).is_ok() {
                        out.max_imu = out.max_imu.max(imu_q.len() as u32);
                    } else {
                        out.imu_overruns += 1;
                    }
                }
            }
            Some(2) => {
                out.busy_cycles[2] += dt;
                if let Some((left, item)) = job.as_mut()
                    && spend(left)
                {
                    let item = *item;
                    job = None;
                    if let Some(item) = item {
                        if log_q.len() < log_cap && log_q.push_back(item).is_ok() {
                            out.max_log_items = out.max_log_items.max(log_q.len() as u32);
                        } else {
                            out.log_overruns += 1;
                        }
                    }
                }
            }
            Some(3) => {
                out.busy_cycles[3] += dt;
                if let Some(f) = frame.as_mut() {
                    let seg_done = if f.cpu > 0 {
                        spend(&mut f.cpu)
                    } else {
                        spend(&mut f.chunk)
                    };
                    if seg_done && f.cpu == 0 && f.chunk == 0 && f.chunks == 0 {
                        out.frames += 1;
                        out.worst_frame_cycles = out.worst_frame_cycles.max(t - f.asked);
                        frame = None;
                    }
                }
            }
            Some(_) => {
                out.busy_cycles[4] += dt;
                if writer > 0 && spend(&mut writer) {
                    // The record is in the block buffer; a full block goes to the card.
                    block_bytes += writer_bytes;
                    if block_bytes >= 512 {
                        block_bytes -= 512;
                        let mut wait = sd_block;
                        if t >= next_stall {
                            next_stall = t + stall_every;
                            wait += sd_stall;
                        }
                        card_until = Some(t + wait.max(1));
                    }
                }
            }
            None => {}
        }
    }
    out.cycles = t;
    out
}

/// The largest factor (to within 1 %) by which the costs selected by `grow` (a [`Scale`]
/// for a factor) can grow while `ok` holds (e.g. [`Outcome::lossless`]); `None` if it
/// fails already at 1.
pub fn margin(
    costs: &Costs,
    load: &Load,
    caps: &Capacities,
    prio: &Priorities,
    grow: impl Fn(f64) -> Scale,
    ok: impl Fn(&Outcome) -> bool,
) -> Option<f64> {
    let ok = |k: f64| ok(&simulate(costs, load, caps, prio, grow(k)));
    if !ok(1.0) {
        return None;
    }
    let (mut lo, mut hi) = (1.0f64, 2.0f64);
    while ok(hi) {
        lo = hi;
        hi *= 2.0;
        if hi > 1024.0 {
            return Some(lo);
        }
    }
    while hi / lo > 1.01 {
        let mid = libm::sqrt(lo * hi);
        if ok(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(lo)
}

/// The processing task's order: an IMU record stamped with `queued` (the DRDY task's
/// running count of samples queued when the IMU was read) is due once the task has
/// taken that many samples (`taken`; both counts wrap), or when no sample waits (the ADC
/// stalled), so samples and IMU records reach the application in time order.
pub fn imu_record_due(taken: u32, queued: u32, samples_waiting: bool) -> bool {
    taken.wrapping_sub(queued) < u32::MAX / 2 || !samples_waiting
}

#[cfg(test)]
#[path = "schedule_tests.rs"]
mod tests;
