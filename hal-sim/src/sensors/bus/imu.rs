//! Emulated IMU chips on one `embedded_hal::i2c::I2c` bus: a Bosch BMI160 (accelerometer +
//! gyroscope, 0x68) and an ST LSM303AGR (accelerometer 0x19, magnetometer 0x1E), fed
//! from the world's truth through the measurement-level noise model
//! ([`crate::sensors::ImuModel`]: the same bias, white noise and seed stream).
//!
//! Register behaviour (what `bmi160` 1.x and `lsm303agr` 1.x use):
//! - I2C: a write sets the register pointer and writes the following bytes to successive
//!   registers; a read returns bytes from the pointer on, auto-incrementing (the
//!   LSM303AGR's sub-address bit 7, its multi-byte flag, is masked off).
//! - BMI160: `CHIP_ID` 0xD1; `CMD` (0x7E) power-mode commands update `PMU_STATUS`;
//!   `ACC_RANGE`/`GYR_RANGE` set the scales (±2/4/8/16 g; ±2000…125 °/s); `ACC_CONF`/
//!   `GYR_CONF` ODR (power-on 100 Hz); data `GYR` 0x0C–0x11, `ACC` 0x12–0x17 (little-endian
//!   i16), zero while suspended; `STATUS` DRDY bits.
//! - LSM303AGR magnetometer: `WHO_AM_I_M` 0x40; `CFG_REG_A_M` mode (continuous, single,
//!   idle) and ODR 10–100 Hz; `STATUS_REG_M` ZYXDA; `OUTX_L_REG_M`… (0x68–0x6D,
//!   little-endian i16, 1.5 mG/LSB). Accelerometer: `WHO_AM_I_A` 0x33 and its control
//!   registers are stored; it is not used by the receiver and reads zero data.
//! - Samples are taken at the chip's ODR grid on the simulation clock (the newest one at
//!   or before the clock), mapped from the body frame to the chip's axes with the
//!   firmware's board mapping ([`firmware::drivers::imu`]), quantized to the LSB and
//!   clamped to the i16 range (full scale).
use super::SimClock;
use crate::io::session::Imu;
use crate::sensors::ImuModel;
use crate::world::World;
use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource, Operation};
use firmware::drivers::imu::{AxisMap, BMI160_TO_BODY, LSM303AGR_MAG_TO_BODY};
use std::cell::RefCell;
use std::rc::Rc;

/// BMI160 I2C address (SDO low).
pub const BMI160_ADDR: u8 = 0x68;
/// LSM303AGR accelerometer I2C address.
pub const LSM303AGR_ACC_ADDR: u8 = 0x19;
/// LSM303AGR magnetometer I2C address.
pub const LSM303AGR_MAG_ADDR: u8 = 0x1E;

const G: f64 = 9.80665;

/// The world's IMU truth plus noise, one [`ImuModel`] draw per sample time (cached, so
/// both chips see the same sample when they read at the same time).
#[derive(Debug)]
pub struct ImuSampler<'w> {
    world: &'w World,
    model: ImuModel,
    last: Option<Imu>,
}

impl<'w> ImuSampler<'w> {
    /// Samples `world` through `model`.
    pub fn new(world: &'w World, model: ImuModel) -> Self {
        Self {
            world,
            model,
            last: None,
        }
    }

    /// The noisy sample at `t` (body frame, SI units, µT).
    pub fn at(&mut self, t: f64) -> Imu {
        match &self.last {
            Some(s) if s.t == t => s.clone(),
            _ => {
                let s = self.model.sample(self.world, t);
                self.last = Some(s.clone());
                s
            }
        }
    }
}

/// A body vector as a chip's little-endian i16 triple at `lsb` per count.
fn encode(map: &AxisMap, body: [f64; 3], lsb: f64) -> [u8; 6] {
    let chip = map.to_chip(body);
    let mut out = [0u8; 6];
    for (k, v) in chip.iter().enumerate() {
        let c = (v / lsb).round().clamp(-32768.0, 32767.0) as i16;
        out[2 * k..2 * k + 2].copy_from_slice(&c.to_le_bytes());
    }
    out
}

/// The time of the newest sample at or before `now` on an `odr_hz` grid.
fn grid(now: f64, odr_hz: f64) -> f64 {
    (now * odr_hz + 1e-6).floor() / odr_hz
}

#[derive(Debug)]
struct Bmi160 {
    regs: [u8; 128],
    ptr: u8,
}

impl Bmi160 {
    fn new() -> Self {
        let mut regs = [0u8; 128];
        regs[0x00] = 0xD1;
        regs[0x40] = 0x28; // ACC_CONF: 100 Hz
        regs[0x41] = 0x03; // ACC_RANGE: ±2 g
        regs[0x42] = 0x28; // GYR_CONF: 100 Hz
        regs[0x43] = 0x00; // GYR_RANGE: ±2000 °/s
        Self { regs, ptr: 0 }
    }

    fn odr_hz(conf: u8) -> f64 {
        100.0 * 2f64.powi(i32::from(conf & 0x0F) - 8)
    }

    fn acc_lsb(&self) -> f64 {
        let g = match self.regs[0x41] & 0x0F {
            0x05 => 4.0,
            0x08 => 8.0,
            0x0C => 16.0,
            _ => 2.0,
        };
        g * G / 32768.0
    }

    /// Datasheet sensitivity: 16.4 LSB/(°/s) at ±2000 °/s, doubling per range step.
    fn gyr_lsb(&self) -> f64 {
        let lsb_per_dps = 16.4 * f64::from(1u16 << (self.regs[0x43] & 0x07).min(4));
        (1.0 / lsb_per_dps).to_radians()
    }

    fn write(&mut self, reg: u8, v: u8) {
        match reg {
            0x7E => {
                // CMD: power modes into PMU_STATUS (acc bits 5:4, gyr 3:2, mag 1:0).
                let pmu = &mut self.regs[0x03];
                match v {
                    0x10..=0x12 => *pmu = (*pmu & !0x30) | ((v & 0x03) << 4),
                    0x14 | 0x15 | 0x17 => *pmu = (*pmu & !0x0C) | ((v & 0x03) << 2),
                    0x18..=0x1A => *pmu = (*pmu & !0x03) | (v & 0x03),
                    0xB6 => *self = Self::new(),
                    _ => {}
                }
            }
            0x00..=0x1B => {}
            _ => self.regs[usize::from(reg & 0x7F)] = v,
        }
    }

    /// Refreshes the data registers before a read that starts at `reg`.
    fn latch(&mut self, sampler: &mut ImuSampler<'_>, now: f64) {
        let acc_on = self.regs[0x03] & 0x30 != 0;
        let gyr_on = self.regs[0x03] & 0x0C != 0;
        let ta = grid(now, Self::odr_hz(self.regs[0x40]));
        let tg = grid(now, Self::odr_hz(self.regs[0x42]));
        let a = if acc_on {
            encode(&BMI160_TO_BODY, sampler.at(ta).acc, self.acc_lsb())
        } else {
            [0; 6]
        };
        let g = if gyr_on {
            encode(&BMI160_TO_BODY, sampler.at(tg).gyr, self.gyr_lsb())
        } else {
            [0; 6]
        };
        self.regs[0x0C..0x12].copy_from_slice(&g);
        self.regs[0x12..0x18].copy_from_slice(&a);
        self.regs[0x1B] = if acc_on { 0x80 } else { 0 } | if gyr_on { 0x40 } else { 0 };
    }
}

#[derive(Debug)]
struct Lsm303agr {
    acc: [u8; 128],
    mag: [u8; 128],
    acc_ptr: u8,
    mag_ptr: u8,
    /// Time of the last single-mode measurement.
    single_t: Option<f64>,
}

impl Lsm303agr {
    fn new() -> Self {
        let mut acc = [0u8; 128];
        acc[0x0F] = 0x33;
        acc[0x20] = 0x07;
        let mut mag = [0u8; 128];
        mag[0x4F] = 0x40;
        mag[0x60] = 0x03; // idle
        Self {
            acc,
            mag,
            acc_ptr: 0,
            mag_ptr: 0,
            single_t: None,
        }
    }

    fn mag_odr_hz(&self) -> f64 {
        match (self.mag[0x60] >> 2) & 0b11 {
            0 => 10.0,
            1 => 20.0,
            2 => 50.0,
            _ => 100.0,
        }
    }

    fn write_mag(&mut self, reg: u8, v: u8, now: f64) {
        match reg {
            0x60 => {
                self.mag[0x60] = v & !0x60; // reboot / soft reset bits self-clear
                if v & 0x03 == 0x01 {
                    self.single_t = Some(now);
                }
            }
            0x61..=0x63 => self.mag[usize::from(reg)] = v,
            _ => {}
        }
    }

    fn latch_mag(&mut self, sampler: &mut ImuSampler<'_>, now: f64) {
        let t = match self.mag[0x60] & 0x03 {
            0x00 => Some(grid(now, self.mag_odr_hz())),
            _ => self.single_t.take(),
        };
        if let Some(t) = t {
            let m = encode(
                &LSM303AGR_MAG_TO_BODY,
                sampler.at(t).mag.unwrap_or([0.0; 3]),
                0.15,
            );
            self.mag[0x68..0x6E].copy_from_slice(&m);
            self.mag[0x67] = 0x0F;
            if self.mag[0x60] & 0x03 == 0x01 {
                self.mag[0x60] |= 0x03; // back to idle after a single measurement
            }
        }
    }
}

/// Everything on the emulated I2C bus.
#[derive(Debug)]
struct Bus<'w> {
    sampler: ImuSampler<'w>,
    clock: SimClock,
    bmi: Bmi160,
    lsm: Lsm303agr,
    transactions: u64,
}

impl Bus<'_> {
    fn transaction(&mut self, address: u8, ops: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        self.transactions += 1;
        let now = self.clock.now();
        let nack = ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address);
        if ![BMI160_ADDR, LSM303AGR_ACC_ADDR, LSM303AGR_MAG_ADDR].contains(&address) {
            return Err(nack);
        }
        for op in ops.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    let Some((&reg, data)) = bytes.split_first() else {
                        continue;
                    };
                    let reg = reg & 0x7F;
                    for (k, &v) in data.iter().enumerate() {
                        let r = reg.wrapping_add(k as u8) & 0x7F;
                        match address {
                            BMI160_ADDR => self.bmi.write(r, v),
                            LSM303AGR_ACC_ADDR => self.lsm.acc[usize::from(r)] = v,
                            _ => self.lsm.write_mag(r, v, now),
                        }
                    }
                    match address {
                        BMI160_ADDR => self.bmi.ptr = reg,
                        LSM303AGR_ACC_ADDR => self.lsm.acc_ptr = reg,
                        _ => self.lsm.mag_ptr = reg,
                    }
                }
                Operation::Read(buf) => {
                    let (regs, ptr): (&[u8; 128], u8) = match address {
                        BMI160_ADDR => {
                            if (0x0C..0x1C).contains(&self.bmi.ptr) {
                                self.bmi.latch(&mut self.sampler, now);
                            }
                            (&self.bmi.regs, self.bmi.ptr)
                        }
                        LSM303AGR_ACC_ADDR => (&self.lsm.acc, self.lsm.acc_ptr),
                        _ => {
                            if (0x67..0x6E).contains(&self.lsm.mag_ptr) {
                                self.lsm.latch_mag(&mut self.sampler, now);
                            }
                            (&self.lsm.mag, self.lsm.mag_ptr)
                        }
                    };
                    for (k, b) in buf.iter_mut().enumerate() {
                        *b = regs[usize::from(ptr.wrapping_add(k as u8) & 0x7F)];
                    }
                }
            }
        }
        Ok(())
    }
}

/// A handle on the emulated IMU bus (clone it: one per driver, like `embedded-hal-bus`
/// devices of one bus).
#[derive(Debug, Clone)]
pub struct ImuBus<'w> {
    bus: Rc<RefCell<Bus<'w>>>,
}

impl<'w> ImuBus<'w> {
    /// The BMI160 and LSM303AGR at power-up on one bus, sampling `sampler` on `clock`.
    pub fn new(sampler: ImuSampler<'w>, clock: SimClock) -> Self {
        Self {
            bus: Rc::new(RefCell::new(Bus {
                sampler,
                clock,
                bmi: Bmi160::new(),
                lsm: Lsm303agr::new(),
                transactions: 0,
            })),
        }
    }

    /// I2C transactions so far.
    pub fn transactions(&self) -> u64 {
        self.bus.borrow().transactions
    }
}

impl embedded_hal::i2c::ErrorType for ImuBus<'_> {
    type Error = ErrorKind;
}

impl embedded_hal::i2c::I2c for ImuBus<'_> {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), ErrorKind> {
        self.bus.borrow_mut().transaction(address, operations)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::SensorConfig;
    use crate::world::scenario::{Preset, ScenarioConfig, simulate};
    use firmware::drivers::imu::{ACC_LSB_M_S2, GYR_LSB_RAD_S, Imu, MAG_LSB_UT};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    struct NoDelay;
    impl embedded_hal::delay::DelayNs for NoDelay {
        fn delay_ns(&mut self, _ns: u32) {}
    }

    #[test]
    fn the_firmware_driver_reads_the_noise_free_truth() {
        let mut cfg = ScenarioConfig::new(Preset::Arc, 3);
        cfg.max_duration_s = 20.0;
        cfg.sensors = SensorConfig::noise_free();
        let sim = simulate(&cfg);
        let clock = SimClock::new();
        let model = ImuModel::new(cfg.sensors.imu.clone(), ChaCha8Rng::seed_from_u64(1));
        let bus = ImuBus::new(ImuSampler::new(&sim.world, model), clock.clone());
        let mut imu = Imu::new(bus.clone(), bus.clone(), &mut NoDelay).unwrap();
        for k in 0..1500 {
            let t = k as f64 / 100.0 + 0.003;
            clock.set(t);
            let r = imu.read().unwrap();
            let s = sim.world.rescuer_state(k as f64 / 100.0);
            let mag = s.rot.transpose() * crate::world::physics::V3::from(sim.world.earth_field_ut);
            for i in 0..3 {
                assert!(
                    (f64::from(r.acc[i]) - s.specific_force_body[i]).abs()
                        < 0.51 * ACC_LSB_M_S2 as f64 + 1e-4
                );
                assert!(
                    (f64::from(r.gyr[i]) - s.omega_body[i]).abs()
                        < 0.51 * GYR_LSB_RAD_S as f64 + 1e-5,
                    "k {k} axis {i}: {} vs {}",
                    r.gyr[i],
                    s.omega_body[i]
                );
                assert!((f64::from(r.mag[i]) - mag[i]).abs() < 0.51 * MAG_LSB_UT as f64 + 1e-3);
            }
        }
        assert!(bus.transactions() > 3000);
    }

    #[test]
    fn unknown_addresses_are_not_acknowledged() {
        use embedded_hal::i2c::I2c;
        let cfg = ScenarioConfig::new(Preset::Paper, 1);
        let mut c = cfg.clone();
        c.max_duration_s = 5.0;
        let sim = simulate(&c);
        let model = ImuModel::new(cfg.sensors.imu.clone(), ChaCha8Rng::seed_from_u64(1));
        let mut bus = ImuBus::new(ImuSampler::new(&sim.world, model), SimClock::new());
        let mut b = [0u8; 1];
        assert_eq!(
            bus.write_read(0x50, &[0], &mut b),
            Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))
        );
        bus.write_read(LSM303AGR_ACC_ADDR, &[0x0F], &mut b).unwrap();
        assert_eq!(b[0], 0x33);
    }
}
