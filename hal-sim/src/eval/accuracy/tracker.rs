//! Error bookkeeping of one run, shared by the open- and closed-loop runs: per-pulse errors,
//! consistency (NEES, normalized innovations) and the final result.

use super::*;

/// Error bookkeeping shared by the open- and closed-loop runs.
pub(super) struct Tracker {
    pub(super) result: RunResult,
    pub(super) step_time_s: f64,
    pub(super) steps: usize,
    pub(super) trace: bool,
    pub(super) near: (f64, f64),
    pub(super) truth_next: V3,
    pub(super) last: Option<firmware::estimate::StepReport>,
}

impl Tracker {
    pub(super) fn new(seed: u64, start_distance_m: f64) -> Self {
        Self {
            result: RunResult {
                seed,
                start_distance_m,
                final_distance_m: f64::NAN,
                final_error_m: None,
                final_error_h_m: None,
                final_error_z_m: None,
                error_at_20m: None,
                error_at_10m: None,
                inside_3sigma: 0,
                evaluated_steps: 0,
                nees_inside_95: 0,
                nees_sum: 0.0,
                nis_inside_95: 0,
                nis_evaluated: 0,
                pulses: 0,
                steps_to_probe: None,
                steps_to_mean: None,
                ideal_steps: None,
                reinitializations: 0,
                host_us_per_step: 0.0,
                max_components: 0,
                error_trace: Vec::new(),
                final_error_vec: None,
                final_bound: None,
            },
            step_time_s: 0.0,
            steps: 0,
            trace: std::env::var("SOG_TRACE").is_ok_and(|v| v == seed.to_string()),
            last: None,
            near: (0.0, 0.0),
            truth_next: V3::zeros(),
        }
    }

    /// Records the estimate against the true victim offset `truth` (in G_k = W axes).
    pub(super) fn record(&mut self, est: Option<VictimEstimate>, truth: &V3) {
        let r = &mut self.result;
        r.pulses += 1;
        r.final_distance_m = truth.norm();
        let Some(est) = est else {
            r.error_trace.push(f64::NAN);
            return;
        };
        r.max_components = r.max_components.max(est.n_components);
        let p = V3::new(est.p.x as f64, est.p.y as f64, est.p.z as f64);
        let e = p - truth;
        let err = e.norm();
        r.error_trace.push(err);
        r.final_error_m = Some(err);
        r.final_error_vec = Some(e);
        r.final_error_h_m = Some(e.x.hypot(e.y));
        r.final_error_z_m = Some(e.z.abs());
        if truth.norm() < 20.0 && r.error_at_20m.is_none() {
            r.error_at_20m = Some(err);
        }
        if truth.norm() < 10.0 && r.error_at_10m.is_none() {
            r.error_at_10m = Some(err);
        }
        let cov = M3::from_fn(|i, j| est.cov[(i, j)] as f64);
        if self.trace {
            let d2 = cov
                .try_inverse()
                .map(|inv| (e.transpose() * inv * e)[(0, 0)]);
            let l = self.last;
            eprintln!(
                "k {:3} dist {:6.2} truth [{:7.2} {:7.2} {:6.2}] err {:6.3} [{:6.3} {:6.3} {:6.3}] sd [{:.3} {:.3} {:.3}] md2 {:7.2} n {:3} wmax {:.3} s {:.4}±{:.4} |m| {:.4} d2best {:7.2} pr {} mg {} sp {} near d2 {:7.2} w {:.2e}",
                r.pulses,
                truth.norm(),
                truth.x,
                truth.y,
                truth.z,
                err,
                e.x,
                e.y,
                e.z,
                cov[(0, 0)].sqrt(),
                cov[(1, 1)].sqrt(),
                cov[(2, 2)].sqrt(),
                d2.unwrap_or(f64::NAN),
                est.n_components,
                est.max_weight,
                est.scale,
                est.scale_sigma,
                est.moment.norm(),
                l.map_or(0.0, |l| l.best_d2),
                l.map_or(0, |l| l.pruned),
                l.map_or(0, |l| l.merged),
                l.map_or(0, |l| l.split),
                self.near.0,
                self.near.1,
            );
        }
        if let Some(inv) = cov.try_inverse() {
            r.evaluated_steps += 1;
            let nees = (e.transpose() * inv * e)[(0, 0)];
            if nees <= 9.0 {
                r.inside_3sigma += 1;
            }
            if nees <= CHI2_3DOF_95 {
                r.nees_inside_95 += 1;
            }
            r.nees_sum += nees;
        }
    }

    pub(super) fn step<E: Estimator + ?Sized>(
        &mut self,
        filter: &mut E,
        components: Components<E>,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) {
        let start = Instant::now();
        let out = filter.step(motion, attitude, pulse);
        self.step_time_s += start.elapsed().as_secs_f64();
        if self.trace && std::env::var("SOG_NEAR").is_ok() {
            let mut v: Vec<(f64, f32, firmware::Vec3, firmware::Vec3)> = components(filter)
                .into_iter()
                .map(|(w, p, c)| {
                    let cd = M3::from_fn(|i, j| c[(i, j)] as f64);
                    let e = V3::new(p.x as f64, p.y as f64, p.z as f64) - self.truth_next;
                    let d2 = cd
                        .try_inverse()
                        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[(0, 0)]);
                    (
                        d2,
                        w,
                        p,
                        firmware::Vec3::new(c[(0, 0)].sqrt(), c[(1, 1)].sqrt(), c[(2, 2)].sqrt()),
                    )
                })
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (d2, w, p, sd) in v.iter().take(4) {
                eprintln!(
                    "   near d2 {d2:8.2} w {w:.2e} p [{:.2} {:.2} {:.2}] sd [{:.2} {:.2} {:.2}] truth [{:.2} {:.2} {:.2}]",
                    p.x,
                    p.y,
                    p.z,
                    sd.x,
                    sd.y,
                    sd.z,
                    self.truth_next.x,
                    self.truth_next.y,
                    self.truth_next.z
                );
            }
        }
        if self.trace {
            self.near = components(filter)
                .into_iter()
                .map(|(w, p, c)| {
                    let c = M3::from_fn(|i, j| c[(i, j)] as f64);
                    let e = V3::new(p.x as f64, p.y as f64, p.z as f64) - self.truth_next;
                    let d2 = c
                        .try_inverse()
                        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[(0, 0)]);
                    (d2, w as f64)
                })
                .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
        }
        self.steps += 1;
        self.last = out.ok();
        if let Ok(report) = out
            && report.outcome == firmware::estimate::StepOutcome::Updated
        {
            self.result.nis_evaluated += 1;
            if f64::from(report.best_d2) <= CHI2_3DOF_95 {
                self.result.nis_inside_95 += 1;
            }
        }
        if let Ok(report) = out
            && report.outcome == firmware::estimate::StepOutcome::Reinitialized
        {
            self.result.reinitializations += 1;
        }
    }

    pub(super) fn finish(mut self) -> RunResult {
        self.result.host_us_per_step = 1e6 * self.step_time_s / self.steps.max(1) as f64;
        self.result
    }
}
