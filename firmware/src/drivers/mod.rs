//! Drivers for the receiver's chips, generic over the `embedded-hal` 1.0 traits.
//!
//! They run unchanged on the board (STM32 HAL types) and on the PC, where `hal-sim`
//! implements the same traits with emulated chips.
//!
//! - [`button`]: the mark button (active-low, debounced by polling).
//! - [`ads131m04`]: TI ADS131M04, the 4-channel simultaneous-sampling 24-bit ΔΣ ADC that
//!   digitises the three antenna coils' intermediate-frequency signals.
//! - [`imu`]: the BMI160 accelerometer + gyroscope and the LSM303AGR magnetometer on I2C
//!   (eldruin's `bmi160` and `lsm303agr` drivers), read in the body frame.

pub mod ads131m04;
pub mod button;
pub mod imu;

pub use button::MarkButton;
