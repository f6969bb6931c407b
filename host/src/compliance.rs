//! Compliance (the paper's CC stage): `W = H_n K_n⁻¹ H_nᵀ + H_v K_v⁻¹ H_vᵀ`, exploiting the
//! structure of `H`.
//!
//! Every constraint row group of this simulation acts on one *point* of each model: a 3-dof block
//! combination `P x = Σ_k w_k x_{block k}` (a gel point embedded in a tetrahedron or a surface
//! triangle, a needle node, a point between two needle nodes, the base node's rotation), seen along
//! up to three directions `D` (the rows). So `H = D P` and
//!
//! ```text
//! W_gh = D_g (P_g K⁻¹ P_hᵀ) D_hᵀ = D_g G_gh D_hᵀ,     G_gh = P_g U_h,   U_h = K⁻¹ P_hᵀ  (n × 3)
//! ```
//!
//! Three solves per point give its *Cartesian columns* `U_h`; every 3×3 block `G_gh` is then a
//! gather of at most four 3×3 blocks of `U_h` — no dense `m`-column solve. On the gel, a point's
//! columns depend only on the factor, not on the needle's direction or on λ: they are cached
//! ([`PointColumns`]) for as long as the factor is reused, so a step with an unchanged factor costs
//! three solves per *new* point only. Observation rows `C = O K⁻¹ Hᵀ` reuse the constraint points'
//! columns (`O_o U_h`), so observations cost no solve at all.

use nalgebra::{Matrix3, Vector3};

/// A linear map from a model's dofs to a 3-vector: `Σ_k w_k x[b_k .. b_k + 3]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointMap {
    /// Start index of each 3-dof block in the (reduced) dof vector, and its weight.
    pub blocks: [(usize, f64); 8],
    /// Number of blocks used.
    pub len: usize,
}

impl PointMap {
    /// A single 3-dof block with weight 1 (a needle node's translation or rotation).
    pub fn single(block: usize) -> Self {
        let mut blocks = [(0, 0.0); 8];
        blocks[0] = (block, 1.0);
        Self { blocks, len: 1 }
    }

    /// A weighted combination of up to eight blocks (two embedded points); blocks given as `None` (fixed, eliminated dofs) are dropped.
    pub fn weighted(blocks: impl IntoIterator<Item = (Option<usize>, f64)>) -> Self {
        let mut m = Self {
            blocks: [(0, 0.0); 8],
            len: 0,
        };
        for (b, w) in blocks {
            if let Some(b) = b
                && w != 0.0
                && m.len < 8
            {
                m.blocks[m.len] = (b, w);
                m.len += 1;
            }
        }
        m
    }

    /// The used blocks.
    pub fn used(&self) -> &[(usize, f64)] {
        &self.blocks[..self.len]
    }

    /// `P x` for a dof vector `x`.
    pub fn apply(&self, x: &[f64]) -> Vector3<f64> {
        self.used()
            .iter()
            .map(|&(b, w)| w * Vector3::new(x[b], x[b + 1], x[b + 2]))
            .sum()
    }

    /// Adds `Pᵀ f` (a force `f` spread on the blocks) to `out`.
    pub fn scatter(&self, f: &Vector3<f64>, out: &mut [f64]) {
        for &(b, w) in self.used() {
            for k in 0..3 {
                out[b + k] += w * f[k];
            }
        }
    }
}

/// The Cartesian columns `U = K⁻¹ Pᵀ` of one point: three dof vectors, stored column after column.
#[derive(Clone, Debug, PartialEq)]
pub struct PointColumns {
    /// `3 × n` values: column `k` is `data[k n .. (k + 1) n]`.
    pub data: Vec<f64>,
    /// Number of dofs `n`.
    pub n: usize,
}

impl PointColumns {
    /// Computes `K⁻¹ Pᵀ` with `solve_many(rhs, 3)`, a solver working in place on three
    /// column-major right-hand sides of length `n`.
    ///
    /// # Errors
    /// Whatever the solver returns.
    pub fn compute<E>(
        map: &PointMap,
        n: usize,
        solve_many: impl FnOnce(&mut [f64], usize) -> Result<(), E>,
    ) -> Result<Self, E> {
        let mut data = unit_loads(std::slice::from_ref(map), n);
        solve_many(&mut data, 3)?;
        Ok(Self { data, n })
    }

    /// The columns of several points with one call of `solve_many(rhs, 3 · maps.len())`: the
    /// solver reads its matrix (for the gel, a sparse factor of tens of megabytes) once for all
    /// the points rather than once per point, and each column is what [`Self::compute`] gives.
    ///
    /// # Errors
    /// Whatever the solver returns.
    pub fn compute_batch<E>(
        maps: &[PointMap],
        n: usize,
        solve_many: impl FnOnce(&mut [f64], usize) -> Result<(), E>,
    ) -> Result<Vec<Self>, E> {
        let mut rhs = unit_loads(maps, n);
        solve_many(&mut rhs, 3 * maps.len())?;
        Ok(rhs
            .chunks_exact(3 * n)
            .map(|data| Self {
                data: data.to_vec(),
                n,
            })
            .collect())
    }

    /// Column `k` (the response to a unit force along axis `k` at the point).
    pub fn column(&self, k: usize) -> &[f64] {
        &self.data[k * self.n..(k + 1) * self.n]
    }

    /// `G = P_other U` (3×3): the displacement of point `other` under unit forces at this point.
    pub fn gather(&self, other: &PointMap) -> Matrix3<f64> {
        let mut g = Matrix3::zeros();
        for k in 0..3 {
            let u = other.apply(self.column(k));
            g.set_column(k, &u);
        }
        g
    }

    /// Adds `U f` (the displacement due to a force `f` at the point) to `out`.
    pub fn add_response(&self, f: &Vector3<f64>, out: &mut [f64]) {
        for k in 0..3 {
            if f[k] != 0.0 {
                for (o, u) in out.iter_mut().zip(self.column(k)) {
                    *o += f[k] * u;
                }
            }
        }
    }
}

/// The right-hand sides `Pᵀ` of `maps`, three column-major columns of length `n` per point, one
/// point after the other.
/// The Cartesian columns of single 3-dof blocks (the nodes of a model), computed on demand and
/// kept while the factor they were solved with is in use: the columns of a point that moves
/// over a few nodes (the tip's contact point on the gel's surface, whose weights change every
/// step) are then sums of kept node columns, with no solve until the point reaches a new node
/// or the factor changes.
#[derive(Clone, Debug, Default)]
pub struct NodeColumns {
    /// `(block, columns)` of every node solved with the factor of `stamp`.
    nodes: Vec<(usize, PointColumns)>,
    /// The factor the columns were solved with ([`crate::linalg::Cholesky::stamp`]).
    stamp: u64,
}

impl NodeColumns {
    /// The columns of `map`, `Σ_k w_k U_k` over its blocks' node columns `U_k` (those missing
    /// solved together with `solve_many`), for a factor of stamp `stamp` (the kept columns of
    /// another factor are dropped first). Returns the columns and how many nodes were solved.
    ///
    /// # Errors
    /// Whatever the solver returns.
    pub fn point<E>(
        &mut self,
        map: &PointMap,
        n: usize,
        stamp: u64,
        solve_many: impl FnOnce(&mut [f64], usize) -> Result<(), E>,
    ) -> Result<(PointColumns, usize), E> {
        if stamp != self.stamp || self.nodes.first().is_some_and(|(_, c)| c.n != n) {
            self.nodes.clear();
            self.stamp = stamp;
        }
        let missing: Vec<PointMap> = map
            .used()
            .iter()
            .filter(|(b, _)| !self.nodes.iter().any(|(kept, _)| kept == b))
            .map(|&(b, _)| PointMap::single(b))
            .collect();
        if !missing.is_empty() {
            let cols = PointColumns::compute_batch(&missing, n, solve_many)?;
            self.nodes
                .extend(missing.iter().map(|m| m.blocks[0].0).zip(cols));
        }
        let mut data = vec![0.0; 3 * n];
        for &(b, w) in map.used() {
            if let Some((_, u)) = self.nodes.iter().find(|(kept, _)| *kept == b) {
                for (d, v) in data.iter_mut().zip(&u.data) {
                    *d += w * v;
                }
            }
        }
        Ok((PointColumns { data, n }, missing.len()))
    }
}

fn unit_loads(maps: &[PointMap], n: usize) -> Vec<f64> {
    let mut rhs = vec![0.0; 3 * n * maps.len()];
    for (cols, map) in rhs.chunks_exact_mut(3 * n).zip(maps) {
        for &(b, w) in map.used() {
            for k in 0..3 {
                cols[k * n + b + k] += w;
            }
        }
    }
    rhs
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// A deterministic SPD matrix.
    fn spd(n: usize) -> DMatrix<f64> {
        let a = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 11) as f64 / 11.0 - 0.4);
        &a * a.transpose() + DMatrix::identity(n, n) * n as f64
    }

    #[test]
    fn point_columns_reproduce_the_dense_compliance() {
        let n = 15;
        let k = spd(n);
        let kinv = k.clone().try_inverse().unwrap();
        let p = PointMap::weighted([(Some(0), 0.2), (Some(6), 0.3), (None, 0.1), (Some(9), 0.4)]);
        let q = PointMap::weighted([(Some(3), 0.5), (Some(12), 0.5)]);
        let solve = |rhs: &mut [f64], cols: usize| -> Result<(), ()> {
            for c in 0..cols {
                let b = DVector::from_column_slice(&rhs[c * n..(c + 1) * n]);
                rhs[c * n..(c + 1) * n].copy_from_slice((&kinv * b).as_slice());
            }
            Ok(())
        };
        let up = PointColumns::compute(&p, n, solve).unwrap();
        let uq = PointColumns::compute(&q, n, solve).unwrap();
        // Dense P matrices.
        let dense = |m: &PointMap| {
            let mut d = DMatrix::zeros(3, n);
            for &(b, w) in m.used() {
                for r in 0..3 {
                    d[(r, b + r)] += w;
                }
            }
            d
        };
        let (dp, dq) = (dense(&p), dense(&q));
        let g_pq = &dp * &kinv * dq.transpose();
        let g = uq.gather(&p);
        for i in 0..3 {
            for j in 0..3 {
                assert!((g[(i, j)] - g_pq[(i, j)]).abs() < 1e-14, "{g} vs {g_pq}");
            }
        }
        // Symmetry: G_pq = G_qpᵀ.
        assert!((up.gather(&q).transpose() - g).norm() < 1e-14);
        // Response to a force.
        let f = Vector3::new(1.0, -2.0, 0.5);
        let mut x = vec![0.0; n];
        up.add_response(&f, &mut x);
        let expect = &kinv * dp.transpose() * DVector::from_column_slice(f.as_slice());
        assert!((DVector::from_vec(x) - expect).norm() < 1e-13);
        // Scatter is the transpose of apply.
        let mut s = vec![0.0; n];
        p.scatter(&f, &mut s);
        let y = DVector::from_fn(n, |i, _| i as f64);
        let lhs = DVector::from_vec(s).dot(&y);
        let rhs = p.apply(y.as_slice()).dot(&f);
        assert!((lhs - rhs).abs() < 1e-12);
    }

    /// A point moving over the same nodes (the tip's contact point) needs no solve while the
    /// factor is the same; its columns are those of a direct solve to round-off; a new node
    /// solves that node alone, and a new factor solves again.
    #[test]
    fn node_columns_give_a_moving_points_columns_with_no_new_solve() {
        let n = 15;
        let kinv = spd(n).try_inverse().unwrap();
        let solved = std::cell::Cell::new(0);
        let solve = |rhs: &mut [f64], cols: usize| -> Result<(), ()> {
            solved.set(solved.get() + cols);
            for c in 0..cols {
                let b = DVector::from_column_slice(&rhs[c * n..(c + 1) * n]);
                rhs[c * n..(c + 1) * n].copy_from_slice((&kinv * b).as_slice());
            }
            Ok(())
        };
        let mut nodes = NodeColumns::default();
        let on =
            |w: [f64; 3]| PointMap::weighted([(Some(0), w[0]), (Some(6), w[1]), (Some(9), w[2])]);
        let close = |a: &PointColumns, map: &PointMap| {
            let direct = PointColumns::compute(map, n, |r: &mut [f64], c| -> Result<(), ()> {
                for k in 0..c {
                    let b = DVector::from_column_slice(&r[k * n..(k + 1) * n]);
                    r[k * n..(k + 1) * n].copy_from_slice((&kinv * b).as_slice());
                }
                Ok(())
            })
            .unwrap();
            let err = a
                .data
                .iter()
                .zip(&direct.data)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-15, "off the direct solve by {err:e}");
        };
        let first = on([0.2, 0.3, 0.5]);
        let (cols, solved_nodes) = nodes.point(&first, n, 7, solve).unwrap();
        assert_eq!((solved_nodes, solved.get()), (3, 9));
        close(&cols, &first);
        // The point moves inside the same triangle: no solve.
        let moved = on([0.25, 0.35, 0.4]);
        let (cols, solved_nodes) = nodes.point(&moved, n, 7, solve).unwrap();
        assert_eq!((solved_nodes, solved.get()), (0, 9));
        close(&cols, &moved);
        // Onto a neighbour sharing two nodes: one node solved.
        let next = PointMap::weighted([(Some(6), 0.5), (Some(9), 0.3), (Some(12), 0.2)]);
        let (cols, solved_nodes) = nodes.point(&next, n, 7, solve).unwrap();
        assert_eq!((solved_nodes, solved.get()), (1, 12));
        close(&cols, &next);
        // A new factor: the kept columns are not used.
        let (_, solved_nodes) = nodes.point(&moved, n, 8, solve).unwrap();
        assert_eq!((solved_nodes, solved.get()), (3, 21));
    }
}
