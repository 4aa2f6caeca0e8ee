//! Geometry of the guidance: flux-line direction, the belief's horizontal Mahalanobis
//! distance and principal axis, whether a heading supports going to the mean, and the
//! arrow's angle conventions (bearings from north toward west, positive to the left).

use crate::Vec3;
use crate::estimate::VictimEstimate;
use crate::frame::wrap_pi;

/// Unit horizontal flux-line direction in `G` for the field `h`, with the sign that
/// agrees with `reference` (a horizontal direction); `None` when the field is vertical.
pub fn flux_direction(h: &Vec3, reference: &[f32; 2]) -> Option<[f32; 2]> {
    let n = libm::sqrtf(h.x * h.x + h.y * h.y);
    // A field within ~0.5° of vertical has no usable horizontal direction.
    if !n.is_finite() || n <= 1e-2 * h.norm() || n == 0.0 {
        return None;
    }
    let (x, y) = (h.x / n, h.y / n);
    if x * reference[0] + y * reference[1] < 0.0 {
        Some([-x, -y])
    } else {
        Some([x, y])
    }
}

/// Squared horizontal Mahalanobis distance of the receiver (the origin of `G_k`) from the
/// mixture mean, with the mixture covariance of IROS eq. 18 (0 if it is singular).
pub fn horizontal_mahalanobis2(est: &VictimEstimate) -> f32 {
    let c = &est.cov;
    let (a, b, d) = (c[(0, 0)], c[(0, 1)], c[(1, 1)]);
    let det = a * d - b * b;
    if det.is_nan() || det <= 0.0 {
        return 0.0;
    }
    let (x, y) = (est.p.x, est.p.y);
    let m = (d * x * x - 2.0 * b * x * y + a * y * y) / det;
    if m.is_finite() { m } else { 0.0 }
}

/// Whether a heading known to within the variance `yaw_var` (rad²) can support sending the
/// rescuer to a belief's mean at all (issue 22: "when the inputs cannot support a belief
/// ... the status is not localized"). The belief is in `G_k`, north-aligned; a heading
/// error δψ ~ N(0, σψ²) turns all of it about the receiver, `p → Rz(δψ) p`, and the arrow
/// with it. Along `p` that adds the second moment `a |p_h|²`, `a = E[(cos δψ − 1)²] =
/// 3/2 − 2 e^(−σψ²/2) + e^(−2σψ²)/2`, so the squared Mahalanobis distance of the receiver
/// (IROS 2006 §III-C, eq. 18) is at most `1 / a` whatever the filter's own covariance and
/// the distance: the test `go_to_mean_d2 · a < 1` is necessary for the go-to-mean rule
/// once the heading's share is counted (σψ < 39° for `go_to_mean_d2` = 9). With a
/// magnetometer σψ is a few degrees and this never binds; without one σψ stays ≥ π and
/// the arrow to the mean was measured 30–68° off on 5 of the 14 validation logs while
/// "localized" (`docs/session-log.md`). Not finite: unknown, no.
pub fn heading_supports(yaw_var: f32, go_to_mean_d2: f32) -> bool {
    if yaw_var.is_nan() || yaw_var == f32::INFINITY {
        return false;
    }
    let v = yaw_var.max(0.0);
    let a = 1.5 - 2.0 * libm::expf(-0.5 * v) + 0.5 * libm::expf(-2.0 * v);
    go_to_mean_d2 * a < 1.0
}

/// Unit principal axis (horizontal, `G`) and largest standard deviation (m) of the
/// horizontal block of the covariance `cov`.
pub fn horizontal_axis(cov: &crate::Mat3) -> ([f32; 2], f32) {
    let (a, b, c) = (cov[(0, 0)], cov[(0, 1)], cov[(1, 1)]);
    let half = 0.5 * (a - c);
    let lmax = 0.5 * (a + c) + libm::sqrtf(half * half + b * b);
    // Eigenvector of [[a, b], [b, c]] for lmax.
    let (vx, vy) = if libm::fabsf(b) > 1e-12 {
        (lmax - c, b)
    } else if a >= c {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let n = libm::sqrtf(vx * vx + vy * vy);
    let axis = if n > 0.0 && n.is_finite() {
        [vx / n, vy / n]
    } else {
        [1.0, 0.0]
    };
    let sigma = libm::sqrtf(lmax.max(0.0));
    (axis, if sigma.is_finite() { sigma } else { f32::MAX })
}

/// A bearing in `G` (rad) relative to the device's yaw: positive to the left, (-π, π].
pub fn relative_arrow(bearing: f32, yaw: f32) -> f32 {
    wrap_pi(bearing - yaw)
}

/// Radians to degrees in (-180, 180] (the session-log replay's `arrow_deg`).
pub fn to_degrees_wrapped(a: f32) -> f32 {
    let d = wrap_pi(a) * (180.0 / core::f32::consts::PI);
    if d <= -180.0 { 180.0 } else { d }
}
