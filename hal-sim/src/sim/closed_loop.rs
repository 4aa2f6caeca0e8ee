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

mod act;
mod person;
pub(crate) use act::*;
pub use person::*;

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

#[cfg(test)]
mod tests;
