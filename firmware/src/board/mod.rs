//! The board: one description of the reference design ([`profile`]) that the board binary
//! and `hal-sim`'s emulated board both read.

pub mod profile;

pub use profile::{
    AdcProfile, AnalogProfile, BoardProfile, Capacity, Defaults, IfRange, ImuProfile, REFERENCE,
    UnitTolerances,
};
