//! Test-only scenario generator: a rescuer walking at 1 m/s with one pulse per second
//! toward a buried dipole (the papers' protocol), noisy sign-ambiguous pulses, noisy
//! dead-reckoned displacements with a walk-long scale error, and the true geometry for
//! scoring. The full Monte Carlo lives in `hal-sim`; this is the small, fast version
//! the unit tests use.

use super::{Attitude, Displacement, Estimator, Mat6, Pulse, SogConfig};
use crate::dipole::field;
use crate::frame::{Rpy, rotation_from_rpy, rpy_from_rotation, wrap_pi};
use crate::{Mat3, Vec3};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// How a run is driven.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Setup {
    pub seed: u64,
    /// Displacements and attitude exact (ICRA 2006).
    pub known_trajectory: bool,
    /// Walk toward the mixture mean once it is trusted (IROS III-C).
    pub closed_loop: bool,
    /// Curve the open-loop path (heading changes by up to ±25° along the walk).
    pub curved: bool,
    /// True walk-long scale error (σ), 0 for none.
    pub scale_sigma: f32,
    /// Per-step translation noise (m, per axis) and rotation noise (rad, per angle).
    pub sigma_t: f32,
    pub sigma_r: f32,
    pub max_steps: usize,
    /// Pulses taken standing at the probe point before the closed-loop run ends.
    pub dwell: usize,
}

impl Setup {
    pub fn robocentric(seed: u64) -> Self {
        Self {
            seed,
            known_trajectory: false,
            closed_loop: false,
            curved: false,
            scale_sigma: 0.02,
            sigma_t: 0.03,
            sigma_r: 0.005,
            max_steps: 150,
            dwell: 3,
        }
    }

    pub fn known(seed: u64) -> Self {
        Self {
            known_trajectory: true,
            scale_sigma: 0.0,
            sigma_t: 0.0,
            sigma_r: 0.0,
            ..Self::robocentric(seed)
        }
    }
}

/// What a run measured.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Outcome {
    /// Final 3-D error of the mixture mean (m).
    pub err_3d: f32,
    /// Final horizontal error of the mixture mean (m); in closed loop, the horizontal
    /// distance from the probe point to the victim.
    pub err_h: f32,
    pub steps: usize,
    /// Fraction of updated steps with the truth inside the 3σ ellipsoid (3-dof χ² ≤ 14.16).
    pub consistent: f32,
    pub reinits: usize,
    pub max_components: usize,
    pub final_components: usize,
    pub initial_distance: f32,
}

fn gauss(rng: &mut SmallRng) -> f32 {
    // Box–Muller.
    let u1: f32 = rng.random_range(1e-7..1.0);
    let u2: f32 = rng.random();
    libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(2.0 * core::f32::consts::PI * u2)
}

fn gauss3(rng: &mut SmallRng, s: f32) -> Vec3 {
    Vec3::new(gauss(rng), gauss(rng), gauss(rng)) * s
}

/// Runs one scenario through an estimator built from `config`.
pub(crate) fn run<E: Estimator>(setup: &Setup, estimator: &mut E, config: &SogConfig) -> Outcome {
    let mut rng = SmallRng::seed_from_u64(setup.seed);
    // Noise overrides for sensitivity studies (SIGMA_T, SIGMA_R, SCALE_SIGMA).
    let mut setup = *setup;
    if let Some(v) = std::env::var("SIGMA_T").ok().and_then(|v| v.parse().ok()) {
        setup.sigma_t = v;
    }
    if let Some(v) = std::env::var("SIGMA_R").ok().and_then(|v| v.parse().ok()) {
        setup.sigma_r = v;
    }
    if let Some(v) = std::env::var("SCALE_SIGMA")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        setup.scale_sigma = v;
    }
    // Victim: random depth 0.3–3 m under a snow surface 1 m below the receiver.
    let depth = rng.random_range(0.3f32..3.0);
    let victim = Vec3::new(0.0, 0.0, -(config.receiver_height + depth));
    let dir = loop {
        let d = gauss3(&mut rng, 1.0);
        if d.norm() > 0.1 {
            break d.normalize();
        }
    };
    let moment = dir * rng.random_range(3e-3f32..3e-2);
    // Start 40–70 m away in a random direction.
    let dist0 = rng.random_range(40.0f32..70.0);
    let az0 = rng.random_range(-3.1f32..3.1);
    let mut pos = Vec3::new(dist0 * libm::cosf(az0), dist0 * libm::sinf(az0), 0.0);
    let lateral = rng.random_range(-3.0f32..3.0);
    let to_victim = -pos.normalize();
    let side = Vec3::new(-to_victim.y, to_victim.x, 0.0);
    let aim = victim.xy().push(0.0) + side * lateral;
    let curve = if setup.curved {
        rng.random_range(-0.4f32..0.4)
    } else {
        0.0
    };
    let mut heading = libm::atan2f(aim.y - pos.y, aim.x - pos.x);
    if setup.closed_loop {
        heading += rng.random_range(-0.5f32..0.5);
    }
    let scale_true = 1.0 + setup.scale_sigma * gauss(&mut rng);
    let phase = rng.random_range(0.0f32..6.0);
    let attitude_at = |t: f32, heading: f32| -> Rpy {
        Rpy::new(
            0.05 * libm::sinf(0.3 * t + phase),
            0.15 + 0.05 * libm::sinf(0.2 * t + 2.0 * phase),
            heading + 0.05 * libm::sinf(0.5 * t + phase),
        )
    };
    let noise_sigma = |h: &Vec3| -> f32 {
        libm::sqrtf(config.sigma_bkg * config.sigma_bkg + (config.k_sen * h.norm()).powi(2))
    };

    let mut t = 0.0f32;
    let mut rpy = attitude_at(t, heading);
    let mut out = Outcome {
        err_3d: f32::INFINITY,
        err_h: f32::INFINITY,
        steps: 0,
        consistent: 0.0,
        reinits: 0,
        max_components: 0,
        final_components: 0,
        initial_distance: (victim - pos).norm(),
    };
    let (mut n_upd, mut n_in) = (0usize, 0usize);
    let mut trusted = false;
    let mut dwell = 0usize;
    let mut motion = Displacement::zero();
    for k in 0..setup.max_steps {
        // Pulse at the current pose.
        let r_wr = rotation_from_rpy(&rpy);
        let h_w = field(&(pos - victim), &moment).unwrap_or_else(|_| Vec3::zeros());
        let h_r = r_wr.transpose() * h_w;
        // The same draw either way: a known sign keeps the run's noise otherwise equal.
        let keep = rng.random::<bool>();
        let sign = if keep || !config.sign_ambiguous {
            1.0
        } else {
            -1.0
        };
        let h_meas = (h_r + gauss3(&mut rng, noise_sigma(&h_r))) * sign;
        let attitude = if setup.known_trajectory {
            Attitude {
                rpy,
                cov: Mat3::zeros(),
            }
        } else {
            let noisy = rpy
                + Vec3::new(
                    gauss(&mut rng) * 0.01,
                    gauss(&mut rng) * 0.01,
                    gauss(&mut rng) * 0.05,
                );
            Attitude::with_sigmas(noisy, 0.01, 0.05)
        };
        let report = estimator.step(&motion, &attitude, &Pulse { h: h_meas, t });
        out.steps = k + 1;
        if let Ok(r) = report {
            if r.outcome == super::StepOutcome::Reinitialized {
                out.reinits += 1;
            }
            out.max_components = out.max_components.max(r.n_components);
        }
        let truth_g = victim - pos;
        let est = estimator.estimate();
        if std::env::var("SOG_TRACE").is_ok()
            && let (Some(e), Ok(r)) = (est, report)
        {
            {
                std::println!(
                    "k {k} dist {:.2} err {:.3} sig {:.3} n {} wmax {:.3} d2 {:.2} pr {} mg {} sp {} dr {} s {:.3}±{:.3} (true {:.3}) trusted {trusted}",
                    truth_g.norm(),
                    (e.p - truth_g).norm(),
                    libm::sqrtf(e.cov.trace()),
                    r.n_components,
                    e.max_weight,
                    r.best_d2,
                    r.pruned,
                    r.merged,
                    r.split,
                    r.dropped,
                    e.scale,
                    e.scale_sigma,
                    scale_true
                );
            }
        }
        if let Some(e) = est {
            let err = e.p - truth_g;
            out.err_3d = err.norm();
            out.err_h = err.xy().norm();
            out.final_components = e.n_components;
            n_upd += 1;
            if let Some(ch) = e.cov.cast::<f64>().cholesky() {
                let d2 = ch.solve(&err.cast::<f64>()).dot(&err.cast::<f64>());
                if d2 <= 14.16 {
                    n_in += 1;
                }
            }
            let sig_h = libm::sqrtf(e.cov[(0, 0)] + e.cov[(1, 1)]);
            if setup.closed_loop && sig_h < 0.2 * e.p.xy().norm().max(2.5) {
                trusted = true;
            }
        }

        // Next pose.
        let (mut step_len, mut new_heading) = (1.0f32, heading);
        if setup.closed_loop {
            // Before the mixture is trusted, follow the flux line (IROS III-C), taking
            // the sense that approaches the victim (a rescuer turns back when the
            // signal weakens).
            let flux = h_w.xy();
            if !trusted && flux.norm() > 0.0 {
                let f = flux.normalize();
                let toward = (victim - pos).xy();
                let f = if f.dot(&toward) < 0.0 { -f } else { f };
                new_heading = libm::atan2f(f.y, f.x);
            }
            if trusted && let Some(e) = est {
                {
                    let d = e.p.xy().norm();
                    if d < 0.05 {
                        // At the probe point: a few more pulses standing still.
                        dwell += 1;
                        if dwell > setup.dwell {
                            break;
                        }
                    }
                    step_len = d.min(1.0);
                    new_heading = libm::atan2f(e.p.y, e.p.x);
                }
            }
        } else {
            let along = (aim - pos).dot(&Vec3::new(libm::cosf(heading), libm::sinf(heading), 0.0));
            if along < 0.5 {
                break;
            }
            step_len = along.min(1.0);
            new_heading = heading + curve / (dist0 * 0.5);
            // Re-aim gently so curved walks still end near the aim point.
            let want = libm::atan2f(aim.y - pos.y, aim.x - pos.x);
            new_heading += 0.15 * wrap_pi(want - new_heading);
        }
        let new_pos =
            pos + Vec3::new(libm::cosf(new_heading), libm::sinf(new_heading), 0.0) * step_len;
        t += 1.0;
        let new_rpy = attitude_at(t, new_heading);
        // True displacement in R_{k-1}, then what dead reckoning reports.
        let r_prev = rotation_from_rpy(&rpy);
        let r_new = rotation_from_rpy(&new_rpy);
        let dp_true = r_prev.transpose() * (new_pos - pos);
        let drot_true = rpy_from_rotation(&(r_prev.transpose() * r_new));
        let dp_meas = dp_true / scale_true + gauss3(&mut rng, setup.sigma_t);
        let drot_meas = drot_true + gauss3(&mut rng, setup.sigma_r);
        motion = if setup.known_trajectory {
            Displacement {
                translation: dp_true,
                rotation: drot_true,
                cov: Mat6::zeros(),
                ..Displacement::zero()
            }
        } else {
            Displacement::with_sigmas(
                dp_meas,
                drot_meas,
                setup.sigma_t.max(1e-3),
                setup.sigma_r.max(1e-4),
            )
        };
        pos = new_pos;
        heading = new_heading;
        rpy = new_rpy;
    }
    out.consistent = if n_upd > 0 {
        n_in as f32 / n_upd as f32
    } else {
        0.0
    };
    out
}
