//! Second-order forward-mode automatic differentiation on a fixed number of variables.
//!
//! `Hd` carries a value, its gradient and its (symmetric) Hessian with respect to `N`
//! independent variables. Arithmetic applies the product and chain rules exactly, so a scalar
//! function written with `Hd` yields its exact first and second derivatives (no finite
//! differences). Used by the beam element to obtain internal forces and tangent stiffness from
//! the element energy.

use std::ops::{Add, Mul, Neg, Sub};

/// Number of independent variables of the beam element energy: relative translation (3) and
/// the two nodal rotation increments (3 + 3).
pub(crate) const N: usize = 9;

/// A value with exact gradient and Hessian with respect to `N` variables. Only the upper
/// triangle `h[i][j]`, `j ≥ i`, of the symmetric Hessian is maintained; read it with [`Hd::hess`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hd {
    pub v: f64,
    pub g: [f64; N],
    pub h: [[f64; N]; N],
}

impl Hd {
    /// A constant.
    pub fn cst(v: f64) -> Self {
        Self {
            v,
            g: [0.0; N],
            h: [[0.0; N]; N],
        }
    }

    /// Variable number `k` with value `v`.
    pub fn var(v: f64, k: usize) -> Self {
        let mut s = Self::cst(v);
        s.g[k] = 1.0;
        s
    }

    /// Hessian entry `(i, j)` (either order).
    pub fn hess(&self, i: usize, j: usize) -> f64 {
        if i <= j { self.h[i][j] } else { self.h[j][i] }
    }

    /// `f(self)` given `f`, `f'`, `f''` at `self.v`.
    fn chain(self, f0: f64, f1: f64, f2: f64) -> Self {
        let mut r = Self::cst(f0);
        for i in 0..N {
            r.g[i] = f1 * self.g[i];
        }
        for i in 0..N {
            for j in i..N {
                r.h[i][j] = f1 * self.h[i][j] + f2 * self.g[i] * self.g[j];
            }
        }
        r
    }

    pub fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s, -0.25 / (s * self.v))
    }

    pub fn recip(self) -> Self {
        let r = 1.0 / self.v;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }

    pub fn scale(self, s: f64) -> Self {
        let mut r = self;
        r.v *= s;
        r.g.iter_mut().for_each(|x| *x *= s);
        for i in 0..N {
            for j in i..N {
                r.h[i][j] *= s;
            }
        }
        r
    }
}

impl Add for Hd {
    type Output = Hd;
    fn add(mut self, o: Hd) -> Hd {
        self.v += o.v;
        for i in 0..N {
            self.g[i] += o.g[i];
            for j in i..N {
                self.h[i][j] += o.h[i][j];
            }
        }
        self
    }
}

impl Sub for Hd {
    type Output = Hd;
    fn sub(self, o: Hd) -> Hd {
        self + (-o)
    }
}

impl Neg for Hd {
    type Output = Hd;
    fn neg(self) -> Hd {
        self.scale(-1.0)
    }
}

impl Add<f64> for Hd {
    type Output = Hd;
    fn add(mut self, o: f64) -> Hd {
        self.v += o;
        self
    }
}

impl Mul<f64> for Hd {
    type Output = Hd;
    fn mul(self, o: f64) -> Hd {
        self.scale(o)
    }
}

impl Mul for Hd {
    type Output = Hd;
    fn mul(self, o: Hd) -> Hd {
        let mut r = Hd::cst(self.v * o.v);
        for i in 0..N {
            r.g[i] = self.v * o.g[i] + o.v * self.g[i];
        }
        for i in 0..N {
            for j in 0..N {
                r.h[i][j] = self.v * o.h[i][j]
                    + o.v * self.h[i][j]
                    + self.g[i] * o.g[j]
                    + o.g[i] * self.g[j];
            }
        }
        r
    }
}

/// A 3-vector of [`Hd`].
pub(crate) type V3 = [Hd; 3];

pub(crate) fn dot(a: &V3, b: &V3) -> Hd {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn cross(a: &V3, b: &V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(crate) fn add(a: &V3, b: &V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub(crate) fn scale(a: &V3, s: Hd) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub(crate) fn scale_f(a: &V3, s: f64) -> V3 {
    [a[0].scale(s), a[1].scale(s), a[2].scale(s)]
}

/// Cross product of a variable vector with a constant vector.
pub(crate) fn cross_c(a: &V3, b: &[f64; 3]) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_of_a_known_function() {
        // f(x, y) = sqrt(x² y + 1) / y at (1.3, 0.7)
        let (x0, y0) = (1.3, 0.7);
        let x = Hd::var(x0, 0);
        let y = Hd::var(y0, 1);
        let f = (x * x * y + 1.0).sqrt() * y.recip();
        let fe = |x: f64, y: f64| (x * x * y + 1.0).sqrt() / y;
        let e = 1e-4;
        let gx = (fe(x0 + e, y0) - fe(x0 - e, y0)) / (2.0 * e);
        let gy = (fe(x0, y0 + e) - fe(x0, y0 - e)) / (2.0 * e);
        let hxy = (fe(x0 + e, y0 + e) - fe(x0 + e, y0 - e) - fe(x0 - e, y0 + e)
            + fe(x0 - e, y0 - e))
            / (4.0 * e * e);
        assert!((f.v - fe(x0, y0)).abs() < 1e-14);
        assert!((f.g[0] - gx).abs() < 1e-7 && (f.g[1] - gy).abs() < 1e-7);
        assert!((f.hess(0, 1) - hxy).abs() < 1e-5 && (f.hess(1, 0) - hxy).abs() < 1e-5);
    }
}
