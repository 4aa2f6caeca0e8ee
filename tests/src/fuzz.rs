//! Fuzz harnesses: one function per target, each taking arbitrary bytes.
//!
//! The cargo-fuzz targets in `tests/fuzz/` call these functions under libFuzzer, and
//! `tests/tests/fuzz_corpus.rs` replays every saved corpus and regression input through
//! the same functions on stable Rust, so a crash once found stays fixed. A harness
//! panics (fails) when the code under test panics or breaks one of the invariants of
//! `docs/architecture.md`: no panic reachable from sensor data, a refused input leaves
//! the state unchanged, NaN/Inf never leave a function.
//!
//! The bytes are decoded by [`Bytes`], which never fails: when the input runs out every
//! read returns zero, and each decoded `f32` is either a raw bit pattern, a special value
//! (NaN, ±∞, ±`f32::MAX`, subnormal, zero) or a plausible value spread over many decades,
//! so the fuzzer reaches both the refusal paths and the deep numeric paths.
use std::cell::RefCell;
use std::convert::Infallible;
use std::rc::Rc;

use firmware::Vec3;
use firmware::estimate::{self, Attitude, DefaultSog, Displacement, Estimator, Mat6};

/// A never-failing decoder of fuzz bytes.
#[derive(Debug, Clone)]
pub struct Bytes<'a> {
    data: &'a [u8],
}

impl<'a> Bytes<'a> {
    /// Decodes `data`.
    pub fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    /// Whether every byte has been consumed.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The next byte, 0 past the end.
    pub fn u8(&mut self) -> u8 {
        match self.data.split_first() {
            Some((&b, rest)) => {
                self.data = rest;
                b
            }
            None => 0,
        }
    }

    /// The next `N` bytes (zero-padded past the end).
    pub fn array<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        for o in out.iter_mut() {
            *o = self.u8();
        }
        out
    }

    /// A little-endian `u16`.
    pub fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.array())
    }

    /// A boolean from one byte's low bit.
    pub fn bool(&mut self) -> bool {
        self.u8() & 1 == 1
    }

    /// An `f32`: one tag byte, then its payload. `scale` sets the order of magnitude of
    /// the "plausible" values (e.g. 1e-5 for fields in A/m, 10 for m/s²).
    pub fn f32(&mut self, scale: f32) -> f32 {
        let tag = self.u8();
        match tag % 16 {
            0 => f32::from_bits(u32::from_le_bytes(self.array())),
            1 => f32::NAN,
            2 => f32::INFINITY,
            3 => f32::NEG_INFINITY,
            4 => 0.0,
            5 => f32::MAX,
            6 => -f32::MAX,
            7 => f32::from_bits(u32::from(self.u16())), // subnormal
            8 => {
                // Any decade from 1e-12 to 1e12 of the scale.
                let e = i32::from(self.u8() % 25) - 12;
                f32::from(self.u16() as i16) / 32768.0 * scale * 10f32.powi(e)
            }
            // Mostly plausible values: within ±4 × scale.
            _ => f32::from(self.u16() as i16) / 8192.0 * scale,
        }
    }

    /// Three `f32`s of the same scale.
    pub fn vec3(&mut self, scale: f32) -> Vec3 {
        Vec3::new(self.f32(scale), self.f32(scale), self.f32(scale))
    }
}

fn all_finite<'a>(v: impl IntoIterator<Item = &'a f32>) -> bool {
    v.into_iter().all(|x| x.is_finite())
}

// --- session_log_reader -----------------------------------------------------------------

/// `hal_sim::io::session::read` on arbitrary bytes: never panics; a log it accepts has a
/// version-1 header and survives a write/read round trip.
pub fn session_log_reader(data: &[u8]) {
    let Ok(s) = hal_sim::io::session::read(data) else {
        return;
    };
    assert_eq!(s.header.format, hal_sim::io::session::FORMAT);
    let mut out = Vec::new();
    s.write(&mut out).expect("writing to a Vec");
    let again = hal_sim::io::session::read(out.as_slice()).expect("re-reading what was written");
    assert_eq!(again.records.len(), s.records.len());
}

// --- frontend_push ----------------------------------------------------------------------

/// `firmware::frontend::Frontend` on an arbitrary sample stream. The stream is a list of
/// segments: raw samples (any `f32`, NaN/∞/huge included), an IF tone of fuzzed
/// amplitudes and offset (so pulses are detected and analysed), or silence. Checks: a
/// non-finite sample is refused and not consumed; every reported pulse is finite.
pub fn frontend_push(data: &[u8]) {
    use firmware::frontend::{Frontend, FrontendConfig, PulseMeasurement};
    let mut b = Bytes::new(data);
    let mut cfg = FrontendConfig::default();
    if b.u8() & 0x80 != 0 {
        // A fuzzed configuration: `new` must refuse what it cannot run.
        cfg.block_len = usize::from(b.u8());
        cfg.detect_blocks = usize::from(b.u8());
        cfg.warmup_blocks = usize::from(b.u8());
        cfg.k_on = b.f32(2.0);
        cfg.k_off = b.f32(1.5);
        cfg.min_pulse_s = b.f32(0.05);
        cfg.max_offset_hz = b.f32(100.0);
        cfg.floor_time_constant_s = b.f32(0.5);
    }
    let Ok(mut fe) = Frontend::new(cfg) else {
        return;
    };
    let mut n: u64 = 0;
    let mut budget: u32 = 200_000; // samples per input, to keep executions fast
    while !b.is_empty() && budget > 0 {
        let kind = b.u8();
        let mut samples: Vec<([f32; 3], bool)> = Vec::new();
        match kind % 4 {
            0 => {
                let k = 1 + usize::from(b.u8() % 16);
                for _ in 0..k {
                    let v = [b.f32(1e-3), b.f32(1e-3), b.f32(1e-3)];
                    samples.push((v, b.bool()));
                }
            }
            1 | 2 => {
                let len = 16 * (1 + u32::from(b.u16() % 512));
                let amp = [b.f32(1e-3), b.f32(1e-3), b.f32(1e-3)];
                let df = f32::from(b.u8() as i8) * 0.8;
                let noise = f32::from(b.u8()) * 1e-7;
                let clip = b.u8() == 0xFF;
                let f = (2000.0 + df) / 8000.0;
                for i in 0..len {
                    let ph = 2.0 * std::f32::consts::PI * f * (n + u64::from(i)) as f32;
                    let c = ph.cos();
                    // Deterministic pseudo-noise.
                    let r = (((n + u64::from(i)).wrapping_mul(2_654_435_761) >> 7) % 2001) as f32
                        / 1000.0
                        - 1.0;
                    let v = amp.map(|a| a * c + noise * r);
                    samples.push((v, clip));
                }
            }
            _ => {
                let len = 16 * (1 + u32::from(b.u8()));
                let noise = f32::from(b.u8()) * 1e-7;
                for i in 0..len {
                    let r = (((n + u64::from(i)).wrapping_mul(40_503) >> 3) % 2001) as f32 / 1000.0
                        - 1.0;
                    samples.push(([noise * r, -noise * r, noise * r * 0.5], false));
                }
            }
        }
        for (v, clipped) in samples {
            budget = budget.saturating_sub(1);
            let before = fe.samples();
            match fe.push(v, clipped) {
                Err(_) => {
                    assert!(!all_finite(&v), "finite sample refused: {v:?}");
                    assert_eq!(fe.samples(), before, "refused sample was consumed");
                }
                Ok(p) => {
                    assert!(all_finite(&v), "non-finite sample accepted: {v:?}");
                    n += 1;
                    if let Some(p) = p {
                        assert!(
                            p.t_s.is_finite()
                                && p.duration_s.is_finite()
                                && p.carrier_offset_hz.is_finite()
                                && p.sigma_a_per_m.is_finite()
                                && p.residual_fraction.is_finite()
                                && p.quadrature_fraction.is_finite(),
                            "non-finite pulse {p:?}"
                        );
                        if let PulseMeasurement::Field(h) = p.measurement {
                            assert!(all_finite(h.iter()), "non-finite field {p:?}");
                        }
                    }
                }
            }
        }
        assert!(fe.noise_floor().is_finite());
    }
}

// --- estimator_step ---------------------------------------------------------------------

fn displacement(b: &mut Bytes) -> Displacement {
    let translation = b.vec3(1.0);
    let rotation = b.vec3(0.3);
    let mode = b.u8();
    let cov = match mode % 4 {
        0 => Displacement::with_sigmas(translation, rotation, b.f32(0.05), b.f32(0.02)).cov,
        1 => Mat6::zeros(),
        2 => {
            // Fully arbitrary (mostly invalid) covariance.
            let mut c = Mat6::zeros();
            for v in c.iter_mut() {
                *v = b.f32(0.01);
            }
            c
        }
        _ => {
            // Symmetric A Aᵀ from fuzzed A: valid unless it overflows.
            let mut a = Mat6::zeros();
            for v in a.iter_mut() {
                *v = b.f32(0.1);
            }
            a * a.transpose()
        }
    };
    Displacement {
        translation,
        rotation,
        cov,
        ..Displacement::zero()
    }
}

fn attitude(b: &mut Bytes) -> Attitude {
    let rpy = b.vec3(1.0);
    if b.bool() {
        Attitude::with_sigmas(rpy, b.f32(0.01), b.f32(0.05))
    } else {
        let mut cov = firmware::Mat3::zeros();
        for v in cov.iter_mut() {
            *v = b.f32(0.01);
        }
        Attitude { rpy, cov }
    }
}

fn check_estimate(f: &DefaultSog) {
    if let Some(e) = f.estimate() {
        assert!(
            all_finite(e.p.iter())
                && all_finite(e.cov.iter())
                && all_finite(e.moment.iter())
                && e.scale.is_finite()
                && e.scale_sigma.is_finite(),
            "non-finite estimate {e:?}"
        );
    }
    if f.is_initialized() {
        let mut w = 0.0f32;
        for (wi, p, c) in f.components() {
            assert!(wi.is_finite() && all_finite(p.iter()) && all_finite(c.iter()));
            assert!((0..3).all(|i| c[(i, i)] >= 0.0), "negative variance {c}");
            w += wi;
        }
        assert!((w - 1.0).abs() < 1e-3, "weights sum to {w}");
    }
}

/// `SogFilter` (the firmware's `DefaultSog`) stepped with arbitrary displacements,
/// attitudes and pulses. Checks: no panic; a refused step leaves the filter unchanged;
/// `estimate()` is finite; the mixture weights sum to one.
pub fn estimator_step(data: &[u8]) {
    let mut b = Bytes::new(data);
    let mut cfg = estimate::SogConfig::default();
    if b.bool() {
        cfg = estimate::SogConfig::known_trajectory();
    }
    let Ok(f) = DefaultSog::new(cfg) else {
        return;
    };
    let mut f = Box::new(f);
    // `FUZZ_TRACE=1` prints every step's inputs (to read a crash input).
    let trace = std::env::var_os("FUZZ_TRACE").is_some();
    let mut t = 0.0f32;
    let mut steps = 0;
    while !b.is_empty() && steps < 48 {
        steps += 1;
        let motion = displacement(&mut b);
        let att = attitude(&mut b);
        let h = b.vec3(1e-5);
        // Mostly increasing time, sometimes arbitrary.
        t = if b.u8() < 16 { b.f32(10.0) } else { t + 1.0 };
        let pulse = estimate::Pulse { h, t };
        let before = f.clone();
        if trace {
            eprintln!("step {steps}: {motion:?} {att:?} {pulse:?}");
        }
        match f.step(&motion, &att, &pulse) {
            Ok(_) => check_estimate(&f),
            Err(e) => assert!(f == before, "refused step ({e:?}) changed the state"),
        }
        if b.u8() == 0xA5 {
            f.reset();
        }
    }
}

// --- ads131m04_frames -------------------------------------------------------------------

/// The bus replies of a fake device: bytes from the fuzz input, then zeros, with an
/// error once the input is spent (so every loop of the caller ends).
#[derive(Debug)]
pub struct Wire<'a> {
    bytes: Bytes<'a>,
    calls: u32,
}

impl<'a> Wire<'a> {
    fn new(data: &'a [u8]) -> Self {
        Self {
            bytes: Bytes::new(data),
            calls: 0,
        }
    }

    fn fill(&mut self, buf: &mut [u8]) -> Result<(), FakeBusError> {
        self.calls += 1;
        if self.bytes.is_empty() || self.calls > 4096 {
            return Err(FakeBusError);
        }
        for x in buf.iter_mut() {
            *x = self.bytes.u8();
        }
        Ok(())
    }
}

/// The fake buses' error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FakeBusError;

impl embedded_hal::spi::Error for FakeBusError {
    fn kind(&self) -> embedded_hal::spi::ErrorKind {
        embedded_hal::spi::ErrorKind::Other
    }
}

impl embedded_hal::i2c::Error for FakeBusError {
    fn kind(&self) -> embedded_hal::i2c::ErrorKind {
        embedded_hal::i2c::ErrorKind::Other
    }
}

/// An SPI device answering arbitrary bytes.
#[derive(Debug)]
pub struct FakeSpi<'a>(Rc<RefCell<Wire<'a>>>);

impl embedded_hal::spi::ErrorType for FakeSpi<'_> {
    type Error = FakeBusError;
}

impl embedded_hal::spi::SpiDevice for FakeSpi<'_> {
    fn transaction(
        &mut self,
        operations: &mut [embedded_hal::spi::Operation<'_, u8>],
    ) -> Result<(), FakeBusError> {
        use embedded_hal::spi::Operation;
        let mut w = self.0.borrow_mut();
        for op in operations {
            match op {
                Operation::Read(buf) | Operation::TransferInPlace(buf) => w.fill(buf)?,
                Operation::Transfer(read, _) => w.fill(read)?,
                Operation::Write(_) | Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}

/// A DRDY pin reading arbitrary levels.
#[derive(Debug)]
pub struct FakePin<'a>(Rc<RefCell<Wire<'a>>>);

impl embedded_hal::digital::ErrorType for FakePin<'_> {
    type Error = Infallible;
}

impl embedded_hal::digital::InputPin for FakePin<'_> {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.0.borrow_mut().bytes.u8() & 1 == 1)
    }
    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(self.0.borrow_mut().bytes.u8() & 1 == 0)
    }
}

/// A delay that does not wait.
#[derive(Debug)]
pub struct NoDelay;

impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// The ADS131M04 driver over an SPI device answering arbitrary bytes, driven through a
/// fuzzed sequence of operations. Checks: no panic; volts are finite.
pub fn ads131m04_frames(data: &[u8]) {
    use firmware::drivers::ads131m04::{
        Ads131m04, Channel, Config, Gain, Osr, PowerMode, Register, WordLength,
    };
    let (ops, replies) = data.split_at(data.len().min(32));
    let wire = Rc::new(RefCell::new(Wire::new(replies)));
    let mut adc = Ads131m04::new(FakeSpi(wire.clone()), FakePin(wire));
    adc.set_drdy_poll_limit(8);
    for &op in ops {
        let _ = match op % 16 {
            0 => adc.reset(&mut NoDelay).map(drop),
            1 => adc.check_id().map(drop),
            2 => adc.status().map(drop),
            3 => adc
                .read_register(
                    [
                        Register::ID,
                        Register::STATUS,
                        Register::MODE,
                        Register::CLOCK,
                    ][usize::from(op >> 6)],
                )
                .map(drop),
            4 => adc.configure(&Config::default()).map(drop),
            5 => adc.set_word_length(match op >> 4 {
                0..=3 => WordLength::Bits16,
                4..=7 => WordLength::Bits24,
                8..=11 => WordLength::Bits32ZeroPad,
                _ => WordLength::Bits32SignExtend,
            }),
            6 => adc.set_gain(
                Channel::ALL[usize::from(op >> 4) % 4],
                if op & 0x80 != 0 { Gain::G16 } else { Gain::G1 },
            ),
            7 => adc.set_osr(
                if op & 0x40 != 0 {
                    Osr::Osr64Turbo
                } else {
                    Osr::Osr512
                },
                if op & 0x80 != 0 {
                    PowerMode::HighResolution
                } else {
                    PowerMode::LowPower
                },
            ),
            8..=10 => adc.read_frame_when_ready().map(|f| {
                let v = adc.to_volts(&f);
                assert!(all_finite(v.iter()), "non-finite volts {v:?}");
            }),
            11 => adc.read_frame().map(|f| {
                let v = adc.to_volts(&f);
                assert!(all_finite(v.iter()), "non-finite volts {v:?}");
            }),
            12 => adc.standby(),
            13 => adc.wakeup(),
            14 => adc.lock(),
            _ => adc.unlock(),
        };
        let _ = adc.config();
    }
}

// --- imu_driver -------------------------------------------------------------------------

/// An I2C bus answering arbitrary bytes; when `honest_ids` is set the two chips' ID
/// registers answer their true values so that initialisation can succeed.
#[derive(Debug, Clone)]
pub struct FakeI2c<'a> {
    wire: Rc<RefCell<Wire<'a>>>,
    honest_ids: bool,
}

impl embedded_hal::i2c::ErrorType for FakeI2c<'_> {
    type Error = FakeBusError;
}

impl embedded_hal::i2c::I2c for FakeI2c<'_> {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), FakeBusError> {
        use embedded_hal::i2c::Operation;
        let mut reg = None;
        let mut w = self.wire.borrow_mut();
        for op in operations {
            match op {
                Operation::Write(bytes) => reg = bytes.first().copied(),
                Operation::Read(buf) => {
                    // BMI160 CHIP_ID (0x00) = 0xD1; LSM303AGR WHO_AM_I_M (0x4F) = 0x40.
                    let id = match (address, reg) {
                        (0x68 | 0x69, Some(0x00)) => Some(0xD1),
                        (0x1E, Some(0x4F)) => Some(0x40),
                        _ => None,
                    };
                    match (self.honest_ids, id, &mut **buf) {
                        (true, Some(id), [only]) => {
                            w.calls += 1;
                            *only = id;
                        }
                        _ => w.fill(buf)?,
                    }
                }
            }
        }
        Ok(())
    }
}

/// `firmware::drivers::imu::Imu` over an I2C bus answering arbitrary bytes: `new`, then
/// reads. Checks: no panic; readings are finite.
pub fn imu_driver(data: &[u8]) {
    use firmware::drivers::imu::Imu;
    let mut b = Bytes::new(data);
    let honest_ids = b.bool();
    let wire = Rc::new(RefCell::new(Wire::new(b.data)));
    let bus = FakeI2c {
        wire: wire.clone(),
        honest_ids,
    };
    let Ok(mut imu) = Imu::new(bus.clone(), bus, &mut NoDelay) else {
        return;
    };
    for _ in 0..64 {
        match imu.read() {
            Ok(r) => assert!(
                all_finite(r.acc.iter()) && all_finite(r.gyr.iter()) && all_finite(r.mag.iter()),
                "non-finite reading {r:?}"
            ),
            Err(_) => {
                if wire.borrow().bytes.is_empty() {
                    break;
                }
            }
        }
    }
    let _ = imu.destroy();
}

// --- app_receiver -----------------------------------------------------------------------

/// `firmware::app::Receiver` on an arbitrary interleaving of IMU samples and pulses (and,
/// now and then, the display). Checks: no panic; the estimate and the display's numbers
/// are finite.
pub fn app_receiver(data: &[u8]) {
    use firmware::app::{AppConfig, Receiver};
    use firmware::timebase::Instant;
    // A fuzzed time: seconds when it is one, else its bits as a far-off time stamp.
    let stamp = |x: f32| {
        Instant::from_secs_f64(f64::from(x))
            .unwrap_or(Instant::from_micros(u64::from(x.to_bits()) << 20))
    };
    let mut b = Bytes::new(data);
    let earth = Vec3::new(20.0, -1.0, -44.0);
    let step = if b.bool() { Some(0.75) } else { None };
    let Ok(rx) = Receiver::new(AppConfig::new(earth, step)) else {
        return;
    };
    let mut rx = Box::new(rx);
    let mut t = 0.0f32;
    let mut ops = 0;
    while !b.is_empty() && ops < 4000 {
        ops += 1;
        let op = b.u8();
        match op % 8 {
            0..=4 => {
                // A run of IMU samples: plausible (level, still or walking) with fuzzed
                // perturbations, or fully fuzzed.
                let n = 1 + usize::from(b.u8() % 64);
                let fuzzed = op & 0x80 != 0;
                let base_acc = Vec3::new(0.0, 0.0, 9.81);
                let mag = Vec3::new(20.0, -1.0, -44.0);
                let da = b.vec3(1.0);
                let dg = b.vec3(0.2);
                for i in 0..n {
                    t += 0.01;
                    let ti = if fuzzed && i == 0 { b.f32(10.0) } else { t };
                    let wob = ((i as f32) * 0.9).sin();
                    let acc = base_acc + da * wob;
                    let gyr = dg * wob;
                    let m = if op & 0x40 != 0 { None } else { Some(&mag) };
                    let _ = rx.on_imu(stamp(ti), &acc, &gyr, m);
                }
            }
            5 | 6 => {
                let h = b.vec3(1e-5);
                let tp = if op & 0x80 != 0 { b.f32(10.0) } else { t };
                let src = if b.bool() { Some(b.u8() % 10) } else { None };
                if let Ok(d) = rx.on_pulse(stamp(tp), &h, src) {
                    let _ = d;
                }
            }
            _ => {
                let _ = rx.display_model();
            }
        }
        if let Some(e) = rx.estimate() {
            assert!(
                all_finite(e.p.iter()) && all_finite(e.cov.iter()) && all_finite(e.moment.iter()),
                "non-finite estimate {e:?}"
            );
        }
    }
    let _ = rx.display_model();
}

// --- receiver_json, replay: tests/src/fuzz/replay_path.rs ----------------------------

mod replay_path;
pub use replay_path::{receiver_json, replay};

/// A harness: takes the fuzz input, panics on a failure.
pub type Harness = fn(&[u8]);

/// The fuzz targets by name, for the corpus replay.
pub const TARGETS: &[(&str, Harness)] = &[
    ("session_log_reader", session_log_reader),
    ("frontend_push", frontend_push),
    ("estimator_step", estimator_step),
    ("ads131m04_frames", ads131m04_frames),
    ("imu_driver", imu_driver),
    ("app_receiver", app_receiver),
    ("receiver_json", receiver_json),
    ("replay", replay),
];
