//! Pedestrian dead reckoning with its covariance: Kleiner, Dornhege & Dali, eq. 1–3.
//!
//! The 2-D pose `l = (x, y, θ)` with covariance `Σ_l` is driven by the odometry input
//! `u = (d, α)` (distance walked, heading change) with covariance `Σ_u`:
//! ```text
//! l_t = F(l_{t-1}, u_t) = [x + cos θ · d, y + sin θ · d, θ + α]        (eq. 1)
//! Σ_l_t = ∇F_l Σ_l_{t-1} ∇F_lᵀ + ∇F_u Σ_u ∇F_uᵀ                         (eq. 2)
//! Σ_u = diag(d σ_d², α σ_α²)                                             (eq. 3)
//! ```
//! The stride moves along the heading *before* the turn (θ_{t-1}); to walk a stride
//! along a measured heading, first turn to it ([`PdrPose::propagate`] with `d = 0`), then
//! stride with `α = 0`.

use crate::Mat3;
use nalgebra::Matrix3x2;

/// A 2-D pose with covariance (x, y in m; θ in rad, in whatever level frame the caller
/// chose).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdrPose {
    /// x, m.
    pub x: f32,
    /// y, m.
    pub y: f32,
    /// Heading θ, rad (not wrapped: it accumulates the turns).
    pub theta: f32,
    /// Covariance of `(x, y, θ)`.
    pub cov: Mat3,
}

/// Kleiner et al. eq. 3: input covariance entries `(var_d, var_α) = (|d| σ_d², |α| σ_α²)`
/// with `σ_d` in √m and `σ_α` in √rad.
pub fn kleiner_input_var(d: f32, alpha: f32, sigma_d: f32, sigma_alpha: f32) -> (f32, f32) {
    (
        libm::fabsf(d) * sigma_d * sigma_d,
        libm::fabsf(alpha) * sigma_alpha * sigma_alpha,
    )
}

impl PdrPose {
    /// The pose `(0, 0, θ)` with zero covariance.
    pub fn origin(theta: f32) -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            theta,
            cov: Mat3::zeros(),
        }
    }

    /// Kleiner eq. 1–2: stride `d` along the current heading, then turn by `alpha`;
    /// `var_d` and `var_alpha` are the input variances (eq. 3, or any other model).
    pub fn propagate(&mut self, d: f32, alpha: f32, var_d: f32, var_alpha: f32) {
        let (s, c) = (libm::sinf(self.theta), libm::cosf(self.theta));
        // ∇F_l: ∂(x', y', θ')/∂(x, y, θ).
        let fl = Mat3::new(1.0, 0.0, -s * d, 0.0, 1.0, c * d, 0.0, 0.0, 1.0);
        // ∇F_u: ∂(x', y', θ')/∂(d, α).
        let fu = Matrix3x2::new(c, 0.0, s, 0.0, 0.0, 1.0);
        let su = nalgebra::Matrix2::new(var_d.max(0.0), 0.0, 0.0, var_alpha.max(0.0));
        let cov = fl * self.cov * fl.transpose() + fu * su * fu.transpose();
        self.cov = 0.5 * (cov + cov.transpose());
        self.x += c * d;
        self.y += s * d;
        self.theta += alpha;
    }

    /// Adds the effect of an error of variance `var` in the direction of the last stride
    /// `(dx, dy)` only (a walking-direction error that does not carry over to θ).
    pub fn add_stride_direction_noise(&mut self, dx: f32, dy: f32, var: f32) {
        // ∂(x, y)/∂e of a stride rotated by e: (−dy, dx).
        let j = nalgebra::Vector3::new(-dy, dx, 0.0);
        self.cov += j * j.transpose() * var.max(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_walk_matches_closed_form() {
        // n strides of d along a fixed heading θ0 with only length noise: variance along
        // track n·var_d, none across.
        let th = 0.7f32;
        let mut p = PdrPose::origin(th);
        for _ in 0..10 {
            p.propagate(0.6, 0.0, 0.01, 0.0);
        }
        let (s, c) = (th.sin(), th.cos());
        let along = c * c * p.cov[(0, 0)] + 2.0 * s * c * p.cov[(0, 1)] + s * s * p.cov[(1, 1)];
        let across = s * s * p.cov[(0, 0)] - 2.0 * s * c * p.cov[(0, 1)] + c * c * p.cov[(1, 1)];
        assert!((along - 0.1).abs() < 1e-5 && across.abs() < 1e-6);
        assert!((p.x - 6.0 * c).abs() < 1e-4 && (p.y - 6.0 * s).abs() < 1e-4);
    }

    #[test]
    fn heading_noise_grows_across_track_like_the_closed_form() {
        // With θ noise σ² per stride accumulated (random walk), after n strides of d along
        // x the y variance is d² σ² Σ_{k=0}^{n-1} k² (the first stride uses θ_0 exactly).
        let (d, var_a, n) = (0.5f32, 1e-3f32, 8);
        let mut p = PdrPose::origin(0.0);
        for _ in 0..n {
            p.propagate(d, 0.0, 0.0, var_a);
        }
        let expected: f32 = (0..n).map(|k| (k * k) as f32).sum::<f32>() * d * d * var_a;
        assert!((p.cov[(1, 1)] - expected).abs() < 1e-5 * expected.max(1.0));
        assert!((p.cov[(2, 2)] - n as f32 * var_a).abs() < 1e-6);
    }

    #[test]
    fn covariance_matches_finite_difference_jacobians() {
        // Linearised propagation vs numeric Jacobians of eq. 1 at a random-ish point.
        let mut p = PdrPose::origin(0.3);
        p.propagate(0.7, 0.2, 0.0, 0.0);
        p.cov = Mat3::new(0.04, 0.01, 0.002, 0.01, 0.03, -0.001, 0.002, -0.001, 0.005);
        let (d, a, vd, va) = (0.65, -0.1, 0.0016, 0.0009);
        let f = |x: [f64; 3], u: [f64; 2]| {
            [
                x[0] + x[2].cos() * u[0],
                x[1] + x[2].sin() * u[0],
                x[2] + u[1],
            ]
        };
        let x0 = [p.x as f64, p.y as f64, p.theta as f64];
        let u0 = [d as f64, a as f64];
        let h = 1e-6;
        let mut jl = [[0.0f64; 3]; 3];
        let mut ju = [[0.0f64; 2]; 3];
        for k in 0..3 {
            let (mut xp, mut xm) = (x0, x0);
            xp[k] += h;
            xm[k] -= h;
            let (fp, fm) = (f(xp, u0), f(xm, u0));
            for i in 0..3 {
                jl[i][k] = (fp[i] - fm[i]) / (2.0 * h);
            }
        }
        for k in 0..2 {
            let (mut up, mut um) = (u0, u0);
            up[k] += h;
            um[k] -= h;
            let (fp, fm) = (f(x0, up), f(x0, um));
            for i in 0..3 {
                ju[i][k] = (fp[i] - fm[i]) / (2.0 * h);
            }
        }
        let su = [vd as f64, va as f64];
        let mut expected = [[0.0f64; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                let mut v = 0.0;
                for a in 0..3 {
                    for b in 0..3 {
                        v += jl[i][a] * p.cov[(a, b)] as f64 * jl[j][b];
                    }
                }
                for k in 0..2 {
                    v += ju[i][k] * su[k] * ju[j][k];
                }
                expected[i][j] = v;
            }
        }
        p.propagate(d, a, vd, va);
        for (i, row) in expected.iter().enumerate() {
            for (j, e) in row.iter().enumerate() {
                assert!((p.cov[(i, j)] as f64 - e).abs() < 1e-6, "{i}{j}");
            }
        }
    }

    #[test]
    fn eq3_input_variances() {
        let (vd, va) = kleiner_input_var(2.0, -0.5, 0.05, 0.1);
        assert!((vd - 2.0 * 0.0025).abs() < 1e-7 && (va - 0.5 * 0.01).abs() < 1e-7);
    }
}
