//! Calibration a built unit can do on itself or on the bench, and the record it keeps.
//!
//! - [`mag`]: magnetometer hard- and soft-iron from a rotation in place (ellipsoid fit).
//! - [`antenna`]: the antenna coils' gain and phase from a reference transmitter at known
//!   poses on the bench (`docs/antenna-bench-calibration.md`).
//! - [`record`]: the versioned, CRC-protected record a unit stores in flash.

pub mod antenna;
pub mod mag;
pub mod record;

pub use antenna::{AntennaCalibrator, AntennaFit, AntennaFitError};
pub use mag::{MagCalibrator, MagFit, MagFitError};
pub use record::{CalibrationRecord, RECORD_LEN, RECORD_VERSION, RecordError};
