//! Constraint rows of one step as groups of [`Attachment`]s, and the frame they make.
//!
//! A row group (base χ, tip contact φ, sliding point ψ) acts on one or two points: the needle
//! side with sign +1, the gel side with sign −1 (the gel receives the opposite force), each seen
//! along the group's directions `D` (up to three rows per attachment). With the points' Cartesian
//! columns ([`PointColumns`]) this gives, without any further solve,
//!
//! - `W_gh = Σ_{a∈g, b∈h, same model} s_a s_b D_a (P_a U_b) D_bᵀ`,
//! - `C_oh = Σ_{b∈h, model of o} s_b A_o (P_o U_b) D_bᵀ` for each observation `o = A_o P_o x`,
//! - the corrective motion `Δx = Σ_h Σ_{b∈h} s_b U_b D_bᵀ λ_h` (`x = x_free + K⁻¹ Hᵀ λ`,
//!   [`crate::step::correct`]).
//!
//! Sign conventions are those of `docs/architecture.md` (`w = W λ − δ`, positive `δ` violated).

use crate::compliance::{PointColumns, PointMap};
use nalgebra::{Matrix3, Vector3};
use needle_core::payload::{ComplianceFrame, GroupKind, NCLEAR, NOBS, RowGroup};

/// Most values (`3 · points · dofs`) of the right-hand sides solved together by
/// [`PointStore::compute_missing`]: 16 points of a 19 800-node gel (57 k dofs), 22 MB; every
/// point of the smaller gels.
const COLUMN_BATCH_VALUES: usize = 3 * 16 * 57_000;

/// Which model a point belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// The needle (6 dofs per node: translation, world-frame rotation increment).
    Needle,
    /// The gel (3 dofs per free node).
    Gel,
}

/// A point of a model with its Cartesian columns `K⁻¹ Pᵀ`, computed on demand and cached.
#[derive(Clone, Debug)]
pub struct StoredPoint {
    /// The point's map from dofs.
    pub map: PointMap,
    /// Its columns, once computed with the current factor.
    pub cols: Option<PointColumns>,
}

/// The points of one model that this step's rows touch.
#[derive(Clone, Debug, Default)]
pub struct PointStore {
    /// The points; rows refer to them by index.
    pub points: Vec<StoredPoint>,
}

impl PointStore {
    /// Adds a point (columns not yet computed) and returns its index.
    pub fn push(&mut self, map: PointMap) -> usize {
        self.points.push(StoredPoint { map, cols: None });
        self.points.len() - 1
    }

    /// Computes the missing columns with `solve_many(rhs, ncols)` on `n` dofs; returns how many
    /// points needed a solve.
    ///
    /// # Errors
    /// Whatever the solver returns.
    pub fn compute_missing<E>(
        &mut self,
        n: usize,
        solve_many: impl FnMut(&mut [f64], usize) -> Result<(), E>,
    ) -> Result<usize, E> {
        let per_batch = COLUMN_BATCH_VALUES / (3 * n.max(1));
        self.compute_missing_in_batches(n, per_batch, solve_many)
    }

    /// [`Self::compute_missing`] with at most `per_batch` points per call of `solve_many`
    /// ([`PointColumns::compute_batch`]: one pass of the solver over its factor per batch rather
    /// than per point).
    fn compute_missing_in_batches<E>(
        &mut self,
        n: usize,
        per_batch: usize,
        mut solve_many: impl FnMut(&mut [f64], usize) -> Result<(), E>,
    ) -> Result<usize, E> {
        let missing: Vec<usize> = (0..self.points.len())
            .filter(|&i| self.points[i].cols.is_none())
            .collect();
        for batch in missing.chunks(per_batch.max(1)) {
            let maps: Vec<PointMap> = batch.iter().map(|&i| self.points[i].map).collect();
            let cols = PointColumns::compute_batch(&maps, n, &mut solve_many)?;
            for (&i, c) in batch.iter().zip(cols) {
                self.points[i].cols = Some(c);
            }
        }
        Ok(missing.len())
    }

    /// Drops every cached column (after a refactorisation).
    pub fn invalidate(&mut self) {
        for p in &mut self.points {
            p.cols = None;
        }
    }

    /// The columns of point `i`.
    ///
    /// # Panics
    /// If they were not computed (the compliance stage computes them before any use).
    pub(crate) fn cols(&self, i: usize) -> &PointColumns {
        // Invariant: `compute_missing` ran before any frame is filled.
        self.points[i]
            .cols
            .as_ref()
            .unwrap_or_else(|| panic!("point {i}: columns not computed"))
    }
}

/// One model-side of a row group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attachment {
    /// The model.
    pub model: Model,
    /// Index of the point in that model's [`PointStore`].
    pub point: usize,
    /// First row of the group this attachment's directions fill.
    pub row_offset: usize,
    /// Number of rows (1 to 3).
    pub rows: usize,
    /// Row directions (row `r` of `d`), world frame.
    pub d: Matrix3<f64>,
    /// +1 on the needle side, −1 on the gel side.
    pub sign: f64,
}

/// What a row group models.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GroupRole {
    /// Needle base χ.
    Base,
    /// Tip on the gel surface φ (before puncture).
    Contact,
    /// Sliding point ψ with this identifier.
    Sliding(usize),
}

/// A group of consecutive rows.
#[derive(Clone, Debug, PartialEq)]
pub struct ConstraintGroup {
    /// Solver kind and friction parameters, `start` filled when the frame is built.
    pub kind: RowGroup,
    /// What it models.
    pub role: GroupRole,
    /// Number of rows.
    pub rows: usize,
    /// Its attachments (needle and/or gel).
    pub attachments: Vec<Attachment>,
    /// Violation after free motion, per row [mm or rad].
    pub delta: [f64; 6],
}

impl ConstraintGroup {
    /// A needle–gel group: the same `rows` directions `d` on needle point `needle` (sign +1) and
    /// gel point `gel` (sign −1), as contact and sliding groups are.
    pub fn pair(
        kind: RowGroup,
        role: GroupRole,
        rows: usize,
        (needle, gel): (usize, usize),
        d: Matrix3<f64>,
        delta: [f64; 6],
    ) -> Self {
        let side = |model, point, sign| Attachment {
            model,
            point,
            row_offset: 0,
            rows,
            d,
            sign,
        };
        Self {
            kind,
            role,
            rows,
            attachments: vec![
                side(Model::Needle, needle, 1.0),
                side(Model::Gel, gel, -1.0),
            ],
            delta,
        }
    }
}

/// An observed 3-vector `o = A P x` of one model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// The model.
    pub model: Model,
    /// The observed point's map.
    pub map: PointMap,
    /// The linear map applied to the point's displacement (identity for a position).
    pub a: Matrix3<f64>,
    /// Value after free motion.
    pub free: Vector3<f64>,
}

/// What a clearance row of the frame bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClearanceKind {
    /// An obstacle's margin: the obstacle's index in the scene's order.
    Obstacle(usize),
    /// The bound on the entry point's shift (`inverse.max_entry_shift`).
    EntryShift,
    /// The needle's yield strain at a node (counted from the base, node 0 at the flange).
    Bending(usize),
}

/// An obstacle seen by the controller: the nearest point `p` of the inserted needle, the
/// obstacle's point `s` it is measured to, and the clearance linearised at the start of the
/// step, `d ≈ clearance + nᵀ ((p − s) − current)`.
#[derive(Clone, Debug)]
pub struct ClearanceObservation {
    /// The needle point nearest to the obstacle (position observation).
    pub needle: Observation,
    /// The obstacle's point as a sum of gel observations: a sphere's centre (one), a mesh
    /// obstacle's closest surface point (its triangle's three vertices, each observation's `a`
    /// its barycentric weight times the identity).
    pub obstacle: Vec<Observation>,
    /// The clearance at the start of the step [mm] (a sphere: `|p − s| − r`).
    pub clearance: f64,
    /// Unit vector along which the clearance grows with `p − s` (a sphere: `(p − s)/|p − s|`).
    pub normal: Vector3<f64>,
    /// `p − s` at the start of the step (before the free motion), where the distance is
    /// linearised [mm].
    pub current: Vector3<f64>,
    /// What the row bounds.
    pub kind: ClearanceKind,
}

/// All rows and observations of one step.
#[derive(Clone, Debug, Default)]
pub struct ConstraintSet {
    /// Needle points.
    pub needle: PointStore,
    /// Gel points.
    pub gel: PointStore,
    /// Row groups in frame order (group 0: the base).
    pub groups: Vec<ConstraintGroup>,
}

impl ConstraintSet {
    fn store(&self, m: Model) -> &PointStore {
        match m {
            Model::Needle => &self.needle,
            Model::Gel => &self.gel,
        }
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.groups.iter().map(|g| g.rows).sum()
    }

    /// First row of each group.
    pub fn starts(&self) -> Vec<usize> {
        let mut s = Vec::with_capacity(self.groups.len());
        let mut r = 0;
        for g in &self.groups {
            s.push(r);
            r += g.rows;
        }
        s
    }

    /// Writes `W`, `δ_free`, the groups, and `C`, `o_free` for `observations` (laid out by
    /// `needle_core::payload::ObsIndex`) into `frame`. Other fields are the caller's.
    ///
    /// # Panics
    /// If the rows exceed the frame's capacity or a point's columns were not computed (both are
    /// checked by the caller, the world, before).
    pub fn fill_frame<const M: usize, const N: usize>(
        &self,
        observations: &[Observation; NOBS / 3],
        frame: &mut ComplianceFrame<M, N>,
    ) {
        let m = self.rows();
        assert!(m <= M, "{m} rows exceed the frame capacity {M}");
        let starts = self.starts();
        frame.m = m as u32;
        frame.group_count = self.groups.len() as u32;
        for (k, g) in self.groups.iter().enumerate() {
            let mut kind = g.kind;
            kind.start = starts[k] as u32;
            kind.len = g.rows as u32;
            frame.groups[k] = kind;
            frame.delta_free[starts[k]..starts[k] + g.rows].copy_from_slice(&g.delta[..g.rows]);
        }
        for row in frame.w.iter_mut().take(m) {
            row[..m].fill(0.0);
        }
        // W: symmetric, fill block (g, h) for h ≥ g and mirror.
        for (gi, g) in self.groups.iter().enumerate() {
            for (hi, h) in self.groups.iter().enumerate().skip(gi) {
                for a in &g.attachments {
                    for b in h.attachments.iter().filter(|b| b.model == a.model) {
                        let store = self.store(a.model);
                        let gab = store.cols(b.point).gather(&store.points[a.point].map);
                        let blk = a.sign * b.sign * a.d * gab * b.d.transpose();
                        for r in 0..a.rows {
                            for c in 0..b.rows {
                                let (i, j) =
                                    (starts[gi] + a.row_offset + r, starts[hi] + b.row_offset + c);
                                frame.w[i][j] += blk[(r, c)];
                                if gi != hi {
                                    frame.w[j][i] += blk[(r, c)];
                                }
                            }
                        }
                    }
                }
            }
        }
        // C and o_free.
        for (k, o) in observations.iter().enumerate() {
            for r in 0..3 {
                frame.o_free[3 * k + r] = o.free[r];
                frame.c[3 * k + r][..m].fill(0.0);
            }
            self.add_observation_rows(o, &starts, |r, j, v| frame.c[3 * k + r][j] += v);
        }
    }

    /// Adds the rows `C_o` of observation `o` (`o = o_free + C_o λ`) through `add(r, j, value)`
    /// (observation row `r` of 3, frame column `j`); `starts` are the groups' first rows.
    fn add_observation_rows(
        &self,
        o: &Observation,
        starts: &[usize],
        mut add: impl FnMut(usize, usize, f64),
    ) {
        for (hi, h) in self.groups.iter().enumerate() {
            for b in h.attachments.iter().filter(|b| b.model == o.model) {
                let gob = self.store(o.model).cols(b.point).gather(&o.map);
                let blk = b.sign * o.a * gob * b.d.transpose();
                for r in 0..3 {
                    for c in 0..b.rows {
                        add(r, starts[hi] + b.row_offset + c, blk[(r, c)]);
                    }
                }
            }
        }
    }

    /// Writes the frame's obstacle clearances (call after [`Self::fill_frame`]): for each
    /// [`ClearanceObservation`] (at most `NCLEAR`), the clearance linearised at the start of the
    /// step (`p₀ − s₀`, where the step ends up: the needle moves little per step) along its
    /// normal `n` — for a sphere the distance `|p − c| − r` of the needle point `p` to the centre
    /// `c`, `n = (p₀ − c₀)/|p₀ − c₀|`; for a mesh the signed distance to the closest surface
    /// point `s`, `n` along the closest pair:
    /// `d_free = d₀ + nᵀ ((p_free − s_free) − (p₀ − s₀))` and
    /// `clearance_c = nᵀ (C_p − C_s)`. (Linearised at the free motion instead, the rows fail
    /// where the unconstrained needle's free motion carries `p` through the obstacle: `n` is
    /// then meaningless, and the prediction was 4 mm off on `obstacles_tight`.)
    pub fn fill_clearances<const M: usize, const N: usize>(
        &self,
        clearances: &[ClearanceObservation],
        frame: &mut ComplianceFrame<M, N>,
    ) {
        let m = self.rows().min(M);
        let starts = self.starts();
        let count = clearances.len().min(NCLEAR);
        frame.clearance_count = count as u32;
        frame.reserved = 0;
        for (k, cl) in clearances.iter().take(count).enumerate() {
            let n = cl.normal;
            let mut free = cl.needle.free;
            for o in &cl.obstacle {
                free -= o.free;
            }
            frame.clearance_free[k] = cl.clearance + n.dot(&(free - cl.current));
            let row = &mut frame.clearance_c[k];
            row[..m].fill(0.0);
            self.add_observation_rows(&cl.needle, &starts, |r, j, v| row[j] += n[r] * v);
            for o in &cl.obstacle {
                self.add_observation_rows(o, &starts, |r, j, v| row[j] -= n[r] * v);
            }
        }
        for k in count..NCLEAR {
            frame.clearance_free[k] = 0.0;
            frame.clearance_c[k][..m].fill(0.0);
        }
    }
}

/// `Kind::X as u32` for building row groups.
pub fn group(kind: GroupKind, mu: f64, r0: f64) -> RowGroup {
    RowGroup {
        kind: kind as u32,
        start: 0,
        len: 0,
        reserved: 0,
        mu,
        r0,
    }
}

/// Two unit vectors completing `t` (unit) into a right-handed orthonormal frame, chosen
/// continuously: the first is `t × a` for the world axis `a` least aligned with `t`.
pub fn orthonormal_pair(t: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let a = if t.x.abs() <= t.y.abs() && t.x.abs() <= t.z.abs() {
        Vector3::x()
    } else if t.y.abs() <= t.z.abs() {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let u = t.cross(&a).normalize();
    let v = t.cross(&u);
    (u, v)
}

/// The skew matrix `[v]×` with `[v]× x = v × x`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    fn spd(n: usize, seed: usize) -> DMatrix<f64> {
        let a = DMatrix::from_fn(n, n, |i, j| {
            (((i + seed) * 7 + j * 13) % 11) as f64 / 11.0 - 0.4
        });
        &a * a.transpose() + DMatrix::identity(n, n) * n as f64
    }

    fn dense_p(m: &PointMap, n: usize) -> DMatrix<f64> {
        let mut d = DMatrix::zeros(3, n);
        for &(b, w) in m.used() {
            for r in 0..3 {
                d[(r, b + r)] += w;
            }
        }
        d
    }

    /// A base group and a sliding group on a needle tip point and a gel point; returns the set
    /// and the tip's point index.
    fn sample_set() -> (ConstraintSet, usize) {
        let mut set = ConstraintSet::default();
        let base_t = set.needle.push(PointMap::single(0));
        let base_r = set.needle.push(PointMap::single(3));
        let tip = set
            .needle
            .push(PointMap::weighted([(Some(6), 0.25), (Some(9), 0.75)]));
        let gp = set.gel.push(PointMap::weighted([
            (Some(0), 0.1),
            (Some(6), 0.2),
            (Some(12), 0.3),
            (Some(15), 0.4),
        ]));
        let eye = Matrix3::identity();
        set.groups.push(ConstraintGroup {
            kind: group(GroupKind::Bilateral, 0.0, 0.0),
            role: GroupRole::Base,
            rows: 6,
            attachments: vec![
                Attachment {
                    model: Model::Needle,
                    point: base_t,
                    row_offset: 0,
                    rows: 3,
                    d: eye,
                    sign: 1.0,
                },
                Attachment {
                    model: Model::Needle,
                    point: base_r,
                    row_offset: 3,
                    rows: 3,
                    d: eye,
                    sign: 1.0,
                },
            ],
            delta: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
        });
        let t = Vector3::new(0.3, -0.2, 0.9).normalize();
        let (u, v) = orthonormal_pair(&t);
        let d = Matrix3::from_rows(&[u.transpose(), v.transpose(), t.transpose()]);
        set.groups.push(ConstraintGroup {
            kind: group(GroupKind::Sliding, 0.1, 0.0),
            role: GroupRole::Sliding(0),
            rows: 3,
            attachments: vec![
                Attachment {
                    model: Model::Needle,
                    point: tip,
                    row_offset: 0,
                    rows: 3,
                    d,
                    sign: 1.0,
                },
                Attachment {
                    model: Model::Gel,
                    point: gp,
                    row_offset: 0,
                    rows: 3,
                    d,
                    sign: -1.0,
                },
            ],
            delta: [0.0; 6],
        });
        (set, tip)
    }

    /// The dense `H_n`, `H_v` of `set` on `nn` needle and `nv` gel dofs.
    fn dense_h(set: &ConstraintSet, nn: usize, nv: usize) -> (DMatrix<f64>, DMatrix<f64>) {
        let m = set.rows();
        let mut hn = DMatrix::zeros(m, nn);
        let mut hv = DMatrix::zeros(m, nv);
        let starts = set.starts();
        for (gi, g) in set.groups.iter().enumerate() {
            for a in &g.attachments {
                let (store, h, n) = match a.model {
                    Model::Needle => (&set.needle, &mut hn, nn),
                    Model::Gel => (&set.gel, &mut hv, nv),
                };
                let blk = a.sign * a.d * dense_p(&store.points[a.point].map, n);
                for r in 0..a.rows {
                    for c in 0..n {
                        h[(starts[gi] + a.row_offset + r, c)] += blk[(r, c)];
                    }
                }
            }
        }
        (hn, hv)
    }

    /// Columns computed in batches are each point's own, and cached ones are kept.
    #[test]
    fn batched_columns_are_each_points_own() {
        let n = 12;
        let ki = spd(n, 3).try_inverse().unwrap();
        let calls = std::cell::Cell::new(Vec::new());
        let solve = |rhs: &mut [f64], cols: usize| -> Result<(), ()> {
            let mut c = calls.take();
            c.push(cols);
            calls.set(c);
            for c in 0..cols {
                let b = DVector::from_column_slice(&rhs[c * n..(c + 1) * n]);
                rhs[c * n..(c + 1) * n].copy_from_slice((&ki * b).as_slice());
            }
            Ok(())
        };
        let mut store = PointStore::default();
        for i in 0..5 {
            store.push(PointMap::weighted([
                (Some(3 * (i % 4)), 0.3),
                (Some(3), 0.1 * i as f64),
            ]));
        }
        // Point 1 already has columns: they stay as they are.
        let kept = PointColumns::compute(&store.points[1].map, n, solve).unwrap();
        store.points[1].cols = Some(kept.clone());
        calls.set(Vec::new());
        assert_eq!(store.compute_missing_in_batches(n, 2, solve), Ok(4));
        assert_eq!(calls.take(), vec![6, 6]);
        for (i, p) in store.points.iter().enumerate() {
            let alone = PointColumns::compute(&p.map, n, solve).unwrap();
            assert_eq!(p.cols.as_ref(), Some(&alone), "point {i}");
        }
        assert_eq!(store.points[1].cols.as_ref(), Some(&kept));
        // Nothing missing: no call.
        calls.set(Vec::new());
        assert_eq!(store.compute_missing_in_batches(n, 2, solve), Ok(0));
        assert!(calls.take().is_empty());
    }

    /// The frame's W, C and the correction equal the dense `H K⁻¹ Hᵀ` algebra.
    #[test]
    fn frame_blocks_match_dense_algebra() {
        let (nn, nv) = (12, 18);
        let (kn, kv) = (spd(nn, 1), spd(nv, 2));
        let (kni, kvi) = (
            kn.clone().try_inverse().unwrap(),
            kv.clone().try_inverse().unwrap(),
        );
        let (mut set, tip) = sample_set();
        let eye = Matrix3::identity();
        let solve = |ki: &DMatrix<f64>, n: usize| {
            let ki = ki.clone();
            move |rhs: &mut [f64], cols: usize| -> Result<(), ()> {
                for c in 0..cols {
                    let b = DVector::from_column_slice(&rhs[c * n..(c + 1) * n]);
                    rhs[c * n..(c + 1) * n].copy_from_slice((&ki * b).as_slice());
                }
                Ok(())
            }
        };
        set.needle.compute_missing(nn, solve(&kni, nn)).unwrap();
        set.gel.compute_missing(nv, solve(&kvi, nv)).unwrap();

        let m = set.rows();
        let (hn, hv) = dense_h(&set, nn, nv);
        let w_dense = &hn * &kni * hn.transpose() + &hv * &kvi * hv.transpose();

        let tip_dir = Vector3::new(0.0, 0.0, 1.0);
        let obs = [
            Observation {
                model: Model::Needle,
                map: set.needle.points[tip].map,
                a: eye,
                free: Vector3::x(),
            },
            Observation {
                model: Model::Needle,
                map: PointMap::single(9),
                a: -skew(&tip_dir),
                free: tip_dir,
            },
            Observation {
                model: Model::Gel,
                map: PointMap::single(3),
                a: eye,
                free: Vector3::y(),
            },
            Observation {
                model: Model::Gel,
                map: PointMap::single(6),
                a: eye,
                free: Vector3::z(),
            },
            Observation {
                model: Model::Gel,
                map: PointMap::weighted([(Some(9), 0.5), (Some(12), 0.5)]),
                a: eye,
                free: Vector3::zeros(),
            },
        ];
        let mut frame = Box::new(std::mem::MaybeUninit::<ComplianceFrame<16>>::uninit());
        let frame = ComplianceFrame::init_in_place(&mut frame);
        set.fill_frame(&obs, frame);
        assert_eq!(frame.m as usize, m);
        for i in 0..m {
            for j in 0..m {
                assert!(
                    (frame.w[i][j] - w_dense[(i, j)]).abs() < 1e-13,
                    "W[{i}][{j}]"
                );
            }
        }
        for (k, o) in obs.iter().enumerate() {
            let (h, ki, n) = match o.model {
                Model::Needle => (&hn, &kni, nn),
                Model::Gel => (&hv, &kvi, nv),
            };
            let c = o.a * dense_p(&o.map, n) * ki * h.transpose();
            for r in 0..3 {
                for j in 0..m {
                    assert!(
                        (frame.c[3 * k + r][j] - c[(r, j)]).abs() < 1e-13,
                        "C obs {k} row {r} col {j}"
                    );
                }
            }
        }
        let lambda: Vec<f64> = (0..m).map(|i| 0.1 * i as f64 - 0.3).collect();
        let (mut dxn, mut dxv) = (vec![0.0; nn], vec![0.0; nv]);
        crate::step::correct::add_correction(&set, &lambda, &mut dxn, &mut dxv);
        let l = DVector::from_vec(lambda);
        assert!((DVector::from_vec(dxn) - &kni * hn.transpose() * &l).norm() < 1e-13);
        assert!((DVector::from_vec(dxv) - &kvi * hv.transpose() * &l).norm() < 1e-13);
    }

    #[test]
    fn orthonormal_pair_is_right_handed() {
        for t in [
            Vector3::z(),
            -Vector3::z(),
            Vector3::new(0.3, -0.2, 0.9).normalize(),
            Vector3::x(),
        ] {
            let (u, v) = orthonormal_pair(&t);
            assert!(u.dot(&t).abs() < 1e-15 && v.dot(&t).abs() < 1e-15 && u.dot(&v).abs() < 1e-15);
            assert!((u.cross(&v) - t).norm() < 1e-15);
        }
    }
}
