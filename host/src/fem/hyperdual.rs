//! Forward-mode automatic differentiation on a fixed number of variables, to second or first
//! order.
//!
//! `Hd` carries a value, its gradient and its (symmetric) Hessian with respect to `N`
//! independent variables. Arithmetic applies the product and chain rules exactly, so a scalar
//! function written with `Hd` yields its exact first and second derivatives (no finite
//! differences). Used by the beam element to obtain internal forces and tangent stiffness from
//! the element energy.
//!
//! `D1` carries the value and the gradient only. Every operation computes a value and a gradient
//! entry by the same expression as `Hd`'s (which never reads its Hessian for them), so a function
//! written once for both ([`Ad`]) gives a `D1` bit for bit the value and gradient of the `Hd`, at
//! a sixth of the entries: what a step needs when it does not use the Hessian.

// `&a * &b` is deliberate: `Hd` is `Copy` but 440 bytes, and the by-value operators copy it.
#![allow(clippy::op_ref)]

use std::ops::{Add, Mul, Neg, Sub};

/// Number of independent variables of the beam element energy: relative translation (3) and
/// the two nodal rotation increments (3 + 3).
pub(crate) const N: usize = 9;

/// Entries of the packed upper Hessian triangle, `N (N + 1) / 2`.
const H: usize = N * (N + 1) / 2;

/// `(i, j)`, `j ≥ i`, of each packed Hessian entry: row by row of the upper triangle.
const PAIRS: [(usize, usize); H] = {
    let mut out = [(0, 0); H];
    let (mut i, mut k) = (0, 0);
    while i < N {
        let mut j = i;
        while j < N {
            out[k] = (i, j);
            k += 1;
            j += 1;
        }
        i += 1;
    }
    out
};

/// A number with derivatives with respect to the `N` variables: [`Hd`] (value, gradient,
/// Hessian) or [`D1`] (value, gradient). The operations give a `D1` exactly the value and
/// gradient an `Hd` gets: the same expressions, entry by entry.
pub(crate) trait Ad:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Mul<f64, Output = Self>
    + Add<f64, Output = Self>
{
    /// A constant.
    fn cst(v: f64) -> Self;
    /// Variable number `k` with value `v`.
    fn var(v: f64, k: usize) -> Self;
    /// The gradient.
    fn grad(&self) -> &[f64; N];
    /// `√self`.
    fn sqrt(self) -> Self;
    /// `1 / self`.
    fn recip(self) -> Self;
    /// `s · self`.
    fn scale(&self, s: f64) -> Self;
    /// `self + o`.
    fn add_ref(&self, o: &Self) -> Self;
    /// Each entry `x` of `self` becomes `put(x, p)`, `p` the entry of the product `a b`
    /// ([`Hd`]'s `fold_product`).
    fn fold(&mut self, a: &Self, b: &Self, put: impl Fn(f64, f64) -> f64);
    /// [`Ad::fold`] for a `b` of the variables `o..o + 3` alone ([`Hd`]'s
    /// `fold_product_local`).
    fn fold_local(&mut self, a: &Self, b: &Self, o: usize, put: impl Fn(f64, f64) -> f64);
    /// `self · o`.
    fn mul_ref(&self, o: &Self) -> Self {
        let mut r = Self::cst(0.0);
        r.fold(self, o, |_, p| p);
        r
    }
    /// `self + a b`, in place.
    fn mul_add(&mut self, a: &Self, b: &Self) {
        self.fold(a, b, |s, p| s + p);
    }
    /// `self − a b`, in place.
    fn mul_sub(&mut self, a: &Self, b: &Self) {
        self.fold(a, b, |s, p| s - p);
    }
    /// `self ← a b` (`first`) or `self ← self + a b`, for a `b` of the variables `o..o + 3`
    /// alone.
    fn mul_local(&mut self, a: &Self, b: &Self, o: usize, first: bool) {
        if first {
            self.fold_local(a, b, o, |_, p| p);
        } else {
            self.fold_local(a, b, o, |s, p| s + p);
        }
    }
    /// Component `j` of [`rotated_column`]`(a, offset)`.
    fn rotated(a: &[f64; 3], offset: usize, j: usize) -> Self;
}

/// A value with exact gradient and Hessian with respect to `N` variables. Only the upper
/// triangle of the symmetric Hessian is stored (packed row by row, [`PAIRS`]); read it with
/// [`Hd::hess`]. The operators also take references, and [`Ad::mul_add`] / [`Ad::mul_sub`]
/// accumulate a product in place: a value is 440 bytes, and copying operands and temporaries
/// cost as much as the arithmetic.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hd {
    pub v: f64,
    pub g: [f64; N],
    h: [f64; H],
}

impl Hd {
    /// A constant.
    pub fn cst(v: f64) -> Self {
        Self {
            v,
            g: [0.0; N],
            h: [0.0; H],
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
        let (i, j) = if i <= j { (i, j) } else { (j, i) };
        // Row i of the packed upper triangle starts after i rows of N, N − 1, … entries, at
        // i N − i (i − 1) / 2, and holds columns i.. .
        self.h[i * (2 * N - i - 1) / 2 + j]
    }

    /// `f(self)` given `f`, `f'`, `f''` at `self.v`.
    fn chain(&self, f0: f64, f1: f64, f2: f64) -> Self {
        Self {
            v: f0,
            g: core::array::from_fn(|i| f1 * self.g[i]),
            h: core::array::from_fn(|k| {
                let (i, j) = PAIRS[k];
                f1 * self.h[k] + f2 * self.g[i] * self.g[j]
            }),
        }
    }

    pub fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s, -0.25 / (s * self.v))
    }

    pub fn recip(self) -> Self {
        let r = 1.0 / self.v;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }

    pub fn scale(&self, s: f64) -> Self {
        Self {
            v: self.v * s,
            g: self.g.map(|x| x * s),
            h: self.h.map(|x| x * s),
        }
    }

    /// The product's entries in the order of [`Mul`], each passed to `put(acc, product)`.
    #[inline(always)]
    fn fold_product(&mut self, a: &Hd, b: &Hd, put: impl Fn(f64, f64) -> f64) {
        self.v = put(self.v, a.v * b.v);
        for i in 0..N {
            self.g[i] = put(self.g[i], a.v * b.g[i] + b.v * a.g[i]);
        }
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            let p = a.v * b.h[k] + b.v * a.h[k] + a.g[i] * b.g[j] + b.g[i] * a.g[j];
            self.h[k] = put(self.h[k], p);
        }
    }

    /// [`Self::fold_product`] for a `b` that depends only on the three variables `o..o + 3` (its
    /// gradient and Hessian zero elsewhere): the terms of `b`'s zero entries are left out, which
    /// changes no sum but for the sign of a zero result (`x + 0 = x`); a product with an
    /// infinite entry of `a` would give NaN there and gives ±∞ here.
    #[inline(always)]
    fn fold_product_local(&mut self, a: &Hd, b: &Hd, o: usize, put: impl Fn(f64, f64) -> f64) {
        debug_assert!(o + 3 <= N);
        self.v = put(self.v, a.v * b.v);
        // Every entry's `b.v · a` part first (one pass), then the few terms `b`'s three
        // variables add, each sum in the order of `fold_product` (`x + y = y + x` exactly).
        let mut g: [f64; N] = core::array::from_fn(|i| b.v * a.g[i]);
        for (gi, bg) in g[o..o + 3].iter_mut().zip(&b.g[o..o + 3]) {
            *gi += a.v * bg;
        }
        let mut h: [f64; H] = core::array::from_fn(|k| b.v * a.h[k]);
        for i in 0..N {
            let row = i * (2 * N - i - 1) / 2;
            if (o..o + 3).contains(&i) {
                for j in i..N {
                    let k = row + j;
                    h[k] = if j < o + 3 {
                        (a.v * b.h[k] + h[k]) + a.g[i] * b.g[j] + b.g[i] * a.g[j]
                    } else {
                        h[k] + b.g[i] * a.g[j]
                    };
                }
            } else if i < o {
                for j in o..o + 3 {
                    h[row + j] += a.g[i] * b.g[j];
                }
            }
        }
        for (out, x) in self.g.iter_mut().zip(g) {
            *out = put(*out, x);
        }
        for (out, x) in self.h.iter_mut().zip(h) {
            *out = put(*out, x);
        }
    }
}

impl Add<&Hd> for &Hd {
    type Output = Hd;
    fn add(self, o: &Hd) -> Hd {
        Hd {
            v: self.v + o.v,
            g: core::array::from_fn(|i| self.g[i] + o.g[i]),
            h: core::array::from_fn(|k| self.h[k] + o.h[k]),
        }
    }
}

impl Sub<&Hd> for &Hd {
    type Output = Hd;
    /// `self + (−o)`, which IEEE arithmetic makes the same numbers as `self − o`.
    fn sub(self, o: &Hd) -> Hd {
        Hd {
            v: self.v - o.v,
            g: core::array::from_fn(|i| self.g[i] - o.g[i]),
            h: core::array::from_fn(|k| self.h[k] - o.h[k]),
        }
    }
}

impl Sub for Hd {
    type Output = Hd;
    fn sub(self, o: Hd) -> Hd {
        <&Hd as Sub<&Hd>>::sub(&self, &o)
    }
}

impl Neg for Hd {
    type Output = Hd;
    fn neg(self) -> Hd {
        self.scale(-1.0)
    }
}

impl Mul<&Hd> for &Hd {
    type Output = Hd;
    fn mul(self, o: &Hd) -> Hd {
        let mut r = Hd::cst(0.0);
        r.fold_product(self, o, |_, p| p);
        r
    }
}

impl Hd {
    /// Component `j` of [`rotated_column`]`(a, offset)`.
    fn rotated_component(a: &[f64; 3], offset: usize, j: usize) -> Self {
        debug_assert!(offset + 3 <= N);
        let mut r = Hd::cst(a[j]);
        // (ω × a)_j = ω_{j+1} a_{j+2} − ω_{j+2} a_{j+1}.
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        r.g[offset + j1] = a[j2];
        r.g[offset + j2] = -a[j1];
        // ½ ∂²/∂ω_p∂ω_q of ω_j (ω·a) − a_j |ω|²: ½ (δ_jp a_q + δ_jq a_p) − a_j δ_pq.
        for p in 0..3 {
            for q in p..3 {
                let v = if p == q {
                    if p == j { 0.0 } else { -a[j] }
                } else if p == j {
                    0.5 * a[q]
                } else if q == j {
                    0.5 * a[p]
                } else {
                    0.0
                };
                let (i, k) = (offset + p, offset + q);
                r.h[i * (2 * N - i - 1) / 2 + k] = v;
            }
        }
        r
    }
}

impl Ad for Hd {
    fn cst(v: f64) -> Self {
        Hd::cst(v)
    }
    fn var(v: f64, k: usize) -> Self {
        Hd::var(v, k)
    }
    fn grad(&self) -> &[f64; N] {
        &self.g
    }
    fn sqrt(self) -> Self {
        Hd::sqrt(self)
    }
    fn recip(self) -> Self {
        Hd::recip(self)
    }
    fn scale(&self, s: f64) -> Self {
        Hd::scale(self, s)
    }
    fn add_ref(&self, o: &Self) -> Self {
        self + o
    }
    fn fold(&mut self, a: &Self, b: &Self, put: impl Fn(f64, f64) -> f64) {
        self.fold_product(a, b, put);
    }
    fn fold_local(&mut self, a: &Self, b: &Self, o: usize, put: impl Fn(f64, f64) -> f64) {
        self.fold_product_local(a, b, o, put);
    }
    fn rotated(a: &[f64; 3], offset: usize, j: usize) -> Self {
        Hd::rotated_component(a, offset, j)
    }
}

/// A value with its exact gradient with respect to `N` variables: [`Hd`] without the Hessian.
/// Each operation computes the value and every gradient entry by the expression [`Hd`]'s uses.
#[derive(Clone, Copy, Debug)]
pub(crate) struct D1 {
    pub v: f64,
    pub g: [f64; N],
}

impl D1 {
    /// [`Hd::fold_product`]'s value and gradient.
    #[inline(always)]
    fn fold_product(&mut self, a: &D1, b: &D1, put: impl Fn(f64, f64) -> f64) {
        self.v = put(self.v, a.v * b.v);
        for i in 0..N {
            self.g[i] = put(self.g[i], a.v * b.g[i] + b.v * a.g[i]);
        }
    }

    /// [`Hd::fold_product_local`]'s value and gradient.
    #[inline(always)]
    fn fold_product_local(&mut self, a: &D1, b: &D1, o: usize, put: impl Fn(f64, f64) -> f64) {
        debug_assert!(o + 3 <= N);
        self.v = put(self.v, a.v * b.v);
        let mut g: [f64; N] = core::array::from_fn(|i| b.v * a.g[i]);
        for (gi, bg) in g[o..o + 3].iter_mut().zip(&b.g[o..o + 3]) {
            *gi += a.v * bg;
        }
        for (out, x) in self.g.iter_mut().zip(g) {
            *out = put(*out, x);
        }
    }

    /// [`Hd`]'s `chain`: `f(self)` given `f` and `f'` at `self.v`.
    fn chain(&self, f0: f64, f1: f64) -> Self {
        Self {
            v: f0,
            g: core::array::from_fn(|i| f1 * self.g[i]),
        }
    }
}

impl Ad for D1 {
    fn cst(v: f64) -> Self {
        Self { v, g: [0.0; N] }
    }
    fn var(v: f64, k: usize) -> Self {
        let mut s = Self::cst(v);
        s.g[k] = 1.0;
        s
    }
    fn grad(&self) -> &[f64; N] {
        &self.g
    }
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s)
    }
    fn recip(self) -> Self {
        let r = 1.0 / self.v;
        self.chain(r, -r * r)
    }
    fn scale(&self, s: f64) -> Self {
        Self {
            v: self.v * s,
            g: self.g.map(|x| x * s),
        }
    }
    fn add_ref(&self, o: &Self) -> Self {
        Self {
            v: self.v + o.v,
            g: core::array::from_fn(|i| self.g[i] + o.g[i]),
        }
    }
    fn fold(&mut self, a: &Self, b: &Self, put: impl Fn(f64, f64) -> f64) {
        self.fold_product(a, b, put);
    }
    fn fold_local(&mut self, a: &Self, b: &Self, o: usize, put: impl Fn(f64, f64) -> f64) {
        self.fold_product_local(a, b, o, put);
    }
    fn rotated(a: &[f64; 3], offset: usize, j: usize) -> Self {
        debug_assert!(offset + 3 <= N);
        let mut r = Self::cst(a[j]);
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        r.g[offset + j1] = a[j2];
        r.g[offset + j2] = -a[j1];
        r
    }
}

impl Sub for D1 {
    type Output = D1;
    /// As [`Hd`]'s: `v − o.v`, `g − o.g`.
    fn sub(self, o: D1) -> D1 {
        D1 {
            v: self.v - o.v,
            g: core::array::from_fn(|i| self.g[i] - o.g[i]),
        }
    }
}

/// The operators by value and with a constant, the same for both number types: `a + b` and
/// `a b` are the reference forms' ([`Ad::add_ref`], [`Ad::mul_ref`]), `a + c` adds to the
/// value alone, `a c` scales.
macro_rules! value_operators {
    ($t:ty) => {
        impl Add for $t {
            type Output = $t;
            fn add(self, o: $t) -> $t {
                Ad::add_ref(&self, &o)
            }
        }

        impl Mul for $t {
            type Output = $t;
            fn mul(self, o: $t) -> $t {
                Ad::mul_ref(&self, &o)
            }
        }

        impl Add<f64> for $t {
            type Output = $t;
            fn add(mut self, o: f64) -> $t {
                self.v += o;
                self
            }
        }

        impl Mul<f64> for $t {
            type Output = $t;
            fn mul(self, o: f64) -> $t {
                Ad::scale(&self, o)
            }
        }
    };
}

value_operators!(Hd);
value_operators!(D1);

/// A 3-vector of [`Hd`] (or of another [`Ad`]).
pub(crate) type V3<T = Hd> = [T; 3];

pub(crate) fn dot<T: Ad>(a: &V3<T>, b: &V3<T>) -> T {
    let mut r = a[0].mul_ref(&b[0]);
    r.mul_add(&a[1], &b[1]);
    r.mul_add(&a[2], &b[2]);
    r
}

/// [`dot`] of `a` with a `b` that depends only on the variables `o..o + 3`
/// ([`Hd::fold_product_local`]): the same numbers but for the sign of zeros.
pub(crate) fn dot_local<T: Ad>(a: &V3<T>, b: &V3<T>, o: usize) -> T {
    let mut r = T::cst(0.0);
    r.mul_local(&a[0], &b[0], o, true);
    r.mul_local(&a[1], &b[1], o, false);
    r.mul_local(&a[2], &b[2], o, false);
    r
}

/// `x y − z w`.
fn mul_minus_mul<T: Ad>(x: &T, y: &T, z: &T, w: &T) -> T {
    let mut r = x.mul_ref(y);
    r.mul_sub(z, w);
    r
}

pub(crate) fn cross<T: Ad>(a: &V3<T>, b: &V3<T>) -> V3<T> {
    [
        mul_minus_mul(&a[1], &b[2], &a[2], &b[1]),
        mul_minus_mul(&a[2], &b[0], &a[0], &b[2]),
        mul_minus_mul(&a[0], &b[1], &a[1], &b[0]),
    ]
}

pub(crate) fn add<T: Ad>(a: &V3<T>, b: &V3<T>) -> V3<T> {
    [
        a[0].add_ref(&b[0]),
        a[1].add_ref(&b[1]),
        a[2].add_ref(&b[2]),
    ]
}

pub(crate) fn scale<T: Ad>(a: &V3<T>, s: T) -> V3<T> {
    [a[0].mul_ref(&s), a[1].mul_ref(&s), a[2].mul_ref(&s)]
}

pub(crate) fn scale_f<T: Ad>(a: &V3<T>, s: f64) -> V3<T> {
    [a[0].scale(s), a[1].scale(s), a[2].scale(s)]
}

/// Cross product of a variable vector with a constant vector.
#[cfg(test)]
pub(crate) fn cross_c(a: &V3, b: &[f64; 3]) -> V3 {
    [
        a[1].scale(b[2]) - a[2].scale(b[1]),
        a[2].scale(b[0]) - a[0].scale(b[2]),
        a[0].scale(b[1]) - a[1].scale(b[0]),
    ]
}

/// `(I + W + ½W²) a` for a constant `a`, `W = [ω]×`, as functions of the variables
/// `ω = offset..offset + 3` at `ω = 0`: the value `a`, the gradient `∂(ω × a)/∂ω` and the
/// Hessian `½ ∂²(ω × (ω × a))/∂ω²`, written directly — the numbers the operators give for
/// `a + ω × a + ½ ω × (ω × a)` (every entry a single `±a_q` or `½ a_q`, so no rounding either
/// way), without their 18 products of 440-byte values.
pub(crate) fn rotated_column<T: Ad>(a: &[f64; 3], offset: usize) -> V3<T> {
    core::array::from_fn(|j| T::rotated(a, offset, j))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Value, gradient and Hessian equal entry by entry (`==`: zeros of either sign equal).
    fn equal_numbers(x: &Hd, y: &Hd) -> bool {
        x.v == y.v
            && x.g.iter().zip(&y.g).all(|(p, q)| p == q)
            && x.h.iter().zip(&y.h).all(|(p, q)| p == q)
    }

    #[test]
    fn packed_hessian_indices_are_the_pairs() {
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            let mut x = Hd::cst(0.0);
            x.h[k] = 1.0 + k as f64;
            assert_eq!(x.hess(i, j), 1.0 + k as f64);
            assert_eq!(x.hess(j, i), 1.0 + k as f64);
        }
        assert_eq!(PAIRS[H - 1], (N - 1, N - 1));
    }

    #[test]
    fn in_place_products_are_the_operators() {
        let vars: Vec<Hd> = (0..N).map(|k| Hd::var(0.3 + 0.1 * k as f64, k)).collect();
        let a = (vars[0] * vars[4] + vars[2]).sqrt() * vars[7];
        let b = (vars[1] * vars[8] + 2.0).recip() - vars[3] * vars[5];
        let c = a * b + vars[6];
        let mut add = c;
        add.mul_add(&a, &b);
        let mut sub = c;
        sub.mul_sub(&a, &b);
        let same = |x: &Hd, y: &Hd| {
            x.v.to_bits() == y.v.to_bits()
                && x.g
                    .iter()
                    .zip(&y.g)
                    .all(|(p, q)| p.to_bits() == q.to_bits())
                && x.h
                    .iter()
                    .zip(&y.h)
                    .all(|(p, q)| p.to_bits() == q.to_bits())
        };
        assert!(same(&add, &(c + a * b)));
        assert!(same(&sub, &(c - a * b)));
        assert!(same(&(c - a), &(c + (-a))));
        assert!(add.h.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn rotated_column_is_the_operators_numbers() {
        // The same numbers as the products it replaces.
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for offset in [3, 6] {
            for _ in 0..200 {
                let a = [next(), next(), 1e-3 * next()];
                let w: V3 = core::array::from_fn(|i| Hd::var(0.0, offset + i));
                let wa = cross_c(&w, &a);
                let wwa = cross(&w, &wa);
                let c: V3 = a.map(Hd::cst);
                let old = add(&add(&c, &wa), &scale_f(&wwa, 0.5));
                let new = rotated_column(&a, offset);
                for j in 0..3 {
                    assert!(
                        equal_numbers(&old[j], &new[j]),
                        "a {a:?}, offset {offset}, component {j}"
                    );
                }
            }
        }
    }

    #[test]
    fn dot_local_is_dot_for_a_factor_of_three_variables() {
        // A full factor (every variable) against one of variables o..o + 3 only: every entry
        // equal to the plain product's.
        let vars: Vec<Hd> = (0..N).map(|k| Hd::var(0.2 + 0.15 * k as f64, k)).collect();
        for o in [0, 3, 6] {
            let a: V3 = core::array::from_fn(|r| {
                (vars[r] * vars[(r + 4) % N] + vars[8 - r]).sqrt() * vars[(r + 2) % N]
            });
            let b: V3 = core::array::from_fn(|r| {
                (vars[o + r] * vars[o + (r + 1) % 3] + 1.0).recip() - vars[o + (r + 2) % 3]
            });
            assert!(
                b.iter()
                    .all(|x| (0..N).all(|i| (o..o + 3).contains(&i) || x.g[i] == 0.0))
            );
            assert!(
                equal_numbers(&dot(&a, &b), &dot_local(&a, &b, o)),
                "offset {o}"
            );
        }
    }

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
