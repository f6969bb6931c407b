//! Local problems of the 2×2 blocks: the lateral pair of a sliding point (a bilateral solve)
//! and the tangential pair of a Coulomb contact (the friction-disk projection).

/// A symmetric 2×2 block `[[a, b], [b, c]]` with its eigen-decomposition (eigenvalues floored at
/// `1e-13 ·` the largest, so that solves stay finite on singular blocks).
#[derive(Clone, Copy, Debug)]
pub(super) struct Sym2 {
    pub(super) a: f64,
    pub(super) b: f64,
    pub(super) c: f64,
    l1: f64,
    l2: f64,
    cs: f64,
    sn: f64,
    /// The inverse of the (floored) block, `[[p, q], [q, r]]`: a solve is then two products
    /// and two fused adds, with no division on the sweep's dependent chain.
    inv: [f64; 3],
}

impl Sym2 {
    pub(super) fn new(a: f64, b: f64, c: f64) -> Self {
        let th = 0.5 * libm::atan2(2.0 * b, a - c);
        let (sn, cs) = libm::sincos(th);
        let l1 = a * cs * cs + 2.0 * b * cs * sn + c * sn * sn;
        let l2 = a * sn * sn - 2.0 * b * cs * sn + c * cs * cs;
        let floor = 1e-13 * l1.max(l2).max(f64::MIN_POSITIVE);
        let (l1, l2) = (l1.max(floor), l2.max(floor));
        let (i1, i2) = (1.0 / l1, 1.0 / l2);
        let inv = [
            cs * cs * i1 + sn * sn * i2,
            cs * sn * (i1 - i2),
            sn * sn * i1 + cs * cs * i2,
        ];
        Self {
            a,
            b,
            c,
            l1,
            l2,
            cs,
            sn,
            inv,
        }
    }

    pub(super) fn pack(&self) -> [f64; 10] {
        [
            self.a,
            self.b,
            self.c,
            self.l1,
            self.l2,
            self.cs,
            self.sn,
            self.inv[0],
            self.inv[1],
            self.inv[2],
        ]
    }

    pub(super) fn unpack(f: &[f64]) -> Self {
        Self {
            a: f[0],
            b: f[1],
            c: f[2],
            l1: f[3],
            l2: f[4],
            cs: f[5],
            sn: f[6],
            inv: [f[7], f[8], f[9]],
        }
    }

    /// Solves `A x = (r1, r2)` with the (floored) block's inverse.
    #[inline]
    pub(super) fn solve(&self, r1: f64, r2: f64) -> (f64, f64) {
        let [p, q, r] = self.inv;
        (p * r1 + q * r2, q * r1 + r * r2)
    }

    /// [`Self::solve`] lane by lane, `L` right-hand sides `(r1[i], r2[i])` at once (the same
    /// operations on each lane: the same results), written as loops over the lanes for the
    /// compiler to vectorise.
    #[inline(always)]
    pub(super) fn solve_lanes<const L: usize>(
        &self,
        r1: &[f64; L],
        r2: &[f64; L],
    ) -> ([f64; L], [f64; L]) {
        let [p, q, r] = self.inv;
        let (mut x1, mut x2) = ([0.0; L], [0.0; L]);
        for i in 0..L {
            x1[i] = p * r1[i] + q * r2[i];
            x2[i] = q * r1[i] + r * r2[i];
        }
        (x1, x2)
    }

    /// `argmin ½ xᵀ A x + gᵀ x` subject to `|x| ≤ rho` (2-D trust-region problem).
    pub(super) fn disk_minimiser(&self, g1: f64, g2: f64, rho: f64) -> (f64, f64) {
        if !(rho > 0.0) {
            return (0.0, 0.0);
        }
        let (h1, h2) = (self.cs * g1 + self.sn * g2, -self.sn * g1 + self.cs * g2);
        let norm = |nu: f64| libm::hypot(h1 / (self.l1 + nu), h2 / (self.l2 + nu));
        let (mut y1, mut y2);
        if norm(0.0) <= rho {
            y1 = -h1 / self.l1;
            y2 = -h2 / self.l2;
        } else {
            // Newton on φ(ν) = 1/|x(ν)| − 1/ρ (Moré–Sorensen): increasing and concave, so the
            // iterates rise monotonically to the root from ν = 0.
            let mut nu = 0.0f64;
            for _ in 0..60 {
                let (a1, a2) = (self.l1 + nu, self.l2 + nu);
                let (z1, z2) = (h1 / a1, h2 / a2);
                let n2 = z1 * z1 + z2 * z2;
                let n = libm::sqrt(n2);
                let phi = 1.0 / n - 1.0 / rho;
                let dphi = (z1 * z1 / a1 + z2 * z2 / a2) / (n2 * n);
                if !(dphi > 0.0) {
                    break;
                }
                let step = phi / dphi;
                nu -= step;
                if !(nu >= 0.0) {
                    nu = 0.0;
                }
                if libm::fabs(step) <= 1e-15 * (nu + self.l1.max(self.l2)) {
                    break;
                }
            }
            y1 = -h1 / (self.l1 + nu);
            y2 = -h2 / (self.l2 + nu);
            let n = libm::hypot(y1, y2);
            if n > rho && n > 0.0 {
                y1 *= rho / n;
                y2 *= rho / n;
            }
        }
        if !(y1.is_finite() && y2.is_finite()) {
            return (0.0, 0.0);
        }
        (self.cs * y1 - self.sn * y2, self.sn * y1 + self.cs * y2)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    /// `A x − r` relative to `|A| |x| + |r|`.
    fn relative_residual(a: f64, b: f64, c: f64, x: (f64, f64), r: (f64, f64)) -> f64 {
        let e1 = a * x.0 + b * x.1 - r.0;
        let e2 = b * x.0 + c * x.1 - r.1;
        let scale = (a.abs() + b.abs() + c.abs()) * (x.0.abs() + x.1.abs()) + r.0.abs() + r.1.abs();
        libm::hypot(e1, e2) / scale
    }

    /// The block's inverse solves it to round-off, also ill-conditioned, agrees with the
    /// eigen-decomposition's solve, and unpacks as it was packed; every lane of `solve_lanes`
    /// is `solve`, bit for bit.
    #[test]
    fn the_precomputed_inverse_solves_the_block_as_the_eigen_decomposition() {
        let blocks = [
            (2.0, 0.5, 1.0),
            (1e3, -3e2, 4e2),
            (1.0, 0.999_999, 1.0), // condition ≈ 2e6
            (5e-4, 1e-5, 3e-4),
            (7.0, 0.0, 7.0),
        ];
        for &(a, b, c) in &blocks {
            let e = Sym2::new(a, b, c);
            let back = Sym2::unpack(&e.pack());
            for (r1, r2) in [(1.0, 0.0), (0.0, 1.0), (-0.3, 2.5), (1e-6, -4e3)] {
                let x = back.solve(r1, r2);
                let cond = e.l1.max(e.l2) / e.l1.min(e.l2);
                assert!(
                    relative_residual(a, b, c, x, (r1, r2)) <= 1e-15 * cond.max(1.0) * 8.0,
                    "[[{a}, {b}], [{b}, {c}]] x = ({r1}, {r2}): {x:?}"
                );
                // The eigen-decomposition's solve, as before the inverse.
                let (u1, u2) = (e.cs * r1 + e.sn * r2, -e.sn * r1 + e.cs * r2);
                let (y1, y2) = (u1 / e.l1, u2 / e.l2);
                let eig = (e.cs * y1 - e.sn * y2, e.sn * y1 + e.cs * y2);
                let size = libm::hypot(eig.0, eig.1);
                assert!(
                    libm::hypot(x.0 - eig.0, x.1 - eig.1) <= 1e-14 * cond.max(1.0) * size,
                    "{x:?} against {eig:?}"
                );
                let (l1, l2) = back.solve_lanes(&[r1, 0.5, r1], &[r2, -1.0, r2]);
                for k in [0, 2] {
                    assert_eq!(l1[k].to_bits(), x.0.to_bits());
                    assert_eq!(l2[k].to_bits(), x.1.to_bits());
                }
            }
        }
    }

    /// A singular block (a sliding point whose lateral rows coincide) keeps finite solves: its
    /// eigenvalues are floored, and so is its inverse. (A zero diagonal never gets here: the
    /// frame's validation refuses it.)
    #[test]
    fn a_singular_block_solves_finite() {
        for (a, b, c) in [(1.0, 1.0, 1.0), (4.0, -2.0, 1.0), (1e-12, 1e-12, 1e-12)] {
            let e = Sym2::new(a, b, c);
            let x = e.solve(1.0, -2.0);
            assert!(x.0.is_finite() && x.1.is_finite(), "{a} {b} {c}: {x:?}");
        }
    }
}
