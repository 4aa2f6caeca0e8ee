//! A minimal `f32` complex number for the I/Q path (trigonometry through `libm`, so the
//! host tests and the Cortex-M4F compute the same values).

use core::ops::{Add, AddAssign, Mul, Sub};

/// A complex number `re + j·im`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct C32 {
    /// Real (in-phase) part.
    pub re: f32,
    /// Imaginary (quadrature) part.
    pub im: f32,
}

impl C32 {
    /// Zero.
    pub const ZERO: C32 = C32 { re: 0.0, im: 0.0 };

    /// `re + j·im`.
    pub const fn new(re: f32, im: f32) -> C32 {
        C32 { re, im }
    }
    /// `e^{jθ}`.
    pub fn cis(theta: f32) -> C32 {
        let (s, c) = libm::sincosf(theta);
        C32 { re: c, im: s }
    }
    /// Complex conjugate.
    pub fn conj(self) -> C32 {
        C32::new(self.re, -self.im)
    }
    /// `|z|²`.
    pub fn norm_sqr(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    /// `|z|`.
    pub fn abs(self) -> f32 {
        libm::sqrtf(self.norm_sqr())
    }
    /// Argument in (−π, π].
    pub fn arg(self) -> f32 {
        libm::atan2f(self.im, self.re)
    }
    /// `z · k` for a real `k`.
    pub fn scale(self, k: f32) -> C32 {
        C32::new(self.re * k, self.im * k)
    }
    /// Whether both parts are finite.
    pub fn is_finite(self) -> bool {
        self.re.is_finite() && self.im.is_finite()
    }
}

impl Add for C32 {
    type Output = C32;
    fn add(self, o: C32) -> C32 {
        C32::new(self.re + o.re, self.im + o.im)
    }
}

impl AddAssign for C32 {
    fn add_assign(&mut self, o: C32) {
        self.re += o.re;
        self.im += o.im;
    }
}

impl Sub for C32 {
    type Output = C32;
    fn sub(self, o: C32) -> C32 {
        C32::new(self.re - o.re, self.im - o.im)
    }
}

impl Mul for C32 {
    type Output = C32;
    fn mul(self, o: C32) -> C32 {
        C32::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
}
