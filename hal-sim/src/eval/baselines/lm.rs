//! Levenberg–Marquardt batch fit of the victim's position and moment over all the pulses
//! so far (Tardós' slides `002_*`, "nonlinear optimization": the dipole measurement model
//! of ICRA 2006 eq. 2–7 as a nonlinear least-squares problem, with the moment prior as a
//! regularizing residual), fed the rescuer's dead-reckoned poses.
//!
//! Host-only (in hal-sim, `f64` nalgebra): the fit keeps every pulse (memory and time per
//! step grow with the walk) and re-runs a multi-start search, which fits neither the
//! firmware's fixed-capacity, no-heap design nor its per-pulse time budget on the
//! Cortex-M4F; it is a reference for what a batch estimator achieves on the same data.
//!
//! The problem: parameters `θ = [p_T (m, world); m (mA·m², world)]`, residuals per pulse
//! `(s_k h_k − H(p_k − p_T, m)) / σ_k` with the noise of ICRA eq. 10 (`σ_k² = σ_bkg² +
//! (k_sen |h_k|)²` per component) and the sign `s_k = ±1` that fits best (pulses are
//! sign-ambiguous: the cost is `Σ min_s |s h_k − H|²/σ_k²`); two prior residuals: the
//! log-moment magnitude around the geometric mean of its range and the transmitter's
//! height around mid-depth, each range spanning ±2σ. The dipole field is symmetric, so
//! the cost has mirror minima: the fit starts from points on the ring of ranges the first
//! pulse allows (ICRA eq. 16, `r ∈ [(m_min/4π|h|)^⅓, (2 m_max/4π|h|)^⅓]`), each with the
//! moment that explains the first pulse exactly, runs a few iterations from each, refines
//! the most promising to convergence, keeps the best, and warm-starts from it on the next
//! pulse (a full multi-start again every few pulses).
use super::dr::{DeadReckoning, WorldPulse, single_estimate, single_report};
use crate::world::physics::{M3, V3, dipole_field};
use firmware::estimate::{
    Attitude, Displacement, EstimateError, Estimator, Pulse, SogConfig, StepReport, VictimEstimate,
};
use firmware::nalgebra::{SMatrix, SVector};
use std::f64::consts::PI;

/// 6-vector of parameters.
pub type V6 = SVector<f64, 6>;
type M6 = SMatrix<f64, 6, 6>;
type J3x6 = SMatrix<f64, 3, 6>;

/// Moments are fitted in mA·m² so that positions and moments are both O(1 … 100).
const M_UNIT: f64 = 1e-3;
/// Closest range at which the model is evaluated (the firmware's dipole guard), m.
const MIN_RANGE_M: f64 = firmware::dipole::MIN_RANGE_M as f64;

/// Settings of the fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmConfig {
    /// Moment magnitude range, A·m².
    pub m_range: [f64; 2],
    /// Burial depth range below the snow, m.
    pub depth_range: [f64; 2],
    /// Receiver height above the snow, m.
    pub receiver_height: f64,
    /// Background noise per component, A/m (ICRA eq. 10).
    pub sigma_bkg: f64,
    /// Noise proportional to |H| (ICRA eq. 10).
    pub k_sen: f64,
    /// Saturation level of a field component, A/m.
    pub h_saturation: f64,
    /// Azimuths of the multi-start ring.
    pub starts_azimuth: usize,
    /// Ranges of the multi-start ring.
    pub starts_range: usize,
    /// A full multi-start on the first pulses and then every this many pulses.
    pub multistart_every: usize,
    /// Iterations of every start before the most promising are refined.
    pub probe_iterations: usize,
    /// Starts refined to convergence (the lowest costs after `probe_iterations`).
    pub refined_starts: usize,
    /// Iterations per LM run.
    pub max_iterations: usize,
}

impl LmConfig {
    /// The fit's settings from the SOGs filter's configuration (same priors and noise).
    pub fn from_sog(c: &SogConfig) -> Self {
        Self {
            m_range: [f64::from(c.m_min), f64::from(c.m_max)],
            depth_range: [f64::from(c.depth_min), f64::from(c.depth_max)],
            receiver_height: f64::from(c.receiver_height),
            sigma_bkg: f64::from(c.sigma_bkg),
            k_sen: f64::from(c.k_sen),
            h_saturation: f64::from(c.h_saturation),
            starts_azimuth: 12,
            starts_range: 3,
            multistart_every: 10,
            probe_iterations: 4,
            refined_starts: 4,
            max_iterations: 30,
        }
    }

    /// Checks that the settings are finite and consistent.
    pub fn validate(&self) -> Result<(), EstimateError> {
        let v = [
            self.m_range[0],
            self.m_range[1],
            self.depth_range[0],
            self.depth_range[1],
            self.receiver_height,
            self.sigma_bkg,
            self.k_sen,
            self.h_saturation,
        ];
        let ok = v.iter().all(|x| x.is_finite())
            && self.m_range[0] > 0.0
            && self.m_range[1] >= self.m_range[0]
            && self.depth_range[0] >= 0.0
            && self.depth_range[1] >= self.depth_range[0]
            && self.sigma_bkg > 0.0
            && self.k_sen >= 0.0
            && self.h_saturation > 0.0
            && self.starts_azimuth > 0
            && self.starts_range > 0
            && self.multistart_every > 0
            && self.probe_iterations > 0
            && self.refined_starts > 0
            && self.max_iterations > 0;
        if ok {
            Ok(())
        } else {
            Err(EstimateError::InvalidConfig)
        }
    }

    fn log_m0(&self) -> f64 {
        0.5 * (self.m_range[0] * self.m_range[1]).ln()
    }

    fn sigma_log_m(&self) -> f64 {
        ((self.m_range[1] / self.m_range[0]).ln() / 4.0).max(0.05)
    }

    /// Prior mean of the transmitter's height in the world frame (the first receiver is
    /// at z = 0, `receiver_height` above the snow).
    fn z0(&self) -> f64 {
        -(self.receiver_height + 0.5 * (self.depth_range[0] + self.depth_range[1]))
    }

    fn sigma_z(&self) -> f64 {
        ((self.depth_range[1] - self.depth_range[0]) / 4.0).max(0.25)
    }
}

/// A pulse ready for the fit: receiver position, field in world axes, noise.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Obs {
    p: V3,
    h: V3,
    sigma: f64,
}

/// The dipole field at `r = receiver − transmitter` (A/m, moment in A·m²) and its
/// Jacobians with respect to `r` and to the moment (ICRA eq. 2–3 written in vectors:
/// `H = (3 (m·r) r / |r|⁵ − m / |r|³) / 4π`).
pub fn field_and_jacobians(r: &V3, m: &V3) -> (V3, M3, M3) {
    let d = r.norm();
    let (d3, d5, d7) = (d.powi(3), d.powi(5), d.powi(7));
    let mr = m.dot(r);
    let k = 1.0 / (4.0 * PI);
    let h = dipole_field(r, m);
    let dh_dm = (r * r.transpose() * (3.0 / d5) - M3::identity() / d3) * k;
    let dh_dr = ((r * m.transpose() + m * r.transpose() + M3::identity() * mr) * (3.0 / d5)
        - r * r.transpose() * (15.0 * mr / d7))
        * k;
    (h, dh_dr, dh_dm)
}

impl Obs {
    /// Whitened residual (best sign) and its Jacobian w.r.t. θ, or `None` when the
    /// transmitter hypothesis sits on the receiver.
    fn residual(&self, th: &V6) -> Option<(V3, J3x6)> {
        let pt = th.fixed_rows::<3>(0).into_owned();
        let m = th.fixed_rows::<3>(3).into_owned() * M_UNIT;
        let r = self.p - pt;
        if r.norm() < MIN_RANGE_M {
            return None;
        }
        let (f, dr, dm) = field_and_jacobians(&r, &m);
        let s = if self.h.dot(&f) < 0.0 { -1.0 } else { 1.0 };
        let e = (self.h * s - f) / self.sigma;
        let mut j = J3x6::zeros();
        // e = (s h − H(p − p_T, m))/σ: ∂e/∂p_T = +∂H/∂r / σ, ∂e/∂m = −∂H/∂m / σ.
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(dr / self.sigma));
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-dm * (M_UNIT / self.sigma)));
        Some((e, j))
    }
}

/// The prior residuals (log-moment, height) and their Jacobian rows.
fn prior(cfg: &LmConfig, th: &V6) -> [(f64, V6); 2] {
    let m = th.fixed_rows::<3>(3).into_owned();
    let n2 = m.norm_squared().max(1e-300);
    let sl = cfg.sigma_log_m();
    let em = ((n2.sqrt() * M_UNIT).ln() - cfg.log_m0()) / sl;
    let mut jm = V6::zeros();
    jm.fixed_rows_mut::<3>(3).copy_from(&(m / (n2 * sl)));
    let sz = cfg.sigma_z();
    let ez = (th[2] - cfg.z0()) / sz;
    let mut jz = V6::zeros();
    jz[2] = 1.0 / sz;
    [(em, jm), (ez, jz)]
}

/// The cost `Σ |e|²` at `th`, or infinity where the model cannot be evaluated.
fn cost(cfg: &LmConfig, obs: &[Obs], th: &V6) -> f64 {
    let mut c = 0.0;
    for o in obs {
        match o.residual(th) {
            Some((e, _)) => c += e.norm_squared(),
            None => return f64::INFINITY,
        }
    }
    c + prior(cfg, th).iter().map(|(e, _)| e * e).sum::<f64>()
}

/// Gauss–Newton normal equations `(JᵀJ, Jᵀe)` at `th`.
fn normal_equations(cfg: &LmConfig, obs: &[Obs], th: &V6) -> Option<(M6, V6)> {
    let (mut a, mut g) = (M6::zeros(), V6::zeros());
    for o in obs {
        let (e, j) = o.residual(th)?;
        a += j.transpose() * j;
        g += j.transpose() * e;
    }
    for (e, j) in prior(cfg, th) {
        a += j * j.transpose();
        g += j * e;
    }
    Some((a, g))
}

/// One Levenberg–Marquardt run from `th` (Marquardt's scaling: damping `λ diag(JᵀJ)`).
/// Returns the end point and its cost.
fn levenberg_marquardt(cfg: &LmConfig, obs: &[Obs], mut th: V6, iterations: usize) -> (V6, f64) {
    let mut c = cost(cfg, obs, &th);
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let Some((a, g)) = normal_equations(cfg, obs, &th) else {
            break;
        };
        let mut improved = false;
        while lambda < 1e12 {
            let mut damped = a;
            for i in 0..6 {
                damped[(i, i)] += lambda * a[(i, i)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|ch| ch.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            // The Gauss–Newton model's decrease of Σe² for this step: when it is
            // negligible (whitened residuals: 1e-3 of a χ² unit) the fit has converged.
            let predicted = -(2.0 * g.dot(&step) + step.dot(&(a * step)));
            if predicted < 1e-3 {
                return (th, c);
            }
            let next = th + step;
            let cn = cost(cfg, obs, &next);
            if cn < c {
                let rel = (c - cn) / c.max(1e-300);
                th = next;
                c = cn;
                lambda = (lambda / 10.0).max(1e-12);
                improved = rel > 1e-7 && step.norm() > 1e-7;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (th, c)
}

/// Starting points on the first pulse's ring (ICRA eq. 16): each position with the moment
/// that explains the first pulse exactly (`H` is linear in `m`).
fn ring_starts(cfg: &LmConfig, first: &Obs) -> Vec<V6> {
    let hn = first.h.norm();
    let k = 4.0 * PI * hn;
    let r_min = (cfg.m_range[0] / k).cbrt();
    let r_max = (2.0 * cfg.m_range[1] / k).cbrt();
    let dz = cfg.z0() - first.p.z;
    let mut out = Vec::with_capacity(cfg.starts_azimuth * cfg.starts_range);
    for i in 0..cfg.starts_range {
        let f = (i as f64 + 0.5) / cfg.starts_range as f64;
        let r = r_min * (r_max / r_min).powf(f);
        let horizontal = (r * r - dz * dz).max(0.25).sqrt();
        for j in 0..cfg.starts_azimuth {
            let az = 2.0 * PI * (j as f64 + 0.5 * (i % 2) as f64) / cfg.starts_azimuth as f64;
            let pt = first.p + V3::new(horizontal * az.cos(), horizontal * az.sin(), dz);
            let r_vec = first.p - pt;
            let (_, _, dm) = field_and_jacobians(&r_vec, &V3::zeros());
            let Some(m) = dm.try_inverse().map(|inv| inv * first.h) else {
                continue;
            };
            let mut th = V6::zeros();
            th.fixed_rows_mut::<3>(0).copy_from(&pt);
            th.fixed_rows_mut::<3>(3).copy_from(&(m / M_UNIT));
            out.push(th);
        }
    }
    out
}

/// The batch fit as an [`Estimator`] (host only).
#[derive(Debug, Clone)]
pub struct LmFit {
    cfg: LmConfig,
    dr: DeadReckoning,
    obs: Vec<Obs>,
    best: Option<(V6, f64)>,
    last_rpy: firmware::Vec3,
}

impl LmFit {
    /// A fit with `cfg`, refused when the settings are inconsistent.
    pub fn new(cfg: LmConfig) -> Result<Self, EstimateError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            dr: DeadReckoning::default(),
            obs: Vec::new(),
            best: None,
            last_rpy: firmware::Vec3::zeros(),
        })
    }

    /// The fitted parameters `[p_T (m, world); m (A·m²)]` and the cost.
    pub fn solution(&self) -> Option<(V3, V3, f64)> {
        self.best.map(|(th, c)| {
            (
                th.fixed_rows::<3>(0).into_owned(),
                th.fixed_rows::<3>(3).into_owned() * M_UNIT,
                c,
            )
        })
    }

    fn obs_of(&self, w: &WorldPulse) -> Obs {
        let s = self.cfg.sigma_bkg.hypot(self.cfg.k_sen * w.h.norm());
        Obs {
            p: w.p,
            h: w.h,
            sigma: s,
        }
    }

    fn refit(&mut self) {
        let n = self.obs.len();
        let mut candidates: Vec<V6> = Vec::new();
        if let Some((th, _)) = self.best {
            candidates.push(th);
        }
        if (n <= self.cfg.multistart_every || n.is_multiple_of(self.cfg.multistart_every))
            && let Some(first) = self.obs.first()
        {
            candidates.extend(ring_starts(&self.cfg, first));
        }
        // A few iterations from every start, then the most promising ones to convergence.
        let mut probed: Vec<(V6, f64)> = candidates
            .into_iter()
            .map(|th| levenberg_marquardt(&self.cfg, &self.obs, th, self.cfg.probe_iterations))
            .filter(|(_, c)| c.is_finite())
            .collect();
        probed.sort_by(|a, b| a.1.total_cmp(&b.1));
        let mut best: Option<(V6, f64)> = None;
        for (th, _) in probed.into_iter().take(self.cfg.refined_starts) {
            let (th, c) = levenberg_marquardt(&self.cfg, &self.obs, th, self.cfg.max_iterations);
            if c.is_finite() && best.is_none_or(|(_, bc)| c < bc) {
                best = Some((th, c));
            }
        }
        if best.is_some() {
            self.best = best;
        }
    }
}

impl Estimator for LmFit {
    fn step(
        &mut self,
        motion: &Displacement,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Result<StepReport, EstimateError> {
        let w = self
            .dr
            .peek(motion, attitude, pulse, self.cfg.h_saturation)?;
        let first = self.obs.is_empty();
        self.dr.commit(w);
        self.obs.push(self.obs_of(&w));
        self.last_rpy = attitude.rpy;
        self.refit();
        Ok(single_report(first))
    }

    fn estimate(&self) -> Option<VictimEstimate> {
        let (th, _) = self.best?;
        let rx = self.dr.last()?.p;
        let pt = th.fixed_rows::<3>(0).into_owned();
        // Position covariance: the position block of (JᵀJ)⁻¹ at the solution.
        let cov = normal_equations(&self.cfg, &self.obs, &th)
            .and_then(|(a, _)| a.try_inverse())
            .map_or(M3::identity() * 1e4, |inv| {
                inv.fixed_view::<3, 3>(0, 0).into_owned()
            });
        let rel = pt - rx;
        let m = th.fixed_rows::<3>(3).into_owned() * M_UNIT;
        let cov = cov.map(|x| x as f32);
        let moment = crate::world::physics::to_f32(&m);
        Some(single_estimate(&rel, cov, moment, self.last_rpy))
    }

    fn reset(&mut self) {
        self.dr.reset();
        self.obs.clear();
        self.best = None;
    }

    fn is_initialized(&self) -> bool {
        self.best.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn g(rng: &mut ChaCha8Rng) -> f64 {
        StandardNormal.sample(rng)
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let r = V3::new(g(&mut rng), g(&mut rng), g(&mut rng)) * 10.0;
            let m = V3::new(g(&mut rng), g(&mut rng), g(&mut rng)) * 1e-2;
            let (h, dr, dm) = field_and_jacobians(&r, &m);
            assert!((h - dipole_field(&r, &m)).norm() <= 1e-12 * h.norm());
            for i in 0..3 {
                let eps = 1e-6 * r.norm();
                let mut e = V3::zeros();
                e[i] = eps;
                let fd = (dipole_field(&(r + e), &m) - dipole_field(&(r - e), &m)) / (2.0 * eps);
                let err = (fd - dr.column(i)).norm();
                assert!(err <= 1e-6 * dr.norm(), "dH/dr col {i}: {err:e}");
                let em = e / r.norm() * 1e-4;
                let fd =
                    (dipole_field(&r, &(m + em)) - dipole_field(&r, &(m - em))) / (2.0 * em[i]);
                let err = (fd - dm.column(i)).norm();
                assert!(err <= 1e-6 * dm.norm(), "dH/dm col {i}: {err:e}");
            }
        }
    }

    #[test]
    fn residual_jacobian_matches_finite_differences() {
        let cfg = LmConfig::from_sog(&SogConfig::default());
        let o = Obs {
            p: V3::new(3.0, -2.0, 0.5),
            h: V3::new(1e-7, -3e-7, 2e-7),
            sigma: 1e-8,
        };
        let th = V6::new(10.0, 4.0, -2.0, 5.0, -3.0, 8.0);
        let (e0, j) = o.residual(&th).unwrap();
        for i in 0..6 {
            let mut d = V6::zeros();
            d[i] = 1e-5;
            let (ep, _) = o.residual(&(th + d)).unwrap();
            let (em, _) = o.residual(&(th - d)).unwrap();
            let fd = (ep - em) / 2e-5;
            assert!(
                (fd - j.column(i)).norm() <= 1e-5 * j.norm() + 1e-9,
                "column {i}"
            );
        }
        assert!(e0.iter().all(|x| x.is_finite()));
        // Prior rows, too.
        for (k, (_, row)) in prior(&cfg, &th).iter().enumerate() {
            for i in 0..6 {
                let mut d = V6::zeros();
                d[i] = 1e-6;
                let fd = (prior(&cfg, &(th + d))[k].0 - prior(&cfg, &(th - d))[k].0) / 2e-6;
                assert!((fd - row[i]).abs() < 1e-6, "prior {k} column {i}");
            }
        }
    }

    /// A seeded walk toward a buried transmitter with exact poses and the ICRA noise:
    /// the fit ends within decimetres.
    #[test]
    fn converges_on_a_seeded_walk_and_refuses_bad_input() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let sog = SogConfig::default();
        let mut fit = LmFit::new(LmConfig::from_sog(&sog)).unwrap();
        let tx = V3::new(30.0, -12.0, -2.5);
        let m = V3::new(0.006, -0.002, 0.004);
        let att = Attitude::with_sigmas(firmware::Vec3::zeros(), 0.0, 0.0);
        let mut p = V3::zeros();
        let mut prev = p;
        for k in 0..40 {
            // Walk straight toward the victim's surface point, 1 m per pulse, stopping 1 m short.
            let to = V3::new(tx.x, tx.y, 0.0) - p;
            if to.norm() > 1.0 {
                p += to.normalize();
            }
            let h_true = dipole_field(&(p - tx), &m);
            let s = f64::from(sog.sigma_bkg).hypot(f64::from(sog.k_sen) * h_true.norm());
            let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
            let h = (h_true + V3::new(g(&mut rng), g(&mut rng), g(&mut rng)) * s) * sign;
            let motion = Displacement::with_sigmas(
                crate::world::physics::to_f32(&(p - prev)),
                firmware::Vec3::zeros(),
                0.0,
                0.0,
            );
            prev = p;
            fit.step(
                &motion,
                &att,
                &Pulse {
                    h: crate::world::physics::to_f32(&h),
                    t: k as f32,
                },
            )
            .unwrap();
        }
        let est = fit.estimate().unwrap();
        let err =
            (V3::new(f64::from(est.p.x), f64::from(est.p.y), f64::from(est.p.z)) - (tx - p)).norm();
        assert!(err < 0.3, "final error {err}");
        // A refused pulse leaves the fit as it was.
        let before = fit.solution();
        let bad = Pulse {
            h: firmware::Vec3::new(f32::NAN, 0.0, 0.0),
            t: 100.0,
        };
        assert_eq!(
            fit.step(&Displacement::zero(), &att, &bad),
            Err(EstimateError::NonFinite)
        );
        let zero = Pulse {
            h: firmware::Vec3::zeros(),
            t: 100.0,
        };
        assert_eq!(
            fit.step(&Displacement::zero(), &att, &zero),
            Err(EstimateError::ZeroField)
        );
        assert_eq!(fit.solution(), before);
        let mut bad_cfg = LmConfig::from_sog(&sog);
        bad_cfg.sigma_bkg = f64::NAN;
        assert!(LmFit::new(bad_cfg).is_err());
    }
}
