//! Open-loop route families a rescuer may walk: a straight line with a miss distance, a
//! circular arc, the classical flux-line search and a zig-zag strip search. Each returns
//! waypoints on the snow surface (north, west) starting from the rescuer's start point.
use crate::world::physics::V3;
use crate::world::rescuer::Waypoint;
use crate::world::transmitter::Transmitter;
use rand::Rng;
use std::f64::consts::TAU;

/// Spacing of the waypoints along smooth routes, m.
pub const SPACING_M: f64 = 5.0;

/// Random short stops along a route: each waypoint is a stop with this probability.
#[derive(Debug, Clone, Copy)]
pub struct Stops {
    /// Probability that a waypoint is a stop.
    pub probability: f64,
    /// Range of stop durations, s.
    pub duration_s: [f64; 2],
}

impl Stops {
    /// Stops about every 25 m, 1.5–4 s long.
    pub const DEFAULT: Stops = Stops {
        probability: 0.2,
        duration_s: [1.5, 4.0],
    };
    /// No stops.
    pub const NONE: Stops = Stops {
        probability: 0.0,
        duration_s: [0.0, 0.0],
    };

    fn draw(&self, rng: &mut impl Rng) -> f64 {
        if self.probability > 0.0 && rng.random::<f64>() < self.probability {
            rng.random_range(self.duration_s[0]..=self.duration_s[1])
        } else {
            0.0
        }
    }
}

fn sample_polyline(
    rng: &mut impl Rng,
    points: &[[f64; 2]],
    stops: Stops,
    final_stop_s: f64,
) -> Vec<Waypoint> {
    let mut out: Vec<Waypoint> = points
        .iter()
        .map(|&p| Waypoint {
            p,
            stop_s: stops.draw(rng),
        })
        .collect();
    if let Some(last) = out.last_mut() {
        last.stop_s = final_stop_s;
    }
    out
}

/// Points every `SPACING_M` from `a` to `b` (excluding `a`, including `b`).
fn segment(a: [f64; 2], b: [f64; 2]) -> Vec<[f64; 2]> {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let n = (dx.hypot(dy) / SPACING_M).ceil().max(1.0) as usize;
    (1..=n)
        .map(|i| {
            let f = i as f64 / n as f64;
            [a[0] + f * dx, a[1] + f * dy]
        })
        .collect()
}

/// A straight line from `start` passing `miss_m` to the left (negative: right) of the
/// `target` point and continuing `overshoot_m` beyond the closest approach.
pub fn line(
    rng: &mut impl Rng,
    start: [f64; 2],
    target: [f64; 2],
    miss_m: f64,
    overshoot_m: f64,
    stops: Stops,
) -> Vec<Waypoint> {
    let d = V3::new(target[0] - start[0], target[1] - start[1], 0.0);
    let dist = d.norm().max(1e-6);
    let u = d / dist;
    let left = V3::new(-u.y, u.x, 0.0);
    let aim = V3::new(target[0], target[1], 0.0) + left * miss_m;
    let dir = (aim - V3::new(start[0], start[1], 0.0)).normalize();
    let along = (aim - V3::new(start[0], start[1], 0.0)).norm() + overshoot_m;
    let end = [start[0] + dir.x * along, start[1] + dir.y * along];
    sample_polyline(rng, &segment(start, end), stops, 2.0)
}

/// A circular arc from `start` to `target`, leaving at `angle_rad` to the left of the
/// straight bearing (negative: right) and ending at the target.
pub fn arc(
    rng: &mut impl Rng,
    start: [f64; 2],
    target: [f64; 2],
    angle_rad: f64,
    stops: Stops,
) -> Vec<Waypoint> {
    let (dx, dy) = (target[0] - start[0], target[1] - start[1]);
    let chord = dx.hypot(dy);
    let bearing = dy.atan2(dx);
    let a = angle_rad.clamp(-1.4, 1.4);
    if a.abs() < 1e-3 {
        return sample_polyline(rng, &segment(start, target), stops, 2.0);
    }
    let length = chord * a / a.sin();
    let kappa = -2.0 * a / length;
    let h0 = bearing + a;
    let n = (length / SPACING_M).ceil().max(1.0) as usize;
    let pts: Vec<[f64; 2]> = (1..=n)
        .map(|i| {
            let s = length * i as f64 / n as f64;
            let h = h0 + kappa * s;
            [
                start[0] + (h.sin() - h0.sin()) / kappa,
                start[1] - (h.cos() - h0.cos()) / kappa,
            ]
        })
        .collect();
    sample_polyline(rng, &pts, stops, 2.0)
}

/// The classical flux-line search: follow the horizontal direction of the field at
/// receiver height `height_m`, in the sense in which |H| grows, in 1 m steps, until within
/// 1.5 m (horizontally) of the transmitter; then walk onto it. At most `max_len_m` long.
pub fn flux_line(
    rng: &mut impl Rng,
    start: [f64; 2],
    tx: &Transmitter,
    height_m: f64,
    max_len_m: f64,
    stops: Stops,
) -> Vec<Waypoint> {
    let target = [tx.position[0], tx.position[1]];
    let mut p = V3::new(start[0], start[1], height_m);
    let mut prev: Option<V3> = None;
    let mut pts = Vec::new();
    let mut walked = 0.0;
    let step = 1.0;
    while walked < max_len_m {
        let to_tx = V3::new(target[0] - p.x, target[1] - p.y, 0.0);
        if to_tx.norm() < 1.5 {
            break;
        }
        let Some(h) = tx.field_at(&p) else { break };
        let hz = V3::new(h.x, h.y, 0.0);
        let mut d = if hz.norm() > 0.0 {
            hz.normalize()
        } else {
            to_tx.normalize()
        };
        let sense = match prev {
            Some(q) => d.dot(&q),
            None => {
                let fwd = tx.field_at(&(p + d * 0.5)).map_or(0.0, |x| x.norm());
                let back = tx.field_at(&(p - d * 0.5)).map_or(0.0, |x| x.norm());
                fwd - back
            }
        };
        if sense < 0.0 {
            d = -d;
        }
        p += d * step;
        walked += step;
        prev = Some(d);
        pts.push([p.x, p.y]);
    }
    // Thin to the waypoint spacing, then finish on the transmitter.
    let stride = SPACING_M.round().max(1.0) as usize;
    let mut thin: Vec<[f64; 2]> = pts
        .iter()
        .skip(stride - 1)
        .step_by(stride)
        .copied()
        .collect();
    thin.push(target);
    sample_polyline(rng, &thin, stops, 2.0)
}

/// A zig-zag strip search from `start` along `axis_rad`: legs across a strip
/// `width_m` wide, advancing `advance_m` along the axis per leg, until `length_m` along it.
pub fn zigzag(
    rng: &mut impl Rng,
    start: [f64; 2],
    axis_rad: f64,
    width_m: f64,
    advance_m: f64,
    length_m: f64,
    stops: Stops,
) -> Vec<Waypoint> {
    let (c, s) = (axis_rad.cos(), axis_rad.sin());
    let at = |along: f64, left: f64| {
        [
            start[0] + c * along - s * left,
            start[1] + s * along + c * left,
        ]
    };
    let mut corners = vec![at(0.0, 0.0), at(advance_m * 0.5, 0.5 * width_m)];
    let mut along = advance_m * 0.5;
    let mut side = -1.0;
    while along < length_m {
        along += advance_m;
        corners.push(at(along, side * 0.5 * width_m));
        side = -side;
    }
    let mut pts = Vec::new();
    for w in corners.windows(2) {
        pts.extend(segment(w[0], w[1]));
    }
    sample_polyline(rng, &pts, stops, 2.0)
}

/// A uniformly random bearing, rad.
pub fn random_bearing(rng: &mut impl Rng) -> f64 {
    rng.random_range(0.0..TAU)
}
