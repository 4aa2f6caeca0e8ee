//! The board: one description of the reference design ([`profile`]) that the board binary
//! and `hal-sim`'s emulated board both read, its pin map ([`pins`]), and the hardware-free
//! parts of the board binary's supervision: the progress-checked watchdog feeder
//! ([`watchdog`]), the crash record kept across a reset ([`crash`]), the guarded and
//! recoverable I2C bus ([`i2c_bus`]) and its bounded master driver ([`i2c_master`]), the antenna ADC's bounded SPI master
//! ([`spi_master`]), the sensor-fault and battery display
//! ([`health`]), gain ranging applied and logged ([`gain`]), the guidance tones ([`sound`]) and the session log on the microSD card
//! ([`sd_log`]) with the device events a replay needs ([`board_log`]), the settings stored in flash
//! ([`settings`], kept safe against power cuts by [`settings_store`]) and the two-button menu that edits them ([`menu`])
//! with its calibration procedures ([`procedure`]). The processing task's logic, behind a
//! hardware trait, is [`process`]. The board binary's tasks hand records to the
//! log writer as [`log_item`]s and screens to the display task as [`view`]s; the buttons, the
//! menu and the tone are driven by [`controls`].

// The board's log lines (defmt over RTT, feature `defmt`): compiled out without it, the
// format and arguments still evaluated (by reference), so no binding goes unused.
#[cfg(feature = "defmt")]
macro_rules! log_info { ($($t:tt)*) => { defmt::info!($($t)*) }; }
#[cfg(feature = "defmt")]
macro_rules! log_warn { ($($t:tt)*) => { defmt::warn!($($t)*) }; }
#[cfg(feature = "defmt")]
macro_rules! log_error { ($($t:tt)*) => { defmt::error!($($t)*) }; }
#[cfg(not(feature = "defmt"))]
macro_rules! log_info { ($fmt:literal $(, $arg:expr)* $(,)?) => {{ let _ = $fmt; $(let _ = &$arg;)* }}; }
#[cfg(not(feature = "defmt"))]
macro_rules! log_warn { ($fmt:literal $(, $arg:expr)* $(,)?) => {{ let _ = $fmt; $(let _ = &$arg;)* }}; }
#[cfg(not(feature = "defmt"))]
macro_rules! log_error { ($fmt:literal $(, $arg:expr)* $(,)?) => {{ let _ = $fmt; $(let _ = &$arg;)* }}; }

pub mod board_log;
pub mod controls;
pub mod crash;
pub mod gain;
pub mod health;
pub mod i2c_bus;
pub mod i2c_master;
pub mod log_item;
pub mod menu;
pub mod pins;
pub mod procedure;
pub mod process;
pub mod profile;
pub mod schedule;
pub mod sd_log;
pub mod settings;
pub mod settings_store;
pub mod sound;
pub mod spi_master;
pub mod view;
pub mod watchdog;

pub use profile::{
    AdcProfile, AnalogProfile, BoardProfile, Capacity, Defaults, IfRange, ImuProfile, REFERENCE,
    UnitTolerances,
};
