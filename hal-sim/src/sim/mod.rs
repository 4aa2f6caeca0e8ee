//! The simulated searches: one rescuer closed loop per receiver mode (SOG single victim,
//! classic mode, multiple victims) and the open-loop `simulate` generator.

pub mod classic_loop;
pub mod closed_loop;
pub mod multi;
pub mod simulate;
