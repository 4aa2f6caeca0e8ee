//! The simulated world: buried transmitters, the walking rescuer and the Earth's field,
//! with continuous-time truth queries that sensor models (measurement-level now,
//! bus-level chip emulations later) sample.
use crate::physics::V3;
use crate::rescuer::{Rescuer, RescuerState};
use crate::transmitter::Transmitter;

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
