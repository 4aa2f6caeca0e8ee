//! Closed-loop rescue: a simulated rescuer walks where the firmware's display points and
//! stops at "probe here" (IROS 2006 §III-C, ICRA 2006 §V-D, in the loop with a person).
//!
//! Every 10 ms tick the world advances, the receiver gets an IMU sample synthesized from
//! the rescuer's kinematics (specific force with the ≈ 1.8 Hz step bounce, gyro with a
//! constant bias, magnetometer), and, when the buried transmitter's pulse centre falls in
//! the tick, a pulse vector with the noise model of ICRA 2006 eq. 10,
//! `σ² = σ_bkg² + (k_sen |H|)²` per component, and a random overall sign. Both go to one
//! [`firmware::app::Receiver`], exactly as on the board.
//!
//! The rescuer model:
//! - reads the display with a lag (0.5 s) and walks toward the direction it showed
//!   relative to where they were facing then, with a slowly varying heading error
//!   (AR(1), σ ≈ 5°, 2 s correlation), turning at most 1.2 rad/s and stopping to turn on
//!   the spot when the arrow is far off;
//! - walks at ≈ 1 m/s (0.56 m steps at 1.8 Hz), the receiver 1 m above the snow,
//!   0.35 m ahead of the torso, with a 2 cm step bounce, step-coupled roll and pitch and
//!   a few degrees of hand wobble;
//! - in the fine search (localized, less than 2 m to walk) walks step by step: on each
//!   display update that came after they stopped, `round(walk / step)` steps (at most
//!   3) along the arrow, then stands;
//! - stops at "probe here".
//!
//! The scenario follows the papers' protocol (start 40–70 m away, random bearing, depth
//! 0.3–3 m, random moment), except that the rescuer starts where the primary search found
//! the first signal: when the transmitter is too weak to be received with a usable
//! signal-to-noise ratio at the drawn distance, the start moves in along the same bearing.
use crate::physics::{GRAVITY_W, M3, V3, body_rate_from_rpy_rates, rotation_from_rpy};
use crate::receiver_config::{ImuNoise, PulseNoise, ReceiverConfig};
use crate::rescuer::{Wobble, wrap_pi};
use crate::sog_replay::sog_config;
use crate::transmitter::{Transmitter, TransmitterSpec};
use crate::world::earth_field_ut;
use firmware::Vec3;
use firmware::app::{AppConfig, DisplayModel, Receiver};
use firmware::guidance::Status;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;
use std::collections::VecDeque;
use std::f64::consts::{PI, TAU};

/// Settings of a closed-loop run.
#[derive(Debug, Clone, PartialEq)]
pub struct ClosedLoopConfig {
    /// Scenario seed.
    pub seed: u64,
    /// Reaction lag of the rescuer, s.
    pub lag_s: f64,
    /// Standard deviation of the rescuer's heading error, degrees.
    pub heading_noise_deg: f64,
    /// The run stops unfinished when the path exceeds this multiple of the ideal path
    /// (plus 20 m).
    pub max_path_factor: f64,
    /// Remaining walk below which the rescuer goes step by step, m.
    pub fine_walk_m: f64,
    /// The rescuer's true step length, m.
    pub step_length_m: f64,
    /// Cadence, steps/s.
    pub cadence_hz: f64,
    /// Relative error of the calibrated step length the receiver is told.
    pub calibration_error: Option<f64>,
}

impl ClosedLoopConfig {
    /// The default rescuer for `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            lag_s: 0.5,
            heading_noise_deg: 5.0,
            max_path_factor: 4.0,
            fine_walk_m: 2.0,
            step_length_m: 0.56,
            cadence_hz: 1.8,
            calibration_error: None,
        }
    }
}

/// The state at one pulse.
#[derive(Debug, Clone, Serialize)]
pub struct PulseRow {
    /// Pulse time, s.
    pub t: f64,
    /// True receiver position in W, m.
    pub rx: [f64; 3],
    /// Estimated victim position in W (true receiver + estimate relative to it), m.
    pub victim_est: Option<[f64; 3]>,
    /// Horizontal error of the estimate, m.
    pub error_h_m: Option<f64>,
    /// True 3-D distance receiver–victim, m.
    pub true_distance_m: f64,
    /// Horizontal path walked by the receiver so far, m.
    pub path_m: f64,
    /// Components in the mixture.
    pub n_components: usize,
    /// The display after the pulse.
    #[serde(skip)]
    pub display: DisplayModel,
    /// Its status word.
    pub status: &'static str,
}

/// The mixture at one moment, for plots: components in W (horizontal).
#[derive(Debug, Clone, Serialize)]
pub struct Snapshot {
    /// Time, s.
    pub t: f64,
    /// True receiver position (north, west), m.
    pub rx: [f64; 2],
    /// `(weight, mean (north, west), covariance [xx, xy, yy])` per component.
    pub components: Vec<(f64, [f64; 2], [f64; 3])>,
    /// Status at that moment.
    pub status: &'static str,
}

/// The outcome of one closed-loop rescue.
#[derive(Debug, Clone, Serialize)]
pub struct Outcome {
    /// Scenario seed.
    pub seed: u64,
    /// Victim (transmitter) position in W, m.
    pub victim: [f64; 3],
    /// Start of the receiver in W, m.
    pub start: [f64; 3],
    /// Ideal path: straight to the victim, horizontally, m.
    pub ideal_path_m: f64,
    /// Horizontal path walked by the receiver, m.
    pub path_m: f64,
    /// Time of "probe here" (as the rescuer saw it), s.
    pub probe_t: Option<f64>,
    /// Time at the end of the run, s.
    pub end_t: f64,
    /// Horizontal error of the final estimate, m.
    pub error_h_m: Option<f64>,
    /// Depth error of the final estimate, m.
    pub error_z_m: Option<f64>,
    /// Horizontal distance of the receiver from the victim at the end (where the
    /// rescuer stands to probe), m.
    pub miss_h_m: f64,
    /// Pulses processed.
    pub pulses: usize,
    /// Receiver track (north, west) every 0.1 s.
    pub track: Vec<[f64; 2]>,
    /// One row per pulse.
    pub rows: Vec<PulseRow>,
    /// The mixture at a few moments.
    pub snapshots: Vec<Snapshot>,
    /// Mixture re-initializations.
    pub reinitializations: u32,
}

impl Outcome {
    /// Path walked over the ideal path.
    pub fn path_ratio(&self) -> f64 {
        self.path_m / self.ideal_path_m.max(1e-9)
    }
}

fn gauss(rng: &mut impl Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// The drawn scenario.
struct Scenario {
    tx: Transmitter,
    start: V3,
    heading: f64,
    step_cal: f64,
}

/// Tick of the simulation (the IMU period), s.
const DT: f64 = 0.01;
/// Height of the receiver above the snow, m.
const HOLD_HEIGHT_M: f64 = 1.0;
/// Receiver ahead of / left of the torso, m.
const HOLD_OFFSET_M: [f64; 2] = [0.35, -0.1];
/// Vertical bounce of the receiver per step, m (≈ 2.6 m/s² at 1.8 Hz).
const BOB_M: f64 = 0.02;
/// Smallest |H| / σ_bkg at the start (the primary search's first usable signal).
const START_SNR: f64 = 12.0;

fn draw_scenario(cfg: &ClosedLoopConfig, rng: &mut ChaCha8Rng, noise: &PulseNoise) -> Scenario {
    let d0: f64 = rng.random_range(40.0..=70.0);
    let bearing: f64 = rng.random_range(-PI..PI);
    let depth: f64 = rng.random_range(0.3..=3.0);
    let tx = Transmitter::random(
        rng,
        &TransmitterSpec::default(),
        [d0 * bearing.cos(), d0 * bearing.sin(), -depth],
    );
    let heading = rng.random_range(-PI..PI);
    let step_cal =
        cfg.step_length_m * (1.0 + cfg.calibration_error.unwrap_or_else(|| 0.02 * gauss(rng)));
    // Move the start in along the bearing until the signal is usable.
    let tx_p = V3::from(tx.position);
    let mut d = d0;
    let start_at =
        |d: f64| tx_p - V3::new(d * bearing.cos(), d * bearing.sin(), -depth - HOLD_HEIGHT_M);
    while d > 8.0
        && tx
            .field_at(&start_at(d))
            .is_none_or(|h| h.norm() < START_SNR * noise.sigma_bkg_a_per_m)
    {
        d -= 1.0;
    }
    let mut start = start_at(d);
    start.z = HOLD_HEIGHT_M;
    Scenario {
        tx,
        start,
        heading,
        step_cal,
    }
}

/// Receiver pose at one tick.
#[derive(Debug, Clone, Copy)]
struct Pose {
    t: f64,
    p: V3,
    rpy: V3,
}

/// The walking person (torso on the snow surface).
struct Person {
    c: [f64; 2],
    psi: f64,
    psi_dot: f64,
    w: f64,
    w_target: f64,
    phase: f64,
    psi_des: f64,
    wobble: [Wobble; 3],
}

impl Person {
    fn advance(&mut self, cfg: &ClosedLoopConfig) {
        let err = wrap_pi(self.psi_des - self.psi);
        let cmd = (1.5 * err).clamp(-1.2, 1.2);
        self.psi_dot += (cmd - self.psi_dot) * DT / 0.2;
        let device = self.device_xy();
        self.psi += self.psi_dot * DT;
        if self.w < 0.05 {
            // Turning on the spot, the rescuer pivots around the receiver, keeping it over
            // the spot (dead reckoning sees no steps, so the receiver must not move).
            let (s, c) = self.psi.sin_cos();
            let [f, l] = HOLD_OFFSET_M;
            self.c = [device[0] - (f * c - l * s), device[1] - (f * s + l * c)];
        }
        self.w += (self.w_target - self.w) * DT / 0.15;
        let v = cfg.step_length_m * cfg.cadence_hz * self.w;
        self.c[0] += v * self.psi.cos() * DT;
        self.c[1] += v * self.psi.sin() * DT;
        self.phase += cfg.cadence_hz * self.w * DT;
    }

    /// Horizontal receiver position (north, west).
    fn device_xy(&self) -> [f64; 2] {
        let (s, c) = self.psi.sin_cos();
        let [f, l] = HOLD_OFFSET_M;
        [self.c[0] + f * c - l * s, self.c[1] + f * s + l * c]
    }

    fn pose(&self, t: f64) -> Pose {
        let (s, c) = self.psi.sin_cos();
        let [f, l] = HOLD_OFFSET_M;
        let bob = BOB_M * self.w * (TAU * self.phase).cos();
        let p = V3::new(
            self.c[0] + f * c - l * s,
            self.c[1] + f * s + l * c,
            HOLD_HEIGHT_M + bob,
        );
        let roll = self.wobble[0].at(t).v + 0.03 * self.w * (PI * self.phase).sin();
        let pitch = 0.1 + self.wobble[1].at(t).v + 0.02 * self.w * (TAU * self.phase).cos();
        let yaw = self.psi + self.wobble[2].at(t).v;
        Pose {
            t,
            p,
            rpy: V3::new(roll, pitch, yaw),
        }
    }
}

/// IMU sample synthesized at the middle pose of three consecutive ticks.
fn imu_sample(
    rng: &mut ChaCha8Rng,
    noise: &ImuNoise,
    bias: &V3,
    earth: &V3,
    [a, b, c]: [&Pose; 3],
) -> (Vec3, Vec3, Vec3) {
    let acc_w = (c.p - 2.0 * b.p + a.p) / (DT * DT);
    let rates = V3::new(
        wrap_pi(c.rpy.x - a.rpy.x),
        wrap_pi(c.rpy.y - a.rpy.y),
        wrap_pi(c.rpy.z - a.rpy.z),
    ) / (2.0 * DT);
    let rot = rotation_from_rpy(&b.rpy);
    let f_b = rot.transpose() * (acc_w - V3::from(GRAVITY_W));
    let w_b = body_rate_from_rpy_rates(&b.rpy, &rates) + bias;
    let m_b = rot.transpose() * earth;
    let mut n = |s: f64| V3::new(s * gauss(rng), s * gauss(rng), s * gauss(rng));
    let f = |v: V3| Vec3::new(v.x as f32, v.y as f32, v.z as f32);
    (
        f(f_b + n(noise.acc_noise_m_s2)),
        f(w_b + n(noise.gyr_noise_rad_s)),
        f(m_b + n(noise.mag_noise_ut)),
    )
}

/// What the rescuer saw on the display at one tick.
#[derive(Debug, Clone, Copy)]
struct Seen {
    t: f64,
    display: DisplayModel,
    /// Torso heading when it was seen.
    psi: f64,
}

/// The rescuer's fine-search plan: walk to `end_phase`, then stand.
#[derive(Debug, Clone, Copy, Default)]
struct StepPlan {
    end_phase: Option<f64>,
    acted_pulse: u32,
    stopped_at: f64,
}

/// Runs one closed-loop rescue; `on_pulse` sees every pulse's row and the receiver.
pub fn run(
    cfg: &ClosedLoopConfig,
    on_pulse: &mut dyn FnMut(&PulseRow, &Receiver),
) -> anyhow::Result<Outcome> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let receiver_cfg = ReceiverConfig::default();
    let pulse_noise = receiver_cfg.pulse_noise.clone();
    let imu_noise = receiver_cfg.imu.clone();
    let sc = draw_scenario(cfg, &mut rng, &pulse_noise);
    let earth = V3::from(earth_field_ut(48.0, 63.0));
    let mut app = AppConfig::new(
        Vec3::new(earth.x as f32, earth.y as f32, earth.z as f32),
        Some(sc.step_cal as f32),
    );
    app.sog = sog_config(&receiver_cfg).with_calibrated_step(true);
    app.guidance.receiver_height_m = app.sog.receiver_height;
    let mut rx = Box::new(
        Receiver::new(app).map_err(|e| anyhow::anyhow!("receiver refused its config: {e:?}"))?,
    );
    let bias_max = imu_noise.gyr_bias_max_rad_s;
    let bias = V3::new(
        rng.random_range(-bias_max..=bias_max),
        rng.random_range(-bias_max..=bias_max),
        rng.random_range(-bias_max..=bias_max),
    );
    let torso = [
        sc.start.x - HOLD_OFFSET_M[0] * sc.heading.cos() + HOLD_OFFSET_M[1] * sc.heading.sin(),
        sc.start.y - HOLD_OFFSET_M[0] * sc.heading.sin() - HOLD_OFFSET_M[1] * sc.heading.cos(),
    ];
    let mut person = Person {
        c: torso,
        psi: sc.heading,
        psi_dot: 0.0,
        w: 0.0,
        w_target: 0.0,
        phase: 0.0,
        psi_des: sc.heading,
        wobble: [
            Wobble::random(&mut rng, 0.035, 0.1, 1.0),
            Wobble::random(&mut rng, 0.035, 0.1, 1.0),
            Wobble::random(&mut rng, 0.07, 0.05, 0.5),
        ],
    };
    let tx_p = V3::from(sc.tx.position);
    let ideal = (tx_p - sc.start).xy().norm();
    let max_path = cfg.max_path_factor * ideal + 20.0;
    let sigma_heading = cfg.heading_noise_deg.to_radians();
    let ar = (-DT / 2.0f64).exp();
    let mut heading_err = sigma_heading * gauss(&mut rng);
    let lag_ticks = (cfg.lag_s / DT).round().max(0.0) as usize;

    let mut poses: VecDeque<Pose> = VecDeque::with_capacity(3);
    let mut seen: VecDeque<Seen> = VecDeque::with_capacity(lag_ticks + 2);
    let mut plan = StepPlan::default();
    let mut rows = Vec::new();
    let mut snapshots: Vec<Snapshot> = Vec::new();
    let mut track = Vec::new();
    let mut path_m = 0.0;
    let mut next_pulse = 0u64;
    let mut probe_t = None;
    let mut last_status = Status::NoSignal;
    let mut last_snapshot_t = f64::NEG_INFINITY;
    let max_t = 3.0 * max_path / (cfg.step_length_m * cfg.cadence_hz) + 60.0;
    let mut t = 0.0;
    let mut k: u64 = 0;
    while t < max_t && path_m < max_path {
        person.advance(cfg);
        k += 1;
        t = k as f64 * DT;
        let pose = person.pose(t);
        if let Some(prev) = poses.back() {
            path_m += (pose.p - prev.p).xy().norm();
        }
        poses.push_back(pose);
        if poses.len() > 3 {
            poses.pop_front();
        }
        if poses.len() < 3 {
            continue;
        }
        let (p0, p1, p2) = (poses[0], poses[1], poses[2]);
        // The IMU sample of the middle tick.
        let (acc, gyr, mag) = imu_sample(&mut rng, &imu_noise, &bias, &earth, [&p0, &p1, &p2]);
        let _ = rx.on_imu(p1.t as f32, &acc, &gyr, Some(&mag));
        if k.is_multiple_of(10) {
            track.push([p1.p.x, p1.p.y]);
        }
        // A pulse centred within this tick.
        let centre = sc.tx.phase_s + next_pulse as f64 * sc.tx.period_s + 0.5 * sc.tx.on_time_s;
        if centre <= p1.t + 0.5 * DT {
            next_pulse += 1;
            let rot: M3 = rotation_from_rpy(&p1.rpy);
            if let Some(h_w) = sc.tx.field_at(&p1.p)
                && h_w.norm() >= 3.0 * pulse_noise.sigma_bkg_a_per_m
            {
                let sigma = pulse_noise
                    .sigma_bkg_a_per_m
                    .hypot(pulse_noise.k_sen * h_w.norm());
                let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
                let h_b = (rot.transpose() * h_w
                    + V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * sigma)
                    * sign;
                let h = Vec3::new(h_b.x as f32, h_b.y as f32, h_b.z as f32);
                if let Ok(display) = rx.on_pulse(centre as f32, &h, None) {
                    let est = rx.estimate();
                    let victim_est = est.map(|e| {
                        [
                            p1.p.x + f64::from(e.p.x),
                            p1.p.y + f64::from(e.p.y),
                            p1.p.z + f64::from(e.p.z),
                        ]
                    });
                    let row = PulseRow {
                        t: centre,
                        rx: p1.p.into(),
                        victim_est,
                        error_h_m: victim_est.map(|v| (V3::from(v) - tx_p).xy().norm()),
                        true_distance_m: (tx_p - p1.p).norm(),
                        path_m,
                        n_components: rx.filter().len(),
                        display,
                        status: display.status.as_str(),
                    };
                    let status_changed = display.status != last_status;
                    if est.is_some()
                        && (snapshots.is_empty()
                            || status_changed
                            || centre - last_snapshot_t > 20.0)
                    {
                        snapshots.push(snapshot(&rx, centre, &p1.p, display.status));
                        last_snapshot_t = centre;
                    }
                    last_status = display.status;
                    on_pulse(&row, &rx);
                    rows.push(row);
                }
            }
        }
        // The rescuer reads the display (with the lag) and acts.
        seen.push_back(Seen {
            t: p1.t,
            display: rx.display_model(),
            psi: person.psi,
        });
        while seen.len() > lag_ticks + 1 {
            seen.pop_front();
        }
        heading_err = ar * heading_err + (1.0 - ar * ar).sqrt() * sigma_heading * gauss(&mut rng);
        let Some(view) = seen.front().copied() else {
            continue;
        };
        if view.display.status == Status::Probe {
            probe_t = Some(view.t.max(p1.t));
            break;
        }
        act(cfg, &mut person, &mut plan, &view, heading_err, p1.t);
    }
    let end = poses.back().map_or(sc.start, |p| p.p);
    if let Some(r) = rows.last()
        && rx.estimate().is_some()
    {
        snapshots.push(snapshot(&rx, r.t, &V3::from(r.rx), r.display.status));
    }
    let final_est = rx.estimate().map(|e| {
        let rx_p = poses.get(1).map_or(end, |p| p.p);
        rx_p + V3::new(f64::from(e.p.x), f64::from(e.p.y), f64::from(e.p.z))
    });
    Ok(Outcome {
        seed: cfg.seed,
        victim: sc.tx.position,
        start: sc.start.into(),
        ideal_path_m: ideal,
        path_m,
        probe_t,
        end_t: t,
        error_h_m: final_est.map(|v| (v - tx_p).xy().norm()),
        error_z_m: final_est.map(|v| (v.z - tx_p.z).abs()),
        miss_h_m: (tx_p - end).xy().norm(),
        pulses: rows.len(),
        track,
        rows,
        snapshots,
        reinitializations: rx.stats().reinitializations,
    })
}

/// The rescuer's reaction to what they saw.
fn act(
    cfg: &ClosedLoopConfig,
    person: &mut Person,
    plan: &mut StepPlan,
    view: &Seen,
    heading_err: f64,
    t: f64,
) {
    let d = &view.display;
    let Some(arrow) = d.arrow_deg else {
        // Nothing to follow: stand (before the first signal) or keep going.
        if d.pulses == 0 {
            person.w_target = 0.0;
        }
        return;
    };
    let desired = view.psi + f64::from(arrow).to_radians() + heading_err;
    let fine =
        d.status == Status::Localized && d.walk_m.is_some_and(|w| f64::from(w) < cfg.fine_walk_m);
    if !fine {
        plan.end_phase = None;
        person.psi_des = desired;
        // Far off the arrow: stop and turn on the spot.
        let off = wrap_pi(desired - person.psi).abs();
        person.w_target = if off > 0.9 { 0.0 } else { 1.0 };
        return;
    }
    // Fine search, step by step.
    if let Some(end) = plan.end_phase {
        let turning = wrap_pi(person.psi_des - person.psi).abs() > 0.15;
        person.w_target = if turning || person.phase >= end - 0.27 {
            0.0
        } else {
            1.0
        };
        if person.phase >= end - 0.27 && person.w < 0.05 {
            plan.end_phase = None;
            plan.stopped_at = t;
        }
        return;
    }
    person.w_target = 0.0;
    if person.w > 0.05 {
        plan.stopped_at = t;
        return;
    }
    // A display update taken after standing still: plan the next steps.
    if d.pulses > plan.acted_pulse && f64::from(d.t_s) > plan.stopped_at {
        plan.acted_pulse = d.pulses;
        let walk = f64::from(d.walk_m.unwrap_or(0.0));
        let n = (walk / cfg.step_length_m).round().min(3.0);
        if n >= 1.0 {
            person.psi_des = desired;
            plan.end_phase = Some(person.phase + n);
        }
    }
}

fn snapshot(rx: &Receiver, t: f64, rx_p: &V3, status: Status) -> Snapshot {
    let components = rx
        .filter()
        .components()
        .map(|(w, p, c)| {
            (
                f64::from(w),
                [rx_p.x + f64::from(p.x), rx_p.y + f64::from(p.y)],
                [
                    f64::from(c[(0, 0)]),
                    f64::from(c[(0, 1)]),
                    f64::from(c[(1, 1)]),
                ],
            )
        })
        .collect();
    Snapshot {
        t,
        rx: [rx_p.x, rx_p.y],
        components,
        status: status.as_str(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn imu_at_rest_reads_gravity_and_earth_field() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let quiet = ImuNoise {
            gyr_noise_rad_s: 0.0,
            acc_noise_m_s2: 0.0,
            mag_noise_ut: 0.0,
            ..ImuNoise::default()
        };
        let pose = |t| Pose {
            t,
            p: V3::new(1.0, 2.0, 1.0),
            rpy: V3::new(0.0, 0.0, 0.5),
        };
        let earth = V3::new(21.0, 0.0, -42.0);
        let (a, g, m) = imu_sample(
            &mut rng,
            &quiet,
            &V3::zeros(),
            &earth,
            [&pose(0.0), &pose(0.01), &pose(0.02)],
        );
        assert!((a - Vec3::new(0.0, 0.0, 9.80665)).norm() < 1e-4);
        assert!(g.norm() < 1e-9);
        assert!((m.norm() - earth.norm() as f32).abs() < 1e-3 && m.z < -41.0);
    }
}
