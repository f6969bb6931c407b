//! Constraint solve: projected **block** Gauss-Seidel on `w = W λ − δ` (paper §III-D, step 4).
//!
//! Rows come in groups (see [`GroupKind`]); each sweep visits the groups in order and solves each
//! group's local problem exactly with the other groups' forces fixed:
//!
//! * bilateral (1…6 rows, e.g. the 6 needle-base rows): `λ_g ← λ_g − W_gg⁻¹ w_g` (`w_g = 0`);
//! * unilateral row: `λ ← max(0, λ − w / W_ii)`;
//! * contact `[n, t1, t2]` with Coulomb friction: the normal row as a unilateral row, then the
//!   tangential pair as the disk-constrained problem `min ½ xᵀ W_tt x + gᵀ x, |x| ≤ μ λ_n` solved
//!   exactly (a 2-D trust-region problem, secular equation by Newton). Its optimality conditions
//!   are the sliding law (`w_t` opposite to `λ_t` on the disk edge), so fixed points of the sweep
//!   are Coulomb solutions — a Euclidean projection after a `W_tt⁻¹` step would not be;
//! * sliding point `[l1, l2, axial]`: the lateral pair as a bilateral 2×2 block, then the axial
//!   row clamped to `|λ_a| ≤ μ_n |λ_l| + r_0`.
//!
//! The block inverses are computed once per frame by [`BlockGs::prepare`] and reused by every
//! solve of the step. `w` is kept up to date with row updates (`W` symmetric: column = row, a
//! contiguous `axpy`), so one sweep costs `m²` multiply-adds.
//!
//! The stopping test is the largest `|W_ii Δλ_i|` of a sweep relative to the problem scale
//! (`‖δ‖∞`); running out of iterations is reported, not an error. Optionally, when the problem has
//! only bilateral and unilateral rows (no contact friction, no sliding point, whose rows are
//! bounded rather than equalities), a **polish** solves the equality system of the active set found by GS
//! (bilateral rows and unilateral rows with `λ > 0`) by conjugate gradients and updates the active
//! set primal-dual style until the LCP conditions hold to round-off; the polish result is kept
//! only if it is feasible, otherwise the GS iterate is returned.
//!
//! Files by verb: `prepare.rs` (block factors, once per frame), `sweep.rs` (the solve loop and
//! the group updates of one sweep), `project.rs` (the 2×2 blocks and the friction-disk
//! projection), `polish.rs` (active-set polish of frictionless problems), `active_set.rs` (the
//! dense factor of the free rows and its response to the base rows).

mod active_set;
mod polish;
mod prepare;
mod project;
mod sweep;

pub use active_set::ActiveSet;
pub(crate) use sweep::{BatchStart, GsBatch};

/// Tuning of one constraint solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GsParams {
    /// Stop when the largest `|W_ii Δλ_i|` of a sweep is below `tolerance · ‖δ‖∞` [-].
    pub tolerance: f64,
    /// Largest number of sweeps.
    pub max_iterations: u32,
    /// Polish frictionless problems on the active set (see the module docs).
    pub polish: bool,
    /// Over-relaxation ω of the bilateral, unilateral and sliding updates (projected SOR;
    /// 1 = plain Gauss-Seidel, useful range 1…1.5). The fixed point — the solution — does not
    /// depend on ω; contact (Coulomb) groups always use ω = 1.
    pub relaxation: f64,
}

impl Default for GsParams {
    fn default() -> Self {
        Self {
            tolerance: 1e-7,
            max_iterations: 400,
            polish: false,
            relaxation: 1.0,
        }
    }
}

/// Outcome of one constraint solve.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SolveReport {
    /// Sweeps performed.
    pub iterations: u32,
    /// Largest `|W_ii Δλ_i|` of the last sweep over the problem scale [-] (0 after a polish).
    pub residual: f64,
    /// Whether the tolerance was reached (or the polish succeeded).
    pub converged: bool,
    /// Whether the result comes from the active-set polish.
    pub polished: bool,
}

/// Raw group kinds as stored in [`Block::kind`] (the values of [`crate::payload::GroupKind`]).
const KIND_BILATERAL: u8 = 1;
const KIND_UNILATERAL: u8 = 2;
const KIND_CONTACT: u8 = 3;
const KIND_SLIDING: u8 = 4;

/// One row group as the sweep reads it (kind, rows, friction law).
#[derive(Clone, Copy, Debug, Default)]
struct Block {
    kind: u8,
    len: u8,
    start: u32,
    mu: f64,
    r0: f64,
}

/// Projected block Gauss-Seidel solver with capacity `M` rows; owns the per-frame block factors
/// and the solve scratch (no allocation).
#[derive(Clone, Debug)]
pub struct BlockGs<const M: usize> {
    m: usize,
    n_blocks: usize,
    /// A contact or sliding group is present: rows with bounds, out of the polish's reach.
    frictional: bool,
    blocks: [Block; M],
    /// Per block, at row `start`: packed factors (≤ 6 values per row of the block).
    factors: [[f64; 6]; M],
    diag: [f64; M],
    w: [f64; M],
    scratch: [[f64; M]; 4],
    active: [u8; M],
}

crate::zeroed::impl_zeroable!(GsParams {
    tolerance,
    max_iterations,
    polish,
    relaxation
});
crate::zeroed::impl_zeroable!(Block {
    kind,
    len,
    start,
    mu,
    r0
});
crate::zeroed::impl_zeroable!(BlockGs<const M> {
    m,
    n_blocks,
    frictional,
    blocks,
    factors,
    diag,
    w,
    scratch,
    active,
});

impl<const M: usize> Default for BlockGs<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const M: usize> BlockGs<M> {
    /// An empty solver (no frame prepared: solves return at once).
    pub const fn new() -> Self {
        Self {
            m: 0,
            n_blocks: 0,
            frictional: false,
            blocks: [Block {
                kind: 0,
                len: 0,
                start: 0,
                mu: 0.0,
                r0: 0.0,
            }; M],
            factors: [[0.0; 6]; M],
            diag: [0.0; M],
            w: [0.0; M],
            scratch: [[0.0; M]; 4],
            active: [0; M],
        }
    }

    /// Rows of the prepared problem.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// The residual `w = W λ − δ` of the last solve (rows `0..m`).
    pub fn last_residual(&self) -> &[f64] {
        &self.w[..self.m]
    }
}

/// Number of needle-base rows, first in every frame.
const BASE: usize = crate::payload::BASE_ROWS;
