//! Team scenarios: 2–4 rescuers searching one debris field with 2–5 buried transmitters,
//! each rescuer walking to a subset of the victims (the subsets overlap) and recording its
//! own session log.
//!
//! What makes the logs independent, as real receivers' would be:
//! - each receiver's clock has its own epoch (0–1000 s) and rate error (±`clock_ppm`);
//! - each log's `src` labels are local: the front end numbers the transmitters in the
//!   order it first heard them, so the same victim has different labels in different logs
//!   and association must go by signature;
//! - each rescuer's start is known only from a GNSS fix with σ = `start_fix_sigma_m`
//!   (`starts.json`, the only shared input besides the logs).
use crate::io::receiver_config::{Pdr, ReceiverConfig};
use crate::io::session::{Header, Imu, Pulse, Session};
use crate::sensors::{ImuModel, PulseModel, SensorConfig, quantize, round_significant};
use crate::world::rescuer::{GaitParams, Plan, Rescuer, Waypoint, wrap_pi};
use crate::world::scenario::{draw_person, merge, stream};
use crate::world::transmitter::{Transmitter, TransmitterSpec};
use crate::world::{World, earth_field_ut};
use anyhow::Context;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What defines one team scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeamConfig {
    /// Seed of every random draw.
    pub seed: u64,
    /// Rescuers (2–4).
    pub rescuers: usize,
    /// Victims (2–5).
    pub victims: usize,
    /// Side of the square debris field holding the victims, m.
    pub field_m: f64,
    /// σ of each rescuer's GNSS start fix, m.
    pub start_fix_sigma_m: f64,
    /// Largest receiver clock rate error, ppm.
    pub clock_ppm: f64,
    /// Sensors of every receiver.
    pub sensors: SensorConfig,
}

impl TeamConfig {
    /// Defaults for `rescuers` and `victims` (clamped to 2–4 and 2–5) with a seed.
    pub fn new(seed: u64, rescuers: usize, victims: usize) -> Self {
        Self {
            seed,
            rescuers: rescuers.clamp(2, 4),
            victims: victims.clamp(2, 5),
            field_m: 60.0,
            start_fix_sigma_m: 2.0,
            clock_ppm: 20.0,
            sensors: SensorConfig::default(),
        }
    }
}

/// A rescuer's GNSS start fix (`starts.json`: one per log, in the logs' order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StartFix {
    /// Position (north, west), m.
    pub p: [f64; 2],
    /// σ per axis, m.
    pub sigma_m: f64,
}

/// The truth of one rescuer (evaluation only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RescuerTruth {
    /// True start (north, west), m.
    pub start: [f64; 2],
    /// The victims the route visits (transmitter indices).
    pub visits: Vec<usize>,
    /// Log clock: `t_log = epoch_s + t (1 + rate_ppm·1e-6)`.
    pub epoch_s: f64,
    /// Clock rate error, ppm.
    pub rate_ppm: f64,
    /// `src_map[label]`: the transmitter behind each local `src` label.
    pub src_map: Vec<usize>,
}

/// The truth of a team scenario (`team-truth.json`, evaluation only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeamTruth {
    /// The configuration.
    pub config: TeamConfig,
    /// The transmitters.
    pub transmitters: Vec<Transmitter>,
    /// Per rescuer.
    pub rescuers: Vec<RescuerTruth>,
}

/// A simulated team search.
#[derive(Debug, Clone)]
pub struct TeamSim {
    /// Truth.
    pub truth: TeamTruth,
    /// Per rescuer: session log, truth log, receiver configuration, start fix.
    pub logs: Vec<(Session, Session, ReceiverConfig, StartFix)>,
}

fn normal(rng: &mut impl Rng) -> f64 {
    StandardNormal.sample(rng)
}

fn place_victims(cfg: &TeamConfig, rng: &mut ChaCha8Rng) -> Vec<Transmitter> {
    let mut out: Vec<Transmitter> = Vec::new();
    let spec = TransmitterSpec::default();
    let half = 0.5 * cfg.field_m;
    let mut tries = 0;
    while out.len() < cfg.victims && tries < 10_000 {
        tries += 1;
        let p = [
            quantize(15.0 + rng.random_range(0.0..cfg.field_m), 1e3),
            quantize(rng.random_range(-half..half), 1e3),
            quantize(-rng.random_range(0.3..2.0), 1e3),
        ];
        let far = out
            .iter()
            .all(|t| (t.position[0] - p[0]).hypot(t.position[1] - p[1]) > 10.0);
        let mut tx = Transmitter::random(rng, &spec, p);
        // Periods at least 5 ms apart: distinct transmitters of one scenario (the limit
        // of signatures is stated in the report, not exercised by chance here).
        let distinct = out.iter().all(|t| (t.period_s - tx.period_s).abs() > 5e-3);
        if far && distinct {
            tx.moment = tx.moment.map(|x| round_significant(x, 6));
            tx.period_s = quantize(tx.period_s, 1e5);
            tx.on_time_s = quantize(tx.on_time_s, 1e4);
            tx.phase_s = quantize(tx.phase_s, 1e4);
            out.push(tx);
        }
    }
    out
}

/// Which victims each rescuer walks to: victim `v` belongs to rescuer `v mod R`; victim 0
/// is also visited by rescuer 1 and other victims, with probability ½, by the next rescuer.
/// The last victim stays with one rescuer when there are more victims than rescuers.
fn assign(cfg: &TeamConfig, rng: &mut ChaCha8Rng, n: usize) -> Vec<Vec<usize>> {
    let r = cfg.rescuers;
    let mut visits = vec![Vec::new(); r];
    for v in 0..n {
        visits[v % r].push(v);
        let single = v + 1 == n && n > r;
        if v == 0 || (!single && rng.random::<bool>()) {
            visits[(v + 1) % r].push(v);
        }
    }
    visits
}

/// Waypoints every ≤ 5 m from `a` to `b` (excluding `a`).
fn segment(a: [f64; 2], b: [f64; 2], out: &mut Vec<Waypoint>) {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let n = (dx.hypot(dy) / 5.0).ceil().max(1.0) as usize;
    for i in 1..=n {
        let f = i as f64 / n as f64;
        out.push(Waypoint {
            p: [quantize(a[0] + f * dx, 1e3), quantize(a[1] + f * dy, 1e3)],
            stop_s: 0.0,
        });
    }
}

fn route(start: [f64; 2], targets: &[[f64; 2]], rng: &mut ChaCha8Rng) -> Vec<Waypoint> {
    let mut out = Vec::new();
    let mut at = start;
    for t in targets {
        // Pass 1–2 m beside the victim (a fine search ends within a metre or two) and
        // stand there a few seconds (probing).
        let b = rng.random_range(0.0..std::f64::consts::TAU);
        let d = rng.random_range(1.0..2.0);
        let p = [t[0] + d * b.cos(), t[1] + d * b.sin()];
        segment(at, p, &mut out);
        if let Some(w) = out.last_mut() {
            w.stop_s = quantize(rng.random_range(3.0..6.0), 1e2);
        }
        at = p;
    }
    out
}

/// A receiver's clock: `t_log = epoch_s + t (1 + rate_ppm·1e-6)`, at 10 µs resolution.
#[derive(Debug, Clone, Copy)]
struct Clock {
    epoch_s: f64,
    rate_ppm: f64,
}

impl Clock {
    fn at(&self, t: f64) -> f64 {
        quantize(self.epoch_s + t * (1.0 + self.rate_ppm * 1e-6), 1e5)
    }
}

/// Rescuer `r`'s start on the start line (its lane), gait and walk to its victims.
fn walker(
    cfg: &TeamConfig,
    r: usize,
    transmitters: &[Transmitter],
    visits: &[usize],
    rng: &mut ChaCha8Rng,
) -> ([f64; 2], GaitParams, Rescuer) {
    let half = 0.5 * cfg.field_m;
    let lane = cfg.field_m / cfg.rescuers as f64;
    let start = [
        quantize(rng.random_range(-5.0..0.0), 1e3),
        quantize(
            -half + (r as f64 + 0.5) * lane + rng.random_range(-3.0..3.0),
            1e3,
        ),
    ];
    let mut order: Vec<usize> = visits.to_vec();
    order.sort_by(|a, b| {
        let d = |i: &usize| transmitters.get(*i).map_or(0.0, |t| t.position[0]);
        d(a).total_cmp(&d(b))
    });
    let targets: Vec<[f64; 2]> = order
        .iter()
        .filter_map(|&i| transmitters.get(i).map(|t| [t.position[0], t.position[1]]))
        .collect();
    // A rescuer without an assigned victim sweeps its lane to the far end of the field.
    let waypoints = if targets.is_empty() {
        let mut w = Vec::new();
        segment(start, [15.0 + cfg.field_m, start[1]], &mut w);
        w
    } else {
        route(start, &targets, rng)
    };
    let (gait, hold) = draw_person(rng);
    let first = waypoints.first().map_or(start, |w| w.p);
    let plan = Plan {
        start,
        start_heading_rad: quantize(
            wrap_pi((first[1] - start[1]).atan2(first[0] - start[0]) + 0.3 * normal(rng)),
            1e4,
        ),
        start_wait_s: 2.0,
        waypoints,
        end_wait_s: 3.0,
    };
    let rescuer = Rescuer::new(rng, gait.clone(), hold, &plan, MAX_DURATION_S);
    (start, gait, rescuer)
}

/// Longest walk, s.
const MAX_DURATION_S: f64 = 1200.0;

/// The received pulses of all transmitters up to `duration` with local `src` labels (the
/// order in which this receiver first heard each transmitter): the pulses on the log's
/// clock, the label map and the pulses' true times.
fn labelled_pulses(
    world: &World,
    duration: f64,
    model: &mut PulseModel,
    clock: Clock,
) -> (Vec<Pulse>, Vec<usize>, Vec<f64>) {
    let times = world.pulse_schedule(duration);
    let mut src_map: Vec<usize> = Vec::new();
    let mut pulses = Vec::new();
    let mut truth_times = Vec::new();
    for (t, i) in times {
        if let Some(mut p) = model.measure(world, i, t) {
            let label = match src_map.iter().position(|&x| x == i) {
                Some(l) => l,
                None => {
                    src_map.push(i);
                    src_map.len() - 1
                }
            };
            p.src = Some(label as u32);
            p.t = clock.at(t);
            truth_times.push(t);
            pulses.push(p);
        }
    }
    (pulses, src_map, truth_times)
}

/// Truth records at 2 Hz and at every pulse (`extra` true times), on the log's clock.
fn truth_log(
    world: &World,
    header: Header,
    duration: f64,
    extra: Vec<f64>,
    clock: Clock,
) -> Session {
    let mut truth = Session::new(header);
    truth.records = world.truth_records(2.0, duration, extra, |t| clock.at(t));
    truth
}

/// What the receiver is told (its calibrated step length, 2 % off) and the GNSS start fix.
fn receiver_and_fix(
    cfg: &TeamConfig,
    rng: &mut ChaCha8Rng,
    gait: &GaitParams,
    start: [f64; 2],
) -> (ReceiverConfig, StartFix) {
    let receiver = ReceiverConfig {
        sign_ambiguous: cfg.sensors.sign_ambiguous,
        pulse_noise: cfg.sensors.pulse.clone(),
        imu: cfg.sensors.imu.clone(),
        victim_depth_range_m: [0.0, 3.0],
        pdr: Some(Pdr {
            step_length_m: quantize(gait.step_length_m * (1.0 + 0.02 * normal(rng)), 1e3),
        }),
        ..ReceiverConfig::default()
    };
    let s = cfg.start_fix_sigma_m;
    let fix = StartFix {
        p: [
            quantize(start[0] + s * normal(rng), 1e2),
            quantize(start[1] + s * normal(rng), 1e2),
        ],
        sigma_m: s,
    };
    (receiver, fix)
}

/// Simulates rescuer `r` of the team.
fn simulate_rescuer(
    cfg: &TeamConfig,
    r: usize,
    transmitters: &[Transmitter],
    visits: &[usize],
) -> ((Session, Session, ReceiverConfig, StartFix), RescuerTruth) {
    let base = 100 + 10 * r as u64;
    let mut rng = stream(cfg.seed, base);
    let (start, gait, rescuer) = walker(cfg, r, transmitters, visits, &mut rng);
    let world = World {
        transmitters: transmitters.to_vec(),
        rescuer,
        earth_field_ut: earth_field_ut(48.0, 63.0).map(|x| quantize(x, 1e3)),
    };
    let duration = world.end_s().min(MAX_DURATION_S);
    let clock = Clock {
        epoch_s: quantize(rng.random_range(0.0..1000.0), 1e3),
        rate_ppm: quantize(rng.random_range(-cfg.clock_ppm..=cfg.clock_ppm), 1e2),
    };
    let mut imu_model = ImuModel::new(cfg.sensors.imu.clone(), stream(cfg.seed, base + 1));
    let mut pulse_model = PulseModel::new(cfg.sensors.clone(), stream(cfg.seed, base + 2));
    let hz = cfg.sensors.imu.hz;
    let imu: Vec<Imu> = (0..=(duration * hz).floor() as u64)
        .map(|k| {
            let mut s = imu_model.sample(&world, k as f64 / hz);
            s.t = clock.at(s.t);
            s
        })
        .collect();
    let (pulses, src_map, truth_times) = labelled_pulses(&world, duration, &mut pulse_model, clock);
    let header = Header::new(hz, world.earth_field_ut, cfg.sensors.sign_ambiguous);
    let mut session = Session::new(header.clone());
    session.records = merge(imu, pulses);
    let truth = truth_log(&world, header, duration, truth_times, clock);
    let (receiver, fix) = receiver_and_fix(cfg, &mut stream(cfg.seed, base + 3), &gait, start);
    let rt = RescuerTruth {
        start,
        visits: visits.to_vec(),
        epoch_s: clock.epoch_s,
        rate_ppm: clock.rate_ppm,
        src_map,
    };
    ((session, truth, receiver, fix), rt)
}

/// Draws and simulates a team scenario (rescuers in parallel).
pub fn simulate(cfg: &TeamConfig) -> TeamSim {
    use rayon::prelude::*;
    let mut rng = stream(cfg.seed, 0);
    let transmitters = place_victims(cfg, &mut rng);
    let visits = assign(cfg, &mut rng, transmitters.len());
    let runs: Vec<_> = (0..cfg.rescuers)
        .into_par_iter()
        .map(|r| simulate_rescuer(cfg, r, &transmitters, visits.get(r).map_or(&[], |v| v)))
        .collect();
    let (logs, rescuers) = runs.into_iter().unzip();
    TeamSim {
        truth: TeamTruth {
            config: cfg.clone(),
            transmitters,
            rescuers,
        },
        logs,
    }
}

fn write_log(s: &Session, path: &Path) -> anyhow::Result<()> {
    use std::io::Write;
    let mut f = crate::io::session::create_file(path)
        .with_context(|| format!("creating {}", path.display()))?;
    s.write(&mut f)?;
    f.flush()?;
    Ok(())
}

/// Writes `dir/r<i>/{session.jsonl,truth.jsonl,receiver.json}`, `dir/starts.json` and
/// `dir/team-truth.json`; returns the session-log paths.
pub fn write(sim: &TeamSim, dir: &Path) -> anyhow::Result<Vec<std::path::PathBuf>> {
    let mut paths = Vec::new();
    for (i, (session, truth, receiver, _)) in sim.logs.iter().enumerate() {
        let d = dir.join(format!("r{i}"));
        std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
        let p = d.join("session.jsonl");
        write_log(session, &p)?;
        write_log(truth, &d.join("truth.jsonl"))?;
        std::fs::write(d.join("receiver.json"), receiver.to_json())?;
        paths.push(p);
    }
    let starts: Vec<StartFix> = sim.logs.iter().map(|l| l.3).collect();
    std::fs::write(
        dir.join("starts.json"),
        serde_json::to_string_pretty(&starts)?,
    )?;
    std::fs::write(
        dir.join("team-truth.json"),
        serde_json::to_string_pretty(&sim.truth)?,
    )?;
    Ok(paths)
}
