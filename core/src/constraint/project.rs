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
}

impl Sym2 {
    pub(super) fn new(a: f64, b: f64, c: f64) -> Self {
        let th = 0.5 * libm::atan2(2.0 * b, a - c);
        let (sn, cs) = libm::sincos(th);
        let l1 = a * cs * cs + 2.0 * b * cs * sn + c * sn * sn;
        let l2 = a * sn * sn - 2.0 * b * cs * sn + c * cs * cs;
        let floor = 1e-13 * l1.max(l2).max(f64::MIN_POSITIVE);
        Self {
            a,
            b,
            c,
            l1: l1.max(floor),
            l2: l2.max(floor),
            cs,
            sn,
        }
    }

    pub(super) fn pack(&self) -> [f64; 10] {
        [
            self.a, self.b, self.c, self.l1, self.l2, self.cs, self.sn, 0.0, 0.0, 0.0,
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
        }
    }

    /// Solves `A x = (r1, r2)` through the (floored) eigen-decomposition.
    #[inline]
    pub(super) fn solve(&self, r1: f64, r2: f64) -> (f64, f64) {
        let (u1, u2) = (self.cs * r1 + self.sn * r2, -self.sn * r1 + self.cs * r2);
        let (y1, y2) = (u1 / self.l1, u2 / self.l2);
        (self.cs * y1 - self.sn * y2, self.sn * y1 + self.cs * y2)
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
        let (mut x1, mut x2) = ([0.0; L], [0.0; L]);
        for i in 0..L {
            let (u1, u2) = (
                self.cs * r1[i] + self.sn * r2[i],
                -self.sn * r1[i] + self.cs * r2[i],
            );
            let (y1, y2) = (u1 / self.l1, u2 / self.l2);
            x1[i] = self.cs * y1 - self.sn * y2;
            x2[i] = self.sn * y1 + self.cs * y2;
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
