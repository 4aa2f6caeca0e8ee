//! The board: one description of the reference design ([`profile`]) that the board binary
//! and `hal-sim`'s emulated board both read, its pin map ([`pins`]), and the hardware-free
//! parts of the board binary's supervision: the progress-checked watchdog feeder
//! ([`watchdog`]) and the crash record kept across a reset ([`crash`]).

pub mod crash;
pub mod i2c_bus;
pub mod pins;
pub mod profile;
pub mod watchdog;

pub use profile::{
    AdcProfile, AnalogProfile, BoardProfile, Capacity, Defaults, IfRange, ImuProfile, REFERENCE,
    UnitTolerances,
};
