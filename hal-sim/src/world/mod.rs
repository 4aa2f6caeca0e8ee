//! The simulated world: buried transmitters, the walking rescuer and the Earth's field,
//! with continuous-time truth queries that sensor models (measurement-level now,
//! bus-level chip emulations later) sample.

pub mod jet;
pub mod physics;
pub mod rescuer;
pub mod routes;
pub mod scenario;
pub mod transmitter;
use crate::io::session::{Record, Truth, TruthVictim};
use crate::sensors::quantize;
use crate::world::physics::V3;
use crate::world::rescuer::{Rescuer, RescuerState, wrap_pi};
use crate::world::transmitter::Transmitter;

/// The Earth's field in W (µT) from its total intensity (µT) and inclination (degrees,
/// positive downward), with declination folded into W's north axis.
pub fn earth_field_ut(total_ut: f64, inclination_deg: f64) -> [f64; 3] {
    let i = inclination_deg.to_radians();
    [total_ut * i.cos(), 0.0, -total_ut * i.sin()]
}

/// Everything that exists in one search.
#[derive(Debug, Clone)]
pub struct World {
    /// The buried transmitters (usually one).
    pub transmitters: Vec<Transmitter>,
    /// The rescuer's walk.
    pub rescuer: Rescuer,
    /// Earth's magnetic flux density in W, µT.
    pub earth_field_ut: [f64; 3],
}

impl World {
    /// Every transmitter's pulse centres in `[0, duration)` as `(time, transmitter)`,
    /// times quantized to 0.1 ms as the logs write them, in time order (ties by index).
    pub fn pulse_schedule(&self, duration: f64) -> Vec<(f64, usize)> {
        let mut times: Vec<(f64, usize)> = Vec::new();
        for (i, tx) in self.transmitters.iter().enumerate() {
            times.extend(
                tx.pulse_centres(0.0, duration)
                    .into_iter()
                    .map(|t| (quantize(t, 1e4), i)),
            );
        }
        times.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        times
    }

    /// Truth records (the spec's ground truth) at `hz` over `[0, duration]` and at the
    /// `extra` true times, in time order without repeats; `log_time` maps a true time to
    /// the log's clock.
    pub fn truth_records(
        &self,
        hz: f64,
        duration: f64,
        extra: impl IntoIterator<Item = f64>,
        log_time: impl Fn(f64) -> f64,
    ) -> Vec<Record> {
        let victims: Vec<TruthVictim> = self
            .transmitters
            .iter()
            .map(|tx| TruthVictim {
                p: tx.position,
                m: tx.moment,
            })
            .collect();
        let n = (duration * hz).floor() as u64;
        let mut times: Vec<f64> = (0..=n).map(|k| k as f64 / hz).collect();
        times.extend(extra);
        times.sort_by(f64::total_cmp);
        times.dedup();
        times
            .into_iter()
            .map(|t| {
                let s = self.rescuer_state(t);
                Record::Truth(Truth {
                    t: log_time(t),
                    p: [s.p.x, s.p.y, s.p.z].map(|x| quantize(x, 1e4)),
                    rpy: [s.rpy.x, s.rpy.y, wrap_pi(s.rpy.z)].map(|x| quantize(x, 1e5)),
                    victims: victims.clone(),
                })
            })
            .collect()
    }

    /// The rescuer's (receiver's) full motion state at `t`.
    pub fn rescuer_state(&self, t: f64) -> RescuerState {
        self.rescuer.state(t)
    }

    /// Field of transmitter `i` in W at the receiver at `t`, A/m, whether or not it is on;
    /// `None` for a bad index or within 5 cm of the antenna.
    pub fn field_world(&self, i: usize, t: f64) -> Option<V3> {
        self.transmitters.get(i)?.field_at(&self.rescuer.state(t).p)
    }

    /// Field of transmitter `i` at the receiver at `t` in the body frame R, A/m.
    pub fn field_body(&self, i: usize, t: f64) -> Option<V3> {
        let s = self.rescuer.state(t);
        let h = self.transmitters.get(i)?.field_at(&s.p)?;
        Some(s.rot.transpose() * h)
    }

    /// Whether transmitter `i` is emitting at `t`.
    pub fn transmitter_on(&self, i: usize, t: f64) -> bool {
        self.transmitters.get(i).is_some_and(|tx| tx.is_on(t))
    }

    /// Earth's field in the body frame at `t`, µT.
    pub fn earth_field_body(&self, t: f64) -> V3 {
        self.rescuer.state(t).rot.transpose() * V3::from(self.earth_field_ut)
    }

    /// Time at which the rescuer's plan is complete, s.
    pub fn end_s(&self) -> f64 {
        self.rescuer.end_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_earth_field() {
        let b = earth_field_ut(48.0, 63.0);
        assert!((V3::from(b).norm() - 48.0).abs() < 1e-12);
        assert!(b[0] > 21.0 && b[0] < 22.0 && b[2] < -42.0 && b[2] > -43.0);
    }
}
