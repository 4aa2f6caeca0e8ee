//! Physics and statistics of the generated data.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hal_sim::io::receiver_config::PulseNoise;
use hal_sim::io::session::{Record, read};
use hal_sim::sensors::{ImuModel, PulseModel, SensorConfig};
use hal_sim::world::World;
use hal_sim::world::physics::{M3, V3, exp_so3, rotation_from_rpy};
use hal_sim::world::rescuer::{GaitParams, HoldParams, Plan, Rescuer};
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};
use hal_sim::world::transmitter::{CARRIER_HZ, MIN_ON_TIME_S, PERIOD_RANGE_S, Transmitter};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn noise_free(preset: Preset, seed: u64) -> ScenarioConfig {
    let mut c = ScenarioConfig::new(preset, seed);
    c.sensors = SensorConfig::noise_free();
    c.max_duration_s = 90.0;
    c
}

fn standing_world(hold: HoldParams, tx: Transmitter) -> World {
    let plan = Plan {
        start: [0.0, 0.0],
        start_heading_rad: 0.4,
        start_wait_s: 0.0,
        waypoints: vec![],
        end_wait_s: 1.0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    World {
        transmitters: vec![tx],
        rescuer: Rescuer::new(&mut rng, GaitParams::default(), hold, &plan, 5.0),
        earth_field_ut: [21.8, 0.0, -42.8],
    }
}

fn tx_at(position: [f64; 3], moment: [f64; 3]) -> Transmitter {
    Transmitter {
        position,
        moment,
        carrier_hz: CARRIER_HZ,
        period_s: 1.0,
        on_time_s: 0.1,
        phase_s: 0.0,
    }
}

#[test]
fn integrating_the_noise_free_gyro_reproduces_the_true_attitude() {
    let sim = simulate(&noise_free(Preset::Arc, 7));
    let truth: Vec<_> = sim.truth.truth().collect();
    let imu: Vec<_> = sim.session.imu().collect();
    assert!(imu.len() > 4000);
    let mut rot = rotation_from_rpy(&V3::from(truth[0].rpy));
    let dt = 1.0 / sim.session.header.imu_hz;
    for w in imu.windows(2) {
        let mid = (V3::from(w[0].gyr) + V3::from(w[1].gyr)) * 0.5;
        rot *= exp_so3(&(mid * dt));
    }
    let t_end = imu[imu.len() - 1].t;
    let last = sim.world.rescuer_state(t_end).rot;
    let err = (rot.transpose() * last - M3::identity()).abs().max();
    assert!(err < 5e-3, "attitude error after {t_end} s: {err:e}");
}

#[test]
fn accelerometer_at_rest_reads_plus_g_on_z() {
    let world = standing_world(
        HoldParams::steady(),
        tx_at([20.0, 0.0, -1.0], [0.0, 0.0, 0.01]),
    );
    let mut imu = ImuModel::new(SensorConfig::noise_free().imu, ChaCha8Rng::seed_from_u64(2));
    for k in 0..300 {
        let s = imu.sample(&world, k as f64 * 0.01);
        assert_eq!(s.acc, [0.0, 0.0, 9.8067]);
        assert_eq!(s.gyr, [0.0, 0.0, 0.0]);
    }
    // With a real hand the mean still reads g.
    let world = standing_world(
        HoldParams::default(),
        tx_at([20.0, 0.0, -1.0], [0.0, 0.0, 0.01]),
    );
    let n = 500;
    let mean: f64 = (0..n)
        .map(|k| V3::from(imu.sample(&world, k as f64 * 0.01).acc).norm())
        .sum::<f64>()
        / n as f64;
    assert!((mean - 9.80665).abs() < 0.05, "{mean}");
}

#[test]
fn field_on_the_axis_is_twice_the_equator_in_the_world() {
    let m = 0.02;
    let probe = standing_world(HoldParams::steady(), tx_at([10.0, 0.0, 1.0], [m, 0.0, 0.0]));
    let p = probe.rescuer_state(0.5).p;
    // Transmitter 10 m due south of the receiver, moment pointing north: on its axis.
    let tx = tx_at([p.x - 10.0, p.y, p.z], [m, 0.0, 0.0]);
    let world = standing_world(HoldParams::steady(), tx.clone());
    let on_axis = world.field_world(0, 0.5).unwrap().norm();
    // The same range on the equator (perpendicular to m).
    let equator = tx
        .field_at(&(V3::from(tx.position) + V3::new(0.0, 10.0, 0.0)))
        .unwrap();
    assert!((on_axis / equator.norm() - 2.0).abs() < 1e-9);
    // The body-frame field has the same magnitude.
    assert!((world.field_body(0, 0.5).unwrap().norm() - on_axis).abs() < 1e-15);
}

#[test]
fn pulse_periods_and_on_times_meet_the_standard() {
    for seed in 0..20 {
        let mut c = noise_free(Preset::Paper, seed);
        c.victims = 3;
        let sim = simulate(&c);
        for tx in &sim.world.transmitters {
            assert!((tx.carrier_hz - CARRIER_HZ).abs() <= 80.0);
            assert!(tx.on_time_s >= MIN_ON_TIME_S);
            assert!(tx.period_s >= PERIOD_RANGE_S[0] && tx.period_s <= PERIOD_RANGE_S[1]);
            assert!(tx.position[2] <= -0.3 && tx.position[2] >= -3.0);
        }
        // Consecutive pulses of one source are one period apart (up to the 0.1 ms
        // resolution of t), and every pulse lies where its transmitter is on.
        let mut last: Vec<Option<f64>> = vec![None; 3];
        for p in sim.session.pulses() {
            let i = p.src.unwrap() as usize;
            let tx = &sim.world.transmitters[i];
            assert!(tx.is_on(p.t));
            if let Some(prev) = last[i] {
                let k = ((p.t - prev) / tx.period_s).round();
                assert!(k >= 1.0 && (p.t - prev - k * tx.period_s).abs() < 2e-4);
            }
            last[i] = Some(p.t);
        }
    }
}

#[test]
fn pulse_noise_statistics_match_the_configured_sigma() {
    for (sigma_bkg, k_sen, range) in [
        (2.59e-9, 0.03, 60.0),
        (2.59e-9, 0.03, 8.0),
        (1e-8, 0.1, 20.0),
    ] {
        let tx = tx_at([range, 0.0, -1.0], [0.004, 0.005, 0.003]);
        let world = standing_world(HoldParams::steady(), tx);
        let config = SensorConfig {
            pulse: PulseNoise {
                sigma_bkg_a_per_m: sigma_bkg,
                k_sen,
            },
            detect_factor: 0.0,
            sign_ambiguous: false,
            ..SensorConfig::default()
        };
        let mut model = PulseModel::new(config, ChaCha8Rng::seed_from_u64(3));
        let h = world.field_body(0, 1.0).unwrap();
        let sigma = model.sigma(h.norm());
        assert!((sigma * sigma - sigma_bkg * sigma_bkg - (k_sen * h.norm()).powi(2)).abs() < 1e-30);
        let n = 6000;
        let mut sum = [0.0; 3];
        let mut sum2 = [0.0; 3];
        for _ in 0..n {
            let p = model.measure(&world, 0, 1.0).unwrap();
            for k in 0..3 {
                let e = p.h[k] - h[k];
                sum[k] += e;
                sum2[k] += e * e;
            }
        }
        for k in 0..3 {
            let mean = sum[k] / n as f64;
            let sd = (sum2[k] / n as f64 - mean * mean).sqrt();
            assert!((sd / sigma - 1.0).abs() < 0.05, "σ {sd:e} vs {sigma:e}");
            assert!(
                mean.abs() < 4.0 * sigma / (n as f64).sqrt(),
                "bias {mean:e}"
            );
        }
    }
}

#[test]
fn sign_ambiguity_flips_about_half_the_pulses_and_the_floor_drops_weak_ones() {
    let tx = tx_at([5.0, 0.0, -1.0], [0.0, 0.0, 0.01]);
    let world = standing_world(HoldParams::steady(), tx);
    let mut config = SensorConfig::noise_free();
    config.sign_ambiguous = true;
    let mut model = PulseModel::new(config.clone(), ChaCha8Rng::seed_from_u64(4));
    let h = world.field_body(0, 1.0).unwrap();
    let flipped = (0..1000)
        .filter(|_| model.measure(&world, 0, 1.0).unwrap().h[2] * h.z < 0.0)
        .count();
    assert!((400..600).contains(&flipped), "{flipped}");
    config.pulse.sigma_bkg_a_per_m = 2.59e-9;
    config.detect_factor = 3.0;
    let far = standing_world(
        HoldParams::steady(),
        tx_at([150.0, 0.0, -1.0], [0.0, 0.0, 0.01]),
    );
    let mut model = PulseModel::new(config, ChaCha8Rng::seed_from_u64(4));
    assert!(model.measure(&far, 0, 1.0).is_none());
    assert!(model.measure(&world, 0, 1.0).is_some());
}

#[test]
fn imu_noise_statistics_and_bias_match_the_configuration() {
    let world = standing_world(
        HoldParams::steady(),
        tx_at([20.0, 0.0, -1.0], [0.0, 0.0, 0.01]),
    );
    let noise = SensorConfig::default().imu;
    let mut imu = ImuModel::new(noise.clone(), ChaCha8Rng::seed_from_u64(5));
    let bias = imu.gyr_bias;
    assert!(bias.iter().all(|b| b.abs() <= noise.gyr_bias_max_rad_s));
    let n = 5000;
    let samples: Vec<_> = (0..n)
        .map(|k| imu.sample(&world, k as f64 * 0.01))
        .collect();
    let stats = |f: &dyn Fn(&hal_sim::io::session::Imu) -> f64| {
        let mean = samples.iter().map(f).sum::<f64>() / n as f64;
        let var = samples.iter().map(|s| (f(s) - mean).powi(2)).sum::<f64>() / n as f64;
        (mean, var.sqrt())
    };
    let (m, sd) = stats(&|s| s.acc[0]);
    assert!(m.abs() < 0.01 && (sd / noise.acc_noise_m_s2 - 1.0).abs() < 0.05);
    let (m, sd) = stats(&|s| s.gyr[2]);
    assert!((m - bias.z).abs() < 4e-4 && (sd / noise.gyr_noise_rad_s - 1.0).abs() < 0.05);
    let (m, sd) = stats(&|s| s.mag.unwrap()[1]);
    let truth = world.earth_field_body(0.0);
    assert!((m - truth.y).abs() < 0.02 && (sd / noise.mag_noise_ut - 1.0).abs() < 0.05);
}

#[test]
fn the_walk_is_about_one_metre_per_second_and_the_calibration_about_two_percent() {
    let mut rel = Vec::new();
    for seed in 0..30 {
        let sim = simulate(&ScenarioConfig::new(Preset::Paper, seed));
        let step = sim.draw.gait.step_length_m;
        let speed = step * sim.draw.gait.cadence_hz;
        assert!((0.8..1.25).contains(&speed), "{speed}");
        rel.push(sim.receiver.pdr.as_ref().unwrap().step_length_m / step - 1.0);
        let d0 =
            (sim.world.transmitters[0].position[0]).hypot(sim.world.transmitters[0].position[1]);
        assert!((40.0..=70.0).contains(&d0));
        // The route ends close to the victim.
        let end = sim.world.rescuer_state(sim.draw.duration_s).p;
        let tx = sim.world.transmitters[0].position;
        assert!((end.x - tx[0]).hypot(end.y - tx[1]) < 7.0);
    }
    let sd = (rel.iter().map(|x| x * x).sum::<f64>() / rel.len() as f64).sqrt();
    assert!((0.01..0.035).contains(&sd), "{sd}");
}

#[test]
fn same_seed_same_bytes_and_round_trip() {
    for preset in [Preset::Paper, Preset::FluxLine, Preset::Zigzag] {
        let mut c = ScenarioConfig::new(preset, 11);
        c.max_duration_s = 60.0;
        c.victims = 2;
        let a = simulate(&c);
        let b = simulate(&c);
        assert_eq!(a.session_bytes(), b.session_bytes());
        assert_eq!(a.truth_bytes(), b.truth_bytes());
        assert_eq!(a.receiver, b.receiver);
        c.seed = 12;
        assert_ne!(simulate(&c).session_bytes(), a.session_bytes());
        // generate → parse → write: identical bytes.
        for bytes in [a.session_bytes(), a.truth_bytes()] {
            let parsed = read(&bytes[..]).unwrap();
            assert!(parsed.warnings.is_empty());
            let mut again = Vec::new();
            parsed.write(&mut again).unwrap();
            assert!(again == bytes, "round trip changed the bytes");
        }
        let parsed = read(&a.session_bytes()[..]).unwrap();
        assert_eq!(parsed.records, a.session.records);
        assert!(
            parsed
                .records
                .iter()
                .all(|r| !matches!(r, Record::Pulse(p) if p.src.is_none()))
        );
    }
}

#[test]
fn every_preset_generates() {
    for preset in [
        Preset::Paper,
        Preset::Line,
        Preset::Arc,
        Preset::FluxLine,
        Preset::Zigzag,
        Preset::Deep,
        Preset::Vertical,
        Preset::Far,
        Preset::GyroBias,
    ] {
        let mut c = ScenarioConfig::new(preset, 2);
        c.max_duration_s = 120.0;
        let sim = simulate(&c);
        assert!(sim.session.imu().count() > 1000, "{preset:?}");
        let tx = &sim.world.transmitters[0];
        match preset {
            Preset::Deep => assert_eq!(tx.position[2], -3.0),
            Preset::Vertical => assert!(tx.moment[0] == 0.0 && tx.moment[1] == 0.0),
            Preset::Far => assert!((tx.position[0].hypot(tx.position[1]) - 70.0).abs() < 1e-2),
            Preset::GyroBias => assert_eq!(sim.receiver.imu.gyr_bias_max_rad_s, 0.05),
            _ => {}
        }
    }
}
