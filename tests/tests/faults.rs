//! Fault injection (issue 10): each fault of `hal_sim::sensors::faults` with its defined behaviour,
//! on seeded runs of the real `firmware::app::Receiver` (and the real drivers over the
//! emulated buses for the bus faults). The table is in `hal-sim/reports/reliability.md`.
//!
//! Thresholds are physical, not fitted: a search ends 1–5 m from the victim, where the
//! issue's target is 1 m; a fault the receiver handles must not push it past that.
// Test code: a failed unwrap or a panic is a failed test, the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use firmware::Vec3;
use firmware::app::{AppConfig, AppError, Receiver};
use firmware::drivers::imu::{Chip, Imu, ImuError};
use firmware::guidance::Status;
use firmware::motion::MotionError;
use hal_sim::io::session::Session;
use hal_sim::sensors::ImuModel;
use hal_sim::sensors::bus::imu::{ImuBus, ImuSampler};
use hal_sim::sensors::bus::{NoDelay, SimClock};
use hal_sim::sensors::faults::bus::{
    AdcWindow, Disturbance, Disturbed, FaultWindow, FaultyI2c, I2cFault, PulseKind, SpiFault,
    adc_window, antenna,
};
use hal_sim::sensors::faults::drive::{Trace, drive};
use hal_sim::sensors::faults::measurement;
use hal_sim::sensors::faults::stationary::{self, Stand};
use hal_sim::stamp;
use hal_sim::world::scenario::{Preset, ScenarioConfig, Simulation, simulate, stream};

/// The accuracy target at the end of a search, m.
const TARGET_M: f64 = 1.0;

fn search(seed: u64) -> Simulation {
    simulate(&ScenarioConfig::new(Preset::Paper, seed))
}

fn run(sim: &Simulation, session: &Session) -> Trace {
    drive(session, &sim.receiver, Some(&sim.truth), 0.1).unwrap()
}

fn assert_sane(name: &str, trace: &Trace) {
    assert!(!trace.any_non_finite(), "{name}: a NaN or ∞ came out");
    assert!(
        trace
            .pulses
            .iter()
            .all(|p| p.components <= firmware::estimate::SOG_CAPACITY)
    );
}

fn pulse_times(s: &Session) -> Vec<f64> {
    s.pulses().map(|p| p.t).collect()
}

// ---------------------------------------------------------------- measurement level

#[test]
fn clean_search_meets_the_target() {
    let sim = search(21);
    let trace = run(&sim, &sim.session);
    assert_sane("clean", &trace);
    let e = trace.final_error_m().unwrap();
    println!("clean: final error {e:.3} m, stats {:?}", trace.stats);
    assert!(e < TARGET_M, "clean search final error {e:.3} m");
    assert_eq!(trace.stats.pulses_refused, 0);
}

#[test]
fn dropped_pulses_are_bridged_by_dead_reckoning() {
    // 30 % of the pulses missed: the displacement between the remaining ones is longer,
    // nothing else changes.
    let sim = search(22);
    let faulty = measurement::drop_pulses(&sim.session, 0.3, 7);
    let trace = run(&sim, &faulty);
    assert_sane("dropped", &trace);
    assert!(trace.pulses.len() < sim.session.pulses().count() * 8 / 10);
    assert_eq!(trace.stats.pulses_refused, 0);
    let e = trace.final_error_m().unwrap();
    println!(
        "30 % dropped: final error {e:.3} m, stats {:?}",
        trace.stats
    );
    assert!(e < TARGET_M, "final error {e:.3} m");
}

/// Spurious pulses (EMI detections: random direction, 0.01–1 µA/m, the range of real
/// pulses over a search) every ~8 s on average up to `until`.
fn with_spurious(sim: &Simulation, until: f64) -> Session {
    measurement::spurious_pulses(&sim.session, 8.0, [1e-8, 1e-6], until, 11)
}

#[test]
fn spurious_pulses_are_survived_and_the_search_recovers() {
    // Defined behaviour: a spurious pulse that no component explains (χ² gate, both
    // signs) after a consistent pulse is withheld by the estimator (`pulses_gated`);
    // one that arrives before the mixture exists can initialize it, and the real pulses
    // then rebuild it after `divergence_pulses` inconsistent ones (a counted
    // re-initialization). Nothing goes NaN, and the search converges.
    let sim = search(23);
    let times = pulse_times(&sim.session);
    let until = times[times.len() * 2 / 3];
    let trace = run(&sim, &with_spurious(&sim, until));
    assert_sane("spurious", &trace);
    let e = trace.final_error_m().unwrap();
    println!(
        "spurious until {until:.0} s: final error {e:.3} m, stats {:?}",
        trace.stats
    );
    assert!(e < TARGET_M, "final error {e:.3} m");
}

#[test]
fn spurious_pulses_to_the_end_do_not_capture_the_estimate() {
    // Spurious pulses up to the last one: the outlier gate withholds them, so they
    // neither capture the estimate nor force re-initializations.
    let sim = search(23);
    let trace = run(&sim, &with_spurious(&sim, f64::INFINITY));
    assert_sane("spurious", &trace);
    let e = trace.final_error_m().unwrap();
    println!(
        "spurious to the end: final error {e:.3} m, stats {:?}",
        trace.stats
    );
    assert!(e < TARGET_M, "final error {e:.3} m");
    assert!(trace.stats.pulses_gated > 0);
    assert!(trace.stats.reinitializations <= 1, "{:?}", trace.stats);
}

#[test]
fn imu_dropout_is_bridged_and_counted() {
    // The IMU stops for 2 s in the middle of the walk: the first sample after it is a gap
    // (`MotionError::Gap`), which the application bridges by resynchronizing (counted in
    // `imu_gaps`); nothing is refused and the search still ends on target.
    let sim = search(24);
    let times = pulse_times(&sim.session);
    let mid = times[times.len() / 2];
    let faulty = measurement::imu_dropout(&sim.session, mid - 0.5, 2.0);
    let trace = run(&sim, &faulty);
    assert_sane("imu dropout", &trace);
    println!(
        "imu dropout at {mid}: {:?} {:?}",
        trace.stats, trace.imu_errors
    );
    assert_eq!(trace.stats.imu_gaps, 1);
    assert_eq!(trace.stats.imu_refused, 0);
    assert!(trace.imu_errors.is_empty());
    let e = trace.final_error_m().unwrap();
    println!("imu dropout: final error {e:.3} m, stats {:?}", trace.stats);
    assert!(e < TARGET_M, "final error {e:.3} m");
}

#[test]
fn metal_nearby_is_rejected_by_the_magnetometer_gates() {
    // A shovel next to the receiver for 10 s: +25 µT along the body x axis, far outside
    // the |B| and inclination gates (10 %, 5°) of the attitude filter, so yaw is carried
    // by the gyro meanwhile and the search is unaffected.
    let sim = search(25);
    let times = pulse_times(&sim.session);
    let t0 = times[times.len() / 3];
    let faulty = measurement::mag_disturbance(&sim.session, t0, 10.0, [25.0, 0.0, 0.0]);
    let clean = run(&sim, &sim.session);
    let trace = run(&sim, &faulty);
    assert_sane("metal", &trace);
    let disturbed = 10.0 * sim.session.header.imu_hz;
    let extra = f64::from(trace.mag_rejected) - f64::from(clean.mag_rejected);
    println!(
        "metal: {extra} more mag samples rejected of {disturbed} disturbed, final errors clean {:.3} faulty {:.3} m",
        clean.final_error_m().unwrap(),
        trace.final_error_m().unwrap()
    );
    assert!(extra >= 0.9 * disturbed, "only {extra} rejected");
    let e = trace.final_error_m().unwrap();
    assert!(e < TARGET_M, "final error {e:.3} m");
}

#[test]
fn transmitter_off_shows_no_signal_keeps_the_estimate_and_recovers() {
    // The victim's transmitter stops for 20 s mid-search (e.g. it is switched to send
    // mode and back). Defined behaviour: "NO SIGNAL" once `signal_timeout_s` passes without
    // a pulse, the estimate is kept (not reset), and the first pulse after it comes back
    // restores the guidance.
    let sim = search(26);
    let times = pulse_times(&sim.session);
    let t_off = times[times.len() / 2];
    let faulty = measurement::transmitter_off(&sim.session, t_off, t_off + 20.0);
    let trace = run(&sim, &faulty);
    assert_sane("tx off", &trace);
    let timeout = f64::from(AppConfig::new(Vec3::z(), None).signal_timeout_s);
    let last_before = trace.pulses_in(0.0, t_off).last().unwrap();
    // A localized victim stays pointed at (see the test below); a flux-line one does not.
    let localized = last_before
        .result
        .as_ref()
        .is_ok_and(|d| d.status == Status::Localized);
    let last_before = last_before.t;
    for d in &trace.displays {
        let silent_for = d.t - last_before;
        if d.t < t_off + 20.0 && silent_for > timeout + 0.1 {
            assert_eq!(d.display.status, Status::NoSignal, "at {:.1} s", d.t);
            assert_eq!(d.display.arrow_deg.is_some(), localized, "at {:.1} s", d.t);
        }
        if d.t > last_before && silent_for <= timeout - 0.1 {
            assert_ne!(d.display.status, Status::NoSignal, "at {:.1} s", d.t);
        }
    }
    let first_after = trace.pulses_in(t_off + 20.0, f64::INFINITY).next().unwrap();
    assert!(
        first_after.estimate.is_some(),
        "the estimate was lost while the transmitter was off"
    );
    assert_ne!(
        first_after.result.as_ref().unwrap().status,
        Status::NoSignal
    );
    println!(
        "tx off: final error {:.3} m, stats {:?}",
        trace.final_error_m().unwrap(),
        trace.stats
    );
    // How well the search ends after 20 s without pulses (walking on, the motion alone
    // carries the estimate) is measured over twelve searches, not one: on seeds 20–43,
    // 6 of 24 end over 1 m off with the dead reckoning of either this build or the one
    // before it (different seeds each), so a single seed says little either way.
    let mut finals: Vec<f64> = (20..32)
        .map(|seed| {
            let sim = search(seed);
            let times = pulse_times(&sim.session);
            let t_off = times[times.len() / 2];
            let faulty = measurement::transmitter_off(&sim.session, t_off, t_off + 20.0);
            run(&sim, &faulty).final_error_m().unwrap_or(f64::INFINITY)
        })
        .collect();
    finals.sort_by(f64::total_cmp);
    println!("tx off, seeds 20–31: final errors {finals:.3?}");
    let median = 0.5 * (finals[5] + finals[6]);
    assert!(median < TARGET_M, "median final error {median:.3} m");
    assert!(finals[8] < 2.0 * TARGET_M, "{finals:?}");
}

#[test]
fn transmitter_off_for_good_leaves_the_last_estimate_and_no_signal() {
    let sim = search(27);
    let times = pulse_times(&sim.session);
    let t_off = times[times.len() * 2 / 3];
    let faulty = measurement::transmitter_off(&sim.session, t_off, f64::INFINITY);
    let trace = run(&sim, &faulty);
    assert_sane("tx off for good", &trace);
    let last = trace.displays.last().unwrap();
    assert_eq!(last.display.status, Status::NoSignal);
    assert!(trace.pulses.last().unwrap().estimate.is_some());
}

#[test]
fn a_localized_victim_that_falls_silent_is_pointed_at_as_the_rescuer_walks_on() {
    // The transmitter stops for good once the search control has localized the victim:
    // the display says "no signal" and keeps pointing at the estimate, carried over the
    // walk since the last pulse by the dead reckoning (not the arrow of the last pulse,
    // which a walk of a few metres turns away from the victim).
    let sim = search(24);
    let clean = run(&sim, &sim.session);
    let localized = |p: &&hal_sim::sensors::faults::drive::PulseStep| {
        p.result
            .as_ref()
            .is_ok_and(|d| d.status == Status::Localized)
    };
    let first_localized = clean.pulses.iter().position(|p| localized(&p)).unwrap();
    let last_heard = &clean.pulses[first_localized + 3];
    assert!(localized(&last_heard), "still localized three pulses on");
    let faulty = measurement::transmitter_off(&sim.session, last_heard.t + 0.01, f64::INFINITY);
    let trace = run(&sim, &faulty);
    assert_sane("silent localized", &trace);
    // The estimate at the last pulse, placed in W from that pulse's true pose.
    let truth: Vec<_> = sim.truth.truth().collect();
    let pose_at = |t: f64| truth.iter().find(|r| (r.t - t).abs() < 0.005);
    let at_last = pose_at(last_heard.t).unwrap();
    let e = trace.pulses.last().unwrap().estimate.unwrap();
    let est_w = [
        at_last.p[0] + f64::from(e.p.x),
        at_last.p[1] + f64::from(e.p.y),
    ];
    let timeout = f64::from(AppConfig::new(Vec3::z(), None).signal_timeout_s);
    let mut checked = 0;
    let mut walked_m: f64 = 0.0;
    let (mut worst_deg, mut worst_walk_m): (f64, f64) = (0.0, 0.0);
    for d in &trace.displays {
        if d.t < last_heard.t + timeout + 0.2 {
            continue;
        }
        assert_eq!(d.display.status, Status::NoSignal, "at {:.1} s", d.t);
        let Some(pose) = truth.iter().rev().find(|r| r.t <= d.t && d.t - r.t < 0.06) else {
            continue;
        };
        let (dx, dy) = (est_w[0] - pose.p[0], est_w[1] - pose.p[1]);
        let dist = dx.hypot(dy);
        walked_m = walked_m.max((pose.p[0] - at_last.p[0]).hypot(pose.p[1] - at_last.p[1]));
        let arrow = d.display.arrow_deg.expect("an arrow to the estimate");
        let shown = pose.rpy[2] + f64::from(arrow).to_radians();
        let off = hal_sim::world::rescuer::wrap_pi(shown - dy.atan2(dx)).to_degrees();
        let walk = f64::from(d.display.walk_m.expect("the walk to it"));
        // The dead reckoning's scale error grows with the walk (≈ 2.5 % here): the point
        // shown may be that far off, which turns the arrow by up to its angle at `dist`.
        let allowed_m = 0.75 + 0.05 * walked_m;
        let allowed_deg = (allowed_m / dist).atan().to_degrees() + 5.0;
        worst_walk_m = worst_walk_m.max((walk - dist).abs());
        if dist > 10.0 {
            worst_deg = worst_deg.max(off.abs());
        }
        assert!(
            off.abs() < allowed_deg,
            "at {:.1} s: arrow {off:.1}° off at {dist:.1} m (allowed {allowed_deg:.1}°)",
            d.t
        );
        assert!(
            (walk - dist).abs() < allowed_m,
            "at {:.1} s: walk shown {walk:.2} m, {dist:.2} m to the estimate after {walked_m:.1} m",
            d.t
        );
        checked += 1;
    }
    println!(
        "silent localized: {checked} displays over {walked_m:.1} m walked, arrow at most \
         {worst_deg:.1}° off while over 10 m away, walk at most {worst_walk_m:.2} m off"
    );
    assert!(
        checked >= 20 && walked_m > 5.0,
        "{checked} displays, {walked_m:.1} m"
    );
}

// ---------------------------------------------------------------- rescuer not walking

#[test]
fn standing_still_keeps_a_bounded_finite_estimate() {
    // Two minutes without a step: the displacement between pulses is only the hand's
    // wobble; the estimate converges on the one viewpoint as far as a single position
    // allows (range and bearing from the dipole field) and nothing degenerates.
    // A walk, then two minutes without a step: the displacement between pulses is only
    // the hand's wobble; the estimate made on the walk must neither drift nor collapse.
    let spec = Stand::still(160.0, 31);
    let (log, truth) = stationary::session(&spec);
    let trace = drive(&log, &stationary::receiver_config(), Some(&truth), 0.5).unwrap();
    assert_sane("standing", &trace);
    assert_eq!(trace.stats.pulses_refused, 0);
    assert_eq!(trace.stats.imu_refused, 0);
    let at_stop = trace.pulses_in(0.0, spec.walk_s + 1.0).last().unwrap();
    let last = trace.pulses.last().unwrap();
    let (e0, e) = (at_stop.error_m().unwrap(), last.error_m().unwrap());
    let d = spec.offset().norm();
    println!(
        "standing still at {d:.1} m: error at the stop {e0:.3} m, after 2 min {e:.3} m, {} components, stats {:?}",
        last.components, trace.stats
    );
    assert!(e < TARGET_M, "final error {e:.3} m at {d:.1} m");
    assert_eq!(trace.stats.reinitializations, 0);
    assert_ne!(last.result.as_ref().unwrap().status, Status::NoSignal);
}

#[test]
fn turning_in_place_turns_the_arrow_not_the_estimate() {
    // Standing still, then a full turn in place at 0.5 rad/s: the estimate (in G_k, north-
    // west-up) must not move, and the display's arrow (relative to the device) must turn
    // the other way by the same angle.
    let mut spec = Stand::still(90.0, 32);
    spec.turn_rate = 0.5;
    spec.turn_from_s = 60.0;
    spec.turn_to_s = 60.0 + std::f64::consts::TAU / 0.5;
    let (log, truth) = stationary::session(&spec);
    let trace = drive(&log, &stationary::receiver_config(), Some(&truth), 0.1).unwrap();
    assert_sane("turning", &trace);
    let before = trace.pulses_in(55.0, 60.0).last().unwrap();
    let after = trace.pulses.last().unwrap();
    let (pb, pa) = (before.estimate.unwrap().p, after.estimate.unwrap().p);
    println!(
        "turning: estimate moved {:.3} m; errors {:.3} → {:.3} m",
        (pa - pb).norm(),
        before.error_m().unwrap(),
        after.error_m().unwrap()
    );
    assert!(
        f64::from((pa - pb).norm()) < 0.1 * spec.offset().norm(),
        "the turn moved the estimate"
    );
    // Arrow + heading = the bearing of the estimate, constant while turning.
    let mut worst = 0.0f64;
    for d in trace
        .displays
        .iter()
        .filter(|d| d.t > spec.turn_from_s + 1.0 && d.t < spec.turn_to_s)
    {
        let Some(arrow) = d.display.arrow_deg else {
            continue;
        };
        let bearing = f64::from(arrow).to_radians() + spec.yaw(d.t);
        let expected = f64::from(pb.y).atan2(f64::from(pb.x));
        let diff = (bearing - expected + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        worst = worst.max(diff.abs().to_degrees());
    }
    println!("turning: arrow off the estimate's bearing by at most {worst:.1}°");
    assert!(worst < 10.0, "arrow off by {worst:.1}°");
}

#[test]
fn victim_directly_below_is_localized_without_nan() {
    // The receiver right above the transmitter: the field is along the vertical and the
    // horizontal offset is zero, the geometry where bearing is undefined. The estimate
    // must stay finite and put the victim below the receiver at about the right depth.
    let spec = Stand {
        receiver_p: [0.0, 0.0, 1.0],
        victim: [0.0, 0.0, -1.5],
        moment: [0.009, 0.002, 0.0],
        ..Stand::still(70.0, 33)
    };
    let (log, truth) = stationary::session(&spec);
    let trace = drive(&log, &stationary::receiver_config(), Some(&truth), 0.5).unwrap();
    assert_sane("directly below", &trace);
    assert_eq!(trace.stats.pulses_refused, 0);
    let last = trace.pulses.last().unwrap();
    let est = last.estimate.unwrap();
    let d = last.result.as_ref().unwrap();
    println!(
        "directly below: estimate {:?}, display {:?}",
        est.p.as_slice(),
        d
    );
    let horizontal = f64::from(est.p.x.hypot(est.p.y));
    assert!(horizontal < 0.5, "horizontal offset {horizontal:.2} m");
    assert!(
        (f64::from(-est.p.z) - 2.5).abs() < 0.5,
        "vertical offset {:.2} m (truth 2.5 m)",
        -est.p.z
    );
}

// ---------------------------------------------------------------- bus level

/// A world at the end of a search (the receiver a few metres from the victim: strong
/// pulses) and a fresh receiver with its configuration.
fn bus_world(seed: u64) -> (Simulation, Box<Receiver>) {
    let sim = search(seed);
    let cfg = hal_sim::io::sog_replay::app_config(&sim.session.header, &sim.receiver);
    (sim, Box::new(Receiver::new(cfg).unwrap()))
}

fn window_with(
    sim: &Simulation,
    rx: &mut Receiver,
    disturbances: Vec<Disturbance>,
    spi: (FaultWindow, SpiFault),
    span: (f64, f64),
) -> AdcWindow {
    let cfg = &sim.draw.config;
    let unit = hal_sim::sensors::bus::run::scenario_unit(cfg.seed);
    let signal = antenna(
        &sim.world,
        unit.chain,
        cfg.sensors.pulse.sigma_bkg_a_per_m,
        cfg.sensors.pulse.k_sen,
        cfg.seed,
    );
    adc_window(
        Disturbed::new(signal, disturbances, cfg.seed ^ 0xD15),
        // The shipped unit: its bench calibration, not its chain's exact values.
        &hal_sim::sensors::bus::run::scenario_calibration(
            cfg.seed,
            hal_sim::sensors::bus::run::UnitCalibration::Bench,
        )
        .unwrap(),
        span,
        spi,
        rx,
    )
    .unwrap()
}

fn kinds(w: &AdcWindow, from: f64, to: f64) -> Vec<PulseKind> {
    w.pulses
        .iter()
        .filter(|p| p.t >= from && p.t < to)
        .map(|p| p.kind)
        .collect()
}

fn span_end(sim: &Simulation) -> (f64, f64) {
    let end = sim.draw.duration_s;
    (end - 9.0, end - 0.5)
}

#[test]
fn adc_clean_window_gives_field_pulses() {
    let (sim, mut rx) = bus_world(41);
    let span = span_end(&sim);
    let w = window_with(
        &sim,
        &mut rx,
        vec![],
        (FaultWindow::none(), SpiFault::Error),
        span,
    );
    println!("clean window: {:?}", kinds(&w, 0.0, f64::INFINITY));
    assert!(
        kinds(&w, 0.0, f64::INFINITY)
            .iter()
            .filter(|k| **k == PulseKind::Field)
            .count()
            >= 6
    );
    assert_eq!(w.errors, Default::default());
}

#[test]
fn adc_spi_errors_keep_the_time_base_and_withhold_the_pulse() {
    // 5 % of the SPI transfers fail for 3 s. The driver returns `Error::Comm`; the board
    // feeds a clipped zero sample instead (so the sample clock, the time base, is kept);
    // a pulse with such samples is withheld as saturated, the display flags it
    // (`overlap`, the "!"), and field pulses resume after the window.
    let (sim, mut rx) = bus_world(42);
    let (a, b) = span_end(&sim);
    let faults = (FaultWindow::new(a + 2.0, a + 5.0, 0.05, 5), SpiFault::Error);
    let w = window_with(&sim, &mut rx, vec![], faults, (a, b));
    println!(
        "spi errors {:.2}–{:.2} s: {:?}, {} samples of {:.0}, {:?}",
        a + 2.0,
        a + 5.0,
        w.errors,
        w.samples,
        (b - a) * 8000.0,
        w.pulses.iter().map(|p| (p.t, p.kind)).collect::<Vec<_>>()
    );
    assert!(w.errors.comm > 100 && w.errors.crc == 0);
    // Time base: every conversion of the window was taken (errors included).
    let expected = (b - a) * 8000.0;
    assert!(
        (w.samples as f64 - expected).abs() < 2.0,
        "{} samples",
        w.samples
    );
    let inside = kinds(&w, a + 2.2, a + 5.0);
    assert!(
        !inside.is_empty() && inside.iter().all(|k| *k != PulseKind::Field),
        "{inside:?}"
    );
    let flagged = w
        .pulses
        .iter()
        .filter(|p| p.kind == PulseKind::Saturated)
        .all(|p| matches!(&p.result, Ok(Some(d)) if d.overlap));
    assert!(flagged);
    assert!(rx.stats().pulses_withheld >= 1);
    assert!(
        kinds(&w, a + 5.5, b).contains(&PulseKind::Field),
        "no recovery"
    );
    assert!(
        !rx.display_model().overlap,
        "the flag must clear on the next field pulse"
    );
}

#[test]
fn adc_bit_flips_are_caught_by_the_crc() {
    let (sim, mut rx) = bus_world(43);
    let (a, b) = span_end(&sim);
    let faults = (
        FaultWindow::new(a + 2.0, a + 5.0, 0.05, 6),
        SpiFault::BitFlip,
    );
    let w = window_with(&sim, &mut rx, vec![], faults, (a, b));
    println!("bit flips: {:?}", w.errors);
    assert!(w.errors.crc > 100 && w.errors.comm == 0);
    let inside = kinds(&w, a + 2.2, a + 5.0);
    assert!(inside.iter().all(|k| *k != PulseKind::Field), "{inside:?}");
    assert!(
        kinds(&w, a + 5.5, b).contains(&PulseKind::Field),
        "no recovery"
    );
}

#[test]
fn adc_saturation_withholds_the_pulse_and_flags_it() {
    // The signal overdriven ×10⁴ for 2.5 s: the ADC clips, the frames carry the
    // saturation flags, the front end withholds the pulses as saturated (a clipped vector
    // would be wrong, not just noisy), the display shows "!", and it recovers.
    let (sim, mut rx) = bus_world(44);
    let (a, b) = span_end(&sim);
    let over = Disturbance::Overdrive {
        from_s: a + 2.0,
        to_s: a + 4.5,
        gain: 1e4,
    };
    let w = window_with(
        &sim,
        &mut rx,
        vec![over],
        (FaultWindow::none(), SpiFault::Error),
        (a, b),
    );
    println!(
        "saturation: clipped {} {:?}",
        w.clipped,
        w.pulses.iter().map(|p| (p.t, p.kind)).collect::<Vec<_>>()
    );
    assert!(w.clipped > 0);
    let inside = kinds(&w, a + 2.1, a + 4.5);
    assert!(inside.contains(&PulseKind::Saturated), "{inside:?}");
    assert!(!inside.contains(&PulseKind::Field), "{inside:?}");
    assert!(
        kinds(&w, a + 5.0, b).contains(&PulseKind::Field),
        "no recovery"
    );
    assert!(!w.pulses.iter().any(|p| p.result.is_err()));
}

#[test]
fn emi_burst_gives_no_false_vectors_and_the_floor_recovers() {
    // A 2 s burst of broadband EMI 300× the background (a radio, a generator): the
    // detector's noise floor follows it up, so pulses drowned in it are not reported as
    // vectors; after the burst the floor comes down and field pulses resume.
    let (sim, mut rx) = bus_world(45);
    let (a, b) = span_end(&sim);
    let chain = hal_sim::sensors::bus::run::scenario_unit(sim.draw.config.seed).chain;
    let sigma_v = 300.0
        * hal_sim::sensors::bus::if_signal::sample_sigma(
            sim.draw.config.sensors.pulse.sigma_bkg_a_per_m,
            8000.0,
        )
        / chain.gain_a_per_m_per_v[0];
    let emi = Disturbance::Emi {
        from_s: a + 2.0,
        to_s: a + 4.0,
        sigma_v,
    };
    let w = window_with(
        &sim,
        &mut rx,
        vec![emi],
        (FaultWindow::none(), SpiFault::Error),
        (a, b),
    );
    println!(
        "emi burst {:.2}–{:.2} s: {:?}",
        a + 2.0,
        a + 4.0,
        w.pulses.iter().map(|p| (p.t, p.kind)).collect::<Vec<_>>()
    );
    assert!(
        kinds(&w, a + 6.0, b).contains(&PulseKind::Field),
        "no recovery"
    );
    assert!(!w.pulses.iter().any(|p| p.result.is_err()));
    assert!(
        rx.estimate()
            .is_none_or(|e| e.p.iter().all(|x| x.is_finite()))
    );
}

#[test]
fn imu_i2c_errors_are_reported_skipped_and_bridged() {
    // The IMU chips stop acknowledging (all transfers for 0.5 s), or 20 % of the
    // transfers time out for 3 s. `Imu::read` returns `ImuError::Comm` with the chip and
    // the bus error; the board skips the sample; the application bridges the hole
    // (`imu_gaps`; before the fix in `app.rs` every sample after a gap was refused as
    // `TimeNotIncreasing`, for good) and its heading recovers.
    let sim = search(46);
    let clock = SimClock::new();
    let model = ImuModel::new(sim.draw.config.sensors.imu.clone(), stream(46, 2));
    let bus = ImuBus::new(ImuSampler::new(&sim.world, model), clock.clone());
    let cfg = hal_sim::io::sog_replay::app_config(&sim.session.header, &sim.receiver);
    let mut yaws = Vec::new();
    for (window, kind) in [
        (FaultWindow::none(), I2cFault::Nack),
        (FaultWindow::new(5.0, 5.5, 1.0, 1), I2cFault::Nack),
        (FaultWindow::new(8.0, 11.0, 0.2, 2), I2cFault::Timeout),
    ] {
        let faulty = FaultyI2c::new(bus.clone(), clock.clone(), window.clone(), kind);
        clock.set(0.0);
        let mut imu = Imu::new(faulty.clone(), faulty, &mut NoDelay).unwrap();
        let mut errors = 0;
        let mut rx = Box::new(Receiver::new(cfg).unwrap());
        for k in 1..=3000u32 {
            let t = f64::from(k) / 100.0;
            clock.set(t);
            match imu.read() {
                Ok(r) => rx.on_imu(stamp(t), &r.acc, &r.gyr, Some(&r.mag)).unwrap(),
                Err(ImuError::Comm { chip, error }) => {
                    errors += 1;
                    assert!(matches!(chip, Chip::Bmi160 | Chip::Lsm303agrMag));
                    let expected = match kind {
                        I2cFault::Nack => embedded_hal::i2c::ErrorKind::NoAcknowledge(
                            embedded_hal::i2c::NoAcknowledgeSource::Address,
                        ),
                        I2cFault::Timeout => embedded_hal::i2c::ErrorKind::Other,
                    };
                    assert_eq!(error, expected);
                }
                Err(e) => panic!("unexpected {e:?}"),
            }
        }
        let yaw = f64::from(rx.motion().attitude().0.z);
        println!(
            "{kind:?} {:.1}–{:.1} s: {errors} failed reads, stats {:?}, yaw {:.2}°",
            window.from_s,
            window.to_s,
            rx.stats(),
            yaw.to_degrees()
        );
        match (window.p > 0.0, kind) {
            (false, _) => assert_eq!(errors, 0),
            // 0.5 s without samples is a gap, bridged once.
            (true, I2cFault::Nack) => assert_eq!((errors > 0, rx.stats().imu_gaps), (true, 1)),
            // Single missed samples are within `max_gap_s`: no gap at all.
            (true, I2cFault::Timeout) => assert_eq!((errors > 0, rx.stats().imu_gaps), (true, 0)),
        }
        assert_eq!(rx.stats().imu_refused, 0);
        yaws.push(yaw);
    }
    // 30 s later the heading is back near the run without faults. Measured: the 0.5 s
    // hole (the turn during it is missed) leaves the yaw 9° off, decaying slowly (3.6° at
    // 30 s: the magnetometer's correction is slow after `inflate_for_gap`); the scattered
    // single misses cost nothing (0.1°).
    for y in &yaws[1..] {
        let d = (y - yaws[0] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        assert!(
            d.abs().to_degrees() < 5.0,
            "yaw {:.2}° off the clean run",
            d.to_degrees()
        );
    }
}

#[test]
fn imu_not_answering_at_start_up_is_an_init_error() {
    // Defined behaviour: `Imu::new` hands back `ImuInitError` with the error and both bus
    // handles; the board then runs without dead reckoning (pulses only).
    let sim = search(47);
    let clock = SimClock::new();
    let model = ImuModel::new(sim.draw.config.sensors.imu.clone(), stream(47, 2));
    let bus = ImuBus::new(ImuSampler::new(&sim.world, model), clock.clone());
    let faulty = FaultyI2c::new(
        bus,
        clock,
        FaultWindow::new(0.0, 1.0, 1.0, 3),
        I2cFault::Nack,
    );
    let err = Imu::new(faulty.clone(), faulty, &mut NoDelay)
        .err()
        .unwrap();
    assert!(matches!(
        err.error,
        ImuError::Comm {
            chip: Chip::Bmi160,
            ..
        }
    ));
    // Without IMU samples the application still takes pulses (zero displacement).
    let mut rx = Box::new(
        Receiver::new(hal_sim::io::sog_replay::app_config(
            &sim.session.header,
            &sim.receiver,
        ))
        .unwrap(),
    );
    let p = sim.session.pulses().next().unwrap();
    let h = Vec3::new(p.h[0] as f32, p.h[1] as f32, p.h[2] as f32);
    assert!(rx.on_pulse(stamp(p.t), &h, None).is_ok());
    let nan = Vec3::new(f32::NAN, 0.0, 0.0);
    assert!(matches!(
        rx.on_imu(stamp(p.t + 0.01), &nan, &h, None),
        Err(AppError::Motion(MotionError::NonFinite))
    ));
}

#[test]
fn the_board_path_flags_a_withheld_pulse_too() {
    // The board runs the front end itself (it logs each field pulse before processing)
    // and reports a withheld pulse with `on_withheld`: same flag and counter as
    // `on_adc_sample`, cleared by the next field pulse.
    let sim = search(48);
    let cfg = hal_sim::io::sog_replay::app_config(&sim.session.header, &sim.receiver);
    let mut rx = Box::new(Receiver::new(cfg).unwrap());
    let p = sim.session.pulses().next().unwrap();
    let d = rx.on_withheld(stamp(p.t - 0.5));
    assert!(d.overlap);
    assert_eq!(rx.stats().pulses_withheld, 1);
    let h = Vec3::new(p.h[0] as f32, p.h[1] as f32, p.h[2] as f32);
    assert!(!rx.on_pulse(stamp(p.t), &h, None).unwrap().overlap);
}
