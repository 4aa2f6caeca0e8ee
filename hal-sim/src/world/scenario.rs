//! Seeded scenarios: the world, the sensors and the receiver configuration of one
//! simulated search, from a preset and a seed. The same configuration gives the same
//! bytes on every run.
//!
//! Presets (all start the rescuer at the origin, the victim 40–70 m away horizontally at
//! a random bearing, 0.3–3 m deep, with random moment direction and power; one pulse per
//! second; a person walking at about 1 m/s):
//! - `paper`: the papers' protocol (IROS/ICRA 2006): walk straight toward the victim
//!   (miss distance ≤ 3 m) and stop just past it.
//! - `line`: a straight line passing 5–20 m beside the victim, continuing 20 m past.
//! - `arc`: a circular arc leaving 20–50° off the bearing and ending 1–3 m from the victim.
//! - `flux-line`: the classical flux-line search, following the horizontal field direction.
//! - `zigzag`: a 40 m wide zig-zag strip search along a bearing near the victim's.
//! - hard cases, on the `paper` route: `deep` (3 m burial), `vertical` (vertical moment),
//!   `far` (70 m start), `gyro-bias` (gyro bias up to 0.05 rad/s per axis).
use crate::io::receiver_config::{Pdr, ReceiverConfig};
use crate::io::session::{Header, Imu, Pulse, Record, Session};
use crate::sensors::{ImuModel, PulseModel, SensorConfig, quantize, round_significant};
use crate::world::rescuer::{GaitParams, HoldParams, Plan, Rescuer, Waypoint, wrap_pi};
use crate::world::routes::{self, Stops};
use crate::world::transmitter::{Transmitter, TransmitterSpec};
use crate::world::{World, earth_field_ut};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// A named scenario family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// The papers' protocol: straight toward the victim, stop just past it.
    Paper,
    /// Straight line passing 5–20 m beside the victim.
    Line,
    /// Circular arc ending near the victim.
    Arc,
    /// Classical flux-line search.
    FluxLine,
    /// Zig-zag strip search.
    Zigzag,
    /// `paper` with the victim 3 m deep.
    Deep,
    /// `paper` with a vertical transmitter moment.
    Vertical,
    /// `paper` starting 70 m away.
    Far,
    /// `paper` with a large gyro bias (up to 0.05 rad/s per axis).
    GyroBias,
}

/// Everything that defines one simulated search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioConfig {
    /// Route family and hard case.
    pub preset: Preset,
    /// Seed of every random draw.
    pub seed: u64,
    /// Longest simulated time, s.
    pub max_duration_s: f64,
    /// Number of transmitters (the first one is the preset's target).
    pub victims: usize,
    /// Range of the initial horizontal distance to the target, m.
    pub start_distance_m: [f64; 2],
    /// Range of burial depths below the snow surface, m.
    pub depth_m: [f64; 2],
    /// Transmitter power and pulse ranges.
    pub transmitter: TransmitterSpec,
    /// Sensor noise.
    pub sensors: SensorConfig,
    /// Earth's field magnitude, µT.
    pub earth_total_ut: f64,
    /// Earth's field inclination, degrees downward.
    pub earth_inclination_deg: f64,
    /// Whether `receiver.json` carries the person's calibrated step length.
    pub calibrated: bool,
    /// Relative standard deviation of that calibration.
    pub step_calibration_rel_sigma: f64,
    /// Rate of the truth records (plus one at every pulse), Hz.
    pub truth_hz: f64,
    /// Random stops along the route.
    pub random_stops: bool,
}

impl ScenarioConfig {
    /// The defaults of a preset with a seed.
    pub fn new(preset: Preset, seed: u64) -> Self {
        let mut c = Self {
            preset,
            seed,
            max_duration_s: 900.0,
            victims: 1,
            start_distance_m: [40.0, 70.0],
            depth_m: [0.3, 3.0],
            transmitter: TransmitterSpec::default(),
            sensors: SensorConfig::default(),
            earth_total_ut: 48.0,
            earth_inclination_deg: 63.0,
            calibrated: true,
            step_calibration_rel_sigma: 0.02,
            truth_hz: 10.0,
            random_stops: true,
        };
        match preset {
            Preset::Deep => c.depth_m = [3.0, 3.0],
            Preset::Far => c.start_distance_m = [70.0, 70.0],
            Preset::GyroBias => c.sensors.imu.gyr_bias_max_rad_s = 0.05,
            _ => {}
        }
        c
    }
}

/// The random choices of a scenario beyond the world itself (for `scenario.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioDraw {
    /// The configuration.
    pub config: ScenarioConfig,
    /// The transmitters.
    pub transmitters: Vec<Transmitter>,
    /// The person's gait.
    pub gait: GaitParams,
    /// How the receiver is held.
    pub hold: HoldParams,
    /// The route.
    pub plan: Plan,
    /// The gyro's constant bias, rad/s.
    pub gyr_bias_rad_s: [f64; 3],
    /// Simulated duration, s.
    pub duration_s: f64,
}

/// A generated search: the log, its truth and the receiver configuration.
#[derive(Debug, Clone)]
pub struct Simulation {
    /// All random choices.
    pub draw: ScenarioDraw,
    /// The world (for truth queries).
    pub world: World,
    /// The session log (header, IMU and pulses).
    pub session: Session,
    /// The ground truth (header and truth records).
    pub truth: Session,
    /// What the receiver is told.
    pub receiver: ReceiverConfig,
    /// When each pulse record (in `session` order) was written, s: the session log is then
    /// written in a receiver's order with `seq` ([`crate::io::session::write_as_written`]);
    /// `None`: sorted by `t` (the measurement level).
    pub pulse_written_t: Option<Vec<f64>>,
    /// The device's event records (the bus level's `gain` events): `t` (s) and the line as
    /// the board's writer wrote it, without `seq`; written among the records by `t` when
    /// [`Simulation::pulse_written_t`] is given.
    pub device_events: Vec<(f64, String)>,
}

/// Independent random streams of one seed (shared with the bus level so both levels
/// draw the same noise).
pub fn stream(seed: u64, id: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(id);
    r
}

fn normal(rng: &mut impl Rng) -> f64 {
    StandardNormal.sample(rng)
}

fn place_transmitters(cfg: &ScenarioConfig, rng: &mut ChaCha8Rng) -> Vec<Transmitter> {
    let mut out = Vec::new();
    let depth = |rng: &mut ChaCha8Rng| rng.random_range(cfg.depth_m[0]..=cfg.depth_m[1]);
    let d0 = rng.random_range(cfg.start_distance_m[0]..=cfg.start_distance_m[1]);
    let b0 = routes::random_bearing(rng);
    let mut pos = [d0 * b0.cos(), d0 * b0.sin(), -depth(rng)];
    for i in 0..cfg.victims.max(1) {
        if i > 0 {
            let (r, b) = (rng.random_range(5.0..30.0), routes::random_bearing(rng));
            pos = [
                out_first(&out)[0] + r * b.cos(),
                out_first(&out)[1] + r * b.sin(),
                -depth(rng),
            ];
        }
        let mut tx = Transmitter::random(rng, &cfg.transmitter, pos.map(|x| quantize(x, 1e3)));
        if cfg.preset == Preset::Vertical && i == 0 {
            let m = crate::world::physics::V3::from(tx.moment).norm();
            tx.moment = [0.0, 0.0, if rng.random::<bool>() { m } else { -m }];
        }
        tx.moment = tx.moment.map(|x| round_significant(x, 6));
        tx.period_s = quantize(tx.period_s, 1e4);
        tx.on_time_s = quantize(tx.on_time_s, 1e4);
        tx.phase_s = quantize(tx.phase_s, 1e4);
        tx.carrier_hz = quantize(tx.carrier_hz, 10.0);
        out.push(tx);
    }
    out
}

fn out_first(v: &[Transmitter]) -> [f64; 3] {
    v.first().map_or([0.0; 3], |t| t.position)
}

fn route(
    cfg: &ScenarioConfig,
    rng: &mut ChaCha8Rng,
    tx: &Transmitter,
    hold: &HoldParams,
) -> Vec<Waypoint> {
    let start = [0.0, 0.0];
    let target = [tx.position[0], tx.position[1]];
    let stops = if cfg.random_stops {
        Stops::DEFAULT
    } else {
        Stops::NONE
    };
    let side = |rng: &mut ChaCha8Rng| if rng.random::<bool>() { 1.0 } else { -1.0 };
    match cfg.preset {
        Preset::Paper | Preset::Deep | Preset::Vertical | Preset::Far | Preset::GyroBias => {
            let miss = rng.random_range(-3.0..=3.0);
            routes::line(rng, start, target, miss, 2.0, stops)
        }
        Preset::Line => {
            let miss = side(rng) * rng.random_range(5.0..=20.0);
            routes::line(rng, start, target, miss, 20.0, stops)
        }
        Preset::Arc => {
            let a = side(rng) * rng.random_range(20f64..=50.0).to_radians();
            let (dx, dy) = (target[0], target[1]);
            let d = dx.hypot(dy);
            let miss = rng.random_range(1.0..=3.0) / d.max(1.0);
            let end = [target[0] - dy * miss, target[1] + dx * miss];
            routes::arc(rng, start, end, a, stops)
        }
        Preset::FluxLine => routes::flux_line(rng, start, tx, hold.height_m, 300.0, stops),
        Preset::Zigzag => {
            let bearing = target[1].atan2(target[0]) + rng.random_range(-0.35..=0.35);
            let along = target[0] * bearing.cos() + target[1] * bearing.sin();
            routes::zigzag(rng, start, bearing, 40.0, 12.0, along + 10.0, stops)
        }
    }
}

/// Draws a rescuer's gait and how they hold the receiver (step length 0.50–0.62 m, cadence
/// 1.7–1.9 Hz, 0.9–1.1 m above the snow, pitched 0–0.25 rad).
pub(crate) fn draw_person(rng: &mut ChaCha8Rng) -> (GaitParams, HoldParams) {
    let gait = GaitParams {
        step_length_m: quantize(rng.random_range(0.50..=0.62), 1e3),
        cadence_hz: quantize(rng.random_range(1.7..=1.9), 1e3),
        ..GaitParams::default()
    };
    let hold = HoldParams {
        height_m: quantize(rng.random_range(0.9..=1.1), 1e3),
        pitch_rad: quantize(rng.random_range(0.0..=0.25), 1e3),
        ..HoldParams::default()
    };
    (gait, hold)
}

/// Draws and simulates a scenario.
pub fn simulate(cfg: &ScenarioConfig) -> Simulation {
    let mut rng_world = stream(cfg.seed, 0);
    let mut rng_person = stream(cfg.seed, 1);
    let transmitters = place_transmitters(cfg, &mut rng_world);
    let (gait, hold) = draw_person(&mut rng_person);
    let waypoints = match transmitters.first() {
        Some(tx) => route(cfg, &mut rng_world, tx, &hold),
        None => Vec::new(),
    };
    let first_bearing = waypoints.first().map_or(0.0, |w| w.p[1].atan2(w.p[0]));
    let plan = Plan {
        start: [0.0, 0.0],
        start_heading_rad: quantize(wrap_pi(first_bearing + 0.35 * normal(&mut rng_person)), 1e4),
        start_wait_s: 2.0,
        waypoints,
        end_wait_s: 3.0,
    };
    let rescuer = Rescuer::new(
        &mut rng_person,
        gait.clone(),
        hold.clone(),
        &plan,
        cfg.max_duration_s,
    );
    let world = World {
        transmitters: transmitters.clone(),
        rescuer,
        earth_field_ut: earth_field_ut(cfg.earth_total_ut, cfg.earth_inclination_deg)
            .map(|x| quantize(x, 1e3)),
    };
    let duration = world.end_s().min(cfg.max_duration_s);
    let mut imu_model = ImuModel::new(cfg.sensors.imu.clone(), stream(cfg.seed, 2));
    let mut pulse_model = PulseModel::new(cfg.sensors.clone(), stream(cfg.seed, 3));

    let hz = cfg.sensors.imu.hz;
    let n_imu = (duration * hz).floor() as u64;
    let imu: Vec<Imu> = (0..=n_imu)
        .map(|k| imu_model.sample(&world, k as f64 / hz))
        .collect();
    let pulse_times = world.pulse_schedule(duration);
    let pulses: Vec<Pulse> = pulse_times
        .iter()
        .filter_map(|&(t, i)| pulse_model.measure(&world, i, t))
        .collect();

    let header = Header::new(hz, world.earth_field_ut, cfg.sensors.sign_ambiguous);
    let mut session = Session::new(header.clone());
    session.records = merge(imu, pulses.clone());

    let mut truth = Session::new(header);
    truth.records = world.truth_records(cfg.truth_hz, duration, pulses.iter().map(|p| p.t), |t| t);

    let mut rng_cal = stream(cfg.seed, 4);
    let [lo, hi] = cfg.transmitter.moment_range;
    let receiver = ReceiverConfig {
        m_min: lo,
        m_max: hi,
        m_nom: round_significant((lo * hi).sqrt(), 3),
        sign_ambiguous: cfg.sensors.sign_ambiguous,
        pulse_noise: cfg.sensors.pulse.clone(),
        imu: cfg.sensors.imu.clone(),
        victim_depth_range_m: cfg.depth_m,
        receiver_height_m: 1.0,
        pdr: cfg.calibrated.then(|| Pdr {
            step_length_m: quantize(
                gait.step_length_m * (1.0 + cfg.step_calibration_rel_sigma * normal(&mut rng_cal)),
                1e3,
            ),
        }),
    };
    let b = imu_model.gyr_bias;
    Simulation {
        draw: ScenarioDraw {
            config: cfg.clone(),
            transmitters,
            gait,
            hold,
            plan,
            gyr_bias_rad_s: [b.x, b.y, b.z],
            duration_s: duration,
        },
        world,
        session,
        truth,
        receiver,
        pulse_written_t: None,
        device_events: Vec::new(),
    }
}

/// Merges time-sorted IMU samples and pulses into one time-sorted record stream (an IMU
/// sample goes first at equal times).
pub(crate) fn merge(imu: Vec<Imu>, pulses: Vec<Pulse>) -> Vec<Record> {
    let mut out = Vec::with_capacity(imu.len() + pulses.len());
    let mut p = pulses.into_iter().peekable();
    for s in imu {
        while let Some(x) = p.next_if(|x| x.t < s.t) {
            out.push(Record::Pulse(x));
        }
        out.push(Record::Imu(s));
    }
    out.extend(p.map(Record::Pulse));
    out
}

impl Simulation {
    /// The session log's bytes.
    pub fn session_bytes(&self) -> Vec<u8> {
        let mut v = Vec::new();
        let _ = match &self.pulse_written_t {
            Some(w) => {
                crate::io::session::write_as_written(&self.session, w, &self.device_events, &mut v)
            }
            None => self.session.write(&mut v),
        };
        v
    }

    /// The truth file's bytes.
    pub fn truth_bytes(&self) -> Vec<u8> {
        let mut v = Vec::new();
        let _ = self.truth.write(&mut v);
        v
    }
}
