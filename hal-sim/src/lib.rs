//! Host-side simulator of the avalanche-beacon receiver's world and sensors.
#![deny(missing_docs)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod accuracy;
pub mod accuracy_bound;
pub mod baselines;
pub mod budget_data;
pub mod bus;
pub mod classic_loop;
pub mod closed_loop;
pub mod demo;
pub mod faults;
pub mod field_map;
pub mod inspect;
pub mod jet;
pub mod multi;
pub mod physics;
pub mod plot;
pub mod policies;
pub mod progress;
pub mod receiver_config;
pub mod replay;
pub mod rescue_report;
pub mod rescuer;
pub mod routes;
pub mod scenario;
pub mod sensing_report;
pub mod sensors;
pub mod session;
pub mod sidecar;
pub mod simulate;
pub mod sog_replay;
pub mod team;
pub mod transmitter;
pub mod world;

/// Simulated time (s since the start) as the firmware's time stamp, rounded to the µs
/// (the board's clock); a time before the start or not finite maps to the start.
pub fn stamp(t_s: f64) -> firmware::timebase::Instant {
    firmware::timebase::Instant::from_secs_f64(t_s).unwrap_or_default()
}
