//! Fault injection: the receiver's world when it is not the simulator's default.
//!
//! Every fault has a defined behaviour of the firmware (an error value, what the display
//! shows, how it recovers), checked by a seeded test that drives the real
//! [`firmware::app::Receiver`] (`tests/tests/faults.rs`, and the unit tests here):
//!
//! - [`bus`]: at the chips' buses, under the firmware's real drivers: SPI errors and
//!   timeouts and corrupted frames of the antenna ADC, I2C errors and timeouts of the IMU
//!   chips, ADC saturation and EMI bursts in the analog signal;
//! - [`measurement`]: on a measurement-level session log: dropped and spurious pulses,
//!   IMU dropouts, magnetometer disturbance (metal nearby), a transmitter switching off;
//! - [`stationary`]: a rescuer standing still, turning in place, or standing right above
//!   the victim;
//! - [`drive`]: runs a session through the application and records what it showed;
//! - [`consistency`]: NEES of the whole pipeline over seeded searches
//!   (`hal-sim consistency`).
//!
//! The table of faults and behaviours is in `hal-sim/reports/reliability.md`.
pub mod bus;
pub mod consistency;
pub mod drive;
pub mod measurement;
pub mod stationary;
