//! A rescuer who stops walking: standing still, turning in place, or standing right
//! above the victim. The rescuer's route generator keeps walking, so these sessions are
//! made here: a straight walk of `walk_s` seconds (0.56 m steps at 1.8 Hz, the receiver
//! bobbing 2 cm per step) that ends at `receiver_p`, then standing there with the heading
//! following a turning schedule; the receiver held level; a 100 Hz IMU with white noise
//! and 1 Hz pulses of the dipole field (ICRA 2006 eq. 5) with the receiver's noise model,
//! reported with the largest component positive (sign-ambiguous, as the front end does).
//! From one standpoint alone the victim is not observable (three field components, six
//! unknowns: position and moment), hence the walk before the stop.
use crate::io::receiver_config::{Pdr, ReceiverConfig};
use crate::io::session::{Header, Imu, Pulse, Record, Session, Truth, TruthVictim};
use crate::world::physics::{V3, rotation_from_rpy};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::PI;

/// Earth field in W, µT (48 µT, 63° inclination).
pub const EARTH_UT: [f64; 3] = [21.791, 0.0, -42.768];
/// Standard gravity, m/s².
const G: f64 = 9.80665;
/// Step length (m, the receiver is calibrated to it) and cadence (Hz) of the walk.
pub const STEP_LENGTH_M: f64 = 0.56;
const CADENCE_HZ: f64 = 1.8;
/// Vertical bob of the receiver while walking, m.
const BOB_M: f64 = 0.02;

/// The receiver configuration of these sessions: defaults, calibrated step length.
pub fn receiver_config() -> ReceiverConfig {
    ReceiverConfig {
        pdr: Some(Pdr {
            step_length_m: STEP_LENGTH_M,
        }),
        ..ReceiverConfig::default()
    }
}

/// What the standing rescuer does.
#[derive(Debug, Clone, Copy)]
pub struct Stand {
    /// Transmitter position in W, m (snow surface at z = 0).
    pub victim: [f64; 3],
    /// Transmitter moment in W, A·m².
    pub moment: [f64; 3],
    /// Where the receiver stops, in W, m.
    pub receiver_p: [f64; 3],
    /// Heading of the walk and then while standing (before any turn), rad.
    pub yaw0: f64,
    /// Walking time before the stop, s.
    pub walk_s: f64,
    /// Turning in place: rate (rad/s) during `[turn_from_s, turn_to_s)`.
    pub turn_rate: f64,
    /// Start of the turn, s.
    pub turn_from_s: f64,
    /// End of the turn, s.
    pub turn_to_s: f64,
    /// Length of the session, s.
    pub duration_s: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Stand {
    /// A 40 s walk toward the north-east that stops 12 m south-east of a transmitter
    /// 1.5 m deep; the session lasts `duration_s` in all.
    pub fn still(duration_s: f64, seed: u64) -> Self {
        Self {
            victim: [0.0, 0.0, -1.5],
            moment: [0.008, 0.004, 0.002],
            receiver_p: [-8.0, -9.0, 1.0],
            yaw0: 0.6,
            walk_s: 40.0,
            turn_rate: 0.0,
            turn_from_s: 0.0,
            turn_to_s: 0.0,
            duration_s,
            seed,
        }
    }

    /// The heading at `t`, rad.
    pub fn yaw(&self, t: f64) -> f64 {
        let turning = (t.min(self.turn_to_s) - self.turn_from_s).max(0.0);
        self.yaw0 + self.turn_rate * turning
    }

    /// The receiver's position at `t`, m.
    pub fn position(&self, t: f64) -> V3 {
        let v = STEP_LENGTH_M * CADENCE_HZ;
        let back = v * (self.walk_s - t).max(0.0);
        V3::from(self.receiver_p) - V3::new(self.yaw0.cos(), self.yaw0.sin(), 0.0) * back
    }

    /// The true victim offset from the receiver (W axes) once it stands, m.
    pub fn offset(&self) -> V3 {
        V3::from(self.victim) - V3::from(self.receiver_p)
    }

    fn rate(&self, t: f64) -> f64 {
        if t >= self.turn_from_s && t < self.turn_to_s {
            self.turn_rate
        } else {
            0.0
        }
    }
}

fn gauss3(rng: &mut ChaCha8Rng, sigma: f64) -> V3 {
    V3::from_fn(|_, _| {
        let n: f64 = StandardNormal.sample(rng);
        sigma * n
    })
}

/// Field of a dipole `m` at offset `r` (from the dipole to the receiver), A/m.
fn dipole(r: &V3, m: &V3) -> V3 {
    let d = r.norm();
    let u = r / d;
    (3.0 * u * u.dot(m) - m) / (4.0 * PI * d * d * d)
}

/// The session log and its truth log (victim offset at every pulse).
pub fn session(spec: &Stand) -> (Session, Session) {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let header = Header::new(100.0, EARTH_UT, true);
    let (mut log, mut truth) = (Session::new(header.clone()), Session::new(header));
    let earth = V3::from(EARTH_UT);
    let n = (spec.duration_s * 100.0).floor() as u64;
    for k in 0..=n {
        let t = k as f64 / 100.0;
        let rot = rotation_from_rpy(&V3::new(0.0, 0.0, spec.yaw(t)));
        let w = 2.0 * PI * CADENCE_HZ;
        let bob = if t < spec.walk_s {
            -BOB_M * w * w * (w * t).cos()
        } else {
            0.0
        };
        let (acc, mag) = (
            rot.transpose() * V3::new(0.0, 0.0, G + bob),
            rot.transpose() * earth,
        );
        let acc = acc + gauss3(&mut rng, 0.03);
        let gyr = V3::new(0.0, 0.0, spec.rate(t)) + gauss3(&mut rng, 0.002);
        let mag = mag + gauss3(&mut rng, 0.3);
        log.records.push(Record::Imu(Imu {
            t,
            acc: acc.into(),
            gyr: gyr.into(),
            mag: Some(mag.into()),
        }));
        // A pulse at every half second past the whole second.
        if k % 100 == 50 {
            let p = spec.position(t);
            let h_w = dipole(&(p - V3::from(spec.victim)), &V3::from(spec.moment));
            let h = rot.transpose() * h_w;
            let sigma = (2.59e-9f64.powi(2) + (0.03 * h.norm()).powi(2)).sqrt();
            let h = h + gauss3(&mut rng, sigma);
            let largest = h
                .iter()
                .fold(0.0f64, |a, &x| if x.abs() > a.abs() { x } else { a });
            let h = if largest < 0.0 { -h } else { h };
            log.records.push(Record::Pulse(Pulse {
                t,
                h: h.into(),
                src: None,
            }));
            truth.records.push(Record::Truth(Truth {
                t,
                p: p.into(),
                rpy: [0.0, 0.0, spec.yaw(t)],
                victims: vec![TruthVictim {
                    p: spec.victim,
                    m: spec.moment,
                }],
            }));
        }
    }
    (log, truth)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_session_is_what_was_asked() {
        let mut spec = Stand::still(10.0, 3);
        spec.turn_rate = 0.5;
        spec.turn_from_s = 2.0;
        spec.turn_to_s = 4.0;
        spec.walk_s = 5.0;
        assert!(((spec.position(0.0) - spec.position(5.0)).norm() - 5.0 * 1.008).abs() < 1e-9);
        assert_eq!(spec.position(7.0), V3::from(spec.receiver_p));
        assert!((spec.yaw(10.0) - spec.yaw0 - 1.0).abs() < 1e-12);
        let (log, truth) = session(&spec);
        assert_eq!(log.imu().count(), 1001);
        assert_eq!(log.pulses().count(), 10);
        assert_eq!(truth.truth().count(), 10);
        // The dipole field on its axis: 2m/(4πr³).
        let h = dipole(&V3::new(0.0, 0.0, 2.0), &V3::new(0.0, 0.0, 0.01));
        assert!((h.z - 2.0 * 0.01 / (4.0 * PI * 8.0)).abs() < 1e-15);
    }
}
