//! The simulated rescuer's body: the drawn scenario, the walking person and its receiver pose,
//! the IMU synthesized from the walk, and the constants of its gait and hand motions.

use super::*;

/// The drawn scenario.
pub(crate) struct Scenario {
    pub(crate) tx: Transmitter,
    pub(crate) start: V3,
    pub(crate) heading: f64,
    pub(crate) step_cal: f64,
}

/// Height of the rescuer's lift of the receiver (up, then down), m.
pub const LIFT_M: f64 = 0.4;
/// Duration of the lift (up and down, raised-cosine profile), s.
pub const LIFT_S: f64 = 2.0;

/// Receiver height above the snow after "LOWER TO SNOW", m (the directional search's
/// `CROSS_HEIGHT_M`: a hand-held receiver just above the surface).
pub const LOW_HOLD_M: f64 = 0.2;
/// Duration of the lowering (or raising) of the receiver, s (minimum-jerk profile).
pub const HEIGHT_MOVE_S: f64 = 1.0;
/// Pause of the rescuer after coming to rest before the receiver is moved vertically, s.
pub const SETTLE_S: f64 = 0.5;

/// Tick of the simulation (the IMU period), s.
pub(crate) const DT: f64 = 0.01;
/// Height of the receiver above the snow, m.
pub(crate) const HOLD_HEIGHT_M: f64 = 1.0;
/// Receiver ahead of / left of the torso, m.
pub(crate) const HOLD_OFFSET_M: [f64; 2] = [0.35, -0.1];
/// Vertical bounce of the receiver per step, m (≈ 2.6 m/s² at 1.8 Hz).
pub(super) const BOB_M: f64 = 0.02;
/// Smallest |H| / σ_bkg at the start (the primary search's first usable signal).
pub(super) const START_SNR: f64 = 12.0;
/// Speed of the receiver in the directional search's cross search, m/s.
pub(super) const CRAWL_M_S: f64 = 0.5;
/// Receiver height above the snow in the directional search's cross search, m.
pub(crate) const CROSS_HEIGHT_M: f64 = 0.2;

pub(crate) fn draw_scenario(
    cfg: &ClosedLoopConfig,
    rng: &mut ChaCha8Rng,
    noise: &PulseNoise,
) -> Scenario {
    let d0: f64 = rng.random_range(40.0..=70.0);
    let bearing: f64 = rng.random_range(-PI..PI);
    let depth: f64 = rng.random_range(0.3..=3.0);
    let tx = Transmitter::random(
        rng,
        &cfg.transmitter,
        [d0 * bearing.cos(), d0 * bearing.sin(), -depth],
    );
    let mut heading = rng.random_range(-PI..PI);
    let step_cal =
        cfg.step_length_m * (1.0 + cfg.calibration_error.unwrap_or_else(|| 0.02 * gauss(rng)));
    let tx_p = V3::from(tx.position);
    let mut d = d0;
    let start_at =
        |d: f64| tx_p - V3::new(d * bearing.cos(), d * bearing.sin(), -depth - HOLD_HEIGHT_M);
    match cfg.start {
        StartMode::MoveIn => {
            // Move the start in along the bearing until the signal is usable.
            while d > 8.0
                && tx
                    .field_at(&start_at(d))
                    .is_none_or(|h| h.norm() < START_SNR * noise.sigma_bkg_a_per_m)
            {
                d -= 1.0;
            }
        }
        StartMode::PrimarySearch => heading = bearing,
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

/// The last three poses of the walk (an IMU sample of the middle tick needs both
/// neighbours) and the horizontal path walked so far.
#[derive(Debug, Default)]
pub(crate) struct PoseWindow {
    poses: VecDeque<Pose>,
    /// Horizontal path walked, m.
    pub(crate) path_m: f64,
}

impl PoseWindow {
    /// Adds the tick's pose; returns the three latest once there are three.
    pub(crate) fn push(&mut self, pose: Pose) -> Option<(Pose, Pose, Pose)> {
        if let Some(prev) = self.poses.back() {
            self.path_m += (pose.p - prev.p).xy().norm();
        }
        self.poses.push_back(pose);
        if self.poses.len() > 3 {
            self.poses.pop_front();
        }
        match (self.poses.front(), self.poses.get(1), self.poses.get(2)) {
            (Some(&p0), Some(&p1), Some(&p2)) => Some((p0, p1, p2)),
            _ => None,
        }
    }

    /// The latest pose.
    pub(crate) fn last(&self) -> Option<&Pose> {
        self.poses.back()
    }
}

/// Receiver pose at one tick.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pose {
    pub(crate) t: f64,
    pub(crate) p: V3,
    pub(crate) rpy: V3,
}

/// The walking person (torso on the snow surface).
pub(crate) struct Person {
    pub(crate) c: [f64; 2],
    pub(crate) psi: f64,
    pub(crate) psi_dot: f64,
    pub(crate) w: f64,
    pub(crate) w_target: f64,
    pub(crate) phase: f64,
    pub(crate) psi_des: f64,
    pub(crate) wobble: [Wobble; 3],
    /// Receiver height above the snow, m.
    pub(crate) hold_height: f64,
    /// Fine search of the directional search: the receiver is carried straight to this
    /// point (north, west) at [`CRAWL_M_S`], without steps.
    pub(crate) crawl_to: Option<[f64; 2]>,
    /// Start time of a lift of the receiver under way (see [`LIFT_M`]).
    pub(crate) lift_t0: Option<f64>,
    /// A lowering or raising of the receiver under way: `(start time, from, to)` heights
    /// above the snow (see [`HEIGHT_MOVE_S`]).
    pub(crate) height_move: Option<(f64, f64, f64)>,
    /// Time the rescuer has been standing (no gait), s.
    pub(crate) still_s: f64,
}

impl Person {
    pub(crate) fn advance(&mut self, cfg: &ClosedLoopConfig) {
        if let Some(target) = self.crawl_to {
            let device = self.device_xy();
            let (dx, dy) = (target[0] - device[0], target[1] - device[1]);
            let d = dx.hypot(dy);
            let step = d.min(CRAWL_M_S * DT);
            if d > 1e-9 {
                self.c[0] += dx / d * step;
                self.c[1] += dy / d * step;
            }
            self.w = 0.0;
            self.w_target = 0.0;
            self.psi_dot = 0.0;
            return;
        }
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
        // A person asked to stop finishes the step under way: the gait cycle comes to rest
        // between two steps (the speed decays with 0.15 s, which coasts 0.27 w of a step),
        // so every step is one whole bob cycle — one acceleration peak, as a real step.
        let mut target = self.w_target;
        let into_step = self.phase - self.phase.floor();
        if target == 0.0 && self.w > 1e-3 && into_step > 0.05 && 1.0 - into_step > 0.27 * self.w {
            target = 1.0;
        }
        self.w += (target - self.w) * DT / 0.15;
        self.still_s = if self.w > 1e-3 {
            0.0
        } else {
            self.still_s + DT
        };
        let v = cfg.step_length_m * cfg.cadence_hz * self.w;
        self.c[0] += v * self.psi.cos() * DT;
        self.c[1] += v * self.psi.sin() * DT;
        self.phase += cfg.cadence_hz * self.w * DT;
    }

    /// Horizontal receiver position (north, west).
    pub(crate) fn device_xy(&self) -> [f64; 2] {
        let (s, c) = self.psi.sin_cos();
        let [f, l] = HOLD_OFFSET_M;
        [self.c[0] + f * c - l * s, self.c[1] + f * s + l * c]
    }

    /// Height of the lift under way at `t` (raised cosine, up and back down), m.
    fn lift_offset(&self, t: f64) -> f64 {
        self.lift_t0.map_or(0.0, |t0| {
            let u = ((t - t0) / LIFT_S).clamp(0.0, 1.0);
            0.5 * LIFT_M * (1.0 - (TAU * u).cos())
        })
    }

    /// Height of the receiver above the snow at `t` without the bob and the lift: the
    /// holding height, or the lowering/raising under way (minimum jerk,
    /// `10u³ − 15u⁴ + 6u⁵`: zero velocity and acceleration at both ends), m.
    fn hold_height_at(&self, t: f64) -> f64 {
        self.height_move.map_or(self.hold_height, |(t0, from, to)| {
            let u = ((t - t0) / HEIGHT_MOVE_S).clamp(0.0, 1.0);
            let s = u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
            from + (to - from) * s
        })
    }

    pub(crate) fn pose(&self, t: f64) -> Pose {
        let (s, c) = self.psi.sin_cos();
        let [f, l] = HOLD_OFFSET_M;
        // The bob is a function of the gait phase only (at rest between steps): one dip
        // and one upward acceleration peak per step, none when standing.
        let bob = BOB_M * ((TAU * self.phase).cos() - 1.0);
        let p = V3::new(
            self.c[0] + f * c - l * s,
            self.c[1] + f * s + l * c,
            self.hold_height_at(t) + bob + self.lift_offset(t),
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
pub(crate) fn imu_sample(
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
pub(crate) struct Seen {
    pub(crate) t: f64,
    pub(crate) display: DisplayModel,
    /// Torso heading when it was seen.
    pub(crate) psi: f64,
}

/// The rescuer's fine-search plan: walk to `end_phase`, then stand.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct StepPlan {
    pub(crate) end_phase: Option<f64>,
    pub(crate) acted_pulse: u32,
    pub(crate) stopped_at: f64,
    /// Turned back after losing the signal (until the next arrow).
    pub(crate) turned_back: bool,
    /// Last pulse seen during (or before) the last lift: a lift needs a newer one.
    pub(crate) lift_pulse: u32,
    /// Lifts made.
    pub(crate) lifts: u32,
    /// Lowerings and raisings made.
    pub(crate) height_moves: u32,
}

/// The simulated world's geomagnetic field (48 µT, 63° inclination), µT.
pub(crate) fn sim_earth() -> V3 {
    V3::from(earth_field_ut(48.0, 63.0))
}
