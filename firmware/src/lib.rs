//! Firmware library of a three-axis avalanche-beacon receiver.
//!
//! A buried victim's beacon is a magnetic dipole pulsing at 457 kHz about once a second.
//! This crate turns the receiver's antenna pulses and IMU samples into an estimate of the
//! victim's position relative to the rescuer (robocentric Sum-of-Gaussians filter,
//! Piniés, Tardós & Neira, IROS 2006) and into guidance for the rescuer.
//!
//! It is `no_std`, allocation-free and `f32` throughout, so the same code runs on the
//! Cortex-M4F board and, fed by `hal-sim`, on a PC.
//!
//! Modules:
//! - [`frame`]: rotations and the frame conventions of the session-log spec
//!   (body x-forward/y-left/z-up; geographic x-north/y-west/z-up;
//!   `R = Rz(yaw) Ry(pitch) Rx(roll)`).
//! - [`dipole`]: the magnetic dipole field, its Jacobians, its inverse and the range
//!   bounds implied by a field magnitude.
//! - [`board`]: the reference board's profile (analog chain, ADC, IMU mounting,
//!   capacities, defaults), read by the board binary and by `hal-sim`.
//! - [`calibration`]: calibration a unit can do (magnetometer from a rotation in place)
//!   and the record it keeps.
//! - [`drivers`]: chip drivers generic over `embedded-hal` 1.0 (the antenna ADC).
//! - [`frontend`]: antenna pulse DSP — detection, I/Q demodulation, field vector per
//!   pulse, transmitter separation.
//! - [`motion`]: attitude filter, step detection and pedestrian dead reckoning (Kleiner et
//!   al. eq. 1–3), the displacement between pulses with its covariance (IROS 2006 eq. 4).
//! - [`session_log`]: the session-log writer (spec `arva-session` v1) the board streams.
//! - [`timebase`]: the board's clock from the ADC's sample count, with a stalled-ADC
//!   watchdog.
//! - [`estimate`]: the [`estimate::Estimator`] trait and the robocentric Sum-of-Gaussians
//!   filter [`estimate::SogFilter`] (IROS 2006 Algorithm 1; ICRA 2006 known trajectory).
//! - [`guidance`]: search control (IROS 2006 §III-C, ICRA 2006 §V-D): flux line, then the
//!   mixture mean, fine search and "probe here"; [`guidance::classic`], the receiver's
//!   "classic" mode (the classical directional search, ICRA 2006 §II-A).
//! - [`victims`]: several transmitters — one SOGs mixture per victim, displacement
//!   composition between a victim's pulses, the victim list.
//! - [`app`]: the application state machine [`app::Receiver`] that owns the pipeline.
//! - [`display`]: draws the [`app::DisplayModel`] on any 128×64 monochrome
//!   `embedded-graphics` target.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
// No panic reachable from sensor data (README "Reliability"): no unwrap/expect/panic!
// and no panicking `[]` indexing or slicing outside tests...
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing
    )
)]

pub mod app;
pub mod board;
pub mod calibration;
pub mod dipole;
pub mod display;
pub mod drivers;
// ...except in the filter and motion math, whose 148 `[]` sites (estimate 103, motion
// 41, guidance 4) index fixed-size nalgebra matrices and arrays with constant or
// loop-bounded indices, never with a value from sensor data; rewriting them with `.get()`
// would obscure the equations. Their inputs are covered by the fuzz targets instead.
#[cfg_attr(not(test), allow(clippy::indexing_slicing))]
pub mod estimate;
pub mod frame;
pub mod frontend;
#[cfg_attr(not(test), allow(clippy::indexing_slicing))]
pub mod guidance;
#[cfg_attr(not(test), allow(clippy::indexing_slicing))]
pub mod motion;
pub mod session_log;
pub mod timebase;
pub mod victims;

// The path of before `classic` moved under `guidance`, kept while parallel branches land.
#[doc(hidden)]
pub use guidance::classic;

/// The linear-algebra crate used in this crate's public API, re-exported so that users
/// do not end up with two versions of nalgebra.
pub use nalgebra;

/// A 3-vector of `f32` (positions in m, fields in A/m, moments in A·m², angles in rad).
pub type Vec3 = nalgebra::Vector3<f32>;
/// A 3×3 matrix of `f32` (rotations, Jacobians, covariances).
pub type Mat3 = nalgebra::Matrix3<f32>;
