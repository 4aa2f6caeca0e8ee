//! Bus-level emulation: the receiver's chips behind the `embedded-hal` 1.0 traits, so that
//! the firmware's real drivers run unchanged on the PC.
//!
//! ```text
//! World ─► if_signal (coils, analog chain, EMI) ─► ads131m04 (SpiDevice + DRDY) ─► firmware ADS131M04 driver ─► firmware::frontend ─► pulse records
//!       └► sensors::ImuModel (truth + noise)    ─► imu (I2c: BMI160, LSM303AGR) ─► firmware::drivers::imu  ─────────────────────────► imu records
//! ```
//!
//! - [`if_signal`]: the three coils' IF voltages from the world's fields.
//! - [`ads131m04`]: the emulated ADC (command protocol, framing, CRC, DRDY, saturation).
//! - [`imu`]: the emulated BMI160 and LSM303AGR on one I2C bus.
//! - [`unit`]: one simulated unit's actual parameters, drawn about the board profile's
//!   nominal values with its tolerances.
//! - [`bench`]: the antenna's bench calibration on an emulated unit.
//! - [`detection`]: false alarms and detection of weak pulses against the matched-filter
//!   limit (`sensing-report`'s detection section).
//! - [`mag_cal`]: the magnetometer's rotation-in-place calibration on an emulated unit.
//! - [`run`]: `simulate --bus` — the whole chain into a session log, and the comparison
//!   of its pulses with the measurement level's.
//!
//! All chips run on one [`SimClock`] that the simulation loop advances.
pub mod ads131m04;
pub mod antenna;
pub mod bench;
pub mod detection;
pub mod if_signal;
pub mod imu;
pub mod mag_cal;
pub mod near;
pub mod run;
pub mod unit;

use std::cell::Cell;
use std::rc::Rc;

/// The simulation's time (s), shared by every emulated chip.
#[derive(Debug, Clone, Default)]
pub struct SimClock(Rc<Cell<f64>>);

impl SimClock {
    /// A clock at t = 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// The current time, s.
    pub fn now(&self) -> f64 {
        self.0.get()
    }

    /// Moves the clock to `t` (s).
    pub fn set(&self, t: f64) {
        self.0.set(t);
    }
}

/// A delay that returns at once: simulated time advances only with the [`SimClock`].
#[derive(Debug, Clone, Copy, Default)]
pub struct NoDelay;

impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}
