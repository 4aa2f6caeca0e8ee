//! Second-order forward-mode derivatives ("jets") of scalar functions of time.
//!
//! A [`Jet`] carries a value and its first and second time derivatives. Arithmetic and
//! `sin`/`cos` apply the product and chain rules, so every truth quantity that the world
//! builds from jets comes with exact, mutually consistent velocities and accelerations.
use std::ops::{Add, Mul, Neg, Sub};

/// A value with its first and second derivatives with respect to time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Jet {
    /// The value.
    pub v: f64,
    /// First derivative.
    pub d: f64,
    /// Second derivative.
    pub dd: f64,
}

impl Jet {
    /// A jet from its three components.
    pub const fn new(v: f64, d: f64, dd: f64) -> Self {
        Self { v, d, dd }
    }

    /// A constant (zero derivatives).
    pub const fn constant(v: f64) -> Self {
        Self { v, d: 0.0, dd: 0.0 }
    }

    /// Sine, by the chain rule.
    pub fn sin(self) -> Self {
        let (s, c) = self.v.sin_cos();
        Self::new(s, c * self.d, c * self.dd - s * self.d * self.d)
    }

    /// Cosine, by the chain rule.
    pub fn cos(self) -> Self {
        let (s, c) = self.v.sin_cos();
        Self::new(c, -s * self.d, -s * self.dd - c * self.d * self.d)
    }

    /// Multiplication by a constant.
    pub fn scale(self, k: f64) -> Self {
        Self::new(self.v * k, self.d * k, self.dd * k)
    }
}

impl Add for Jet {
    type Output = Jet;
    fn add(self, o: Jet) -> Jet {
        Jet::new(self.v + o.v, self.d + o.d, self.dd + o.dd)
    }
}

impl Sub for Jet {
    type Output = Jet;
    fn sub(self, o: Jet) -> Jet {
        Jet::new(self.v - o.v, self.d - o.d, self.dd - o.dd)
    }
}

impl Neg for Jet {
    type Output = Jet;
    fn neg(self) -> Jet {
        Jet::new(-self.v, -self.d, -self.dd)
    }
}

impl Mul for Jet {
    type Output = Jet;
    fn mul(self, o: Jet) -> Jet {
        Jet::new(
            self.v * o.v,
            self.d * o.v + self.v * o.d,
            self.dd * o.v + 2.0 * self.d * o.d + self.v * o.dd,
        )
    }
}

impl Add<f64> for Jet {
    type Output = Jet;
    fn add(self, k: f64) -> Jet {
        Jet::new(self.v + k, self.d, self.dd)
    }
}

impl Mul<f64> for Jet {
    type Output = Jet;
    fn mul(self, k: f64) -> Jet {
        self.scale(k)
    }
}

/// Quintic Hermite interpolation on `[0, h]` between `(y0, y0', y0'')` and
/// `(y1, y1', y1'')`, evaluated at `s ∈ [0, h]`: a C² curve with exact derivatives.
pub fn quintic_hermite(a: &Jet, b: &Jet, h: f64, s: f64) -> Jet {
    let u = s / h;
    let (u2, u3) = (u * u, u * u * u);
    let (u4, u5) = (u3 * u, u3 * u2);
    // Basis polynomials in u and their first/second derivatives in u.
    let h0 = 1.0 - 10.0 * u3 + 15.0 * u4 - 6.0 * u5;
    let h1 = u - 6.0 * u3 + 8.0 * u4 - 3.0 * u5;
    let h2 = 0.5 * u2 - 1.5 * u3 + 1.5 * u4 - 0.5 * u5;
    let h3 = 10.0 * u3 - 15.0 * u4 + 6.0 * u5;
    let h4 = -4.0 * u3 + 7.0 * u4 - 3.0 * u5;
    let h5 = 0.5 * u3 - u4 + 0.5 * u5;
    let d0 = -30.0 * u2 + 60.0 * u3 - 30.0 * u4;
    let d1 = 1.0 - 18.0 * u2 + 32.0 * u3 - 15.0 * u4;
    let d2 = u - 4.5 * u2 + 6.0 * u3 - 2.5 * u4;
    let d3 = -d0;
    let d4 = -12.0 * u2 + 28.0 * u3 - 15.0 * u4;
    let d5 = 1.5 * u2 - 4.0 * u3 + 2.5 * u4;
    let e0 = -60.0 * u + 180.0 * u2 - 120.0 * u3;
    let e1 = -36.0 * u + 96.0 * u2 - 60.0 * u3;
    let e2 = 1.0 - 9.0 * u + 18.0 * u2 - 10.0 * u3;
    let e3 = -e0;
    let e4 = -24.0 * u + 84.0 * u2 - 60.0 * u3;
    let e5 = 3.0 * u - 12.0 * u2 + 10.0 * u3;
    let (p0, p1, p2) = (a.v, a.d * h, a.dd * h * h);
    let (q0, q1, q2) = (b.v, b.d * h, b.dd * h * h);
    Jet::new(
        p0 * h0 + p1 * h1 + p2 * h2 + q0 * h3 + q1 * h4 + q2 * h5,
        (p0 * d0 + p1 * d1 + p2 * d2 + q0 * d3 + q1 * d4 + q2 * d5) / h,
        (p0 * e0 + p1 * e1 + p2 * e2 + q0 * e3 + q1 * e4 + q2 * e5) / (h * h),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn product_and_chain_rules_match_differences() {
        let f = |t: f64| {
            let x = Jet::new(t * t, 2.0 * t, 2.0);
            (x.sin() * Jet::new(t, 1.0, 0.0) + x.cos().scale(3.0)).v
        };
        let t = 0.7;
        let x = Jet::new(t * t, 2.0 * t, 2.0);
        let j = x.sin() * Jet::new(t, 1.0, 0.0) + x.cos().scale(3.0);
        let h = 1e-4;
        let d = (f(t + h) - f(t - h)) / (2.0 * h);
        let dd = (f(t + h) - 2.0 * f(t) + f(t - h)) / (h * h);
        assert!((j.d - d).abs() < 1e-6);
        assert!((j.dd - dd).abs() < 1e-4);
    }

    #[test]
    fn quintic_hermite_hits_its_end_conditions_and_reproduces_quintics() {
        let a = Jet::new(1.0, -2.0, 3.0);
        let b = Jet::new(0.5, 4.0, -1.0);
        let h = 0.3;
        assert!((quintic_hermite(&a, &b, h, 0.0) - a).v.abs() < 1e-12);
        let s0 = quintic_hermite(&a, &b, h, 0.0);
        let s1 = quintic_hermite(&a, &b, h, h);
        for (x, y) in [(s0, a), (s1, b)] {
            assert!((x.v - y.v).abs() < 1e-12);
            assert!((x.d - y.d).abs() < 1e-9);
            assert!((x.dd - y.dd).abs() < 1e-7);
        }
        // A cubic is reproduced exactly.
        let p = |t: f64| Jet::new(t * t * t - t, 3.0 * t * t - 1.0, 6.0 * t);
        let m = quintic_hermite(&p(0.0), &p(h), h, 0.1);
        let e = p(0.1);
        assert!((m.v - e.v).abs() < 1e-12 && (m.d - e.d).abs() < 1e-10);
        assert!((m.dd - e.dd).abs() < 1e-8);
    }
}
