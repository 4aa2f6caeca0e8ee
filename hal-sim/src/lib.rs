//! Host-side simulator of the avalanche-beacon receiver's world and sensors.
//!
//! Laid out by role, each layer using only the ones above it in this list:
//! - [`world`]: the `f64` truth — physics, transmitters, the walking rescuer, routes, scenarios;
//! - [`sensors`]: what the receiver's chips see — measurement-level models, the bus-level
//!   chip emulation ([`sensors::bus`]) and fault injection ([`sensors::faults`]);
//! - [`policies`]: rescuer behaviours that are not the firmware's (the idealized directional search);
//! - [`sim`]: the closed loops (single victim, classic mode, multiple victims) and `simulate`;
//! - [`team`]: team searches (several rescuers' logs joined into one map);
//! - [`io`]: session logs, `receiver.json`, `inspect` and `replay`;
//! - [`eval`]: the reports (accuracy, rescue, sensing, baselines), their sidecars and figures;
//! - [`cli`]: what only the command line needs (progress bars, the demo, the field map).
#![deny(missing_docs)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod cli;
pub mod eval;
pub mod io;
pub mod policies;
pub mod sensors;
pub mod sim;
pub mod team;
pub mod world;

/// Simulated time (s since the start) as the firmware's time stamp, rounded to the µs
/// (the board's clock); a time before the start or not finite maps to the start.
pub fn stamp(t_s: f64) -> firmware::timebase::Instant {
    firmware::timebase::Instant::from_secs_f64(t_s).unwrap_or_default()
}
