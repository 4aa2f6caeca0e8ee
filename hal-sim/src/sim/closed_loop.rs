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
//! - on "LOWER TO SNOW" stops, pauses [`SETTLE_S`] at rest, then lowers the receiver to [`LOW_HOLD_M`] above the snow in a brisk
//!   minimum-jerk move of [`HEIGHT_MOVE_S`] (the accelerometer sees it), and goes on with
//!   the same step-by-step walk bent over, the receiver at that height (same gait and step
//!   length: the steps of the fine search are short and deliberate either way); on
//!   "RAISE TO 1M" raises it back the same way;
//! - stops at "probe here".
//!
//! The scenario follows the papers' protocol (start 40–70 m away, random bearing, depth
//! 0.3–3 m, random moment). Where the rescuer starts depends on [`StartMode`]:
//! - [`StartMode::MoveIn`] (default): where the primary search found a usable signal —
//!   when the transmitter is too weak to be received with a usable signal-to-noise ratio
//!   at the drawn distance, the start moves in along the same bearing;
//! - [`StartMode::PrimarySearch`]: at the drawn distance; until the first pulse is
//!   received the rescuer walks straight toward the victim (a primary-search strip whose
//!   centre line passes over the victim), then follows the display.
//!
//! [`Policy::DirectionalSearch`] replaces the receiver by the classical directional search
//! ([`crate::policies::directional`], settings in [`ClosedLoopConfig::ds`]) as the
//! rescuer's own policy, optimistic as in the paper's simulation: the flux line of the
//! true field followed without lag or heading error, the noisy |H| read; in its cross
//! search the receiver is carried from point to point just above the snow.
use crate::io::receiver_config::{ImuNoise, PulseNoise, ReceiverConfig};
use crate::io::sog_replay::sog_config;
use crate::policies::directional::{DirectionalSearch, DsCommand, DsConfig, RescuerView};
use crate::stamp;
use crate::world::earth_field_ut;
use crate::world::physics::{GRAVITY_W, M3, V3, body_rate_from_rpy_rates, rotation_from_rpy};
use crate::world::rescuer::{Wobble, wrap_pi};
use crate::world::transmitter::{Transmitter, TransmitterSpec};
use firmware::Vec3;
use firmware::app::{AppConfig, DisplayModel, Receiver};
use firmware::guidance::{HeightPrompt, Status};
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
    /// Whether the receiver is told the rescuer's (calibrated) step length; without it
    /// the firmware's uncalibrated step model applies.
    pub calibrated: bool,
    /// Where the rescuer starts.
    pub start: StartMode,
    /// Who decides where the rescuer walks.
    pub policy: Policy,
    /// Whether the receiver may ask for a lift in the fine search (the rescuer then
    /// stands and lifts it [`LIFT_M`] up and down over [`LIFT_S`]); without it the
    /// receiver never asks.
    pub lift: bool,
    /// Whether the receiver asks for the receiver to be lowered to the snow in the fine
    /// search (the rescuer then lowers it to [`LOW_HOLD_M`]); without it the whole fine
    /// search is done at the walking height (1 m).
    pub lower: bool,
    /// Overrides the receiver's probe radius (m; "probe here" needs 3σ_h within it, and
    /// a levelled-off σ_h at most half of it): the trade-off between steps and probe-point
    /// error (`rescue-report --probe-tradeoff`). `None`: the firmware's default.
    pub probe_radius_m: Option<f64>,
    /// The directional search's settings (with [`Policy::DirectionalSearch`]).
    pub ds: DsConfig,
    /// The range the transmitter is drawn from (moment magnitude, on-time).
    pub transmitter: TransmitterSpec,
    /// A pulse is received only when |H| is at least this many σ_bkg (0: every pulse).
    pub reception_snr: f64,
}

/// Where a closed-loop rescue starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum StartMode {
    /// Where the signal is usable (|H| ≥ 12 σ_bkg), moved in from the drawn 40–70 m.
    #[default]
    MoveIn,
    /// At the drawn 40–70 m; straight toward the victim until the first pulse.
    PrimarySearch,
}

/// Who decides where the rescuer walks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum Policy {
    /// The firmware's receiver (`app::Receiver`, SOGs and search control).
    #[default]
    Receiver,
    /// The classical directional search with a cross search at the end (see the module
    /// docs); the receiver application is not run.
    DirectionalSearch,
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
            calibrated: true,
            start: StartMode::MoveIn,
            policy: Policy::Receiver,
            lift: true,
            lower: true,
            probe_radius_m: None,
            ds: DsConfig::default(),
            transmitter: TransmitterSpec::default(),
            reception_snr: 3.0,
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
    /// True device attitude (roll, pitch, yaw) at the pulse, rad.
    pub true_rpy: [f64; 3],
    /// Dead-reckoned displacement since the previous pulse: horizontal σ (m, the root
    /// of the trace of its horizontal covariance) and steps counted.
    pub displacement_sigma_h_m: f64,
    /// Steps counted in that displacement.
    pub displacement_steps: u16,
    /// That displacement's error: the dead-reckoned translation minus the true one, both
    /// in the device frame at the previous pulse, forward and left (m; zero at the first
    /// pulse).
    pub displacement_error_m: [f64; 2],
    /// Its covariance's forward–left block `[xx, xy, yy]` (m²).
    pub displacement_cov_m2: [f64; 3],
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
    /// Transmitter moment in W, A·m².
    pub moment: [f64; 3],
    /// Transmitter period, s.
    pub period_s: f64,
    /// The rescuer's nominal walking speed (step length × cadence), m/s.
    pub walk_speed_m_s: f64,
    /// Time of the first received pulse, s.
    pub first_rx_t: Option<f64>,
    /// Receiver position at the first received pulse, m.
    pub first_rx_p: Option<[f64; 3]>,
    /// Horizontal path walked before the first received pulse, m.
    pub path_at_first_rx_m: f64,
    /// Transmitter pulses from the first received one to "probe here" (or "found"),
    /// counting both (received or not).
    pub pulses_to_probe: Option<u64>,
    /// Transmitter pulses from the start to "probe here" (or "found").
    pub pulses_from_start: Option<u64>,
    /// Burial depth (below the snow surface) shown at "probe here", m.
    pub depth_shown_m: Option<f64>,
    /// Where the rescuer stands at the end (receiver position), m.
    pub end_p: [f64; 3],
    /// Lifts of the receiver the rescuer made when asked ("LIFT").
    pub lifts: u32,
    /// Receiver lowered to the snow or raised again on a height prompt.
    pub height_moves: u32,
}

impl Outcome {
    /// Ideal path from the first received pulse: straight to the victim, horizontally, m.
    pub fn ideal_from_first_rx_m(&self) -> Option<f64> {
        self.first_rx_p
            .map(|p| (V3::from(self.victim) - V3::from(p)).xy().norm())
    }

    /// Transmitter pulses the ideal straight walk of `distance_m` takes.
    pub fn ideal_pulses(&self, distance_m: f64) -> f64 {
        distance_m / self.walk_speed_m_s.max(1e-9) / self.period_s.max(1e-9)
    }

    /// Path walked over the ideal path.
    pub fn path_ratio(&self) -> f64 {
        self.path_m / self.ideal_path_m.max(1e-9)
    }
}

/// The gyro bias and the rescuer standing at `start` facing `heading` (rad), drawn from
/// `rng` in this order (every closed loop draws them alike, so one seed gives one rescuer).
pub(crate) fn start_rescuer(
    start: &V3,
    heading: f64,
    gyr_bias_max: f64,
    rng: &mut ChaCha8Rng,
) -> (V3, Person) {
    let bias = V3::new(
        rng.random_range(-gyr_bias_max..=gyr_bias_max),
        rng.random_range(-gyr_bias_max..=gyr_bias_max),
        rng.random_range(-gyr_bias_max..=gyr_bias_max),
    );
    let torso = [
        start.x - HOLD_OFFSET_M[0] * heading.cos() + HOLD_OFFSET_M[1] * heading.sin(),
        start.y - HOLD_OFFSET_M[0] * heading.sin() - HOLD_OFFSET_M[1] * heading.cos(),
    ];
    let person = Person {
        c: torso,
        psi: heading,
        psi_dot: 0.0,
        w: 0.0,
        w_target: 0.0,
        phase: 0.0,
        psi_des: heading,
        wobble: [
            Wobble::random(rng, 0.035, 0.1, 1.0),
            Wobble::random(rng, 0.035, 0.1, 1.0),
            Wobble::random(rng, 0.07, 0.05, 0.5),
        ],
        hold_height: HOLD_HEIGHT_M,
        crawl_to: None,
        lift_t0: None,
        height_move: None,
        still_s: 0.0,
    };
    (bias, person)
}

pub(crate) fn gauss(rng: &mut impl Rng) -> f64 {
    StandardNormal.sample(rng)
}

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
const BOB_M: f64 = 0.02;
/// Smallest |H| / σ_bkg at the start (the primary search's first usable signal).
const START_SNR: f64 = 12.0;
/// Speed of the receiver in the directional search's cross search, m/s.
const CRAWL_M_S: f64 = 0.5;
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

/// The application's configuration in the simulated rescues: the simulated world's
/// geomagnetic field (48 µT, 63°), the receiver description's noise model in the
/// estimator and guidance, and the calibrated step length when there is one.
pub(crate) fn app_config(receiver: &ReceiverConfig, step_length_m: Option<f64>) -> AppConfig {
    let earth = sim_earth();
    let mut app = AppConfig::new(
        Vec3::new(earth.x as f32, earth.y as f32, earth.z as f32),
        step_length_m.map(|s| s as f32),
    );
    app.sog = sog_config(receiver, app.sog);
    app.guidance.receiver_height_m = app.sog.receiver_height;
    app.guidance.sigma_bkg = app.sog.sigma_bkg;
    app
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
    let earth = sim_earth();
    let mut app = app_config(&receiver_cfg, cfg.calibrated.then_some(sc.step_cal));
    if !cfg.lift {
        app.guidance.lift_max_pulses = 0;
    }
    if !cfg.lower {
        app.guidance.lower_within_m = 0.0;
    }
    if let Some(r) = cfg.probe_radius_m {
        // The default pair is 0.3 m and 0.15 m: the plateau's ceiling stays half the radius.
        app.guidance.probe_radius_m = r as f32;
        app.guidance.probe_plateau_max_sigma_m = (0.5 * r) as f32;
    }
    let mut rx = Box::new(
        Receiver::new(app).map_err(|e| anyhow::anyhow!("receiver refused its config: {e:?}"))?,
    );
    let (bias, mut person) = start_rescuer(
        &sc.start,
        sc.heading,
        imu_noise.gyr_bias_max_rad_s,
        &mut rng,
    );
    let primary = (cfg.start == StartMode::PrimarySearch).then_some(sc.heading);
    let mut ds = DirectionalSearch::new(cfg.ds);
    let mut first_rx: Option<(f64, V3, u64, f64)> = None;
    let mut pulses_at_probe = None;
    let tx_p = V3::from(sc.tx.position);
    let ideal = (tx_p - sc.start).xy().norm();
    let max_path = cfg.max_path_factor * ideal + 20.0;
    let sigma_heading = cfg.heading_noise_deg.to_radians();
    let ar = (-DT / 2.0f64).exp();
    let mut heading_err = sigma_heading * gauss(&mut rng);
    let lag_ticks = (cfg.lag_s / DT).round().max(0.0) as usize;

    let mut window = PoseWindow::default();
    // True pose at the previous processed pulse (dead-reckoning consistency rows).
    let mut prev_pose: Option<(V3, M3)> = None;
    let mut seen: VecDeque<Seen> = VecDeque::with_capacity(lag_ticks + 2);
    let mut plan = StepPlan::default();
    let mut rows = Vec::new();
    let mut snapshots: Vec<Snapshot> = Vec::new();
    let mut track = Vec::new();
    let mut next_pulse = 0u64;
    let mut probe_t = None;
    let mut last_status = Status::NoSignal;
    let mut last_snapshot_t = f64::NEG_INFINITY;
    let max_t = 3.0 * max_path / (cfg.step_length_m * cfg.cadence_hz) + 60.0;
    let mut t = 0.0;
    let mut k: u64 = 0;
    while t < max_t && window.path_m < max_path {
        person.advance(cfg);
        k += 1;
        t = k as f64 * DT;
        let Some((p0, p1, p2)) = window.push(person.pose(t)) else {
            continue;
        };
        // The IMU sample of the middle tick.
        let (acc, gyr, mag) = imu_sample(&mut rng, &imu_noise, &bias, &earth, [&p0, &p1, &p2]);
        let _ = rx.on_imu(stamp(p1.t), &acc, &gyr, Some(&mag));
        if k.is_multiple_of(10) {
            track.push([p1.p.x, p1.p.y]);
        }
        // A pulse centred within this tick.
        let centre = sc.tx.phase_s + next_pulse as f64 * sc.tx.period_s + 0.5 * sc.tx.on_time_s;
        if centre <= p1.t + 0.5 * DT {
            next_pulse += 1;
            let rot: M3 = rotation_from_rpy(&p1.rpy);
            if let Some(h_w) = sc.tx.field_at(&p1.p)
                && h_w.norm() >= cfg.reception_snr * pulse_noise.sigma_bkg_a_per_m
            {
                if first_rx.is_none() {
                    first_rx = Some((centre, p1.p, next_pulse - 1, window.path_m));
                }
                let sigma = pulse_noise
                    .sigma_bkg_a_per_m
                    .hypot(pulse_noise.k_sen * h_w.norm());
                let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
                let h_b = (rot.transpose() * h_w
                    + V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * sigma)
                    * sign;
                let h = Vec3::new(h_b.x as f32, h_b.y as f32, h_b.z as f32);
                if cfg.policy == Policy::DirectionalSearch {
                    // Optimistic: the classical receiver's field in W, exactly rotated.
                    let cmd = ds.on_pulse(centre, &(rot * h_b), &h_w, &p1.p, &ds_view(&person));
                    apply_ds(cmd, &mut person);
                } else if let Some(d) = Some(
                    rx.motion()
                        .clone()
                        .take_displacement(rx.seconds(stamp(centre))),
                ) && let Ok(display) = rx.on_pulse(stamp(centre), &h, None)
                {
                    let true_move = prev_pose.map_or(V3::zeros(), |(pp, pr): (V3, M3)| {
                        pr.transpose() * (p1.p - pp)
                    });
                    let dr_move = prev_pose.map_or(true_move, |_| {
                        V3::new(
                            f64::from(d.translation.x),
                            f64::from(d.translation.y),
                            f64::from(d.translation.z),
                        )
                    });
                    prev_pose = Some((p1.p, rot));
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
                        path_m: window.path_m,
                        n_components: rx.filter().len(),
                        true_rpy: p1.rpy.into(),
                        displacement_sigma_h_m: f64::from(d.cov[(0, 0)] + d.cov[(1, 1)]).sqrt(),
                        displacement_steps: d.steps,
                        displacement_error_m: [dr_move.x - true_move.x, dr_move.y - true_move.y],
                        displacement_cov_m2: [
                            f64::from(d.cov[(0, 0)]),
                            f64::from(d.cov[(0, 1)]),
                            f64::from(d.cov[(1, 1)]),
                        ],
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
        if cfg.policy == Policy::DirectionalSearch {
            if ds.done(person.device_xy()) {
                probe_t = Some(p1.t);
                pulses_at_probe = Some(next_pulse);
                break;
            }
            if first_rx.is_none() {
                walk_primary(&mut person, primary, heading_err);
            } else {
                apply_ds(ds.check_lost(p1.t), &mut person);
            }
            heading_err =
                ar * heading_err + (1.0 - ar * ar).sqrt() * sigma_heading * gauss(&mut rng);
            continue;
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
            pulses_at_probe = Some(next_pulse);
            break;
        }
        if view.display.pulses == 0 && first_rx.is_none() {
            walk_primary(&mut person, primary, heading_err);
        } else {
            act(cfg, &mut person, &mut plan, &view, heading_err, p1.t);
        }
    }
    let end = window.last().map_or(sc.start, |p| p.p);
    if let Some(r) = rows.last()
        && rx.estimate().is_some()
    {
        snapshots.push(snapshot(&rx, r.t, &V3::from(r.rx), r.display.status));
    }
    let final_est = match cfg.policy {
        // The estimate is relative to the receiver at its last pulse (robocentric G_k):
        // placed from that pulse's pose, as each row is — not from where the rescuer
        // stands when the loop ends, up to a reading lag of walking later.
        Policy::Receiver => rx
            .estimate()
            .and_then(|_| rows.last().and_then(|r| r.victim_est))
            .map(V3::from),
        // The classical search's estimate is where it found the maximum.
        Policy::DirectionalSearch => ds.found().map(|f| V3::new(f[0], f[1], tx_p.z)),
    };
    let depth_shown_m = match cfg.policy {
        Policy::Receiver => probe_t.and(rx.display_model().depth_m.map(f64::from)),
        Policy::DirectionalSearch => None,
    };
    Ok(Outcome {
        seed: cfg.seed,
        victim: sc.tx.position,
        start: sc.start.into(),
        ideal_path_m: ideal,
        path_m: window.path_m,
        probe_t,
        end_t: t,
        error_h_m: final_est.map(|v| (v - tx_p).xy().norm()),
        error_z_m: match cfg.policy {
            Policy::Receiver => final_est.map(|v| (v.z - tx_p.z).abs()),
            Policy::DirectionalSearch => None,
        },
        miss_h_m: (tx_p - end).xy().norm(),
        pulses: rows.len(),
        track,
        rows,
        snapshots,
        reinitializations: rx.stats().reinitializations,
        moment: sc.tx.moment,
        period_s: sc.tx.period_s,
        walk_speed_m_s: cfg.step_length_m * cfg.cadence_hz,
        first_rx_t: first_rx.map(|f| f.0),
        first_rx_p: first_rx.map(|f| f.1.into()),
        path_at_first_rx_m: first_rx.map_or(window.path_m, |f| f.3),
        pulses_to_probe: pulses_at_probe
            .zip(first_rx)
            .map(|(n, f)| n.saturating_sub(f.2)),
        pulses_from_start: pulses_at_probe,
        depth_shown_m,
        end_p: end.into(),
        lifts: plan.lifts,
        height_moves: plan.height_moves,
    })
}

/// Primary search: straight on along `heading` (with the rescuer's heading error), or
/// stand when there is none.
pub(crate) fn walk_primary(person: &mut Person, heading: Option<f64>, heading_err: f64) {
    match heading {
        Some(h) => {
            person.psi_des = h + heading_err;
            person.w_target = 1.0;
        }
        None => person.w_target = 0.0,
    }
}

/// Applies a directional-search command to the rescuer.
fn apply_ds(cmd: Option<DsCommand>, person: &mut Person) {
    match cmd {
        Some(DsCommand::Heading { psi, walk }) => {
            person.psi_des = psi;
            person.w_target = if walk { 1.0 } else { 0.0 };
        }
        Some(DsCommand::MoveTo { xy, height }) => {
            person.crawl_to = Some(xy);
            if let Some(h) = height {
                person.hold_height = h;
            }
        }
        None => {}
    }
}

/// What the directional search sees of the rescuer.
fn ds_view(person: &Person) -> RescuerView {
    RescuerView {
        device_xy: person.device_xy(),
        heading: person.psi,
    }
}

/// The rescuer's reaction to what they saw.
pub(crate) fn act(
    cfg: &ClosedLoopConfig,
    person: &mut Person,
    plan: &mut StepPlan,
    view: &Seen,
    heading_err: f64,
    t: f64,
) {
    let d = &view.display;
    if height_prompt(person, plan, d, t) {
        return;
    }
    // A lift under way: stand until it is over.
    if let Some(t0) = person.lift_t0 {
        person.w_target = 0.0;
        plan.lift_pulse = plan.lift_pulse.max(d.pulses);
        if t < t0 + LIFT_S {
            return;
        }
        person.lift_t0 = None;
        plan.stopped_at = t;
    }
    // "LIFT": stand, then lift the receiver up and down (once per new prompt).
    if d.lift {
        person.w_target = 0.0;
        plan.end_phase = None;
        if d.pulses > plan.lift_pulse && person.w < 1e-3 && person.crawl_to.is_none() {
            person.lift_t0 = Some(t);
            plan.lift_pulse = d.pulses;
            plan.lifts += 1;
        }
        plan.stopped_at = t;
        return;
    }
    let Some(arrow) = d.arrow_deg else {
        // Nothing to follow: stand (before the first signal) or keep going; when the
        // signal is lost, turn back once (toward where it was last heard).
        if d.pulses == 0 {
            person.w_target = 0.0;
        } else if d.status == Status::NoSignal && !plan.turned_back {
            plan.turned_back = true;
            person.psi_des = person.psi + PI;
            person.w_target = 0.0;
        } else {
            let off = wrap_pi(person.psi_des - person.psi).abs();
            person.w_target = if off > 0.9 { 0.0 } else { 1.0 };
        }
        return;
    };
    plan.turned_back = false;
    let desired = view.psi + f64::from(arrow).to_radians() + heading_err;
    // Near the shown point the walk goes step by step, also to a silent victim's estimate
    // (shown under "no signal").
    let fine = matches!(d.status, Status::Localized | Status::NoSignal)
        && d.walk_m.is_some_and(|w| f64::from(w) < cfg.fine_walk_m);
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
    if person.w > 1e-3 {
        // Not yet standing.
        plan.stopped_at = t;
        return;
    }
    // A display update taken after standing still: plan the next steps.
    if d.pulses > plan.acted_pulse && d.t_s > plan.stopped_at {
        plan.acted_pulse = d.pulses;
        let walk = f64::from(d.walk_m.unwrap_or(0.0));
        let n = (walk / cfg.step_length_m).round().min(3.0);
        if n >= 1.0 {
            person.psi_des = desired;
            plan.end_phase = Some(person.phase + n);
        }
    }
}

/// "LOWER TO SNOW" / "RAISE TO 1M": stop, pause [`SETTLE_S`] at rest, then move the
/// receiver to the asked height over [`HEIGHT_MOVE_S`]. Returns whether the rescuer is
/// busy with it (stands).
fn height_prompt(person: &mut Person, plan: &mut StepPlan, d: &DisplayModel, t: f64) -> bool {
    if let Some((t0, _, to)) = person.height_move {
        person.w_target = 0.0;
        if t < t0 + HEIGHT_MOVE_S {
            return true;
        }
        person.hold_height = to;
        person.height_move = None;
        plan.stopped_at = t;
    }
    let to = match d.height_prompt {
        HeightPrompt::None => return false,
        HeightPrompt::Lower => LOW_HOLD_M,
        HeightPrompt::Raise => HOLD_HEIGHT_M,
    };
    person.w_target = 0.0;
    plan.end_phase = None;
    plan.stopped_at = plan.stopped_at.max(t - person.still_s);
    // A lift under way is finished first.
    if person.lift_t0.is_some_and(|t0| t >= t0 + LIFT_S) {
        person.lift_t0 = None;
    }
    if person.still_s >= SETTLE_S
        && person.crawl_to.is_none()
        && person.lift_t0.is_none()
        && (to - person.hold_height).abs() > 0.1
    {
        person.height_move = Some((t, person.hold_height, to));
        plan.height_moves += 1;
    }
    true
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

    #[test]
    fn a_rescuer_lowers_the_receiver_and_its_height_is_tracked() {
        // Seed 35: a victim 1.5 m deep, deep enough for the lowering.
        let o = run(&ClosedLoopConfig::new(35), &mut |_, _| {}).expect("run");
        assert!(o.probe_t.is_some(), "reached probe here");
        assert!(o.height_moves >= 1, "the receiver was lowered");
        let last = o.rows.last().expect("pulses");
        // The true receiver is near the snow (within the 4 cm step bounce of 0.2 m), and
        // the tracked height agrees with it.
        assert!(last.rx[2] < LOW_HOLD_M + 0.05, "true height {}", last.rx[2]);
        let tracked = f64::from(last.display.height_m);
        assert!((tracked - last.rx[2]).abs() < 0.06, "tracked {tracked}");
        // The depth shown is below the snow, not below the receiver.
        let depth = o.depth_shown_m.expect("depth shown");
        assert!(
            (depth + o.victim[2]).abs() < 0.3,
            "depth {depth} vs {}",
            -o.victim[2]
        );
        // Without the prompt the whole fine search stays at the walking height.
        let mut cfg = ClosedLoopConfig::new(35);
        cfg.lower = false;
        let o = run(&cfg, &mut |_, _| {}).expect("run");
        assert_eq!(o.height_moves, 0);
        let last = o.rows.last().expect("pulses");
        assert!(last.rx[2] > HOLD_HEIGHT_M - 0.05);
        assert!((f64::from(last.display.height_m) - HOLD_HEIGHT_M).abs() < 0.02);
    }
}
