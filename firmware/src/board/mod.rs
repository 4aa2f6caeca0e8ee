//! The board: one description of the reference design ([`profile`]) that the board binary
//! and `hal-sim`'s emulated board both read, its pin map ([`pins`]), and the hardware-free
//! parts of the board binary's supervision: the progress-checked watchdog feeder
//! ([`watchdog`]), the crash record kept across a reset ([`crash`]), the guarded and
//! recoverable I2C bus ([`i2c_bus`]) and its bounded master driver ([`i2c_master`]), the sensor-fault and battery display
//! ([`health`]), gain ranging applied and logged ([`gain`]), the guidance tones ([`sound`]) and the session log on the microSD card
//! ([`sd_log`]) with the device events a replay needs ([`board_log`]), the settings stored in flash
//! ([`settings`], kept safe against power cuts by [`settings_store`]) and the two-button menu that edits them ([`menu`])
//! with its calibration procedures ([`procedure`]). The board binary's tasks hand records to the
//! log writer as [`log_item`]s and screens to the display task as [`view`]s; the buttons, the
//! menu and the tone are driven by [`controls`].

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
pub mod profile;
pub mod schedule;
pub mod sd_log;
pub mod settings;
pub mod settings_store;
pub mod sound;
pub mod view;
pub mod watchdog;

pub use profile::{
    AdcProfile, AnalogProfile, BoardProfile, Capacity, Defaults, IfRange, ImuProfile, REFERENCE,
    UnitTolerances,
};
