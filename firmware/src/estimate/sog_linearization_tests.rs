use super::super::model::measure;
use super::super::model::{I_M, NX, StateMat, StateVec};
use super::*;

/// The derivation of [`linearization_var`] against the model: the per-axis mean
/// square of `h(p + δ p̂) − h(p) − h'·δ` over `δ ~ N(0, σ_r²)` (3-point Gauss–Hermite,
/// exact for the δ² term; `h'` by central differences) is `(6 |h| σ_r² / r²)²`, and
/// the added variance is `(k |z| σ_r² / r²)²` with tangential variance ignored.
#[test]
fn linearization_variance_matches_the_second_order_term() {
    let (r, sigma) = (20.0f64, 0.6f64);
    let dir = nalgebra::Vector3::new(0.48f64, -0.6, -0.64).normalize();
    let mut x = StateVec::zeros();
    for i in 0..3 {
        x[I_M + i] = [0.9f32, -0.3, 0.5][i];
    }
    let field = |d: f64| {
        let mut xs = x;
        for i in 0..3 {
            xs[I_P + i] = (dir[i] * (r + d)) as f32;
        }
        measure(&xs).unwrap().h.cast::<f64>()
    };
    let h0 = field(0.0);
    let eps = 1e-2;
    let dh = (field(eps) - field(-eps)) / (2.0 * eps);
    let d = 3f64.sqrt() * sigma;
    let err2 = |d: f64| (field(d) - h0 - dh * d).norm_squared();
    let per_axis = (err2(d) + err2(-d)) / 6.0 / 3.0;
    let expected = 6.0 * h0.norm() * sigma * sigma / (r * r);
    let ratio = per_axis.sqrt() / expected;
    assert!((ratio - 1.0).abs() < 0.1, "ratio {ratio}");

    // The component: range variance σ², large tangential variance (ignored).
    let mut p = StateMat::identity() * 1e-4;
    let pd = dir.cast::<f32>();
    let tang = Mat3::identity() - pd * pd.transpose();
    let ppp = pd * pd.transpose() * (sigma * sigma) as f32 + tang * 25.0;
    for i in 0..3 {
        x[I_P + i] = pd[i] * r as f32;
        for j in 0..3 {
            p[(I_P + i, I_P + j)] = ppp[(i, j)];
        }
    }
    let c = Component::new(x, &p, 0.0);
    let z = h0.cast::<f32>();
    let k = 3.0;
    // `expected` is the rms with coefficient 6; the added rms has coefficient k.
    let want = k / 6.0 * expected as f32;
    let got = linearization_var(k, &z, &c);
    assert!(
        (got.sqrt() / want - 1.0).abs() < 1e-3,
        "{got} vs {}",
        want * want
    );
    assert_eq!(linearization_var(0.0, &z, &c), 0.0);
    assert_eq!(NX, p.nrows());
}
