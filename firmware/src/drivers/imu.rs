//! The receiver's IMU: a Bosch BMI160 (accelerometer + gyroscope) and the magnetometer of
//! an ST LSM303AGR, both on I2C, read through eldruin's `bmi160` 1.x and `lsm303agr` 1.x
//! drivers (embedded-hal 1.0, MIT OR Apache-2.0) and turned into the receiver's body
//! frame R (x forward, y left, z up) in SI units.
//!
//! # Chips, addresses, settings
//! | chip | I2C address | setting | resolution |
//! |---|---|---|---|
//! | BMI160 accelerometer | 0x68 | ±8 g, 100 Hz (power-on ODR), normal mode | 4096 LSB/g ≈ 2.4 mm/s² |
//! | BMI160 gyroscope | 0x68 | ±500 °/s, 100 Hz (power-on ODR), normal mode | 65.6 LSB/(°/s) ≈ 2.7e-4 rad/s |
//! | LSM303AGR magnetometer | 0x1E | ±49.152 G, 100 Hz continuous, high resolution | 1.5 mG = 0.15 µT |
//!
//! The LSM303AGR's accelerometer (0x19) is only touched by the driver's `init` (block data
//! update, temperature sensor) and otherwise left powered down: the BMI160's is better.
//!
//! # Chip axes to body axes
//! Each chip's axes are mapped to R by a signed permutation ([`AxisMap`]) fixed by how it
//! sits on the board:
//! - BMI160 ([`BMI160_TO_BODY`]): chip x, y, z along body x (forward), y (left), z (up).
//! - LSM303AGR ([`LSM303AGR_MAG_TO_BODY`]): mounted turned 90° about z, its x axis points
//!   left and its y axis backward: `body = (−chip_y, chip_x, chip_z)`.
//!
//! Both sensors share one I2C bus on the board (e.g. two `embedded-hal-bus` devices of the
//! same bus); [`Imu`] takes one bus handle per chip, of the same type.
//!
//! No call panics and no call waits without bound: every failure is an [`ImuError`].

use crate::Vec3;
use bmi160::interface::I2cInterface as Bmi160I2c;
use bmi160::{
    AccelerometerPowerMode, AccelerometerRange, Bmi160, GyroscopePowerMode, GyroscopeRange,
    SensorSelector, SlaveAddr,
};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{ErrorType, I2c};
use lsm303agr::interface::I2cInterface as LsmI2c;
use lsm303agr::{Lsm303agr, MagMode, MagOutputDataRate, mode::MagContinuous};

/// Standard gravity used to convert g to m/s².
pub const STANDARD_GRAVITY: f32 = 9.80665;
/// BMI160 chip ID (register 0x00).
pub const BMI160_CHIP_ID: u8 = 0xD1;
/// LSM303AGR magnetometer ID (`WHO_AM_I_M`, 0x4F).
pub const LSM303AGR_MAG_ID: u8 = 0x40;
/// Accelerometer LSB at ±8 g, m/s².
pub const ACC_LSB_M_S2: f32 = STANDARD_GRAVITY / 4096.0;
/// Gyroscope LSB at ±500 °/s, rad/s.
pub const GYR_LSB_RAD_S: f32 = core::f32::consts::PI / 180.0 / 65.6;
/// Magnetometer LSB, µT (1.5 mG).
pub const MAG_LSB_UT: f32 = 0.15;
/// Accelerometer full scale, m/s² (a reading at ± this is clipped).
pub const ACC_FULL_SCALE_M_S2: f32 = 32768.0 * ACC_LSB_M_S2;
/// Gyroscope full scale, rad/s.
pub const GYR_FULL_SCALE_RAD_S: f32 = 32768.0 * GYR_LSB_RAD_S;
/// Magnetometer full scale, µT.
pub const MAG_FULL_SCALE_UT: f32 = 32768.0 * MAG_LSB_UT;

/// A signed permutation from a chip's axes to the body frame:
/// `body[i] = sign[i] · chip[axis[i]]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisMap {
    /// The chip axis (0 = x, 1 = y, 2 = z) that each body axis reads.
    pub axis: [usize; 3],
    /// The sign applied to it (+1 or −1).
    pub sign: [i8; 3],
}

impl AxisMap {
    /// Chip axes equal body axes.
    pub const IDENTITY: AxisMap = AxisMap {
        axis: [0, 1, 2],
        sign: [1, 1, 1],
    };

    /// A chip vector in the body frame.
    pub fn to_body(&self, chip: [f32; 3]) -> Vec3 {
        let c = |i: usize| {
            let a = self.axis.get(i).copied().unwrap_or(i);
            let s = f32::from(self.sign.get(i).copied().unwrap_or(1));
            s * chip.get(a).copied().unwrap_or(0.0)
        };
        Vec3::new(c(0), c(1), c(2))
    }

    /// A body vector in the chip's axes (the inverse of [`Self::to_body`]).
    pub fn to_chip(&self, body: [f64; 3]) -> [f64; 3] {
        let mut chip = [0.0; 3];
        for ((b, a), s) in body.iter().zip(self.axis).zip(self.sign) {
            if let Some(c) = chip.get_mut(a) {
                *c = f64::from(s) * b;
            }
        }
        chip
    }
}

/// BMI160 axes → body axes (aligned).
pub const BMI160_TO_BODY: AxisMap = AxisMap::IDENTITY;
/// LSM303AGR magnetometer axes → body axes (chip turned 90° about z: x left, y backward).
pub const LSM303AGR_MAG_TO_BODY: AxisMap = AxisMap {
    axis: [1, 0, 2],
    sign: [-1, 1, 1],
};

/// How both chips sit on a board: their axes → body axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mounting {
    /// BMI160 axes → body axes.
    pub acc_gyr: AxisMap,
    /// LSM303AGR magnetometer axes → body axes.
    pub mag: AxisMap,
}

impl Mounting {
    /// The reference board's mounting ([`BMI160_TO_BODY`], [`LSM303AGR_MAG_TO_BODY`]).
    pub const REFERENCE: Mounting = Mounting {
        acc_gyr: BMI160_TO_BODY,
        mag: LSM303AGR_MAG_TO_BODY,
    };
}

/// Which chip an error concerns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Chip {
    /// The BMI160 accelerometer + gyroscope.
    Bmi160,
    /// The LSM303AGR magnetometer.
    Lsm303agrMag,
}

/// Everything that can go wrong with the IMU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImuError<E> {
    /// The I2C bus reported an error talking to `chip`.
    #[error("I2C error talking to the {chip:?}: {error:?}")]
    Comm {
        /// The chip addressed.
        chip: Chip,
        /// The bus error.
        error: E,
    },
    /// A chip's ID register does not identify the expected chip (the value read).
    #[error("the {chip:?} answered ID {id:#04x}")]
    WrongId {
        /// The chip addressed.
        chip: Chip,
        /// The ID read.
        id: u8,
    },
    /// A driver refused its input, or a data read came back without the data asked for.
    #[error("no valid data from the {0:?}")]
    InvalidData(Chip),
}

/// One reading of all nine axes in the body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuReading {
    /// Specific force, m/s² (at rest and level: `[0, 0, +9.81]`).
    pub acc: Vec3,
    /// Angular rate, rad/s.
    pub gyr: Vec3,
    /// Magnetic flux density, µT.
    pub mag: Vec3,
    /// Whether any axis of any sensor sat at its full-scale code (the value is clipped).
    pub clipped: bool,
}

/// What [`Imu::new`] hands back when initialisation fails: the error and both bus handles.
pub struct ImuInitError<I2C: ErrorType> {
    /// Why it failed.
    pub error: ImuError<I2C::Error>,
    /// The BMI160's bus handle.
    pub i2c_acc_gyr: I2C,
    /// The LSM303AGR's bus handle.
    pub i2c_mag: I2C,
}

impl<I2C: ErrorType> core::fmt::Debug for ImuInitError<I2C> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ImuInitError")
            .field("error", &self.error)
            .finish_non_exhaustive()
    }
}

/// The BMI160 and the LSM303AGR magnetometer, initialised and streaming at 100 Hz.
pub struct Imu<I2C: I2c> {
    acc_gyr: Bmi160<Bmi160I2c<I2C>>,
    mag: Lsm303agr<LsmI2c<I2C>, MagContinuous>,
    mounting: Mounting,
}

fn bmi_err<E>(e: bmi160::Error<E>) -> ImuError<E> {
    match e {
        bmi160::Error::Comm(error) => ImuError::Comm {
            chip: Chip::Bmi160,
            error,
        },
        bmi160::Error::InvalidInputData => ImuError::InvalidData(Chip::Bmi160),
    }
}

fn lsm_err<E>(e: lsm303agr::Error<E>) -> ImuError<E> {
    match e {
        lsm303agr::Error::Comm(error) => ImuError::Comm {
            chip: Chip::Lsm303agrMag,
            error,
        },
        lsm303agr::Error::InvalidInputData => ImuError::InvalidData(Chip::Lsm303agrMag),
    }
}

/// Whether a raw triple holds a full-scale code.
fn at_full_scale(v: [i16; 3]) -> bool {
    v.iter().any(|&x| x == i16::MAX || x == i16::MIN)
}

fn scaled(v: [i16; 3], lsb: f32) -> [f32; 3] {
    v.map(|x| f32::from(x) * lsb)
}

impl<I2C: I2c> Imu<I2C> {
    /// Checks both chips' IDs and configures them: BMI160 accelerometer and gyroscope in
    /// normal mode at ±8 g and ±500 °/s; LSM303AGR `init` (block data update), magnetometer
    /// high-resolution 100 Hz continuous. `delay` covers the start-up times (≈ 90 ms).
    /// The chips sit as on the reference board ([`Mounting::REFERENCE`]).
    pub fn new<D: DelayNs>(
        i2c_acc_gyr: I2C,
        i2c_mag: I2C,
        delay: &mut D,
    ) -> Result<Self, ImuInitError<I2C>> {
        Self::with_mounting(i2c_acc_gyr, i2c_mag, Mounting::REFERENCE, delay)
    }

    /// [`Self::new`] for chips mounted as `mounting` says (a board profile's).
    pub fn with_mounting<D: DelayNs>(
        i2c_acc_gyr: I2C,
        i2c_mag: I2C,
        mounting: Mounting,
        delay: &mut D,
    ) -> Result<Self, ImuInitError<I2C>> {
        let mut bmi = Bmi160::new_with_i2c(i2c_acc_gyr, SlaveAddr::default());
        let mut lsm = Lsm303agr::new_with_i2c(i2c_mag);
        if let Err(error) = Self::setup_bmi(&mut bmi, delay) {
            return Err(ImuInitError {
                error,
                i2c_acc_gyr: bmi.destroy(),
                i2c_mag: lsm.destroy(),
            });
        }
        let setup = (|| {
            let id = lsm.magnetometer_id().map_err(lsm_err)?;
            if !id.is_correct() {
                return Err(ImuError::WrongId {
                    chip: Chip::Lsm303agrMag,
                    id: id.raw(),
                });
            }
            lsm.init().map_err(lsm_err)?;
            lsm.set_mag_mode_and_odr(delay, MagMode::HighResolution, MagOutputDataRate::Hz100)
                .map_err(lsm_err)
        })();
        if let Err(error) = setup {
            return Err(ImuInitError {
                error,
                i2c_acc_gyr: bmi.destroy(),
                i2c_mag: lsm.destroy(),
            });
        }
        match lsm.into_mag_continuous() {
            Ok(mag) => Ok(Imu {
                acc_gyr: bmi,
                mag,
                mounting,
            }),
            Err(e) => Err(ImuInitError {
                error: lsm_err(e.error),
                i2c_acc_gyr: bmi.destroy(),
                i2c_mag: e.dev.destroy(),
            }),
        }
    }

    fn setup_bmi<D: DelayNs>(
        bmi: &mut Bmi160<Bmi160I2c<I2C>>,
        delay: &mut D,
    ) -> Result<(), ImuError<I2C::Error>> {
        let id = bmi.chip_id().map_err(bmi_err)?;
        if id != BMI160_CHIP_ID {
            return Err(ImuError::WrongId {
                chip: Chip::Bmi160,
                id,
            });
        }
        bmi.set_accel_power_mode(AccelerometerPowerMode::Normal)
            .map_err(bmi_err)?;
        // Accelerometer start-up: 3.8 ms.
        delay.delay_ms(4);
        bmi.set_gyro_power_mode(GyroscopePowerMode::Normal)
            .map_err(bmi_err)?;
        // Gyroscope start-up from suspend: 80 ms.
        delay.delay_ms(81);
        bmi.set_accel_range(AccelerometerRange::G8)
            .map_err(bmi_err)?;
        bmi.set_gyro_range(GyroscopeRange::Scale500)
            .map_err(bmi_err)
    }

    /// Reads the latest accelerometer, gyroscope and magnetometer samples (two I2C reads:
    /// 12 bytes from the BMI160, 6 from the LSM303AGR) in the body frame.
    pub fn read(&mut self) -> Result<ImuReading, ImuError<I2C::Error>> {
        let data = self
            .acc_gyr
            .data(SensorSelector::new().accel().gyro())
            .map_err(bmi_err)?;
        let (Some(a), Some(g)) = (data.accel, data.gyro) else {
            return Err(ImuError::InvalidData(Chip::Bmi160));
        };
        let m = self.mag.magnetic_field().map_err(lsm_err)?;
        let (mx, my, mz) = m.xyz_unscaled();
        let (a, g, m) = ([a.x, a.y, a.z], [g.x, g.y, g.z], [mx, my, mz]);
        Ok(ImuReading {
            acc: self.mounting.acc_gyr.to_body(scaled(a, ACC_LSB_M_S2)),
            gyr: self.mounting.acc_gyr.to_body(scaled(g, GYR_LSB_RAD_S)),
            mag: self.mounting.mag.to_body(scaled(m, MAG_LSB_UT)),
            clipped: at_full_scale(a) || at_full_scale(g) || at_full_scale(m),
        })
    }

    /// Gives back both bus handles (BMI160's, LSM303AGR's).
    pub fn destroy(self) -> (I2C, I2C) {
        (self.acc_gyr.destroy(), self.mag.destroy())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::delay::NoopDelay;
    use embedded_hal_mock::eh1::i2c::{Mock as I2cMock, Transaction as T};

    const BMI: u8 = 0x68;
    const ACC: u8 = 0x19;
    const MAG: u8 = 0x1E;

    fn init_bmi() -> Vec<T> {
        vec![
            T::write_read(BMI, vec![0x00], vec![BMI160_CHIP_ID]),
            T::write(BMI, vec![0x7E, 0x11]),
            T::write(BMI, vec![0x7E, 0x15]),
            T::write(BMI, vec![0x41, 0x08]),
            T::write(BMI, vec![0x43, 0x02]),
        ]
    }

    fn init_mag() -> Vec<T> {
        vec![
            T::write_read(MAG, vec![0x4F], vec![LSM303AGR_MAG_ID]),
            // init: CTRL_REG4_A BDU, TEMP_CFG_REG_A, CFG_REG_C_M BDU.
            T::write(ACC, vec![0x23, 0x80]),
            T::write(ACC, vec![0x1F, 0xC0]),
            T::write(MAG, vec![0x62, 0x10]),
            // High resolution, 100 Hz, still idle; then continuous.
            T::write(MAG, vec![0x60, 0x0F]),
            T::write(MAG, vec![0x60, 0x0C]),
        ]
    }

    fn le(v: [i16; 3]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    fn imu(extra: &[T]) -> Imu<I2cMock> {
        let mut t = init_bmi();
        t.extend(init_mag());
        t.extend_from_slice(extra);
        let mut bus = I2cMock::new(&t);
        // Both chips sit on one bus: the two handles are clones of one mock.
        Imu::new(bus.clone(), bus.clone(), &mut NoopDelay::new())
            .map_err(|e| {
                bus.done();
                e.error
            })
            .unwrap()
    }

    fn done(imu: Imu<I2cMock>) {
        let (mut a, _b) = imu.destroy();
        a.done();
    }

    #[test]
    fn reads_scale_and_map_to_body() {
        // Gyro (0x0C..0x11) then accelerometer (0x12..0x17), one burst from 0x0C.
        let gyr = [656, -1312, 0];
        let acc = [0, 2048, 4096];
        let mag = [100, -200, -300];
        let mut data = le(gyr);
        data.extend(le(acc));
        let reads = [
            T::write_read(BMI, vec![0x0C], data),
            T::write_read(MAG, vec![0xE8], le(mag)),
        ];
        let mut imu = imu(&reads);
        let r = imu.read().unwrap();
        let deg = core::f32::consts::PI / 180.0;
        assert!((r.gyr - Vec3::new(10.0 * deg, -20.0 * deg, 0.0)).norm() < 1e-5);
        assert!((r.acc - Vec3::new(0.0, 0.5 * STANDARD_GRAVITY, STANDARD_GRAVITY)).norm() < 1e-4);
        // Chip (15, −30, −45) µT → body (30, 15, −45).
        assert!(
            (r.mag - Vec3::new(30.0, 15.0, -45.0)).norm() < 1e-4,
            "{:?}",
            r.mag
        );
        assert!(!r.clipped);
        done(imu);
    }

    #[test]
    fn full_scale_codes_are_flagged() {
        let mut data = le([0, 0, 0]);
        data.extend(le([i16::MIN, 0, 4096]));
        let reads = [
            T::write_read(BMI, vec![0x0C], data),
            T::write_read(MAG, vec![0xE8], le([0, 0, 0])),
        ];
        let mut imu = imu(&reads);
        let r = imu.read().unwrap();
        assert!(r.clipped);
        assert!((r.acc.x + ACC_FULL_SCALE_M_S2).abs() < 1e-3);
        done(imu);
    }

    #[test]
    fn wrong_ids_hand_the_bus_back() {
        let t = [T::write_read(BMI, vec![0x00], vec![0xD3])];
        let bus = I2cMock::new(&t);
        let Err(e) = Imu::new(bus.clone(), bus, &mut NoopDelay::new()) else {
            panic!("accepted a wrong chip");
        };
        assert_eq!(
            e.error,
            ImuError::WrongId {
                chip: Chip::Bmi160,
                id: 0xD3
            }
        );
        let mut a = e.i2c_acc_gyr;
        a.done();

        let mut t = init_bmi();
        t.push(T::write_read(MAG, vec![0x4F], vec![0x3D]));
        let bus = I2cMock::new(&t);
        let Err(e) = Imu::new(bus.clone(), bus, &mut NoopDelay::new()) else {
            panic!("accepted a wrong magnetometer");
        };
        assert_eq!(
            e.error,
            ImuError::WrongId {
                chip: Chip::Lsm303agrMag,
                id: 0x3D
            }
        );
        let mut m = e.i2c_mag;
        m.done();
    }

    #[test]
    fn bus_errors_name_the_chip() {
        use embedded_hal::i2c::ErrorKind;
        let mut t = init_bmi();
        t.extend(init_mag());
        t.push(T::write_read(BMI, vec![0x0C], vec![0; 12]).with_error(ErrorKind::Bus));
        let bus = I2cMock::new(&t);
        let mut imu = Imu::new(bus.clone(), bus, &mut NoopDelay::new()).unwrap();
        assert_eq!(
            imu.read(),
            Err(ImuError::Comm {
                chip: Chip::Bmi160,
                error: ErrorKind::Bus
            })
        );
        done(imu);
    }

    #[test]
    fn axis_maps_invert() {
        for map in [BMI160_TO_BODY, LSM303AGR_MAG_TO_BODY] {
            let body = [1.0, -2.0, 3.5];
            let chip = map.to_chip(body).map(|x| x as f32);
            let back = map.to_body(chip);
            assert!((back - Vec3::new(1.0, -2.0, 3.5)).norm() < 1e-6);
        }
        // The magnetometer's x axis points left.
        assert_eq!(
            LSM303AGR_MAG_TO_BODY.to_chip([0.0, 1.0, 0.0]),
            [1.0, 0.0, 0.0]
        );
    }

    #[test]
    fn errors_say_which_chip_and_what() {
        let e: ImuError<u8> = ImuError::WrongId {
            chip: Chip::Lsm303agrMag,
            id: 0x40,
        };
        assert_eq!(e.to_string(), "the Lsm303agrMag answered ID 0x40");
        let e: ImuError<&str> = ImuError::Comm {
            chip: Chip::Bmi160,
            error: "nack",
        };
        assert_eq!(e.to_string(), "I2C error talking to the Bmi160: \"nack\"");
        let app = crate::app::AppError::Motion(crate::motion::MotionError::Gap { dt: 2.5 });
        assert_eq!(
            app.to_string(),
            "IMU sample refused: gap of 2.5 s since the previous IMU sample"
        );
    }
}
