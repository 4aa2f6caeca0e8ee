//! End-to-end check of the firmware's motion pipeline (attitude, step detection, dead
//! reckoning, displacement per pulse) on seeded simulated walks, against the world's truth.
//!
//! Prints, per walk: step count error, distance error with the calibrated step length,
//! yaw RMS error of the attitude, walking-direction error per pulse interval, and the
//! displacement error per pulse interval (translation, rotation, NEES).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use firmware::Vec3;
use firmware::frame::{rpy_from_rotation, wrap_pi};
use firmware::motion::{Motion, MotionConfig};
use hal_sim::io::session::Record;
use hal_sim::world::physics::{M3, V3};
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};

struct WalkStats {
    name: String,
    steps_est: u32,
    steps_true: f64,
    dist_est: f64,
    dist_true: f64,
    dist_true_l: f64,
    yaw_rms_deg: f64,
    tilt_rms_deg: f64,
    dir_rms_deg: f64,
    trans_rms_m: f64,
    trans_mean_m: f64,
    rot_rms_deg: f64,
    nees_t: f64,
    nees_r: f64,
    intervals: usize,
}

fn f32m(m: &M3) -> firmware::Mat3 {
    m.map(|x| x as f32)
}

/// Horizontal position of the walker's torso from the receiver's truth (removes the hold
/// offset; sway and hand wobble of a centimetre or two remain).
fn torso(
    world: &hal_sim::world::World,
    hold: &hal_sim::world::rescuer::HoldParams,
    t: f64,
) -> [f64; 2] {
    let s = world.rescuer_state(t);
    let (sn, cs) = s.heading.sin_cos();
    [
        s.p.x - hold.forward_m * cs + hold.left_m * sn,
        s.p.y - hold.forward_m * sn - hold.left_m * cs,
    ]
}

fn run(preset: Preset, seed: u64, max_s: f64) -> WalkStats {
    let mut cfg = ScenarioConfig::new(preset, seed);
    cfg.max_duration_s = max_s;
    let sim = simulate(&cfg);
    let earth = sim.session.header.earth_field_ut.unwrap();
    let step = sim.receiver.pdr.as_ref().map(|p| p.step_length_m as f32);
    let mut m = Motion::new(MotionConfig::new(
        Vec3::new(earth[0] as f32, earth[1] as f32, earth[2] as f32),
        step,
    ));
    let world = &sim.world;
    let (mut yaw_se, mut tilt_se, mut n_att) = (0.0, 0.0, 0usize);
    let (mut dir_se, mut n_dir) = (0.0, 0usize);
    let (mut t_se, mut t_sum, mut r_se, mut nees_t, mut nees_r, mut n_int) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    let mut prev: Option<(f64, firmware::Mat3)> = None;
    for rec in &sim.session.records {
        match rec {
            Record::Imu(s) => {
                let v = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
                let mag = s.mag.map(v);
                m.on_imu_sample(s.t as f32, &v(s.acc), &v(s.gyr), mag.as_ref())
                    .unwrap();
                if s.t > 5.0 {
                    let (rpy, _) = m.attitude();
                    let truth = world.rescuer_state(s.t).rpy;
                    let dy = wrap_pi(rpy.z - truth.z as f32) as f64;
                    let dr = (rpy.x as f64 - truth.x)
                        .abs()
                        .max((rpy.y as f64 - truth.y).abs());
                    yaw_se += dy * dy;
                    tilt_se += dr * dr;
                    n_att += 1;
                }
            }
            Record::Pulse(p) => {
                let (rpy_est, _) = m.attitude();
                let d = m.take_displacement(p.t as f32);
                let r_est_prev = prev.map(|(_, r)| r);
                let r_now_est = firmware::frame::rotation_from_rpy(&rpy_est);
                if let (Some((t0, _)), Some(r0_est)) = (prev, r_est_prev) {
                    let (s0, s1) = (world.rescuer_state(t0), world.rescuer_state(p.t));
                    let r0 = s0.rot;
                    let t_true: V3 = r0.transpose() * (s1.p - s0.p);
                    let rel_true = f32m(&(r0.transpose() * s1.rot));
                    let t_true = Vec3::new(t_true.x as f32, t_true.y as f32, t_true.z as f32);
                    let e_t = d.translation - t_true;
                    let rel_est = firmware::frame::rotation_from_rpy(&d.rotation);
                    let e_r_m = rel_true.transpose() * rel_est;
                    let e_r = rpy_from_rotation(&e_r_m).map(wrap_pi);
                    if std::env::var("MO_DEBUG").is_ok() {
                        println!(
                            "t {:7.2} est {:6.3} {:6.3} {:6.3} true {:6.3} {:6.3} {:6.3} sig {:.3} {:.3} {:.3} steps {} dist {:.2}",
                            p.t,
                            d.translation.x,
                            d.translation.y,
                            d.translation.z,
                            t_true.x,
                            t_true.y,
                            t_true.z,
                            d.cov[(0, 0)].sqrt(),
                            d.cov[(1, 1)].sqrt(),
                            d.cov[(2, 2)].sqrt(),
                            d.steps,
                            d.distance_m
                        );
                    }
                    t_se += e_t.norm_squared() as f64;
                    t_sum += e_t.norm() as f64;
                    r_se += e_r.norm_squared() as f64;
                    let qt = d.cov.fixed_view::<3, 3>(0, 0).into_owned();
                    let qr = d.cov.fixed_view::<3, 3>(3, 3).into_owned();
                    if let (Some(it), Some(ir)) = (qt.try_inverse(), qr.try_inverse()) {
                        nees_t += (e_t.transpose() * it * e_t)[(0, 0)] as f64;
                        nees_r += (e_r.transpose() * ir * e_r)[(0, 0)] as f64;
                    }
                    n_int += 1;
                    // Walking direction of the interval in W (estimated vs true horizontal).
                    let dp = s1.p - s0.p;
                    if dp.xy().norm() > 0.6 {
                        let w_est = r0_est * d.translation;
                        let de = wrap_pi(w_est.y.atan2(w_est.x) - (dp.y.atan2(dp.x)) as f32);
                        dir_se += (de as f64).powi(2);
                        n_dir += 1;
                    }
                }
                prev = Some((p.t, r_now_est));
            }
            _ => {}
        }
    }
    let end = sim.draw.duration_s;
    let steps_true = world.rescuer_state(end).steps;
    // Torso path length, sampled at 0.25 s.
    let hold = &sim.draw.hold;
    let mut dist_true = 0.0;
    let mut last = torso(world, hold, 0.0);
    let n = (end / 0.25) as usize;
    for k in 1..=n {
        let p = torso(world, hold, k as f64 * 0.25);
        dist_true += (p[0] - last[0]).hypot(p[1] - last[1]);
        last = p;
    }
    let rms = |se: f64, n: usize| (se / n.max(1) as f64).sqrt();
    WalkStats {
        name: format!("{preset:?}/{seed}"),
        steps_est: m.total_steps(),
        steps_true,
        dist_est: m.total_distance_m() as f64,
        dist_true,
        dist_true_l: m.total_steps() as f64 * sim.draw.gait.step_length_m,
        yaw_rms_deg: rms(yaw_se, n_att).to_degrees(),
        tilt_rms_deg: rms(tilt_se, n_att).to_degrees(),
        dir_rms_deg: rms(dir_se, n_dir).to_degrees(),
        trans_rms_m: rms(t_se, n_int),
        trans_mean_m: t_sum / n_int.max(1) as f64,
        rot_rms_deg: rms(r_se, n_int).to_degrees(),
        nees_t: nees_t / n_int.max(1) as f64,
        nees_r: nees_r / n_int.max(1) as f64,
        intervals: n_int,
    }
}

fn check(s: &WalkStats) {
    let step_err = (s.steps_est as f64 - s.steps_true) / s.steps_true;
    let dist_err = (s.dist_est - s.dist_true) / s.dist_true;
    println!(
        "{:<12} steps {:>4} vs {:>6.1} ({:+.1} %)  dist {:>6.1} vs {:>6.1} m ({:+.2} %; {:+.2} % at the true mean step length)  \
         yaw rms {:.2}°  tilt rms {:.2}°  walk dir rms {:.2}°  disp/pulse: |Δt| rms {:.3} m \
         (mean {:.3}), rot rms {:.2}°, NEES t {:.2}/3 r {:.2}/3 over {} intervals",
        s.name,
        s.steps_est,
        s.steps_true,
        100.0 * step_err,
        s.dist_est,
        s.dist_true,
        100.0 * dist_err,
        100.0 * (s.dist_true_l - s.dist_true) / s.dist_true,
        s.yaw_rms_deg,
        s.tilt_rms_deg,
        s.dir_rms_deg,
        s.trans_rms_m,
        s.trans_mean_m,
        s.rot_rms_deg,
        s.nees_t,
        s.nees_r,
        s.intervals,
    );
    assert!(s.intervals > 20, "{}", s.name);
    assert!(
        step_err.abs() < 0.04,
        "{}: step count error {step_err}",
        s.name
    );
    assert!(
        dist_err.abs() < 0.05,
        "{}: distance error {dist_err}",
        s.name
    );
    assert!(s.yaw_rms_deg < 3.0, "{}: yaw rms {}", s.name, s.yaw_rms_deg);
    assert!(
        s.tilt_rms_deg < 2.0,
        "{}: tilt rms {}",
        s.name,
        s.tilt_rms_deg
    );
    assert!(
        s.trans_rms_m < 0.3,
        "{}: displacement rms {}",
        s.name,
        s.trans_rms_m
    );
    assert!(
        s.rot_rms_deg < 2.0,
        "{}: rotation rms {}",
        s.name,
        s.rot_rms_deg
    );
    // Q_k must not be wildly over-confident (NEES per 3 dof well below 3× nominal).
    assert!(
        s.nees_t < 9.0 && s.nees_r < 9.0,
        "{}: NEES {} {}",
        s.name,
        s.nees_t,
        s.nees_r
    );
}

#[test]
fn motion_on_line_and_arc_walks() {
    for (preset, seed) in [(Preset::Line, 1), (Preset::Arc, 2), (Preset::Line, 3)] {
        check(&run(preset, seed, 90.0));
    }
}

#[test]
fn motion_on_zigzag_and_gyro_bias_walks() {
    for (preset, seed) in [(Preset::Zigzag, 4), (Preset::GyroBias, 5)] {
        check(&run(preset, seed, 90.0));
    }
}
