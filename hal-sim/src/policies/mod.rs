//! Rescuer policies: who decides where the simulated rescuer goes, independent of how the
//! rescuer and the receiver are simulated.
pub mod directional;
