//! A 2-D histogram filter (Markov localization, slides `002_*`) over the victim's
//! horizontal position.
//!
//! The grid is anchored in the frame `G_1` of the first pulse (geographic axes, origin
//! at the receiver then) and the receiver's position in it is dead-reckoned, so the
//! robocentric belief is the grid shifted by that position (the "shift" of the motion
//! model, exact to sub-cell precision); the motion noise blurs the grid with a
//! `[¼ ½ ¼]` kernel per axis (variance ½ cell² per pass) whenever the accumulated
//! translation variance reaches that. Depth is marginalized over [`DEPTH_LAYERS`] layers
//! spanning the prior's burial depths (each horizontal cell is a column of them).
//!
//! Each cell holds its log-weight and the running mean of the moments that explain the
//! pulses from that position (the dipole inverse `m = G⁻¹ z`, ICRA eq. 6, averaged over
//! the pulses with the sign aligned): **16 bytes per cell, 48 bytes per horizontal
//! cell** (3 depth layers). The first pulse's
//! likelihood is the moment prior (the inverse's magnitude within `[m_min, m_max]`, soft
//! edges); each later pulse's is the sign-ambiguous `½N(±z; h, σ²I)` of the field
//! `h = K_H G(r) m̄` the cell's moment predicts, with `σ² = R + (ε|h|)²`:
//! the pulse noise (ICRA eq. 10) plus the model error of a point hypothesis for a cell
//! of finite size at an assumed depth, `ε = 3δ/|r|` (|H| ∝ r⁻³) with `δ` the RMS of the
//! cell and depth spreads. When the belief's spread falls below an eighth of the grid,
//! the grid zooms in by 2 around the mean (down to [`MIN_CELL_M`]).

use super::super::model::{FIELD_SCALE, K_H, MOMENT_SCALE};
use super::super::{
    Attitude, Displacement, EstimateError, Estimator, SogConfig, StepOutcome, StepReport,
    VictimEstimate,
};
use super::super::{Mode, init::noise_widening};
use super::{LOG_ZERO, Weighted, noise_var, sign_ambiguous_log_lik, step_report, strong_enough};
use crate::dipole::{field, moment_from_field, range_bounds};
use crate::frame::{Rpy, rotation_from_rpy};
use crate::{Mat3, Vec3};

/// Depth layers per horizontal cell.
pub const DEPTH_LAYERS: usize = 3;
/// Smallest cell the zoom goes down to (m).
pub const MIN_CELL_M: f32 = 0.05;
/// Log-normal width of the soft edges of the moment prior (first pulse).
const LOG_MOMENT_EDGE: f32 = 0.1;

/// One cell: log-weight and the moment that explains the pulses from there (16 bytes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Cell {
    log_w: f32,
    /// Running mean of the inferred moment (mA·m² in `G`).
    m: [f32; 3],
}

impl Weighted for Cell {
    fn log_w(&self) -> f32 {
        self.log_w
    }
    fn set_log_w(&mut self, v: f32) {
        self.log_w = v;
    }
}

const EMPTY: Cell = Cell {
    log_w: LOG_ZERO,
    m: [0.0; 3],
};

/// Histogram filter over an `NX × NY` grid (no heap).
#[derive(Debug, Clone, PartialEq)]
pub struct HistogramFilter<const NX: usize, const NY: usize> {
    config: SogConfig,
    cells: [[[Cell; DEPTH_LAYERS]; NY]; NX],
    /// Grid centre in `G_1` (m).
    center: Vec3,
    /// Cell size (m).
    cell: f32,
    /// The receiver in `G_1`, dead-reckoned (m).
    receiver: Vec3,
    /// Translation variance not yet blurred in (m², per horizontal axis).
    pending_var: f32,
    /// The attitude of the previous pulse (rotates the next displacement into `G_1`).
    last_rpy: Rpy,
    pulses: u32,
    initialized: bool,
    last_t: Option<f32>,
}

impl<const NX: usize, const NY: usize> HistogramFilter<NX, NY> {
    /// A filter with the SOGs filter's configuration, or `InvalidConfig`.
    pub fn new(config: SogConfig) -> Result<Self, EstimateError> {
        config.validate()?;
        if NX < 4 || NY < 4 {
            return Err(EstimateError::InvalidConfig);
        }
        Ok(Self {
            config,
            cells: [[[EMPTY; DEPTH_LAYERS]; NY]; NX],
            center: Vec3::zeros(),
            cell: 1.0,
            receiver: Vec3::zeros(),
            pending_var: 0.0,
            last_rpy: Rpy::zeros(),
            pulses: 0,
            initialized: false,
            last_t: None,
        })
    }

    /// Current cell size (m).
    pub fn cell_size(&self) -> f32 {
        self.cell
    }

    /// Thickness of a depth layer (m).
    fn layer(&self) -> f32 {
        (self.config.depth_max - self.config.depth_min) / DEPTH_LAYERS as f32
    }

    /// Centre of cell `(i, j, k)` in `G_1`.
    fn cell_pos(&self, i: usize, j: usize, k: usize) -> Vec3 {
        Vec3::new(
            self.center.x + (i as f32 + 0.5 - 0.5 * NX as f32) * self.cell,
            self.center.y + (j as f32 + 0.5 - 0.5 * NY as f32) * self.cell,
            -(self.config.receiver_height
                + self.config.depth_min
                + (k as f32 + 0.5) * self.layer()),
        )
    }

    /// RMS position spread of a cell's hypothesis: uniform over the cell horizontally
    /// (`cell²/12` per axis) and over its depth layer (`layer²/12`).
    fn spread(&self) -> f32 {
        let l = self.layer();
        libm::sqrtf(self.cell * self.cell / 6.0 + l * l / 12.0)
    }

    fn flat_mut(&mut self) -> &mut [Cell] {
        self.cells.as_flattened_mut().as_flattened_mut()
    }

    fn flat(&self) -> &[Cell] {
        self.cells.as_flattened().as_flattened()
    }

    /// Builds the grid around the receiver from pulse `z` (µA/m in `R_1`).
    fn try_initialize(&mut self, attitude: &Attitude, z: &Vec3, kind: StepOutcome) -> StepReport {
        self.initialized = false;
        if !strong_enough(&self.config, z) {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        let widen = noise_widening(noise_var(&self.config, z), z.norm());
        let Ok((_, r_hi)) = range_bounds(
            z.norm() / FIELD_SCALE,
            self.config.m_min / widen,
            self.config.m_max * widen,
        ) else {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        };
        let half = r_hi.max(1.0);
        self.cell = 2.0 * half / NX.min(NY) as f32;
        self.receiver = Vec3::zeros();
        self.center = Vec3::zeros();
        self.pending_var = 0.0;
        self.last_rpy = attitude.rpy;
        self.pulses = 1;
        let z_g = rotation_from_rpy(&attitude.rpy) * z;
        let (ln_lo, ln_hi) = (
            libm::logf(self.config.m_min * MOMENT_SCALE / widen),
            libm::logf(self.config.m_max * MOMENT_SCALE * widen),
        );
        for i in 0..NX {
            for j in 0..NY {
                for k in 0..DEPTH_LAYERS {
                    let r = self.receiver - self.cell_pos(i, j, k);
                    self.cells[i][j][k] = match moment_from_field(&r, &z_g) {
                        Ok(m) => {
                            let m = m / K_H;
                            let ln_m = libm::logf(m.norm());
                            let out = (ln_lo - ln_m).max(ln_m - ln_hi).max(0.0) / LOG_MOMENT_EDGE;
                            Cell {
                                log_w: -0.5 * out * out,
                                m: [m.x, m.y, m.z],
                            }
                        }
                        Err(_) => EMPTY,
                    };
                }
            }
        }
        if super::normalize(self.flat_mut()).is_none() {
            return step_report(StepOutcome::Waiting, 0, 0.0, 0);
        }
        self.initialized = true;
        step_report(kind, NX * NY * DEPTH_LAYERS, 0.0, 0)
    }

    /// Moves the receiver by the displacement and accumulates its variance.
    fn predict(&mut self, motion: &Displacement) {
        let r = rotation_from_rpy(&self.last_rpy);
        let d = r * (motion.translation + motion.absolute);
        self.receiver += d;
        if self.config.mode == Mode::KnownTrajectory {
            return;
        }
        // Per horizontal axis: the translation noise, the absolute part's, and the
        // walk-long scale error on this step's length (treated as independent per step).
        let sig_s = self.config.scale_sigma * motion.translation.norm();
        let var = 0.5
            * (motion.cov[(0, 0)]
                + motion.cov[(1, 1)]
                + motion.absolute_cov[(0, 0)]
                + motion.absolute_cov[(1, 1)])
            + 0.5 * sig_s * sig_s;
        self.pending_var += var;
        let pass = 0.5 * self.cell * self.cell;
        let mut passes = 0;
        while self.pending_var >= pass && passes < 4 {
            self.blur();
            self.pending_var -= pass;
            passes += 1;
        }
        if passes == 4 {
            self.pending_var = 0.0;
        }
    }

    /// One `[¼ ½ ¼]` pass along each horizontal axis on the weights (linear domain),
    /// layer by layer.
    fn blur(&mut self) {
        let max = self
            .flat()
            .iter()
            .map(|c| c.log_w)
            .fold(f32::NEG_INFINITY, f32::max);
        for k in 0..DEPTH_LAYERS {
            let mut w = [[0.0f32; NY]; NX];
            for (wi, ci) in w.iter_mut().zip(self.cells.iter()) {
                for (wij, cij) in wi.iter_mut().zip(ci.iter()) {
                    *wij = libm::expf(cij[k].log_w - max);
                }
            }
            // Along x; outside the grid counts as zero weight.
            let mut out = [[0.0f32; NY]; NX];
            for (i, oi) in out.iter_mut().enumerate() {
                for (j, o) in oi.iter_mut().enumerate() {
                    let at = |ii: Option<usize>| {
                        ii.and_then(|ii| w.get(ii))
                            .and_then(|row| row.get(j))
                            .copied()
                            .unwrap_or(0.0)
                    };
                    *o = 0.25 * at(i.checked_sub(1)) + 0.5 * at(Some(i)) + 0.25 * at(Some(i + 1));
                }
            }
            // Along y, back into the log-weights.
            for (ci, oi) in self.cells.iter_mut().zip(out.iter()) {
                for (j, c) in ci.iter_mut().enumerate() {
                    let at =
                        |jj: Option<usize>| jj.and_then(|jj| oi.get(jj)).copied().unwrap_or(0.0);
                    let v =
                        0.25 * at(j.checked_sub(1)) + 0.5 * at(Some(j)) + 0.25 * at(Some(j + 1));
                    c[k].log_w = if v > 0.0 {
                        libm::logf(v) + max
                    } else {
                        LOG_ZERO
                    };
                }
            }
        }
    }

    /// Multiplies every cell by the pulse's likelihood and updates its moment.
    fn update(&mut self, attitude: &Attitude, z: &Vec3) {
        let z_g = rotation_from_rpy(&attitude.rpy) * z;
        let r_var = noise_var(&self.config, z);
        let delta = self.spread();
        let n = self.pulses as f32;
        for i in 0..NX {
            for j in 0..NY {
                for k in 0..DEPTH_LAYERS {
                    let pos = self.cell_pos(i, j, k);
                    let cell = &mut self.cells[i][j][k];
                    if cell.log_w > LOG_ZERO {
                        *cell = cell_update(cell, &(self.receiver - pos), &z_g, r_var, delta, n);
                    }
                }
            }
        }
        self.pulses = self.pulses.saturating_add(1);
    }

    /// Weighted mean and covariance of the cell centres in `G_1`, and the heaviest cell.
    fn moments(&self) -> (Vec3, Mat3, (usize, usize, usize), f32) {
        let (mut mean, mut best, mut w_best) = (Vec3::zeros(), (0, 0, 0), 0.0f32);
        for i in 0..NX {
            for j in 0..NY {
                for k in 0..DEPTH_LAYERS {
                    let w = libm::expf(self.cells[i][j][k].log_w);
                    mean += self.cell_pos(i, j, k) * w;
                    if w > w_best {
                        (best, w_best) = ((i, j, k), w);
                    }
                }
            }
        }
        let mut cov = Mat3::zeros();
        for i in 0..NX {
            for j in 0..NY {
                for k in 0..DEPTH_LAYERS {
                    let w = libm::expf(self.cells[i][j][k].log_w);
                    let d = self.cell_pos(i, j, k) - mean;
                    cov += d * d.transpose() * w;
                }
            }
        }
        (mean, cov, best, w_best)
    }

    /// Zooms in by 2 around the mean when the belief fits in an eighth of the grid.
    fn maybe_zoom(&mut self) {
        let (mean, cov, _, _) = self.moments();
        let sigma = libm::sqrtf(cov[(0, 0)].max(cov[(1, 1)]));
        let extent = self.cell * NX.min(NY) as f32;
        if !(sigma < extent / 8.0 && self.cell * 0.5 >= MIN_CELL_M) {
            return;
        }
        let old = self.cells;
        let (old_center, old_cell) = (self.center, self.cell);
        self.cell *= 0.5;
        self.center = Vec3::new(mean.x, mean.y, 0.0);
        for i in 0..NX {
            for j in 0..NY {
                let p = self.cell_pos(i, j, 0);
                let fi = (p.x - old_center.x) / old_cell + 0.5 * NX as f32;
                let fj = (p.y - old_center.y) / old_cell + 0.5 * NY as f32;
                let inside = fi >= 0.0 && fj >= 0.0 && fi < NX as f32 && fj < NY as f32;
                self.cells[i][j] = if inside {
                    old[fi as usize][fj as usize]
                } else {
                    [EMPTY; DEPTH_LAYERS]
                };
            }
        }
        // Each old cell became four: renormalize.
        super::normalize(self.flat_mut());
    }
}

/// One cell's pulse update: the sign-ambiguous likelihood of the field its moment
/// predicts at offset `r` (receiver − cell), and the running mean of its moment over
/// `n` earlier pulses.
fn cell_update(c: &Cell, r: &Vec3, z_g: &Vec3, r_var: f32, delta: f32, n: f32) -> Cell {
    let m = Vec3::new(c.m[0], c.m[1], c.m[2]);
    let (Ok(h), Ok(m_new)) = (field(r, &m), moment_from_field(r, z_g)) else {
        return EMPTY;
    };
    let h = h * K_H;
    // Model error of a point hypothesis for a finite cell: |H| ∝ r⁻³.
    let eps = 3.0 * delta / r.norm();
    let var = r_var + eps * eps * h.norm_squared();
    let d2_pos = (z_g - h).norm_squared() / var;
    let d2_neg = (z_g + h).norm_squared() / var;
    let ll = sign_ambiguous_log_lik(d2_pos, d2_neg) - 1.5 * libm::logf(var);
    let m_new = m_new / K_H;
    let m_new = if m_new.dot(&m) < 0.0 { -m_new } else { m_new };
    let mean = m + (m_new - m) / (n + 1.0);
    Cell {
        log_w: c.log_w + ll,
        m: [mean.x, mean.y, mean.z],
    }
}

impl<const NX: usize, const NY: usize> HistogramFilter<NX, NY> {
    /// One step of the initialized filter with pulse `z` (µA/m in `R_k`).
    fn advance(&mut self, motion: &Displacement, attitude: &Attitude, z: &Vec3) -> StepReport {
        self.predict(motion);
        self.update(attitude, z);
        self.last_rpy = attitude.rpy;
        if super::normalize(self.flat_mut()).is_none() {
            return self.try_initialize(attitude, z, StepOutcome::Reinitialized);
        }
        self.maybe_zoom();
        step_report(StepOutcome::Updated, NX * NY * DEPTH_LAYERS, 0.0, 0)
    }
}

impl<const NX: usize, const NY: usize> Estimator for HistogramFilter<NX, NY> {
    super::staged_step!();

    fn estimate(&self) -> Option<VictimEstimate> {
        if !self.initialized {
            return None;
        }
        let (mean, mut cov, (bi, bj, bk), w_best) = self.moments();
        let l = self.layer();
        cov[(0, 0)] += self.cell * self.cell / 12.0;
        cov[(1, 1)] += self.cell * self.cell / 12.0;
        cov[(2, 2)] += l * l / 12.0;
        let m = self.cells[bi][bj][bk].m;
        Some(VictimEstimate {
            p: mean - self.receiver,
            cov,
            moment: Vec3::new(m[0], m[1], m[2]) / MOMENT_SCALE,
            scale: 1.0,
            scale_sigma: 0.0,
            rpy: self.last_rpy,
            n_components: NX * NY * DEPTH_LAYERS,
            max_weight: w_best,
        })
    }

    fn reset(&mut self) {
        self.initialized = false;
        self.last_t = None;
        self.pulses = 0;
    }

    fn is_initialized(&self) -> bool {
        self.initialized
    }
}
