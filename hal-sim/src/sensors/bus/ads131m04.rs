//! An emulated TI ADS131M04 behind `embedded_hal::spi::SpiDevice` and a DRDY
//! `embedded_hal::digital::InputPin`, converting an [`AnalogInput`] on the simulation
//! clock.
//!
//! What it answers (TI SBAS946, as the firmware driver expects it):
//! - Frames of 6 words of 16, 24 or 32 bits (`MODE.WLENGTH`; a `MODE` write takes effect
//!   from the next frame): response word, channels 0–3, CRC-16-CCITT (seed 0xFFFF) over
//!   every byte before it, in the upper 16 bits of the last word.
//! - Each command is answered in the *next* frame: NULL → STATUS; RESET → 0xFF24 (and
//!   the register map, word length and conversion timeline restart); STANDBY, WAKEUP,
//!   LOCK, UNLOCK → the command echoed; RREG (one register) → its value; WREG (one
//!   register) → `010a_aaaa_a000_0000`. While locked only NULL, RREG and UNLOCK are
//!   obeyed.
//! - Conversions: sample `k` of the current timeline stands for time `t₀ + k/f_DATA` and
//!   is ready (DRDY low) once the clock passes `t₀ + (k+1)/f_DATA`, with
//!   `f_DATA = 8.192 MHz / 2 / OSR` from `CLOCK` (`t₀`: the last RESET or `CLOCK` write).
//!   Every frame clocked while a sample is ready carries it (DRDY then returns high) and
//!   sets the STATUS DRDY bits; others repeat the last conversion. A host that lags behind
//!   gets the pending samples one per frame, as if its DRDY interrupt had kept up.
//! - Codes: `round((v + n) · gain / 1.2 V · 2²³)`, clamped to the 24-bit range
//!   (saturation: full scale is ±1.2 V / gain); disabled channels (`CLOCK.CHn_EN`) read 0;
//!   per-channel PGA gain from `GAIN1`; `n` the input-referred noise of the gain in use
//!   (white, per conversion; off unless [`Ads131m04Spi::set_input_noise`] gives it).
//! - A `GAIN1` write changes the PGA at once, but the sinc³ filter spans three conversion
//!   periods: the first two conversions after it blend the old and the new gain's codes
//!   (weights 5/6 and 1/6 of the old: the cumulative sinc³ response at ⅔ and ⅓).
//!
//! Not emulated: input CRC, multi-register RREG/WREG (answered for the first register
//! only), offset/gain calibration and phase registers (stored, no effect), current detect.
use super::SimClock;
use super::if_signal::AnalogInput;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::cell::RefCell;
use std::convert::Infallible;
use std::rc::Rc;

/// Nominal master clock, Hz.
pub const F_CLKIN_HZ: f64 = 8_192_000.0;
/// The ID register's value (upper byte 0x24: four channels).
pub const ID_VALUE: u16 = 0x2410;

const REG_ID: usize = 0x00;
const REG_STATUS: usize = 0x01;
const REG_MODE: usize = 0x02;
const REG_CLOCK: usize = 0x03;
const REG_GAIN1: usize = 0x04;
const MODE_RESET_BIT: u16 = 1 << 10;

/// CRC-16-CCITT (poly 0x1021, seed 0xFFFF), written independently of the firmware's.
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in bytes {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// What the next frame's first word carries.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Answer {
    Status,
    Word(u16),
}

/// The chip's state, shared by its SPI side and its DRDY pin.
#[derive(Debug)]
struct Core<A> {
    input: A,
    clock: SimClock,
    regs: [u16; 64],
    answer: Answer,
    locked: bool,
    standby: bool,
    epoch_t: f64,
    next_sample: u64,
    last_codes: [i32; 4],
    frames: u64,
    /// Input noise per PGA gain (V rms, index = gain bits) and its generator.
    noise: Option<([f64; 8], ChaCha8Rng)>,
    /// `GAIN1` before the last write and the conversion index the write preceded.
    old_gain: u16,
    gain_changed_at: u64,
}

impl<A: AnalogInput> Core<A> {
    fn reset_registers(&mut self) {
        self.regs = [0; 64];
        self.regs[REG_ID] = ID_VALUE;
        self.regs[REG_STATUS] = 0x0500;
        self.regs[REG_MODE] = 0x0510;
        self.regs[REG_CLOCK] = 0x0F0E;
        self.regs[0x06] = 0x0600;
        for ch in 0..4 {
            self.regs[0x0C + 5 * ch] = 0x8000;
        }
        self.locked = false;
        self.standby = false;
        self.restart_conversions();
    }

    fn restart_conversions(&mut self) {
        self.epoch_t = self.clock.now();
        self.next_sample = 0;
        self.gain_changed_at = u64::MAX;
    }

    fn word_bytes(&self) -> usize {
        match (self.regs[REG_MODE] >> 8) & 0b11 {
            0 => 2,
            1 => 3,
            _ => 4,
        }
    }

    fn data_rate_hz(&self) -> f64 {
        let c = self.regs[REG_CLOCK];
        let osr = if c & (1 << 5) != 0 {
            64.0
        } else {
            match (c >> 2) & 0b111 {
                0 => 128.0,
                1 => 256.0,
                2 => 512.0,
                3 => 1024.0,
                4 => 2048.0,
                5 => 4096.0,
                6 => 8192.0,
                _ => 16256.0,
            }
        };
        F_CLKIN_HZ / 2.0 / osr
    }

    fn sample_time(&self, k: u64) -> f64 {
        self.epoch_t + k as f64 / self.data_rate_hz()
    }

    /// Whether a conversion is waiting to be read (DRDY low).
    fn ready(&self) -> bool {
        !self.standby && self.sample_time(self.next_sample + 1) <= self.clock.now() + 1e-12
    }

    fn status(&self, fresh: bool) -> u16 {
        let mode = self.regs[REG_MODE];
        let mut s = (mode & 0x0300) | (mode & MODE_RESET_BIT);
        if self.locked {
            s |= 1 << 15;
        }
        if fresh {
            s |= (self.regs[REG_CLOCK] >> 8) & 0x0F;
        }
        s
    }

    fn convert(&mut self) -> [i32; 4] {
        let k = self.next_sample;
        let t = self.sample_time(k);
        self.next_sample += 1;
        let v = self.input.volts(t);
        let (clock, gain) = (self.regs[REG_CLOCK], self.regs[REG_GAIN1]);
        // Share of the old gain in this conversion (sinc³ settling after a GAIN1 write).
        let old_share = match k.checked_sub(self.gain_changed_at) {
            Some(0) => 5.0 / 6.0,
            Some(1) => 1.0 / 6.0,
            _ => 0.0,
        };
        let mut codes = [0i32; 4];
        for (ch, code) in codes.iter_mut().enumerate() {
            if clock & (1 << (8 + ch)) == 0 {
                continue;
            }
            let bits = |reg: u16| usize::from((reg >> (4 * ch)) & 0b111);
            let n = match &mut self.noise {
                Some((sigma, rng)) => {
                    let z: f64 = StandardNormal.sample(rng);
                    sigma[bits(gain)] * z
                }
                None => 0.0,
            };
            let code_at = |reg: u16| {
                let g = f64::from(1u16 << bits(reg));
                ((v[ch] + n) * g / 1.2 * 8_388_608.0).clamp(-8_388_608.0, 8_388_607.0)
            };
            let x = if old_share > 0.0 {
                old_share * code_at(self.old_gain) + (1.0 - old_share) * code_at(gain)
            } else {
                code_at(gain)
            };
            *code = x.round() as i32;
        }
        codes
    }

    /// Obeys the command in `mosi` and returns the frame clocked out meanwhile.
    fn exchange(&mut self, mosi: &[u8]) -> Vec<u8> {
        self.frames += 1;
        let w = self.word_bytes();
        let fresh = self.ready();
        if fresh {
            self.last_codes = self.convert();
        }
        // Build the output frame with the answer to the previous command.
        let first = match self.answer {
            Answer::Status => self.status(fresh),
            Answer::Word(x) => x,
        };
        let mut out = Vec::with_capacity(6 * w);
        out.extend_from_slice(&first.to_be_bytes());
        out.resize(w, 0);
        for c in self.last_codes {
            let b = c.to_be_bytes();
            match w {
                2 => out.extend_from_slice(&b[1..3]),
                3 => out.extend_from_slice(&b[1..4]),
                _ if (self.regs[REG_MODE] >> 8) & 0b11 == 3 => out.extend_from_slice(&b),
                _ => {
                    out.extend_from_slice(&b[1..4]);
                    out.push(0);
                }
            }
        }
        let crc = crc16(&out);
        out.extend_from_slice(&crc.to_be_bytes());
        out.resize(6 * w, 0);
        // Decode and obey this frame's command.
        let word = |i: usize| -> u16 {
            let hi = mosi.get(i * w).copied().unwrap_or(0);
            let lo = mosi.get(i * w + 1).copied().unwrap_or(0);
            u16::from_be_bytes([hi, lo])
        };
        let cmd = word(0);
        self.answer = self.obey(cmd, word(1));
        out
    }

    fn obey(&mut self, cmd: u16, data: u16) -> Answer {
        let addr = usize::from((cmd >> 7) & 0x3F);
        match cmd {
            0x0000 => Answer::Status,
            0x0655 => {
                self.locked = false;
                Answer::Word(cmd)
            }
            _ if cmd & 0xE000 == 0xA000 => {
                let v = if addr == REG_STATUS {
                    self.status(false)
                } else {
                    self.regs.get(addr).copied().unwrap_or(0)
                };
                Answer::Word(v)
            }
            _ if self.locked => Answer::Status,
            0x0011 => {
                self.reset_registers();
                Answer::Word(0xFF24)
            }
            0x0022 => {
                self.standby = true;
                Answer::Word(cmd)
            }
            0x0033 => {
                self.standby = false;
                self.restart_conversions();
                Answer::Word(cmd)
            }
            0x0555 => {
                self.locked = true;
                Answer::Word(cmd)
            }
            _ if cmd & 0xE000 == 0x6000 => {
                match addr {
                    REG_ID | REG_STATUS | 0x3E => {}
                    REG_MODE => {
                        // The RESET flag can only be cleared by writing 0.
                        let keep = self.regs[REG_MODE] & data & MODE_RESET_BIT;
                        self.regs[REG_MODE] = (data & !MODE_RESET_BIT) | keep;
                    }
                    REG_CLOCK => {
                        self.regs[REG_CLOCK] = data;
                        self.restart_conversions();
                    }
                    REG_GAIN1 => {
                        if data != self.regs[REG_GAIN1] {
                            self.old_gain = self.regs[REG_GAIN1];
                            self.gain_changed_at = self.next_sample;
                        }
                        self.regs[REG_GAIN1] = data;
                    }
                    _ => {
                        if let Some(r) = self.regs.get_mut(addr) {
                            *r = data;
                        }
                    }
                }
                Answer::Word(0x4000 | ((addr as u16) << 7))
            }
            _ => Answer::Status,
        }
    }
}

/// The SPI side of an emulated ADS131M04 (the device handles chip select itself).
#[derive(Debug)]
pub struct Ads131m04Spi<A> {
    core: Rc<RefCell<Core<A>>>,
}

/// The DRDY pin of an emulated ADS131M04 (low: a conversion is ready).
#[derive(Debug)]
pub struct Ads131m04Drdy<A> {
    core: Rc<RefCell<Core<A>>>,
}

/// A freshly powered-up emulated ADS131M04 converting `input` on `clock`: its SPI device
/// and its DRDY pin.
pub fn ads131m04<A: AnalogInput>(input: A, clock: SimClock) -> (Ads131m04Spi<A>, Ads131m04Drdy<A>) {
    let mut core = Core {
        input,
        clock,
        regs: [0; 64],
        answer: Answer::Status,
        locked: false,
        standby: false,
        epoch_t: 0.0,
        next_sample: 0,
        last_codes: [0; 4],
        frames: 0,
        noise: None,
        old_gain: 0,
        gain_changed_at: u64::MAX,
    };
    core.reset_registers();
    let core = Rc::new(RefCell::new(core));
    (Ads131m04Spi { core: core.clone() }, Ads131m04Drdy { core })
}

impl<A: AnalogInput> Ads131m04Spi<A> {
    /// Conversions delivered since the last reset or `CLOCK` write.
    pub fn samples_delivered(&self) -> u64 {
        self.core.borrow().next_sample
    }

    /// Frames clocked since power-up.
    pub fn frames(&self) -> u64 {
        self.core.borrow().frames
    }

    /// Adds the chip's input-referred noise: `v_rms[g]` V rms per conversion at PGA gain
    /// bits `g` (the board profile's `adc.input_noise_v_rms`), drawn from `seed`.
    pub fn set_input_noise(&self, v_rms: [f32; 8], seed: u64) {
        self.core.borrow_mut().noise =
            Some((v_rms.map(f64::from), ChaCha8Rng::seed_from_u64(seed)));
    }
}

impl<A> embedded_hal::spi::ErrorType for Ads131m04Spi<A> {
    type Error = Infallible;
}

impl<A: AnalogInput> embedded_hal::spi::SpiDevice<u8> for Ads131m04Spi<A> {
    fn transaction(
        &mut self,
        operations: &mut [embedded_hal::spi::Operation<'_, u8>],
    ) -> Result<(), Infallible> {
        use embedded_hal::spi::Operation;
        // One chip-select assertion is one frame: gather what the host clocks out…
        let mut mosi = Vec::new();
        for op in operations.iter() {
            match op {
                Operation::Read(b) => mosi.extend(std::iter::repeat_n(0u8, b.len())),
                Operation::Write(b) => mosi.extend_from_slice(b),
                Operation::Transfer(r, w) => {
                    let mut x = w.to_vec();
                    x.resize(r.len().max(w.len()), 0);
                    mosi.extend(x);
                }
                Operation::TransferInPlace(b) => mosi.extend_from_slice(b),
                Operation::DelayNs(_) => {}
            }
        }
        if mosi.is_empty() {
            return Ok(());
        }
        let miso = self.core.borrow_mut().exchange(&mosi);
        // …and hand back what the device clocked in return (zeros past the frame).
        let mut it = miso.into_iter().chain(std::iter::repeat(0));
        for op in operations.iter_mut() {
            match op {
                Operation::Read(b) | Operation::TransferInPlace(b) => {
                    b.iter_mut().for_each(|x| *x = it.next().unwrap_or(0));
                }
                Operation::Write(b) => {
                    for _ in 0..b.len() {
                        it.next();
                    }
                }
                Operation::Transfer(r, w) => {
                    let n = r.len().max(w.len());
                    for k in 0..n {
                        let x = it.next().unwrap_or(0);
                        if let Some(d) = r.get_mut(k) {
                            *d = x;
                        }
                    }
                }
                Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}

impl<A> embedded_hal::digital::ErrorType for Ads131m04Drdy<A> {
    type Error = Infallible;
}

impl<A: AnalogInput> embedded_hal::digital::InputPin for Ads131m04Drdy<A> {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(!self.core.borrow().ready())
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(self.core.borrow().ready())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::drivers::ads131m04::{
        Ads131m04, Channel, Config, Error, Gain, Register, WordLength,
    };

    /// Constant voltages.
    struct Dc([f64; 4]);
    impl AnalogInput for Dc {
        fn volts(&mut self, _t: f64) -> [f64; 4] {
            self.0
        }
    }

    /// A ramp: channel 0 reads the sample time in volts × 100.
    struct Ramp;
    impl AnalogInput for Ramp {
        fn volts(&mut self, t: f64) -> [f64; 4] {
            [t * 100.0, -0.25, 0.0, 0.0]
        }
    }

    struct NoDelay;
    impl embedded_hal::delay::DelayNs for NoDelay {
        fn delay_ns(&mut self, _ns: u32) {}
    }

    #[test]
    fn crc_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }

    #[test]
    fn driver_configures_and_reads_the_emulated_chip() {
        let clock = SimClock::new();
        let (spi, drdy) = ads131m04(Dc([0.6, -1.5, 0.3, 0.1]), clock.clone());
        let mut adc = Ads131m04::new(spi, drdy);
        adc.reset(&mut NoDelay).unwrap();
        let id = adc.check_id().unwrap();
        assert_eq!(id, ID_VALUE);
        adc.configure(&Config::default()).unwrap();
        adc.set_gain(Channel::Ch2, Gain::G2).unwrap();
        adc.set_drdy_poll_limit(1);
        // No time has passed: no conversion yet.
        assert_eq!(adc.wait_data_ready(), Err(Error::Timeout));
        clock.set(3.0 / 8000.0);
        // The first two conversions after the gain write blend the old gain (1) and the
        // new one (2) with weights 5/6, 1/6 and 1/6, 5/6: read at gain 2, 0.3 V shows as
        // (5/6 · 0.3 + 1/6 · 0.6) / 2 and then (1/6 · 0.3 + 5/6 · 0.6) / 2.
        for want in [0.175, 0.275] {
            let f = adc.read_frame_when_ready().unwrap();
            let v = adc.to_volts(&f);
            assert!((v[2] - want).abs() < 1e-6, "{v:?} vs {want}");
        }
        let f = adc.read_frame_when_ready().unwrap();
        assert!(f.status.data_ready(Channel::Ch0));
        let v = adc.to_volts(&f);
        assert!((v[0] - 0.6).abs() < 1e-6, "{v:?}");
        assert!((v[1] + 1.2).abs() < 1e-6, "saturated at −full scale: {v:?}");
        assert!((v[2] - 0.3).abs() < 1e-6);
        assert!(f.saturated.contains(Channel::Ch1) && f.coils_saturated());
        assert_eq!(adc.wait_data_ready(), Err(Error::Timeout));
        // Register round trip and word-length changes keep the framing in step.
        for wl in [
            WordLength::Bits32SignExtend,
            WordLength::Bits16,
            WordLength::Bits32ZeroPad,
            WordLength::Bits24,
        ] {
            adc.set_word_length(wl).unwrap();
            assert_eq!(adc.status().unwrap().word_length(), wl);
        }
        assert_eq!(adc.read_register(Register::GAIN1).unwrap(), 0x0100);
        adc.lock().unwrap();
        assert!(adc.status().unwrap().locked());
        assert!(adc.set_gain(Channel::Ch0, Gain::G4).is_err());
        adc.unlock().unwrap();
        adc.standby().unwrap();
        adc.wakeup().unwrap();
    }

    #[test]
    fn the_pga_sets_full_scale_and_noise_and_clips() {
        let clock = SimClock::new();
        // 5 mV: inside full scale up to PGA 128 (9.375 mV), 20 mV clips from PGA 64.
        let (spi, drdy) = ads131m04(Dc([5e-3, 20e-3, -20e-3, 0.0]), clock.clone());
        spi.set_input_noise([8e-6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2e-6], 7);
        let mut adc = Ads131m04::new(spi, drdy);
        adc.reset(&mut NoDelay).unwrap();
        adc.configure(&Config::default()).unwrap();
        adc.set_drdy_poll_limit(1);
        let mut t = 0.0;
        for (gain, sigma, clip) in [(Gain::G1, 8e-6, false), (Gain::G128, 2e-6, true)] {
            adc.set_coil_gains(gain).unwrap();
            assert_eq!(
                adc.read_register(Register::GAIN1).unwrap() & 0x0FFF,
                0x111 * gain as u16
            );
            let (mut s1, mut s2, mut n) = (0.0, 0.0, 0.0);
            t += 0.1;
            clock.set(t);
            let mut k = 0;
            while let Ok(f) = adc.read_frame_when_ready() {
                k += 1;
                // Skip the sinc³ transient of the gain write.
                if k <= 2 {
                    continue;
                }
                let v = adc.to_volts(&f);
                let e = f64::from(v[0]) - 5e-3;
                s1 += e;
                s2 += e * e;
                n += 1.0;
                assert_eq!(f.saturated.contains(Channel::Ch1), clip);
                assert_eq!(f.saturated.contains(Channel::Ch2), clip);
                let fs = gain.full_scale_v();
                if clip {
                    assert!(
                        (v[1] - fs).abs() < 1e-6 && (v[2] + fs).abs() < 1e-6,
                        "{v:?}"
                    );
                }
            }
            let sd = (s2 / n - (s1 / n).powi(2)).sqrt();
            assert!(
                n > 700.0 && (sd / sigma - 1.0).abs() < 0.1,
                "gain {gain:?}: σ {sd} vs {sigma}"
            );
            assert!((s1 / n).abs() < 4.0 * sigma / n.sqrt(), "unbiased");
        }
    }

    #[test]
    fn samples_follow_the_clock_one_per_frame() {
        let clock = SimClock::new();
        let (spi, drdy) = ads131m04(Ramp, clock.clone());
        let mut adc = Ads131m04::new(spi, drdy);
        adc.reset(&mut NoDelay).unwrap();
        adc.configure(&Config::default()).unwrap();
        adc.set_drdy_poll_limit(1);
        clock.set(0.01);
        let mut n = 0;
        while let Ok(f) = adc.read_frame_when_ready() {
            let v = adc.to_volts(&f);
            let t = n as f32 / 8000.0;
            assert!(
                (v[0] - 100.0 * t).abs() < 1e-5,
                "sample {n}: {} vs {}",
                v[0],
                100.0 * t
            );
            n += 1;
        }
        assert_eq!(n, 80);
    }
}
