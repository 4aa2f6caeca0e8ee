//! The classical directional search (ICRA 2006 §II-A) as a rescuer policy, independent of
//! how the rescuer is simulated: it reads pulses and returns where to go.
//!
//! Optimistic as in the paper's simulation ("the rescuer follows perfectly the flux
//! lines"): the flux line is that of the true field, its sign chosen to agree with the
//! walking direction; |H| is the noisy reading. Secondary search: the direction is
//! reversed when |H| has not grown over [`DsConfig::flip_m`] (every time, or only over the
//! first metres with [`Reversal::InitialOnly`], the paper's wording); the fine (tertiary)
//! search starts when the classical distance reading (|H| of a nominal beacon on its axis)
//! is below [`DsConfig::fine_m`], or when the flux line was about to be reversed after
//! passing a peak closer than [`DsConfig::peak_m`] (the rescuer goes back to the strongest
//! reading). The fine search is a cross search with the receiver just above the snow:
//! along the walking direction, then across it, with 0.5 m then 0.2 m spacing, one pulse
//! per point, each line continued while |H| grows (reversed when the first point is
//! weaker) and stopped two points after the maximum; "found" is the strongest point of
//! the last line. Without the cross search ([`DsConfig::cross_search`] off) the search
//! ends where the fine search would start.
use crate::world::physics::V3;
use std::f64::consts::PI;

/// When the secondary search reverses along the flux line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reversal {
    /// Whenever |H| has not grown over the flip distance.
    Always,
    /// Only over the first flip distance after the first reception (ICRA §II-A: "if after
    /// following the initial direction along 5 m the signal decreases").
    InitialOnly,
}

/// Settings of the directional search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DsConfig {
    /// Moment of the nominal beacon behind the classical distance reading, A·m².
    pub nominal_moment: f64,
    /// Walk without growth of |H| before reversing, m.
    pub flip_m: f64,
    /// When reversals happen.
    pub reversal: Reversal,
    /// A reading counts as "not grown" only when it is below the best by this many
    /// standard deviations of a reading (ICRA eq. 10 with [`DsConfig::pulse_noise`]);
    /// 0: any reading not above the best (the classical rule).
    pub flip_margin_sigmas: f64,
    /// Pulse noise `(σ_bkg A/m, k_sen)` for the margin.
    pub pulse_noise: (f64, f64),
    /// Classical distance reading below which the fine search starts, m.
    pub fine_m: f64,
    /// A reversal after a peak closer than this (classical reading) starts the fine search, m.
    pub peak_m: f64,
    /// Whether the fine search is done (a cross search); otherwise the search ends where
    /// it would start.
    pub cross_search: bool,
    /// Receiver height above the snow in the cross search, m.
    pub cross_height_m: f64,
    /// Time without a pulse after which the rescuer turns back once, s.
    pub lost_timeout_s: f64,
}

impl Default for DsConfig {
    fn default() -> Self {
        Self {
            nominal_moment: 9.5e-3,
            flip_m: 5.0,
            reversal: Reversal::Always,
            flip_margin_sigmas: 0.0,
            pulse_noise: (2.59e-9, 0.03),
            fine_m: 3.0,
            peak_m: 8.0,
            cross_search: true,
            cross_height_m: 0.2,
            lost_timeout_s: 3.5,
        }
    }
}

/// Cross-search lines: (across the walking direction?, spacing m).
const LINES: [(bool, f64); 4] = [(false, 0.5), (true, 0.5), (false, 0.2), (true, 0.2)];
/// Most points per cross-search line and direction.
const MAX_POINTS: u32 = 12;
/// A cross-search reading counts only with the receiver this close to the point, m.
const AT_POINT_M: f64 = 0.01;
/// Turning on the spot instead of walking when the new heading is this far off, rad.
const TURN_ON_SPOT_RAD: f64 = 0.9;

/// What the policy needs to know about the rescuer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RescuerView {
    /// Horizontal position of the receiver (north, west), m.
    pub device_xy: [f64; 2],
    /// Walking heading, rad.
    pub heading: f64,
}

/// Where the policy sends the rescuer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DsCommand {
    /// Walk (or, with `walk` false, stand and turn) toward heading `psi`, rad.
    Heading {
        /// Desired heading, rad.
        psi: f64,
        /// Whether to walk.
        walk: bool,
    },
    /// Carry the receiver straight to `xy` (north, west), at `height` above the snow if
    /// given.
    MoveTo {
        /// Target, m.
        xy: [f64; 2],
        /// New receiver height above the snow, m.
        height: Option<f64>,
    },
}

/// One line of the cross search.
#[derive(Debug, Clone, Copy)]
struct CrossLine {
    /// Index into [`LINES`].
    line: usize,
    /// Walking direction when the cross search started (north, west), unit.
    forward: [f64; 2],
    /// Centre of this line.
    centre: [f64; 2],
    /// Direction along the line (±1) and points taken in it.
    sign: f64,
    k: u32,
    reversed: bool,
    /// Consecutive points weaker than the best.
    below: u32,
    /// Strongest reading so far and where.
    best_h: f64,
    best_p: [f64; 2],
    /// Where the next reading is taken.
    target: [f64; 2],
}

impl CrossLine {
    fn axis(&self) -> [f64; 2] {
        let [x, y] = self.forward;
        if LINES[self.line].0 { [-y, x] } else { [x, y] }
    }

    fn point(&self, k: u32) -> [f64; 2] {
        let a = self.axis();
        let d = self.sign * f64::from(k) * LINES[self.line].1;
        [self.centre[0] + a[0] * d, self.centre[1] + a[1] * d]
    }

    /// Takes the reading `n` at the current target; returns whether the line is done.
    fn read(&mut self, n: f64) -> bool {
        if n > self.best_h {
            self.best_h = n;
            self.best_p = self.target;
            self.below = 0;
        } else {
            self.below += 1;
        }
        if self.k == 0 {
            false
        } else if self.below >= 1 && self.k == 1 && !self.reversed {
            // The first point is weaker: try the other side.
            self.sign = -self.sign;
            self.reversed = true;
            self.k = 0;
            false
        } else {
            (self.reversed && self.k == 1 && self.below >= 1)
                || self.below >= 2
                || self.k >= MAX_POINTS
        }
    }
}

/// The classical directional search (module docs).
#[derive(Debug, Clone)]
pub struct DirectionalSearch {
    cfg: DsConfig,
    /// Flux-line walking direction (north, west), unit.
    dir: Option<[f64; 2]>,
    best_h: f64,
    best_p: [f64; 2],
    walked_since_best: f64,
    /// Walked since the first reception, m.
    walked: f64,
    last_p: Option<[f64; 2]>,
    cross: Option<CrossLine>,
    found: Option<[f64; 2]>,
    /// Time of the last received pulse, s.
    last_t: f64,
    /// Turned back after losing the signal (until the next pulse).
    turned_back: bool,
}

impl DirectionalSearch {
    /// A search that has heard nothing yet.
    pub fn new(cfg: DsConfig) -> Self {
        Self {
            cfg,
            dir: None,
            best_h: 0.0,
            best_p: [0.0; 2],
            walked_since_best: 0.0,
            walked: 0.0,
            last_p: None,
            cross: None,
            found: None,
            last_t: 0.0,
            turned_back: false,
        }
    }

    /// The strongest point of the last cross-search line (or where the fine search would
    /// have started), once the search is over.
    pub fn found(&self) -> Option<[f64; 2]> {
        self.found
    }

    /// The classical distance reading: the range of the nominal beacon on its axis, m.
    pub fn classical_distance(&self, h: f64) -> f64 {
        (2.0 * self.cfg.nominal_moment / (4.0 * PI * h.max(1e-30))).cbrt()
    }

    /// A pulse received at `p`: `h` is the reading (A/m in W, noisy, sign arbitrary),
    /// `h_true` the field whose flux line the optimistic rescuer follows perfectly.
    pub fn on_pulse(
        &mut self,
        t: f64,
        h: &V3,
        h_true: &V3,
        p: &V3,
        view: &RescuerView,
    ) -> Option<DsCommand> {
        self.last_t = t;
        self.turned_back = false;
        if self.found.is_some() {
            return None;
        }
        let n = h.norm();
        let here = [p.x, p.y];
        if self.cross.is_some() {
            return self.cross_reading(n, view);
        }
        let walked = self
            .last_p
            .map_or(0.0, |q| (here[0] - q[0]).hypot(here[1] - q[1]));
        self.last_p = Some(here);
        self.walked += walked;
        if n > self.best_h {
            self.best_h = n;
            self.best_p = here;
            self.walked_since_best = 0.0;
        } else if self.fallen(n) {
            self.walked_since_best += walked;
            if self.walked_since_best > self.cfg.flip_m {
                if self.classical_distance(self.best_h) <= self.cfg.peak_m {
                    // Passed over the peak: back to the strongest reading, fine search.
                    return Some(self.start_fine(self.best_p, view));
                }
                if self.reversal_allowed() {
                    if let Some(d) = self.dir.as_mut() {
                        *d = [-d[0], -d[1]];
                    }
                    self.best_h = n;
                    self.best_p = here;
                    self.walked_since_best = 0.0;
                }
            }
        }
        if self.classical_distance(n) <= self.cfg.fine_m {
            return Some(self.start_fine(here, view));
        }
        self.follow_flux(h_true, view)
    }

    /// Whether reading `n` (not above the best) counts as walking without growth: below
    /// the best by the margin (any such reading with the classical margin 0).
    fn fallen(&self, n: f64) -> bool {
        let (bkg, k_sen) = self.cfg.pulse_noise;
        let sigma = bkg.hypot(k_sen * self.best_h);
        n <= self.best_h - self.cfg.flip_margin_sigmas * sigma
    }

    fn reversal_allowed(&self) -> bool {
        match self.cfg.reversal {
            Reversal::Always => true,
            Reversal::InitialOnly => self.walked <= self.cfg.flip_m + 1.0,
        }
    }

    /// Along the true field's flux line, the sign agreeing with the walking direction.
    fn follow_flux(&mut self, h_true: &V3, view: &RescuerView) -> Option<DsCommand> {
        let reference = self.dir.unwrap_or([view.heading.cos(), view.heading.sin()]);
        let hf = firmware::Vec3::new(h_true.x as f32, h_true.y as f32, h_true.z as f32);
        let rf = [reference[0] as f32, reference[1] as f32];
        let d = firmware::guidance::flux_direction(&hf, &rf)?;
        let d = [f64::from(d[0]), f64::from(d[1])];
        self.dir = Some(d);
        let psi = d[1].atan2(d[0]);
        let off = crate::world::rescuer::wrap_pi(psi - view.heading).abs();
        Some(DsCommand::Heading {
            psi,
            walk: off <= TURN_ON_SPOT_RAD,
        })
    }

    /// Starts the fine search at `centre` (or ends the search there without it).
    fn start_fine(&mut self, centre: [f64; 2], view: &RescuerView) -> DsCommand {
        if !self.cfg.cross_search {
            self.found = Some(centre);
            return DsCommand::MoveTo {
                xy: centre,
                height: None,
            };
        }
        let forward = self.dir.unwrap_or([view.heading.cos(), view.heading.sin()]);
        self.cross = Some(CrossLine {
            line: 0,
            forward,
            centre,
            sign: 1.0,
            k: 0,
            reversed: false,
            below: 0,
            best_h: 0.0,
            best_p: centre,
            target: centre,
        });
        DsCommand::MoveTo {
            xy: centre,
            height: Some(self.cfg.cross_height_m),
        }
    }

    /// A cross-search reading: counts only with the receiver at the line's point.
    fn cross_reading(&mut self, n: f64, view: &RescuerView) -> Option<DsCommand> {
        let mut c = self.cross?;
        let dev = view.device_xy;
        if (dev[0] - c.target[0]).hypot(dev[1] - c.target[1]) > AT_POINT_M {
            return None;
        }
        if c.read(n) {
            if c.line + 1 == LINES.len() {
                self.found = Some(c.best_p);
                self.cross = Some(c);
                return Some(DsCommand::MoveTo {
                    xy: c.best_p,
                    height: None,
                });
            }
            c.line += 1;
            c.centre = c.best_p;
            c.sign = 1.0;
            c.k = 0;
            c.reversed = false;
            c.below = 0;
        }
        c.k += 1;
        c.target = c.point(c.k);
        self.cross = Some(c);
        Some(DsCommand::MoveTo {
            xy: c.target,
            height: None,
        })
    }

    /// Signal lost for [`DsConfig::lost_timeout_s`] in the secondary search: turn back
    /// once (toward where it was last heard).
    pub fn check_lost(&mut self, t: f64) -> Option<DsCommand> {
        if self.cross.is_some()
            || self.found.is_some()
            || self.turned_back
            || t - self.last_t <= self.cfg.lost_timeout_s
        {
            return None;
        }
        self.turned_back = true;
        let d = self.dir.as_mut()?;
        *d = [-d[0], -d[1]];
        Some(DsCommand::Heading {
            psi: d[1].atan2(d[0]),
            walk: false,
        })
    }

    /// Whether the receiver stands at the found maximum.
    pub fn done(&self, device_xy: [f64; 2]) -> bool {
        self.found
            .is_some_and(|f| (device_xy[0] - f[0]).hypot(device_xy[1] - f[1]) <= AT_POINT_M)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(x: f64, heading: f64) -> RescuerView {
        RescuerView {
            device_xy: [x, 0.0],
            heading,
        }
    }

    /// Walks toward −x (heading π) along a flux line on the x axis while |H| falls
    /// (a far beacon: classical distance ≈ 50 m); returns the headings commanded.
    fn walk_away(cfg: DsConfig, metres: u32) -> Vec<f64> {
        let mut ds = DirectionalSearch::new(cfg);
        (0..=metres)
            .filter_map(|k| {
                let x = -f64::from(k);
                let h = V3::new(1e-8 * (1.0 + 0.05 * x), 0.0, 0.0);
                match ds.on_pulse(
                    f64::from(k),
                    &h,
                    &V3::x(),
                    &V3::new(x, 0.0, 1.0),
                    &view(x, PI),
                ) {
                    Some(DsCommand::Heading { psi, .. }) => Some(psi.cos()),
                    _ => None,
                }
            })
            .collect()
    }

    #[test]
    fn reverses_when_the_signal_has_not_grown_over_the_flip_distance() {
        let c = walk_away(DsConfig::default(), 8);
        // Along −x (the flux sign agreeing with the heading) until 5 m without growth,
        // then along +x.
        assert!(c[..6].iter().all(|&c| c < -0.99), "{c:?}");
        assert!(c[6..].iter().all(|&c| c > 0.99), "{c:?}");
    }

    #[test]
    fn the_initial_only_rule_reverses_once_at_the_start() {
        let cfg = DsConfig {
            reversal: Reversal::InitialOnly,
            ..DsConfig::default()
        };
        let c = walk_away(cfg, 8);
        assert!(c[6..].iter().all(|&c| c > 0.99), "{c:?}");
        // Walking back, the signal falls again after passing the start: no second reversal.
        let mut ds = DirectionalSearch::new(cfg);
        let mut dirs = Vec::new();
        for k in 0..30u32 {
            let x = -f64::from(k);
            let h = V3::new(1e-8 * (1.0 - 0.01 * f64::from(k)), 0.0, 0.0);
            if let Some(DsCommand::Heading { psi, .. }) = ds.on_pulse(
                f64::from(k),
                &h,
                &V3::x(),
                &V3::new(x, 0.0, 1.0),
                &view(x, PI),
            ) {
                dirs.push(psi.cos() > 0.0);
            }
        }
        let flips = dirs.windows(2).filter(|w| w[0] != w[1]).count();
        assert_eq!(flips, 1, "{dirs:?}");
    }

    #[test]
    fn a_margin_ignores_readings_within_the_noise() {
        // Readings that fall by less than 2σ of a reading never count as a decrease.
        let cfg = DsConfig {
            flip_margin_sigmas: 2.0,
            ..DsConfig::default()
        };
        let mut ds = DirectionalSearch::new(cfg);
        for k in 0..20u32 {
            let x = -f64::from(k);
            let h = V3::new(1e-8 - 1e-10 * f64::from(k % 2), 0.0, 0.0);
            let c = ds.on_pulse(
                f64::from(k),
                &h,
                &V3::x(),
                &V3::new(x, 0.0, 1.0),
                &view(x, PI),
            );
            assert!(
                matches!(c, Some(DsCommand::Heading { psi, .. }) if psi.cos() < -0.99),
                "{k}: {c:?}"
            );
        }
    }

    #[test]
    fn without_the_cross_search_it_stops_where_the_fine_search_would_start() {
        let cfg = DsConfig {
            cross_search: false,
            ..DsConfig::default()
        };
        let mut ds = DirectionalSearch::new(cfg);
        // A reading whose classical distance is 2 m (< 3 m).
        let h = 2.0 * cfg.nominal_moment / (4.0 * PI * 8.0);
        let c = ds.on_pulse(
            0.0,
            &V3::new(h, 0.0, 0.0),
            &V3::x(),
            &V3::new(3.0, 4.0, 1.0),
            &view(3.0, 0.0),
        );
        assert_eq!(ds.found(), Some([3.0, 4.0]));
        assert!(matches!(c, Some(DsCommand::MoveTo { xy: [3.0, 4.0], .. })));
    }

    #[test]
    fn turns_back_once_when_the_signal_is_lost() {
        let mut ds = DirectionalSearch::new(DsConfig::default());
        ds.on_pulse(
            0.0,
            &V3::new(1e-7, 0.0, 0.0),
            &V3::x(),
            &V3::zeros(),
            &view(0.0, 0.0),
        );
        assert_eq!(ds.check_lost(2.0), None);
        assert!(matches!(
            ds.check_lost(4.0),
            Some(DsCommand::Heading { walk: false, .. })
        ));
        assert_eq!(ds.check_lost(5.0), None);
    }
}
