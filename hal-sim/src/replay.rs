//! `hal-sim replay`: runs an estimator over a session log and writes the spec's replay
//! JSON Lines, one line per pulse.
//!
//! The estimator is a plug-in behind [`Estimator`]; [`estimator_for`] is the single place
//! that chooses it: the firmware's pipeline. [`NoEstimator`] (empty `victims`) remains for
//! tests of the output format.
use crate::receiver_config::ReceiverConfig;
use crate::session::{Header, Imu, Pulse, Record, Session};
use serde::{Deserialize, Serialize};
use std::io::Write;

/// One victim in a replay line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VictimEstimate {
    /// Estimated position relative to the receiver in G_k (north, west, up), m.
    pub p: [f64; 3],
    /// Covariance of `p`, row-major, m².
    pub cov: [f64; 9],
    /// Straight-line distance to the estimate, m.
    pub dist_m: f64,
    /// Horizontal bearing of the estimate relative to the device's yaw, positive to the
    /// left, degrees in (-180, 180].
    pub dir_deg: f64,
}

impl VictimEstimate {
    /// Fills `dist_m` and `dir_deg` from `p` and the device's yaw (rad).
    pub fn new(p: [f64; 3], cov: [f64; 9], yaw_rad: f64) -> Self {
        let dist_m = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let dir = crate::rescuer::wrap_pi(p[1].atan2(p[0]) - yaw_rad).to_degrees();
        Self {
            p,
            cov,
            dist_m,
            dir_deg: if dir <= -180.0 { 180.0 } else { dir },
        }
    }
}

/// One line of replay output (one processed pulse).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayLine {
    /// Time of the pulse, s.
    pub t: f64,
    /// Number of mixture components alive.
    pub n_components: u32,
    /// Guidance arrow, degrees, positive to the left.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrow_deg: Option<f64>,
    /// Display status word.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
    /// Current estimate per victim; empty before initialization.
    pub victims: Vec<VictimEstimate>,
}

/// An estimator fed by a replayed log.
pub trait Estimator {
    /// Consumes an IMU sample.
    fn on_imu(&mut self, imu: &Imu);
    /// Consumes a pulse and reports the state after it.
    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine;
}

/// The placeholder estimator: no estimate, empty `victims`.
#[derive(Debug, Default, Clone)]
pub struct NoEstimator;

impl Estimator for NoEstimator {
    fn on_imu(&mut self, _imu: &Imu) {}

    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine {
        ReplayLine {
            t: pulse.t,
            n_components: 0,
            arrow_deg: None,
            status: None,
            victims: Vec::new(),
        }
    }
}

/// The estimator `replay` uses for a log with this header and receiver configuration:
/// the firmware's motion + SOGs pipeline ([`crate::sog_replay::SogReplay`]).
pub fn estimator_for(
    header: &Header,
    receiver: &ReceiverConfig,
) -> anyhow::Result<Box<dyn Estimator>> {
    Ok(Box::new(crate::sog_replay::SogReplay::new(
        header, receiver,
    )?))
}

/// Replays `session` through the estimator [`estimator_for`] picks for it and `receiver`,
/// writing the replay JSON Lines to `out`. Returns the number of lines written.
pub fn replay_with_config(
    session: &Session,
    receiver: &ReceiverConfig,
    out: &mut impl Write,
) -> anyhow::Result<usize> {
    let mut estimator = estimator_for(&session.header, receiver)?;
    replay(session, estimator.as_mut(), out, |_| {})
}

/// Feeds every record of `session` to `estimator` in order and writes one JSON line per
/// pulse to `out`; `on_record` is called after each record (for progress). Truth records
/// are never passed on. Returns the number of lines written.
pub fn replay(
    session: &Session,
    estimator: &mut dyn Estimator,
    out: &mut impl Write,
    mut on_record: impl FnMut(usize),
) -> anyhow::Result<usize> {
    let mut lines = 0;
    for (i, r) in session.records.iter().enumerate() {
        match r {
            Record::Imu(x) => estimator.on_imu(x),
            Record::Pulse(p) => {
                let line = estimator.on_pulse(p);
                serde_json::to_writer(&mut *out, &line)?;
                out.write_all(b"\n")?;
                lines += 1;
            }
            Record::Truth(_) => {}
        }
        on_record(i);
    }
    out.flush()?;
    Ok(lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn direction_convention() {
        // Victim to the west while facing north: 90° to the left.
        let v = VictimEstimate::new([0.0, 10.0, 0.0], [0.0; 9], 0.0);
        assert!((v.dir_deg - 90.0).abs() < 1e-9 && (v.dist_m - 10.0).abs() < 1e-12);
        // Facing west, a victim to the north is 90° to the right.
        let v = VictimEstimate::new([5.0, 0.0, -1.0], [0.0; 9], std::f64::consts::FRAC_PI_2);
        assert!((v.dir_deg + 90.0).abs() < 1e-9);
        let v = VictimEstimate::new([-5.0, 0.0, 0.0], [0.0; 9], 0.0);
        assert_eq!(v.dir_deg, 180.0);
    }
}
