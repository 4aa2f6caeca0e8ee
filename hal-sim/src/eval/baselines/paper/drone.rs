//! Mimmo, Bernard & Marconi's full scheme in their own protocol (`003_*` §VI): a receiver
//! with a known pose tracking the reference ξ of eq. 22 exactly (`p_r ≡ ξ`, Theorem 1),
//! the RLS identifier of eq. 12–20 ([`crate::eval::baselines::rls`]) closing the loop through
//! `p̂_t`, the ARVA output of a dipole perturbed by the bounded EMI of §VI.
//!
//! - Reference generator (eq. 22–23): `ξ̇_s = f_s(p̂_t − ξ_s)`,
//!   `f_s(v) = f_smax K|v| / √(1 + K²|v|²) · v/|v|`, `ξ = sat(ξ_s) + ξ_e`,
//!   `ξ_e = (A₁ sin ω₁t, A₂ sin ω₂t, A₃ sin ω₃t)`, `ξ_s(0) = p_r(0) = 0`; `sat` projects
//!   onto the ball where the victim is known to be (the 50 m sphere).
//! - Victim uniform in that ball with a uniformly oriented axis; moment known to the
//!   identifier (the paper's `m` in eq. 12).
//! - EMI (§VI): a randomly oriented vector of magnitude at most
//!   `w̄ = m / (2π ‖p_eq‖³)`, ‖p_eq‖ = 80 m (the on-axis field of the same transmitter at
//!   80 m), magnitude uniform in `[0, w̄]` and direction uniform on the sphere, both drawn
//!   afresh every [`DroneConfig::emi_sample_s`] and held (the sample-and-hold of
//!   Simulink's band-limited white noise block, whose sample time the paper does not give).
//! - The paper integrates the continuous system with ode45 (steps ≤ 1 ms); here every
//!   signal is held over a fixed step [`DroneConfig::dt_s`] and eq. 20 is integrated
//!   exactly over it (see [`RlsState::advance`]).
//!
//! Beside it, the SOGs filter on the same flight: one pulse per second (a beacon's period)
//! of the same noisy field, the drone's known displacement between pulses
//! (`Mode::KnownTrajectory`), the moment known, and the 50 m ball as its prior.
//!
//! The walking-person variant ([`Geometry::Walker`]) keeps the identifier and the
//! generator but draws the victim buried under the snow, keeps the slow part on the
//! receiver's walking height and excites with what a person's arm can do.
use crate::eval::baselines::rls::{RlsConfig, RlsState, m_bar};
use crate::world::physics::{M3, V3, dipole_field, to_f32};
use firmware::estimate::{Attitude, DefaultSog, Displacement, Estimator, Pulse, SogConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

/// ω₁ of §VI, rad/s (ω₂ = ω₁/2, ω₃ = ω₁/4).
pub const OMEGA_1: f64 = 0.72 * PI;

/// The exciting part ξ_e of eq. 22.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Excitation {
    /// Amplitudes A₁, A₂, A₃, m.
    pub amp_m: [f64; 3],
    /// Pulsations ω₁, ω₂, ω₃, rad/s.
    pub omega: [f64; 3],
}

impl Excitation {
    /// The paper's excitation with every amplitude `a` m: ω₁ = 0.72π, ω₁/2, ω₁/4.
    pub fn paper(a: f64) -> Self {
        Self {
            amp_m: [a; 3],
            omega: [OMEGA_1, OMEGA_1 / 2.0, OMEGA_1 / 4.0],
        }
    }

    /// ξ_e(t).
    pub fn at(&self, t: f64) -> V3 {
        V3::from_fn(|i, _| self.amp_m[i] * (self.omega[i] * t).sin())
    }
}

/// Where the victim is and where the receiver may go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Geometry {
    /// The paper: victim uniform in a ball of this radius (m) around the start; the
    /// drone flies in 3-D.
    Drone {
        /// Radius of the ball, m.
        radius_m: f64,
    },
    /// A walking person: the victim buried `depth_m` below the snow within `radius_m`
    /// horizontally; the slow part stays at the receiver's height `height_m` above the
    /// snow (the excitation is the arm's).
    Walker {
        /// Horizontal radius of the search area, m.
        radius_m: f64,
        /// Burial depth range, m.
        depth_m: [f64; 2],
        /// Receiver height above the snow, m.
        height_m: f64,
    },
}

impl Geometry {
    /// The paper's 50 m ball.
    pub const PAPER: Geometry = Geometry::Drone { radius_m: 50.0 };

    /// A victim position drawn uniformly in the region.
    fn draw_victim(&self, rng: &mut impl Rng) -> V3 {
        match *self {
            Geometry::Drone { radius_m } => {
                radius_m * rng.random::<f64>().cbrt() * random_unit(rng)
            }
            Geometry::Walker {
                radius_m,
                depth_m,
                height_m,
            } => {
                let r = radius_m * rng.random::<f64>().sqrt();
                let a = rng.random_range(-PI..PI);
                let depth = rng.random_range(depth_m[0]..=depth_m[1]);
                V3::new(r * a.cos(), r * a.sin(), -depth - height_m)
            }
        }
    }

    /// `sat` of eq. 22: the slow part projected onto the region (the walker's onto its
    /// walking plane, the receiver at the start's height).
    fn saturate(&self, xi_s: &V3) -> V3 {
        match *self {
            Geometry::Drone { radius_m } => {
                let n = xi_s.norm();
                if n > radius_m {
                    xi_s * (radius_m / n)
                } else {
                    *xi_s
                }
            }
            Geometry::Walker { radius_m, .. } => {
                let h = V3::new(xi_s.x, xi_s.y, 0.0);
                let n = h.norm();
                if n > radius_m { h * (radius_m / n) } else { h }
            }
        }
    }

    /// The prior of the SOGs filter: relative depth band below the receiver
    /// (`receiver_height`, `depth_min`, `depth_max` of [`SogConfig`]).
    fn sog_depth_band(&self) -> (f32, f32, f32) {
        match *self {
            Geometry::Drone { radius_m } => (0.0, -radius_m as f32, radius_m as f32),
            Geometry::Walker {
                depth_m, height_m, ..
            } => (height_m as f32, depth_m[0] as f32, depth_m[1] as f32),
        }
    }
}

fn random_unit(rng: &mut impl Rng) -> V3 {
    let z: f64 = rng.random_range(-1.0..=1.0);
    let a: f64 = rng.random_range(-PI..PI);
    let s = (1.0 - z * z).max(0.0).sqrt();
    V3::new(s * a.cos(), s * a.sin(), z)
}

/// The field the receiver measures before the EMI.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldModel {
    /// The dipole (eq. 2): the truth.
    Dipole,
    /// The dipole's direction with the magnitude of the ellipsoidal approximation (eq. 8):
    /// the identifier's own model, which isolates the error of eq. 7.
    Ellipsoid,
}

/// Settings of the drone protocol.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DroneConfig {
    /// Victim region and receiver constraints.
    pub geometry: Geometry,
    /// ξ_e of eq. 22.
    pub excitation: Excitation,
    /// K of eq. 23.
    pub k: f64,
    /// f_smax of eq. 23, m/s.
    pub fs_max: f64,
    /// The identifier (ρ, Γ = γI, κ; metres).
    pub rls: RlsConfig,
    /// Transmitter moment, A·m² (only its ratio to the EMI matters).
    pub moment_am2: f64,
    /// The EMI's equivalent transmitter range ‖p_eq‖, m (`None`: no EMI).
    pub emi_equiv_range_m: Option<f64>,
    /// Hold time of the EMI samples, s.
    pub emi_sample_s: f64,
    /// The measured field's model.
    pub field: FieldModel,
    /// Simulated time, s.
    pub duration_s: f64,
    /// Integration step, s.
    pub dt_s: f64,
    /// Period of the SOGs filter's pulses, s (`None`: no SOGs filter).
    pub sog_period_s: Option<f64>,
    /// Period of the recorded traces, s.
    pub trace_every_s: f64,
    /// Steering: `false` (the paper) steers ξ_s by the identifier; `true` by the SOGs
    /// filter's mean (before its first estimate ξ_s stays where it is).
    pub steer_by_sog: bool,
    /// The identifier's readings: `None` continuous (the paper's ARVA output); `Some(T)`
    /// one per transmitter pulse of period `T` s (a real receiver), each integrated over
    /// the period with its own position (as the common protocol feeds it).
    pub reading_period_s: Option<f64>,
}

/// The paper's adaptation gain Γ = γ I (not given in §VI; see
/// `docs/decisions/rls-drone-protocol.md`).
pub const PAPER_GAMMA: f64 = 1e8;
/// Tolerance κ of Υ's saturation of M̄'s singular values (Property 1; not given in §VI).
pub const PAPER_KAPPA: f64 = 2.0;
/// Nominal transmitter moment, A·m² (geometric mean of EN 300 718's range).
pub const NOMINAL_MOMENT: f64 = 9.5e-3;

impl DroneConfig {
    /// The paper's protocol (§VI): K = 1, f_smax = 0.5 m/s, A_i = 2 m, ω₁ = 0.72π, ρ = 1,
    /// the victim in a 50 m ball, EMI equivalent to the transmitter at 80 m.
    pub fn paper() -> Self {
        Self {
            geometry: Geometry::PAPER,
            excitation: Excitation::paper(2.0),
            k: 1.0,
            fs_max: 0.5,
            rls: RlsConfig::paper(NOMINAL_MOMENT, PAPER_GAMMA, PAPER_KAPPA),
            moment_am2: NOMINAL_MOMENT,
            emi_equiv_range_m: Some(80.0),
            emi_sample_s: 1e-3,
            field: FieldModel::Dipole,
            duration_s: 200.0,
            dt_s: 0.01,
            sog_period_s: Some(1.0),
            trace_every_s: 1.0,
            steer_by_sog: false,
            reading_period_s: None,
        }
    }

    /// The walking-person variant: the victim buried 0.3–3 m within 50 m, the receiver
    /// 1 m above the snow, arm swings of `amp_m` on every axis at the paper's pulsations.
    pub fn walker(amp_m: f64) -> Self {
        Self {
            geometry: Geometry::Walker {
                radius_m: 50.0,
                depth_m: [0.3, 3.0],
                height_m: 1.0,
            },
            excitation: Excitation::paper(amp_m),
            ..Self::paper()
        }
    }

    /// Bound w̄ of the EMI, A/m.
    pub fn emi_bound(&self) -> Option<f64> {
        self.emi_equiv_range_m
            .map(|r| self.moment_am2 / (2.0 * PI * r.powi(3)))
    }
}

/// `f_s` of eq. 23.
pub fn f_s(v: &V3, fs_max: f64, k: f64) -> V3 {
    let n = v.norm();
    if n <= 0.0 {
        return V3::zeros();
    }
    v * (fs_max * k / (1.0 + k * k * n * n).sqrt())
}

/// The bounded EMI of §VI, sampled and held.
struct Emi {
    bound: f64,
    hold_s: f64,
    next_t: f64,
    w: V3,
}

impl Emi {
    fn at(&mut self, t: f64, rng: &mut impl Rng) -> V3 {
        if t + 1e-9 >= self.next_t {
            self.w = self.bound * rng.random::<f64>() * random_unit(rng);
            self.next_t = t + self.hold_s;
        }
        self.w
    }
}

/// One run of the protocol.
#[derive(Debug, Clone)]
pub struct DroneRun {
    /// Scenario seed.
    pub seed: u64,
    /// Victim position (start at the origin), m.
    pub victim: V3,
    /// Trace times, s.
    pub t: Vec<f64>,
    /// Identifier's estimate p̂_t at the trace times, m.
    pub rls_estimate: Vec<V3>,
    /// ‖p̂_t − p_t‖ at the trace times, m.
    pub rls_error: Vec<f64>,
    /// SOGs filter's 3-D error at the trace times (NaN before its first estimate), m.
    pub sog_error: Vec<f64>,
    /// Receiver–victim distance at the trace times, m.
    pub distance: Vec<f64>,
    /// Largest receiver speed, m/s.
    pub max_speed: f64,
}

/// The "final" error is the median over the last this many seconds: the receiver keeps
/// oscillating around the victim (ξ_e), and at the instants where ξ_e's three sines
/// vanish together (every 100/9 s) it passes over the transmitter itself, so a single
/// instant is not representative.
pub const FINAL_WINDOW_S: f64 = 20.0;

impl DroneRun {
    /// Median of `trace` over the last [`FINAL_WINDOW_S`] (`None`: no finite value there).
    fn final_of(&self, trace: &[f64]) -> Option<f64> {
        let end = self.t.last()?;
        let mut v: Vec<f64> = self
            .t
            .iter()
            .zip(trace)
            .filter(|(t, e)| **t >= end - FINAL_WINDOW_S && e.is_finite())
            .map(|(_, e)| *e)
            .collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    }

    /// The identifier's final error (median over the last [`FINAL_WINDOW_S`]), m.
    pub fn rls_final(&self) -> Option<f64> {
        self.final_of(&self.rls_error)
    }

    /// The SOGs filter's final error, m (`None`: no estimate at the end).
    pub fn sog_final(&self) -> Option<f64> {
        self.final_of(&self.sog_error)
    }

    /// The value of `trace` at time `t` (the last sample at or before it).
    pub fn at(&self, trace: &[f64], t: f64) -> Option<f64> {
        let k = self.t.iter().rposition(|&s| s <= t + 1e-9)?;
        trace.get(k).copied().filter(|v| v.is_finite())
    }
}

/// The victim of a seed: position, axis (unit).
pub fn draw_victim(cfg: &DroneConfig, seed: u64) -> (V3, V3) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let p = cfg.geometry.draw_victim(&mut rng);
    (p, random_unit(&mut rng))
}

/// The SOGs filter's settings in this protocol: known trajectory, the moment known, the
/// protocol's region as the depth prior, the EMI's per-axis σ as background noise and the
/// filter's usual sensor term.
fn sog_config(cfg: &DroneConfig) -> Option<SogConfig> {
    let w = cfg.emi_bound()?;
    let (height, dmin, dmax) = cfg.geometry.sog_depth_band();
    let m = cfg.moment_am2 as f32;
    let c = SogConfig {
        m_min: m,
        m_max: m,
        receiver_height: height,
        depth_min: dmin,
        depth_max: dmax,
        // Uniform magnitude in [0, w̄], isotropic: E|w|² = w̄²/3, i.e. w̄/3 per axis.
        sigma_bkg: (w / 3.0) as f32,
        ..SogConfig::known_trajectory()
    };
    c.validate().ok().map(|()| c)
}

/// The measured field (before the EMI) at `p_r`.
struct Source {
    p_t: V3,
    moment: V3,
    mb: M3,
    ab2: (f64, f64),
    m: f64,
    model: FieldModel,
}

impl Source {
    fn field(&self, p_r: &V3) -> V3 {
        let d = p_r - self.p_t;
        let h = dipole_field(&d, &self.moment);
        match self.model {
            FieldModel::Dipole => h,
            FieldModel::Ellipsoid => {
                let (a2, b2) = self.ab2;
                let mag = self.m / (4.0 * PI) * (a2 * b2 / d.dot(&(self.mb * d))).powf(1.5);
                h.normalize() * mag
            }
        }
    }
}

/// The SOGs filter beside the identifier: one pulse per period, known displacement.
struct SogBeside {
    filter: Box<DefaultSog>,
    period: f64,
    next_t: f64,
    last_pulse: Option<V3>,
    estimate: Option<V3>,
}

impl SogBeside {
    fn new(cfg: &DroneConfig) -> Option<Self> {
        let period = cfg.sog_period_s?;
        let filter = DefaultSog::new(sog_config(cfg)?).ok()?;
        Some(Self {
            filter: Box::new(filter),
            period,
            next_t: 0.0,
            last_pulse: None,
            estimate: None,
        })
    }

    /// Feeds the pulse `h` (A/m, W axes) taken at `p_r` at time `t` when one is due.
    fn maybe_pulse(&mut self, t: f64, p_r: &V3, h: &V3, rng: &mut impl Rng) {
        if t + 1e-9 < self.next_t {
            return;
        }
        self.next_t += self.period;
        let motion = self.last_pulse.map_or(Displacement::zero(), |q| {
            Displacement::with_sigmas(to_f32(&(p_r - q)), firmware::Vec3::zeros(), 0.0, 0.0)
        });
        let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
        let pulse = Pulse {
            h: to_f32(&(h * sign)),
            t: t as f32,
        };
        let att = Attitude::with_sigmas(firmware::Vec3::zeros(), 1e-4, 1e-4);
        if self.filter.step(&motion, &att, &pulse).is_ok() && self.filter.is_initialized() {
            self.last_pulse = Some(*p_r);
        }
        // The estimate is relative to the receiver at the last accepted pulse.
        self.estimate = self
            .filter
            .estimate()
            .zip(self.last_pulse)
            .map(|(e, q)| q + V3::new(f64::from(e.p.x), f64::from(e.p.y), f64::from(e.p.z)));
    }
}

/// The identifier fed as configured: continuously (the output of each step's EMI samples
/// averaged, exact against the held φ) or once per reading period.
struct Identifier {
    state: RlsState,
    estimate: V3,
    next_reading_t: f64,
    last_reading_t: Option<f64>,
}

impl Identifier {
    fn advance(&mut self, cfg: &DroneConfig, t: f64, p_r: &V3, y: f64) {
        let dt = match cfg.reading_period_s {
            None => cfg.dt_s,
            Some(period) => {
                if t + 1e-9 < self.next_reading_t {
                    return;
                }
                self.next_reading_t += period;
                let dt = self.last_reading_t.map_or(0.0, |l| t - l);
                self.last_reading_t = Some(t);
                dt
            }
        };
        let mut next = self.state;
        if next
            .advance(&cfg.rls, &(p_r / cfg.rls.length_unit_m), y, dt)
            .is_some()
        {
            self.state = next;
        }
        if let Some(p) = cfg.rls.position(self.state.x()) {
            self.estimate = p;
        }
    }
}

/// Runs the protocol for `seed` (victim `victim` if given, else drawn from the seed).
pub fn run(cfg: &DroneConfig, seed: u64, victim: Option<(V3, V3)>) -> DroneRun {
    let (p_t, axis) = victim.unwrap_or_else(|| draw_victim(cfg, seed));
    let (a2, b2) = cfg.rls.ab2;
    let source = Source {
        p_t,
        moment: axis * cfg.moment_am2,
        mb: m_bar(&axis, a2, b2),
        ab2: (a2, b2),
        m: cfg.moment_am2,
        model: cfg.field,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xd20e_0003);
    let mut emi = cfg.emi_bound().map(|bound| Emi {
        bound,
        hold_s: cfg.emi_sample_s,
        next_t: 0.0,
        w: V3::zeros(),
    });
    let mut sog = SogBeside::new(cfg);
    let mut id = Identifier {
        state: RlsState::default(),
        estimate: V3::zeros(),
        next_reading_t: 0.0,
        last_reading_t: None,
    };
    let mut xi_s = V3::zeros();
    let mut out = DroneRun {
        seed,
        victim: p_t,
        t: Vec::new(),
        rls_estimate: Vec::new(),
        rls_error: Vec::new(),
        sog_error: Vec::new(),
        distance: Vec::new(),
        max_speed: 0.0,
    };
    let mut prev_p: Option<V3> = None;
    let steps = (cfg.duration_s / cfg.dt_s).round() as usize;
    let trace_every = (cfg.trace_every_s / cfg.dt_s).round().max(1.0) as usize;
    for k in 0..=steps {
        let t = k as f64 * cfg.dt_s;
        let p_r = cfg.geometry.saturate(&xi_s) + cfg.excitation.at(t);
        if let Some(p0) = prev_p {
            out.max_speed = out.max_speed.max((p_r - p0).norm() / cfg.dt_s);
        }
        prev_p = Some(p_r);
        let h_n = source.field(&p_r);
        let (h_m, y) = measure(cfg, &mut emi, &mut rng, t, &h_n);
        if let Some(s) = sog.as_mut() {
            s.maybe_pulse(t, &p_r, &h_m, &mut rng);
        }
        if k % trace_every == 0 {
            let sog_hat = sog.as_ref().and_then(|s| s.estimate);
            out.t.push(t);
            out.rls_estimate.push(id.estimate);
            out.rls_error.push((id.estimate - p_t).norm());
            out.sog_error
                .push(sog_hat.map_or(f64::NAN, |s| (s - p_t).norm()));
            out.distance.push((p_r - p_t).norm());
        }
        if k == steps {
            break;
        }
        id.advance(cfg, t, &p_r, y);
        // Generator (eq. 22–23).
        let target = if cfg.steer_by_sog {
            sog.as_ref().and_then(|s| s.estimate).unwrap_or(xi_s)
        } else {
            id.estimate
        };
        xi_s += f_s(&(target - xi_s), cfg.fs_max, cfg.k) * cfg.dt_s;
    }
    out
}

/// The field with the EMI at `t` (for a pulse) and the identifier's output over
/// `[t, t + dt]`: the mean of eq. 15 over the EMI samples within the step (exact for the
/// integral of eq. 20 against the held φ), or at `t` alone for pulse readings.
fn measure(
    cfg: &DroneConfig,
    emi: &mut Option<Emi>,
    rng: &mut impl Rng,
    t: f64,
    h_n: &V3,
) -> (V3, f64) {
    let Some(e) = emi.as_mut() else {
        return (*h_n, cfg.rls.y_of(h_n.norm()));
    };
    let h0 = h_n + e.at(t, rng);
    if cfg.reading_period_s.is_some() {
        return (h0, cfg.rls.y_of(h0.norm()));
    }
    let n = (cfg.dt_s / e.hold_s).round().max(1.0) as usize;
    let mut y_sum = cfg.rls.y_of(h0.norm());
    for i in 1..n {
        let h = h_n + e.at(t + i as f64 * cfg.dt_s / n as f64, rng);
        y_sum += cfg.rls.y_of(h.norm());
    }
    (h0, y_sum / n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f_s_is_bounded_continuous_and_along_v() {
        let v = V3::new(3.0, -4.0, 12.0);
        let f = f_s(&v, 0.5, 1.0);
        assert!((f.normalize() - v.normalize()).norm() < 1e-12);
        assert!(f.norm() < 0.5 && f.norm() > 0.49);
        assert_eq!(f_s(&V3::zeros(), 0.5, 1.0), V3::zeros());
        // Near 0 it is ≈ f_smax K v (continuous through the origin).
        let small = V3::new(1e-6, 0.0, 0.0);
        assert!((f_s(&small, 0.5, 1.0) - small * 0.5).norm() < 1e-15);
    }

    #[test]
    fn saturation_keeps_the_slow_part_in_the_region() {
        let g = Geometry::PAPER;
        let s = g.saturate(&V3::new(60.0, 80.0, 0.0));
        assert!((s.norm() - 50.0).abs() < 1e-12);
        assert_eq!(g.saturate(&V3::new(1.0, 2.0, 3.0)), V3::new(1.0, 2.0, 3.0));
    }

    #[test]
    fn victims_fill_the_ball_uniformly() {
        let cfg = DroneConfig::paper();
        let n = 4000;
        let inside_half = (0..n)
            .filter(|&s| draw_victim(&cfg, s).0.norm() < 25.0)
            .count();
        // P(r < R/2) = 1/8.
        let f = inside_half as f64 / n as f64;
        assert!((f - 0.125).abs() < 0.02, "{f}");
    }

    /// Without EMI and with the identifier's own field model (eq. 8), the scheme is the
    /// ideal case of Theorem 1: the estimate converges to the victim.
    #[test]
    fn noise_free_ellipsoid_field_converges() {
        let cfg = DroneConfig {
            emi_equiv_range_m: None,
            field: FieldModel::Ellipsoid,
            duration_s: 60.0,
            sog_period_s: None,
            ..DroneConfig::paper()
        };
        let r = run(
            &cfg,
            3,
            Some((
                V3::new(-32.8, 27.0, 8.6),
                V3::new(0.3, 0.8, -0.5).normalize(),
            )),
        );
        let e = r.rls_final().unwrap();
        assert!(e < 0.05, "final error {e}");
    }
}
