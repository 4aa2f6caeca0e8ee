//! Least-squares pose graph (Lu & Milios; Kleiner, Dornhege & Dali 2006, eq. 5): find the
//! node positions `l` minimising `Σ (d_ij − d̂_ij)ᵀ Σ_ij⁻¹ (d_ij − d̂_ij)`, the Mahalanobis
//! distance between the relative positions the graph implies and the measured ones.
//!
//! Nodes are horizontal positions (north, west): the rescuers' poses along their walks
//! and the victims' beacons. The receivers' yaw is absolute (magnetometer-aided attitude),
//! so a dead-reckoned edge is a relative position in the common frame and the problem is
//! linear in the positions; Gauss–Newton is run anyway (it converges in one step and stops
//! on the second), which keeps the solver right if a non-linear edge is ever added.
//! At a few hundred nodes the normal matrix is solved dense (nalgebra's Cholesky).
use nalgebra::{DMatrix, DVector, Matrix2, Vector2};

/// One measurement `x_to − x_from = z` with covariance `cov` (`from = None`: a prior
/// `x_to = z`).
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// The node the measurement starts from (`None`: an absolute prior).
    pub from: Option<usize>,
    /// The node the measurement points to.
    pub to: usize,
    /// Measured relative (or absolute) position, m.
    pub z: [f64; 2],
    /// Its covariance `[xx, xy, yy]`, m².
    pub cov: [f64; 3],
}

/// Why a graph could not be solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    /// An edge refers to a node that does not exist.
    #[error("edge {0} refers to a missing node")]
    BadNode(usize),
    /// An edge's covariance is not symmetric positive definite or not finite.
    #[error("edge {0} has a covariance that is not positive definite")]
    BadCovariance(usize),
    /// The normal matrix is singular: some nodes are not tied to an anchored node.
    #[error("the graph is not anchored (a node is not connected to a prior)")]
    Underdetermined,
}

/// The least-squares solution.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Node positions, m.
    pub x: Vec<[f64; 2]>,
    /// Marginal covariance of each node `[xx, xy, yy]`, m².
    pub cov: Vec<[f64; 3]>,
    /// The minimised Mahalanobis sum (eq. 5) at the solution.
    pub chi2: f64,
    /// Gauss–Newton iterations run.
    pub iterations: usize,
}

fn info(cov: &[f64; 3]) -> Option<Matrix2<f64>> {
    let c = Matrix2::new(cov[0], cov[1], cov[1], cov[2]);
    (cov.iter().all(|v| v.is_finite()) && cov[0] > 0.0 && cov[0] * cov[2] > cov[1] * cov[1])
        .then(|| c.try_inverse())
        .flatten()
}

fn residual(e: &Edge, x: &[[f64; 2]]) -> Vector2<f64> {
    let to = x.get(e.to).copied().unwrap_or([0.0; 2]);
    let from = e.from.and_then(|f| x.get(f).copied()).unwrap_or([0.0; 2]);
    Vector2::new(to[0] - from[0] - e.z[0], to[1] - from[1] - e.z[1])
}

/// The Mahalanobis sum of eq. 5 at `x` (edges with a bad covariance count as infinite).
pub fn chi2(edges: &[Edge], x: &[[f64; 2]]) -> f64 {
    edges
        .iter()
        .map(|e| match info(&e.cov) {
            Some(w) => {
                let r = residual(e, x);
                (r.transpose() * w * r)[(0, 0)]
            }
            None => f64::INFINITY,
        })
        .sum()
}

/// Adds `w` at block (`a`, `b`) of the normal matrix.
fn add_block(h: &mut DMatrix<f64>, a: usize, b: usize, w: &Matrix2<f64>) {
    let mut view = h.fixed_view_mut::<2, 2>(2 * a, 2 * b);
    view += w;
}

/// Solves the graph of `n` nodes from the initial guess `x0` (Gauss–Newton on eq. 5).
pub fn solve(n: usize, edges: &[Edge], x0: &[[f64; 2]]) -> Result<Solution, GraphError> {
    let mut weights = Vec::with_capacity(edges.len());
    for (k, e) in edges.iter().enumerate() {
        if e.to >= n || e.from.is_some_and(|f| f >= n || f == e.to) {
            return Err(GraphError::BadNode(k));
        }
        weights.push(info(&e.cov).ok_or(GraphError::BadCovariance(k))?);
    }
    let mut x: Vec<[f64; 2]> = (0..n)
        .map(|i| x0.get(i).copied().unwrap_or([0.0; 2]))
        .collect();
    let mut iterations = 0;
    let mut h_inv = DMatrix::zeros(2 * n, 2 * n);
    while iterations < 20 {
        iterations += 1;
        let mut h = DMatrix::<f64>::zeros(2 * n, 2 * n);
        let mut g = DVector::<f64>::zeros(2 * n);
        // Jacobian of r = x_to − x_from − z: +I for `to`, −I for `from`.
        for (e, w) in edges.iter().zip(&weights) {
            let wr = w * residual(e, &x);
            add_block(&mut h, e.to, e.to, w);
            let mut gt = g.fixed_rows_mut::<2>(2 * e.to);
            gt += wr;
            if let Some(f) = e.from {
                add_block(&mut h, f, f, w);
                add_block(&mut h, f, e.to, &-w);
                add_block(&mut h, e.to, f, &-w);
                let mut gf = g.fixed_rows_mut::<2>(2 * f);
                gf -= wr;
            }
        }
        let chol = h.cholesky().ok_or(GraphError::Underdetermined)?;
        let dx = -chol.solve(&g);
        h_inv = chol.inverse();
        for (i, xi) in x.iter_mut().enumerate() {
            xi[0] += dx[2 * i];
            xi[1] += dx[2 * i + 1];
        }
        if dx.amax() < 1e-9 {
            break;
        }
    }
    let cov = (0..n)
        .map(|i| {
            [
                h_inv[(2 * i, 2 * i)],
                h_inv[(2 * i, 2 * i + 1)],
                h_inv[(2 * i + 1, 2 * i + 1)],
            ]
        })
        .collect();
    Ok(Solution {
        chi2: chi2(edges, &x),
        x,
        cov,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(from: Option<usize>, to: usize, z: [f64; 2], s: f64) -> Edge {
        Edge {
            from,
            to,
            z,
            cov: [s * s, 0.0, s * s],
        }
    }

    /// Two poses (0, 1) and one landmark (2) on a line, per axis independent: the
    /// closed form is the weighted least-squares solution of a 3-unknown linear system.
    #[test]
    fn two_poses_one_landmark_matches_the_closed_form() {
        // Prior x0 = 0 (σ 0.1); odometry x1 − x0 = 10 (σ 1); observations
        // l − x0 = 12 (σ 2), l − x1 = 1 (σ 0.5).
        let edges = vec![
            e(None, 0, [0.0, 0.0], 0.1),
            e(Some(0), 1, [10.0, 0.0], 1.0),
            e(Some(0), 2, [12.0, 3.0], 2.0),
            e(Some(1), 2, [1.0, 3.5], 0.5),
        ];
        let sol = solve(3, &edges, &[[0.0; 2]; 3]).unwrap();
        // Closed form per axis: H = AᵀWA, b = AᵀWz, with A rows [1,0,0],[−1,1,0],[−1,0,1],[0,−1,1].
        let w = [1.0 / 0.01, 1.0, 1.0 / 4.0, 1.0 / 0.25];
        let a = [
            [1.0, 0.0, 0.0],
            [-1.0, 1.0, 0.0],
            [-1.0, 0.0, 1.0],
            [0.0, -1.0, 1.0],
        ];
        for (axis, z) in [[0.0, 10.0, 12.0, 1.0], [0.0, 0.0, 3.0, 3.5]]
            .iter()
            .enumerate()
        {
            let mut h = nalgebra::Matrix3::<f64>::zeros();
            let mut b = nalgebra::Vector3::<f64>::zeros();
            for k in 0..4 {
                let row = nalgebra::Vector3::from(a[k]);
                h += row * row.transpose() * w[k];
                b += row * w[k] * z[k];
            }
            let hi = h.try_inverse().unwrap();
            let x = hi * b;
            for i in 0..3 {
                assert!((sol.x[i][axis] - x[i]).abs() < 1e-9, "{axis} {i}");
                let c = sol.cov[i][if axis == 0 { 0 } else { 2 }];
                assert!((c - hi[(i, i)]).abs() < 1e-9);
            }
        }
        assert!(sol.iterations <= 2);
        // The minimum: any perturbation raises eq. 5.
        let mut y = sol.x.clone();
        y[2][0] += 0.01;
        assert!(chi2(&edges, &y) > sol.chi2);
    }

    #[test]
    fn correlated_covariance_is_used() {
        // One landmark observed from a fixed pose with a correlated covariance and once
        // absolutely: the solution is the information-weighted mean.
        let c1 = [2.0, 1.5, 2.0];
        let edges = vec![
            e(None, 0, [0.0, 0.0], 1e-3),
            Edge {
                from: Some(0),
                to: 1,
                z: [1.0, 0.0],
                cov: c1,
            },
            e(None, 1, [0.0, 1.0], 1.0),
        ];
        let sol = solve(2, &edges, &[[0.0; 2]; 2]).unwrap();
        let w1 = Matrix2::new(2.0, 1.5, 1.5, 2.0).try_inverse().unwrap();
        let w2 = Matrix2::identity();
        let want = (w1 + w2).try_inverse().unwrap()
            * (w1 * Vector2::new(1.0, 0.0) + w2 * Vector2::new(0.0, 1.0));
        // Pose 0 is pinned to within 1 mm, so the landmark matches to that order.
        assert!((sol.x[1][0] - want[0]).abs() < 1e-5 && (sol.x[1][1] - want[1]).abs() < 1e-5);
    }

    #[test]
    fn bad_input_is_an_error() {
        let edges = vec![e(None, 0, [0.0, 0.0], 1.0), e(Some(0), 1, [1.0, 0.0], 1.0)];
        assert_eq!(solve(3, &edges, &[]), Err(GraphError::Underdetermined));
        assert_eq!(solve(1, &edges, &[]), Err(GraphError::BadNode(1)));
        let bad = vec![Edge {
            from: None,
            to: 0,
            z: [0.0; 2],
            cov: [f64::NAN, 0.0, 1.0],
        }];
        assert_eq!(solve(1, &bad, &[]), Err(GraphError::BadCovariance(0)));
    }
}
