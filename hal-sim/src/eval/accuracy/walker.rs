//! The report's own closed loop (ICRA 2006 §VI protocol): a walker on the snow and the IROS
//! 2006 §III-C guidance (flux line, then the mixture mean, probe when close).

use super::*;

/// The closed-loop rescuer: position on the snow, walking heading, hand-held attitude.
pub(super) struct Walker {
    pub(super) p: V3,
    pub(super) heading: f64,
    pub(super) flux_sign: f64,
    pub(super) best_h: f64,
    pub(super) best_h_at: V3,
}

impl Walker {
    pub(super) fn rotation(&self, rng: &mut ChaCha8Rng) -> (V3, M3) {
        // Hand wobble: a few degrees of roll/pitch/yaw about the walking heading.
        let rpy = V3::new(
            0.03 * gauss(rng),
            0.1 + 0.03 * gauss(rng),
            self.heading + 0.05 * gauss(rng),
        );
        (rpy, rotation_from_rpy(&rpy))
    }
}

/// Horizontal direction (unit, W) the flux line points to, sign chosen by `sign`.
pub(super) fn flux_direction(h_w: &V3, sign: f64) -> Option<V3> {
    let d = V3::new(h_w.x, h_w.y, 0.0) * sign;
    (d.norm() > 0.0).then(|| d.normalize())
}

/// Squared Mahalanobis distance of the receiver (the origin of `G_k`) from the mixture
/// mean, horizontally (IROS III-C: the rescuer is sent to the mean once the receiver is
/// far from it in Mahalanobis distance, i.e. once the whole belief lies to one side).
pub(super) fn horizontal_mahalanobis2(est: &VictimEstimate) -> f64 {
    let c = est.cov;
    let (a, b, d) = (c[(0, 0)] as f64, c[(0, 1)] as f64, c[(1, 1)] as f64);
    let det = a * d - b * b;
    if det <= 0.0 {
        return 0.0;
    }
    let (x, y) = (est.p.x as f64, est.p.y as f64);
    (d * x * x - 2.0 * b * x * y + a * y * y) / det
}

/// Unit principal axis (W, horizontal) and largest standard deviation of the horizontal
/// position covariance.
pub(super) fn horizontal_axis(est: &VictimEstimate) -> (V3, f64) {
    let c = est.cov;
    let (a, b, cc) = (c[(0, 0)] as f64, c[(0, 1)] as f64, c[(1, 1)] as f64);
    let lmax = 0.5 * (a + cc) + ((0.5 * (a - cc)).powi(2) + b * b).sqrt();
    // Eigenvector of [[a, b], [b, cc]] for lmax.
    let v = if b.abs() > 1e-12 {
        V3::new(lmax - cc, b, 0.0)
    } else if a >= cc {
        V3::x()
    } else {
        V3::y()
    };
    let n = v.norm();
    let axis = if n > 0.0 { v / n } else { V3::x() };
    (axis, lmax.max(0.0).sqrt())
}

/// Guidance thresholds of the closed loop.
pub(super) const GO_TO_MEAN_D2: f64 = 9.0; // 3σ: the receiver is outside the belief's 3σ ellipse
/// "Probe here" when the mean is this close, horizontally, m.
pub const PROBE_RADIUS_M: f64 = 0.3;
/// Pulses taken standing still over the mean before probing.
pub const PROBE_STILL_PULSES: usize = 4;

/// One closed-loop rescue (the papers' protocol): start 40–70 m away, 1 m/s, a pulse
/// per transmitter period, stop at "probe here".
pub fn run_closed_loop(seed: u64, noise: &MotionNoise) -> RunResult {
    closed_loop(
        seed,
        noise,
        40.0..=70.0,
        |c| DefaultSog::new(c).ok().map(Box::new),
        sog_components,
        &mut |_, _| {},
    )
}

/// As [`run_closed_loop`] (same scenario draw, walker and IROS III-C guidance), with the
/// start distance drawn in `start_m` and any estimator guiding: `make` builds it from
/// the SOGs filter's configuration (`None`: a run that never initialized); `observe`
/// sees the estimator and the true victim offset (W axes) after every pulse.
pub fn run_closed_loop_with<E: Estimator + ?Sized, B: std::ops::DerefMut<Target = E>>(
    seed: u64,
    noise: &MotionNoise,
    start_m: std::ops::RangeInclusive<f64>,
    make: impl FnOnce(SogConfig) -> Option<B>,
    observe: &mut dyn FnMut(&E, &V3),
) -> RunResult {
    closed_loop(seed, noise, start_m, make, |_| Vec::new(), observe)
}

pub(super) fn closed_loop<E: Estimator + ?Sized, B: std::ops::DerefMut<Target = E>>(
    seed: u64,
    noise: &MotionNoise,
    start_m: std::ops::RangeInclusive<f64>,
    make: impl FnOnce(SogConfig) -> Option<B>,
    components: Components<E>,
    observe: &mut dyn FnMut(&E, &V3),
) -> RunResult {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d0 = rng.random_range(start_m);
    let bearing: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    let depth = rng.random_range(0.3..=3.0);
    let tx = Transmitter::random(
        &mut rng,
        &TransmitterSpec::default(),
        [d0 * bearing.cos(), d0 * bearing.sin(), -depth],
    );
    let mut sensors = SensorConfig::default();
    // The pulse noise simulated and declared (×1 normally: the values are unchanged).
    sensors.pulse.sigma_bkg_a_per_m *= noise.pulse_multiplier;
    sensors.pulse.k_sen *= noise.pulse_multiplier;
    let tx_p = V3::from(tx.position);
    let scale = 1.0 + 0.02 * noise.scale_multiplier * gauss(&mut rng);
    let fcfg = filter_config(
        Case::ClosedLoop,
        &sensors,
        [0.3, 3.0],
        TransmitterSpec::default().moment_range,
        noise,
    );
    let Some(mut filter) = make(fcfg) else {
        return Tracker::new(seed, d0).finish();
    };
    let mut tracker = Tracker::new(seed, d0);
    if tracker.trace {
        eprintln!(
            "scale {scale:.4} moment {:?} |m| {:.4}",
            tx.moment,
            V3::from(tx.moment).norm()
        );
    }
    let ideal = (d0 / tx.period_s).ceil() as usize;
    tracker.result.ideal_steps = Some(ideal);
    let mut walker = Walker {
        p: V3::new(0.0, 0.0, 1.0),
        heading: rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
        flux_sign: 1.0,
        best_h: 0.0,
        best_h_at: V3::zeros(),
    };
    let mut previous: Option<(V3, M3)> = None;
    let mut bound_in = crate::eval::accuracy_bound::BoundInput {
        sigma_r: noise.sigma_r_rad,
        attitude_sigma: noise.attitude_sigma_rad,
        scale,
        scale_sigma: 0.02 * noise.scale_multiplier,
        transmitter: (tx_p, V3::from(tx.moment)),
        pulse_noise: (sensors.pulse.sigma_bkg_a_per_m, sensors.pulse.k_sen),
        ..Default::default()
    };
    let mut probe_hold = 0;
    let mut going_to_mean = false;
    let mut sure_hold = 0;
    let mut sweep = 1.0;
    for k in 0..3 * ideal + 10 {
        let t = tx.phase_s + k as f64 * tx.period_s;
        let (rpy, rot) = walker.rotation(&mut rng);
        let Some(h_w) = tx.field_at(&walker.p) else {
            break;
        };
        let sigma = sensors
            .pulse
            .sigma_bkg_a_per_m
            .hypot(sensors.pulse.k_sen * h_w.norm());
        let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
        let h_b = (rot.transpose() * h_w
            + V3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * sigma)
            * sign;
        let motion = match &previous {
            Some((p0, r0)) => {
                noisy_displacement(&mut rng, noise, scale, false, (p0, r0), (&walker.p, &rot))
            }
            None => Displacement::zero(),
        };
        let attitude = noisy_attitude(&mut rng, noise, &rpy, false);
        tracker.truth_next = tx_p - walker.p;
        tracker.step(
            &mut *filter,
            components,
            &motion,
            &attitude,
            &Pulse {
                h: to_f32(&h_b),
                t: t as f32,
            },
        );
        let est = filter.estimate();
        tracker.record(est, &(tx_p - walker.p));
        observe(&*filter, &(tx_p - walker.p));
        if filter.is_initialized() {
            if let Some((p0, r0)) = &previous {
                let walked = (r0.transpose() * (walker.p - p0)).xy().norm();
                bound_in
                    .translation_sigmas
                    .push(noise.translation_sigmas(walked * scale));
            }
            bound_in.poses.push((walker.p, rpy));
            previous = Some((walker.p, rot));
        }
        // Guidance for the next period (IROS III-C): follow the flux line until the
        // receiver is far from the mixture mean in Mahalanobis distance, then walk to
        // the mean; once over it, stand still for a few pulses (no walking error, the
        // strongest field) and probe.
        let step = tx.period_s; // 1 m/s
        if let Some(e) = est
            && horizontal_mahalanobis2(&e) >= GO_TO_MEAN_D2
        {
            going_to_mean = true;
        }
        let target = match est {
            Some(e) if going_to_mean => {
                let to_mean = V3::new(e.p.x as f64, e.p.y as f64, 0.0);
                if to_mean.norm() < PROBE_RADIUS_M {
                    // Over the mean. A single spot cannot separate the transmitter's
                    // position from its moment, so while the 3σ circle is wider than
                    // the probe radius, sweep across the mean along the most uncertain
                    // horizontal axis (±0.5 m, the classical fine search's bracketing);
                    // once sure, stand still for the last pulses and probe.
                    let (axis, sigma) = horizontal_axis(&e);
                    tracker.result.steps_to_mean.get_or_insert(k + 1);
                    probe_hold += 1;
                    if 3.0 * sigma <= PROBE_RADIUS_M {
                        sure_hold += 1;
                        if sure_hold >= PROBE_STILL_PULSES {
                            tracker.result.steps_to_probe = Some(k + 1);
                            break;
                        }
                        None
                    } else if probe_hold >= 4 * PROBE_STILL_PULSES {
                        tracker.result.steps_to_probe = Some(k + 1);
                        break;
                    } else {
                        sure_hold = 0;
                        sweep = -sweep;
                        Some(to_mean + axis * (0.5 * sweep))
                    }
                } else if probe_hold > 0 && to_mean.norm() < 1.0 {
                    // Still sweeping across the mean.
                    sweep = -sweep;
                    Some(to_mean + horizontal_axis(&e).0 * (0.5 * sweep))
                } else {
                    probe_hold = 0;
                    sure_hold = 0;
                    Some(to_mean)
                }
            }
            _ => {
                let hn = h_w.norm();
                // Classical rule: if the signal fell over the last 5 m, turn around.
                if hn > walker.best_h {
                    walker.best_h = hn;
                    walker.best_h_at = walker.p;
                } else if (walker.p - walker.best_h_at).xy().norm() > 5.0 {
                    walker.flux_sign = -walker.flux_sign;
                    walker.best_h_at = walker.p;
                    walker.best_h = hn;
                }
                flux_direction(&h_w, walker.flux_sign).map(|d| d * 10.0)
            }
        };
        if let Some(dir) = target {
            let len = dir.norm().min(step);
            let heading = dir.y.atan2(dir.x) + 0.05 * gauss(&mut rng);
            walker.heading = heading;
            walker.p += V3::new(heading.cos(), heading.sin(), 0.0) * len;
        }
    }
    tracker.result.final_bound = crate::eval::accuracy_bound::final_position_bound(&bound_in);
    tracker.finish()
}
