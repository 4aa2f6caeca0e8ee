//! The checked-in reports: each runs seeded simulations through the firmware and renders
//! markdown (and figures), with a machine-readable sidecar that the staleness test re-runs.

pub mod accuracy;
pub mod accuracy_bound;
pub mod baselines;
pub mod budget_data;
pub mod detection_report;
pub mod multi_report;
pub mod plot;
pub mod rescue_report;
pub mod sensing_report;
pub mod sidecar;
