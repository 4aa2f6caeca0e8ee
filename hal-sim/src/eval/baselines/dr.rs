//! Dead reckoning shared by the batch baselines: the receiver's poses in a world frame
//! fixed at the first pulse, from the per-pulse [`Displacement`] and [`Attitude`] the
//! SOGs filter gets, and the checks every baseline applies to its inputs.
use crate::world::physics::{M3, V3, rotation_from_rpy};
use firmware::estimate::{
    Attitude, Displacement, EstimateError, Pulse, StepOutcome, StepReport, VictimEstimate,
};

/// Largest displacement between two pulses accepted, m (a pulse period at a run is < 10 m).
const MAX_STEP_M: f64 = 1e3;
/// Largest angle accepted, rad.
const MAX_ANGLE_RAD: f64 = 1e3;

/// One pulse, checked and expressed in the dead-reckoning world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPulse {
    /// Receiver position (dead-reckoned), m; the first pulse's receiver is the origin.
    pub p: V3,
    /// Receiver orientation `R_WR` from the attitude of this pulse.
    pub rot: M3,
    /// Field in world axes (`R_WR h`), A/m, sign as received.
    pub h: V3,
    /// Pulse time, s.
    pub t: f64,
}

/// Dead-reckoned receiver pose: `p_k = p_{k-1} + R_{k-1} (t_k + a_k)` where `t_k` is the
/// dead-reckoned translation in `R_{k-1}` axes, `a_k` its absolute part and `R_{k-1}` the
/// absolute attitude measured at the previous pulse (the magnetometer's heading does not
/// drift, unlike composed gyro increments).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DeadReckoning {
    last: Option<WorldPulse>,
}

/// The report of a batch baseline's accepted pulse: one hypothesis, `Initialized` on the
/// first pulse and `Updated` after (these fits have no gating, pruning or merging).
pub(crate) fn single_report(first: bool) -> StepReport {
    StepReport {
        outcome: if first {
            StepOutcome::Initialized
        } else {
            StepOutcome::Updated
        },
        n_components: 1,
        best_d2: 0.0,
        pruned: 0,
        merged: 0,
        split: 0,
        dropped: 0,
    }
}

/// The estimate of a batch baseline: one hypothesis at `rel` (m, from the receiver, world
/// axes) with covariance `cov` and moment `moment`, unit scale, the last attitude `rpy`.
pub(crate) fn single_estimate(
    rel: &V3,
    cov: firmware::Mat3,
    moment: firmware::Vec3,
    rpy: firmware::Vec3,
) -> VictimEstimate {
    VictimEstimate {
        p: crate::world::physics::to_f32(rel),
        cov,
        moment,
        scale: 1.0,
        scale_sigma: 0.0,
        rpy,
        n_components: 1,
        max_weight: 1.0,
    }
}

fn v3(v: &firmware::Vec3) -> V3 {
    V3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z))
}

impl DeadReckoning {
    /// Forgets the poses; the next pulse is the origin again.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// The last accepted pulse.
    pub fn last(&self) -> Option<&WorldPulse> {
        self.last.as_ref()
    }

    /// Checks the inputs of one step and returns the pulse in the world frame, without
    /// committing it (see [`DeadReckoning::commit`]): a refused input leaves the state
    /// intact. `h_saturation` is the receiver's clipping level (A/m).
    pub fn peek(
        &self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
        h_saturation: f64,
    ) -> Result<WorldPulse, EstimateError> {
        let h = v3(&pulse.h);
        let t = f64::from(pulse.t);
        let rpy = v3(&attitude.rpy);
        if !h.iter().chain(rpy.iter()).all(|x| x.is_finite()) || !t.is_finite() {
            return Err(EstimateError::NonFinite);
        }
        if h == V3::zeros() {
            return Err(EstimateError::ZeroField);
        }
        if h.amax() >= h_saturation {
            return Err(EstimateError::Saturated);
        }
        if rpy.amax() > MAX_ANGLE_RAD {
            return Err(EstimateError::OutOfRange);
        }
        let rot = rotation_from_rpy(&rpy);
        let p = match &self.last {
            None => V3::zeros(),
            Some(last) => {
                if t < last.t {
                    return Err(EstimateError::TimeWentBackwards);
                }
                let step = v3(&motion.translation) + v3(&motion.absolute);
                if !step.iter().all(|x| x.is_finite()) {
                    return Err(EstimateError::NonFinite);
                }
                if step.amax() > MAX_STEP_M {
                    return Err(EstimateError::OutOfRange);
                }
                last.p + last.rot * step
            }
        };
        Ok(WorldPulse {
            p,
            rot,
            h: rot * h,
            t,
        })
    }

    /// Makes `pulse` (from [`DeadReckoning::peek`]) the current pose.
    pub fn commit(&mut self, pulse: WorldPulse) {
        self.last = Some(pulse);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::frame::Rpy;

    fn pulse(h: [f32; 3], t: f32) -> Pulse {
        Pulse {
            h: firmware::Vec3::new(h[0], h[1], h[2]),
            t,
        }
    }

    #[test]
    fn integrates_translation_in_the_previous_attitude() {
        let mut dr = DeadReckoning::default();
        // Facing west (yaw 90°): a step "forward" in R goes to +y (west) in W.
        let att = Attitude::with_sigmas(Rpy::new(0.0, 0.0, std::f32::consts::FRAC_PI_2), 0.0, 0.0);
        let still = Displacement::zero();
        let p0 = dr
            .peek(&still, &att, &pulse([1e-6, 0.0, 0.0], 0.0), 1.0)
            .unwrap();
        assert!(p0.p.norm() < 1e-12);
        // The field along R's x is along W's y.
        assert!((p0.h - V3::new(0.0, 1e-6, 0.0)).norm() < 1e-12);
        dr.commit(p0);
        let step =
            Displacement::with_sigmas(firmware::Vec3::new(2.0, 0.0, 0.0), Rpy::zeros(), 0.0, 0.0);
        let p1 = dr
            .peek(&step, &att, &pulse([1e-6, 0.0, 0.0], 1.0), 1.0)
            .unwrap();
        assert!((p1.p - V3::new(0.0, 2.0, 0.0)).norm() < 1e-6, "{}", p1.p);
    }

    #[test]
    fn refuses_bad_input_without_changing_state() {
        let mut dr = DeadReckoning::default();
        let att = Attitude::with_sigmas(Rpy::zeros(), 0.0, 0.0);
        let z = Displacement::zero();
        let ok = dr
            .peek(&z, &att, &pulse([1e-6, 0.0, 0.0], 5.0), 1.0)
            .unwrap();
        dr.commit(ok);
        let before = dr.clone();
        let cases = [
            (pulse([f32::NAN, 0.0, 0.0], 6.0), EstimateError::NonFinite),
            (pulse([0.0, 0.0, 0.0], 6.0), EstimateError::ZeroField),
            (pulse([2.0, 0.0, 0.0], 6.0), EstimateError::Saturated),
            (
                pulse([1e-6, 0.0, 0.0], 4.0),
                EstimateError::TimeWentBackwards,
            ),
        ];
        for (p, want) in cases {
            assert_eq!(dr.peek(&z, &att, &p, 1.0), Err(want));
        }
        let far =
            Displacement::with_sigmas(firmware::Vec3::new(1e30, 0.0, 0.0), Rpy::zeros(), 0.0, 0.0);
        assert_eq!(
            dr.peek(&far, &att, &pulse([1e-6, 0.0, 0.0], 6.0), 1.0),
            Err(EstimateError::OutOfRange)
        );
        assert_eq!(dr, before);
    }
}
