//! Faults applied to a measurement-level session log (seeded where random). Each returns
//! a new session; the header is kept.
use crate::io::session::{Pulse, Record, Session};
use crate::world::physics::V3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Removes every IMU sample in `[t0, t0 + len_s)` (the IMU stopped answering).
pub fn imu_dropout(s: &Session, t0: f64, len_s: f64) -> Session {
    let mut out = s.clone();
    out.records
        .retain(|r| !matches!(r, Record::Imu(x) if x.t >= t0 && x.t < t0 + len_s));
    out
}

/// Adds `extra_ut` (µT, body frame) to every magnetometer reading in `[t0, t0 + len_s)`:
/// metal near the receiver (a shovel, a probe, a phone).
pub fn mag_disturbance(s: &Session, t0: f64, len_s: f64, extra_ut: [f64; 3]) -> Session {
    let mut out = s.clone();
    for r in &mut out.records {
        if let Record::Imu(x) = r
            && x.t >= t0
            && x.t < t0 + len_s
            && let Some(m) = x.mag.as_mut()
        {
            for (mi, e) in m.iter_mut().zip(extra_ut) {
                *mi += e;
            }
        }
    }
    out
}

/// Drops each pulse with probability `p` (missed detections), seeded.
pub fn drop_pulses(s: &Session, p: f64, seed: u64) -> Session {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = s.clone();
    out.records
        .retain(|r| !matches!(r, Record::Pulse(_)) || !rng.random_bool(p));
    out
}

/// Inserts a spurious pulse (an EMI detection: random direction, a magnitude drawn
/// log-uniformly in `h_range` A/m) every `period_s` on average up to `until_s`, seeded.
pub fn spurious_pulses(
    s: &Session,
    period_s: f64,
    h_range: [f64; 2],
    until_s: f64,
    seed: u64,
) -> Session {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = s.clone();
    let (Some(first), Some(last)) = (s.records.first(), s.records.last()) else {
        return out;
    };
    let (t0, t1) = (first.t(), last.t().min(until_s));
    let mut t = t0 + rng.random_range(0.0..period_s);
    while t < t1 {
        let dir = V3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let mag = h_range[0] * (h_range[1] / h_range[0]).powf(rng.random::<f64>());
        let h = dir.normalize() * mag;
        let at = out.records.partition_point(|r| r.t() <= t);
        out.records.insert(
            at,
            Record::Pulse(Pulse {
                t: (t * 1e4).round() / 1e4,
                h: [h.x, h.y, h.z],
                src: None,
            }),
        );
        t += rng.random_range(0.5..1.5) * period_s;
    }
    out
}

/// Removes every pulse in `[t_off, t_on)`: the transmitter switched off (and on again at
/// `t_on`; `f64::INFINITY` for never).
pub fn transmitter_off(s: &Session, t_off: f64, t_on: f64) -> Session {
    let mut out = s.clone();
    out.records
        .retain(|r| !matches!(r, Record::Pulse(p) if p.t >= t_off && p.t < t_on));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::session::{Header, Imu};

    fn session() -> Session {
        let mut s = Session::new(Header::new(100.0, [21.0, 0.0, -42.0], true));
        for k in 0..1000 {
            let t = f64::from(k) * 0.01;
            s.records.push(Record::Imu(Imu {
                t,
                acc: [0.0, 0.0, 9.81],
                gyr: [0.0; 3],
                mag: Some([21.0, 0.0, -42.0]),
            }));
            if k % 100 == 50 {
                s.records.push(Record::Pulse(Pulse {
                    t,
                    h: [1e-6, 0.0, 0.0],
                    src: None,
                }));
            }
        }
        s
    }

    #[test]
    fn transforms_touch_only_their_window() {
        let s = session();
        assert_eq!(imu_dropout(&s, 2.0, 1.0).imu().count(), 900);
        let d = mag_disturbance(&s, 2.0, 1.0, [30.0, 0.0, 0.0]);
        let changed = d
            .imu()
            .filter(|x| x.mag.is_some_and(|m| (m[0] - 51.0).abs() < 1e-9))
            .count();
        assert_eq!(changed, 100);
        assert_eq!(transmitter_off(&s, 3.0, 6.0).pulses().count(), 7);
        let dropped = drop_pulses(&s, 0.5, 1).pulses().count();
        assert!(dropped < 10, "{dropped}");
        let spur = spurious_pulses(&s, 1.0, [1e-8, 1e-6], f64::INFINITY, 2);
        let n = spur.pulses().count();
        assert!((15..=25).contains(&n), "{n}");
        // Still time-ordered.
        assert!(spur.records.windows(2).all(|w| w[0].t() <= w[1].t()));
    }
}
