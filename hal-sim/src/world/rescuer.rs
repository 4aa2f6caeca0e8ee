//! The rescuer: a person walking a planned route with a step-by-step gait, holding the
//! receiver in front of them with hand wobble.
//!
//! The walk is generated once, at construction, by a waypoint-following controller
//! (turn toward the next waypoint; stop and turn on the spot when it lies far off the
//! heading; stand still at stop waypoints) driving smooth gait dynamics, integrated with
//! RK4 on a 100 Hz knot grid. Between knots every base signal (torso position, heading,
//! gait phase, walking activity) is a C² quintic Hermite curve, and the receiver's pose is
//! an analytic function of those curves built with [`Jet`]s. So position, velocity,
//! acceleration, attitude and angular rate at any `t` are exact derivatives of one another.
//!
//! Gait: cadence `f` (steps/s) × step length gives the speed; the step length varies from
//! step to step (smoothly interpolated between per-step values); each step adds a vertical
//! bob and a forward surge (≈ 1.8 Hz specific-force oscillation of a few m/s²) and a lateral
//! sway at half the step rate.
use crate::world::jet::{Jet, quintic_hermite};
use crate::world::physics::{GRAVITY_W, M3, V3, body_rate_from_rpy_rates, rotation_from_rpy};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

/// Knot spacing of the base signals, s.
pub const KNOT_DT_S: f64 = 0.01;

/// How the person walks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaitParams {
    /// Mean step length at normal pace, m.
    pub step_length_m: f64,
    /// Relative standard deviation of the step length from step to step.
    pub step_length_rel_sigma: f64,
    /// Cadence, steps per second (about 1.8 Hz).
    pub cadence_hz: f64,
    /// Relative amplitude of the forward speed oscillation within a step.
    pub surge: f64,
    /// Amplitude of the vertical bob of the receiver, m (2 cm at 1.8 Hz ≈ 2.6 m/s²).
    pub bob_m: f64,
    /// Amplitude of the lateral sway (half the step rate), m.
    pub sway_m: f64,
    /// Largest turning rate, rad/s.
    pub max_yaw_rate_rad_s: f64,
}

impl Default for GaitParams {
    fn default() -> Self {
        Self {
            step_length_m: 0.56,
            step_length_rel_sigma: 0.03,
            cadence_hz: 1.8,
            surge: 0.15,
            bob_m: 0.02,
            sway_m: 0.015,
            max_yaw_rate_rad_s: 1.2,
        }
    }
}

/// How the person holds the receiver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HoldParams {
    /// Height of the receiver above the snow surface, m.
    pub height_m: f64,
    /// Receiver ahead of the torso, m.
    pub forward_m: f64,
    /// Receiver left of the torso, m (negative: right hand).
    pub left_m: f64,
    /// Mean pitch of the device, rad (positive: nose down).
    pub pitch_rad: f64,
    /// Amplitude scale of the hand wobble in roll, pitch and yaw, rad.
    pub wobble_rpy_rad: [f64; 3],
    /// Amplitude scale of the hand's positional wobble, m.
    pub wobble_pos_m: f64,
    /// Amplitude of the step-coupled roll (half step rate) and pitch (step rate), rad.
    pub gait_rp_rad: [f64; 2],
}

impl Default for HoldParams {
    fn default() -> Self {
        Self {
            height_m: 1.0,
            forward_m: 0.35,
            left_m: -0.1,
            pitch_rad: 0.1,
            wobble_rpy_rad: [0.035, 0.035, 0.07],
            wobble_pos_m: 0.01,
            gait_rp_rad: [0.03, 0.02],
        }
    }
}

impl HoldParams {
    /// A perfectly steady, level hold (for tests).
    pub fn steady() -> Self {
        Self {
            pitch_rad: 0.0,
            wobble_rpy_rad: [0.0; 3],
            wobble_pos_m: 0.0,
            gait_rp_rad: [0.0; 2],
            ..Self::default()
        }
    }
}

/// A point of the route on the snow surface (north, west), m.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Waypoint {
    /// Position (north, west), m.
    pub p: [f64; 2],
    /// Standing time at this waypoint, s (0: walk through it).
    pub stop_s: f64,
}

/// The route a person intends to walk.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Start of the torso (north, west), m.
    pub start: [f64; 2],
    /// Initial heading, rad (0 north, positive toward west).
    pub start_heading_rad: f64,
    /// Standing time before the first step, s.
    pub start_wait_s: f64,
    /// Waypoints in order; the walk ends at the last one.
    pub waypoints: Vec<Waypoint>,
    /// Standing time after the last waypoint, s.
    pub end_wait_s: f64,
}

/// Sinusoids with random frequencies and phases: a smooth random signal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Wobble {
    /// `(amplitude, frequency Hz, phase rad)` terms.
    pub terms: Vec<(f64, f64, f64)>,
}

impl Wobble {
    /// A random wobble with RMS about `scale` between `f_lo` and `f_hi` Hz.
    pub fn random(rng: &mut impl Rng, scale: f64, f_lo: f64, f_hi: f64) -> Self {
        let n = 3;
        let terms = (0..n)
            .map(|_| {
                let a = scale * (2.0 / n as f64).sqrt() * rng.random_range(0.5..1.5);
                (a, rng.random_range(f_lo..f_hi), rng.random_range(0.0..TAU))
            })
            .collect();
        Self { terms }
    }

    /// The signal at `t` with its derivatives.
    pub fn at(&self, t: f64) -> Jet {
        self.terms.iter().fold(Jet::default(), |acc, &(a, f, ph)| {
            acc + Jet::new(TAU * f * t + ph, TAU * f, 0.0).sin().scale(a)
        })
    }
}

/// Everything about the rescuer's motion at one instant (world frame W, body frame R).
#[derive(Debug, Clone, PartialEq)]
pub struct RescuerState {
    /// Time, s.
    pub t: f64,
    /// Receiver position in W, m.
    pub p: V3,
    /// Receiver velocity in W, m/s.
    pub v: V3,
    /// Receiver acceleration in W, m/s².
    pub a: V3,
    /// Roll, pitch, yaw of R in W, rad.
    pub rpy: V3,
    /// `R_WR`.
    pub rot: M3,
    /// Angular rate of R relative to W, in R, rad/s.
    pub omega_body: V3,
    /// Specific force in R, `R_WRᵀ (a − g)`, m/s².
    pub specific_force_body: V3,
    /// Steps taken since the start (continuous gait phase).
    pub steps: f64,
    /// Heading of the walker's torso, rad.
    pub heading: f64,
    /// Walking activity in [0, 1] (0 standing, 1 walking at full pace).
    pub activity: f64,
}

/// One knot of the base signals.
#[derive(Debug, Clone, Copy)]
struct Knot {
    cx: Jet,
    cy: Jet,
    psi: Jet,
    phi: Jet,
    w: Jet,
}

/// The rescuer's whole walk, queryable at any time.
#[derive(Debug, Clone)]
pub struct Rescuer {
    gait: GaitParams,
    hold: HoldParams,
    step_lengths: Vec<f64>,
    knots: Vec<Knot>,
    wobble: [Wobble; 6],
    gait_phase: [f64; 2],
    end_of_plan_s: f64,
}

/// ODE state: cx, cy, ψ, ψ̇, ψ̈, w, ẇ, φ.
type State = [f64; 8];

/// Natural frequency of the walking-activity dynamics, rad/s (stop within ≈ 0.5 m).
const OMEGA_W: f64 = 4.0;
/// Natural frequency of the turn-rate dynamics, rad/s.
const OMEGA_R: f64 = 8.0;
/// Turn-rate gain on the heading error, 1/s.
const K_YAW: f64 = 1.5;
/// Heading error beyond which the walker stops and turns on the spot, rad.
const TURN_ON_SPOT_RAD: f64 = 0.9;
/// Distance at which a walk-through waypoint counts as reached, m.
const PASS_RADIUS_M: f64 = 1.0;
/// Distance at which the walker starts stopping at a stop waypoint, m.
const STOP_RADIUS_M: f64 = 0.5;

impl Rescuer {
    /// Generates the walk of `plan`, at most `max_duration_s` long; `rng` draws the
    /// per-step lengths and the hand wobble.
    pub fn new(
        rng: &mut impl Rng,
        gait: GaitParams,
        hold: HoldParams,
        plan: &Plan,
        max_duration_s: f64,
    ) -> Self {
        let n_steps = (max_duration_s.max(1.0) * gait.cadence_hz * 1.5) as usize + 16;
        let sigma = gait.step_length_rel_sigma.max(0.0);
        let normal = Normal::new(0.0, 1.0).ok();
        let step_lengths = (0..n_steps)
            .map(|_| {
                let z: f64 = normal.map_or(0.0, |n| n.sample(rng));
                gait.step_length_m * (1.0 + sigma * z.clamp(-3.0, 3.0))
            })
            .collect();
        let [wr, wp, wy] = hold.wobble_rpy_rad;
        let wobble = [
            Wobble::random(rng, wr, 0.1, 1.2),
            Wobble::random(rng, wp, 0.1, 1.2),
            Wobble::random(rng, wy, 0.05, 0.8),
            Wobble::random(rng, hold.wobble_pos_m, 0.1, 1.0),
            Wobble::random(rng, hold.wobble_pos_m, 0.1, 1.0),
            Wobble::random(rng, hold.wobble_pos_m, 0.1, 1.0),
        ];
        let gait_phase = [rng.random_range(0.0..TAU), rng.random_range(0.0..TAU)];
        let mut me = Self {
            gait,
            hold,
            step_lengths,
            knots: Vec::new(),
            wobble,
            gait_phase,
            end_of_plan_s: 0.0,
        };
        me.integrate(plan, max_duration_s);
        me
    }

    /// Time at which the plan was completed (or the duration limit), s.
    pub fn end_s(&self) -> f64 {
        self.end_of_plan_s
    }

    /// The gait parameters in use.
    pub fn gait(&self) -> &GaitParams {
        &self.gait
    }

    /// Step length as a function of the gait phase, with its first two derivatives in φ.
    fn step_length(&self, phi: f64) -> (f64, f64, f64) {
        let x = (phi - 0.5).max(0.0);
        let k = (x.floor() as usize).min(self.step_lengths.len().saturating_sub(2));
        let u = (x - k as f64).clamp(0.0, 1.0);
        let (a, b) = (self.step_lengths[k], self.step_lengths[k + 1]);
        let d = b - a;
        (
            a + d * 0.5 * (1.0 - (PI * u).cos()),
            d * 0.5 * PI * (PI * u).sin(),
            d * 0.5 * PI * PI * (PI * u).cos(),
        )
    }

    /// Forward speed of the torso as a jet, from the gait phase and activity jets.
    fn speed(&self, phi: Jet, w: Jet) -> Jet {
        let (l, dl, ddl) = self.step_length(phi.v);
        let l = Jet::new(l, dl * phi.d, ddl * phi.d * phi.d + dl * phi.dd);
        let surge = (phi.scale(TAU)).cos().scale(self.gait.surge) + 1.0;
        l * w.scale(self.gait.cadence_hz) * surge
    }

    fn derivative(&self, s: &State, cmd: (f64, f64)) -> State {
        let (w_cmd, r_cmd) = cmd;
        let phi_dot = self.gait.cadence_hz * s[5];
        let (l, _, _) = self.step_length(s[7]);
        let v = l * phi_dot * (1.0 + self.gait.surge * (TAU * s[7]).cos());
        [
            v * s[2].cos(),
            v * s[2].sin(),
            s[3],
            s[4],
            OMEGA_R * OMEGA_R * (r_cmd - s[3]) - 2.0 * OMEGA_R * s[4],
            s[6],
            OMEGA_W * OMEGA_W * (w_cmd - s[5]) - 2.0 * OMEGA_W * s[6],
            phi_dot,
        ]
    }

    fn knot(&self, s: &State, cmd: (f64, f64)) -> Knot {
        let ds = self.derivative(s, cmd);
        let w = Jet::new(s[5], s[6], ds[6]);
        let phi = Jet::new(s[7], ds[7], self.gait.cadence_hz * s[6]);
        let psi = Jet::new(s[2], s[3], s[4]);
        let v = self.speed(phi, w);
        let vx = v * psi.cos();
        let vy = v * psi.sin();
        Knot {
            cx: Jet::new(s[0], vx.v, vx.d),
            cy: Jet::new(s[1], vy.v, vy.d),
            psi,
            phi,
            w,
        }
    }

    fn integrate(&mut self, plan: &Plan, max_duration_s: f64) {
        let dt = KNOT_DT_S;
        let mut s: State = [
            plan.start[0],
            plan.start[1],
            plan.start_heading_rad,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ];
        let mut follower = Follower::new(plan);
        let n_max = (max_duration_s / dt).ceil().max(2.0) as usize;
        let mut knots = Vec::with_capacity(n_max + 1);
        let mut end = None;
        for i in 0..=n_max {
            let t = i as f64 * dt;
            let cmd = follower.command(t, &s, &self.gait);
            knots.push(self.knot(&s, cmd));
            if follower.done_at.is_some_and(|d| t >= d) {
                end = Some(t);
                break;
            }
            let k1 = self.derivative(&s, cmd);
            let k2 = self.derivative(&axpy(&s, 0.5 * dt, &k1), cmd);
            let k3 = self.derivative(&axpy(&s, 0.5 * dt, &k2), cmd);
            let k4 = self.derivative(&axpy(&s, dt, &k3), cmd);
            for j in 0..8 {
                s[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
            }
        }
        self.end_of_plan_s = end.unwrap_or((knots.len() - 1) as f64 * dt);
        self.knots = knots;
    }

    /// The receiver's full motion state at time `t` (s, from 0; after the end of the plan
    /// the person stands where the plan ended).
    pub fn state(&self, t: f64) -> RescuerState {
        let dt = KNOT_DT_S;
        let last = self.knots.len().saturating_sub(1);
        let t = t.max(0.0);
        let tc = t.min(last as f64 * dt);
        let i = ((tc / dt).floor() as usize).min(last.saturating_sub(1));
        let (a, b) = (&self.knots[i], &self.knots[(i + 1).min(last)]);
        let s = tc - i as f64 * dt;
        // Past the last knot the walker stands still (the plan ends standing); the hand
        // keeps wobbling.
        let beyond = t > last as f64 * dt;
        let q = |x: &Jet, y: &Jet| {
            if beyond {
                Jet::constant(y.v)
            } else {
                quintic_hermite(x, y, dt, s)
            }
        };
        let (cx, cy, psi, phi, w) = (
            q(&a.cx, &b.cx),
            q(&a.cy, &b.cy),
            q(&a.psi, &b.psi),
            q(&a.phi, &b.phi),
            q(&a.w, &b.w),
        );
        let g = &self.gait;
        let h = &self.hold;
        // Receiver offset from the torso in the heading frame, with sway.
        let lateral = w * (phi.scale(PI)).sin().scale(g.sway_m) + h.left_m;
        let (cpsi, spsi) = (psi.cos(), psi.sin());
        let px = cx + cpsi.scale(h.forward_m) - spsi * lateral + self.wobble[3].at(t);
        let py = cy + spsi.scale(h.forward_m) + cpsi * lateral + self.wobble[4].at(t);
        let pz = w * (phi.scale(TAU)).cos().scale(g.bob_m) + h.height_m + self.wobble[5].at(t);
        let [gr, gp] = h.gait_rp_rad;
        let [ph_r, ph_p] = self.gait_phase;
        let roll = self.wobble[0].at(t) + w * (phi.scale(PI) + ph_r).sin().scale(gr);
        let pitch =
            self.wobble[1].at(t) + w * (phi.scale(TAU) + ph_p).sin().scale(gp) + h.pitch_rad;
        let yaw = psi + self.wobble[2].at(t);
        let rpy = V3::new(roll.v, pitch.v, yaw.v);
        let rates = V3::new(roll.d, pitch.d, yaw.d);
        let rot = rotation_from_rpy(&rpy);
        let acc = V3::new(px.dd, py.dd, pz.dd);
        let specific = rot.transpose() * (acc - V3::from(GRAVITY_W));
        RescuerState {
            t,
            p: V3::new(px.v, py.v, pz.v),
            v: V3::new(px.d, py.d, pz.d),
            a: acc,
            rpy,
            rot,
            omega_body: body_rate_from_rpy_rates(&rpy, &rates),
            specific_force_body: specific,
            steps: phi.v,
            heading: psi.v,
            activity: w.v,
        }
    }
}

fn axpy(s: &State, k: f64, d: &State) -> State {
    let mut o = *s;
    for j in 0..8 {
        o[j] += k * d[j];
    }
    o
}

/// Wraps an angle to (-π, π].
pub fn wrap_pi(a: f64) -> f64 {
    let w = a - TAU * ((a + PI) / TAU).floor();
    if w <= -PI { w + TAU } else { w }
}

/// The waypoint-following controller.
struct Follower<'a> {
    plan: &'a Plan,
    next: usize,
    stop_until: Option<f64>,
    done_at: Option<f64>,
}

impl<'a> Follower<'a> {
    fn new(plan: &'a Plan) -> Self {
        Self {
            plan,
            next: 0,
            stop_until: Some(plan.start_wait_s),
            done_at: None,
        }
    }

    /// `(walking command, turn-rate command)` at time `t`.
    fn command(&mut self, t: f64, s: &State, gait: &GaitParams) -> (f64, f64) {
        if let Some(until) = self.stop_until {
            if t < until {
                return (0.0, 0.0);
            }
            self.stop_until = None;
        }
        loop {
            let Some(wp) = self.plan.waypoints.get(self.next) else {
                self.done_at.get_or_insert(t + self.plan.end_wait_s);
                return (0.0, 0.0);
            };
            let (dx, dy) = (wp.p[0] - s[0], wp.p[1] - s[1]);
            let dist = dx.hypot(dy);
            let is_last = self.next + 1 == self.plan.waypoints.len();
            let stopping = wp.stop_s > 0.0 || is_last;
            if stopping && dist < STOP_RADIUS_M {
                self.next += 1;
                if !is_last {
                    self.stop_until = Some(t + wp.stop_s);
                }
                return (0.0, 0.0);
            }
            if !stopping && dist < PASS_RADIUS_M {
                self.next += 1;
                continue;
            }
            let err = wrap_pi(dy.atan2(dx) - s[2]);
            let r_cmd = (K_YAW * err).clamp(-gait.max_yaw_rate_rad_s, gait.max_yaw_rate_rad_s);
            let w_cmd = if err.abs() < TURN_ON_SPOT_RAD {
                1.0
            } else {
                0.0
            };
            return (w_cmd, r_cmd);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::physics::exp_so3;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn walk(hold: HoldParams, waypoints: Vec<Waypoint>, dur: f64) -> Rescuer {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let plan = Plan {
            start: [0.0, 0.0],
            start_heading_rad: 0.3,
            start_wait_s: 1.0,
            waypoints,
            end_wait_s: 2.0,
        };
        Rescuer::new(&mut rng, GaitParams::default(), hold, &plan, dur)
    }

    fn wp(x: f64, y: f64, stop_s: f64) -> Waypoint {
        Waypoint { p: [x, y], stop_s }
    }

    #[test]
    fn standing_still_and_level_reads_plus_g_on_z() {
        let r = walk(HoldParams::steady(), vec![], 10.0);
        for i in 0..50 {
            let s = r.state(i as f64 * 0.013);
            assert!((s.specific_force_body - V3::new(0.0, 0.0, 9.80665)).norm() < 1e-9);
            assert!(s.omega_body.norm() < 1e-12);
        }
    }

    #[test]
    fn derivatives_are_consistent_with_positions() {
        let r = walk(
            HoldParams::default(),
            vec![wp(10.0, 0.0, 2.0), wp(10.0, 10.0, 0.0), wp(0.0, 0.0, 0.0)],
            60.0,
        );
        let h = 1e-4;
        for i in 1..400 {
            let t = i as f64 * 0.137;
            let (a, b, c) = (r.state(t - h), r.state(t), r.state(t + h));
            let v = (c.p - a.p) / (2.0 * h);
            let acc = (c.p - 2.0 * b.p + a.p) / (h * h);
            assert!((v - b.v).norm() < 1e-5, "t={t}");
            assert!((acc - b.a).norm() < 2e-2, "t={t} {acc} {}", b.a);
        }
    }

    #[test]
    fn integrating_the_gyro_reproduces_the_attitude() {
        let r = walk(
            HoldParams::default(),
            vec![wp(15.0, 0.0, 3.0), wp(15.0, 15.0, 0.0), wp(0.0, 5.0, 0.0)],
            60.0,
        );
        let dt = 0.002;
        let mut rot = r.state(0.0).rot;
        let n = (60.0 / dt) as usize;
        let mut w_prev = r.state(0.0).omega_body;
        for k in 1..=n {
            let s = r.state(k as f64 * dt);
            let mid = r.state((k as f64 - 0.5) * dt).omega_body;
            // Simpson-weighted rotation vector over the step.
            let w = (w_prev + mid * 4.0 + s.omega_body) / 6.0;
            rot *= exp_so3(&(w * dt));
            w_prev = s.omega_body;
        }
        let truth = r.state(60.0).rot;
        let err = (rot.transpose() * truth - M3::identity()).abs().max();
        assert!(err < 1e-4, "attitude error {err:e}");
    }

    #[test]
    fn walks_its_route_at_step_length_times_cadence() {
        let r = walk(HoldParams::default(), vec![wp(40.0, 0.0, 0.0)], 120.0);
        let end = r.end_s();
        assert!(end > 35.0 && end < 60.0, "end {end}");
        let s = r.state(end);
        assert!((s.p.x - 40.35).abs() < 1.0 && s.p.y.abs() < 1.0, "{}", s.p);
        // Distance per step matches the mean step length within a few %.
        let per_step = 40.0 / s.steps;
        assert!((per_step / 0.56 - 1.0).abs() < 0.05, "{per_step}");
        // Mid-walk speed about 1 m/s, with a step-frequency vertical oscillation.
        let mid = r.state(20.0);
        assert!((mid.v.norm() - 1.0).abs() < 0.25, "{}", mid.v.norm());
        let zs: Vec<f64> = (0..200)
            .map(|i| r.state(15.0 + i as f64 * 0.01).specific_force_body.z)
            .collect();
        let max = zs.iter().cloned().fold(f64::MIN, f64::max);
        let min = zs.iter().cloned().fold(f64::MAX, f64::min);
        assert!(max - min > 3.0 && max - min < 12.0, "{min}..{max}");
    }
}
