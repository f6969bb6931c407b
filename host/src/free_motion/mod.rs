//! Free motion (paper §III-D, step 1): one Newton iteration of static equilibrium per step,
//!
//! ```text
//! (K(x) + M/h²) Δx_free = f_ext − f_int(x)
//! ```
//!
//! for the gel ([`GelModel`], corotational tetrahedra, 3 dofs per node) and the needle
//! ([`NeedleModel`], corotational beams, 6 dofs per node) — two separate sparse systems, one
//! model type: [`FeModel`] holds the node positions, the reduced system and the free motion;
//! its [`Elements`] ([`Tets`], [`Beams`]) hold what differs.
//!
//! - `K` is assembled into a sparse symmetric matrix whose pattern is built once, with a map
//!   from every element-local entry to its value slot, so a step only writes values.
//! - Dirichlet dofs (fixed gel nodes, a clamped needle base) are *eliminated*: the system has
//!   one row per free dof; their displacement is zero and [`FeModel::solve`] returns zero there.
//! - The `M/h²` term (lumped mass, pseudo time step `h`) makes each step a quasi-static
//!   implicit step: a Newton step damped by the inertia of one time step. For the gel it is
//!   optional (`time_step: None` gives the pure static Newton step of the paper). For the
//!   needle it is what makes the system solvable: the needle hangs only on the base constraint
//!   χ (Lagrange multipliers, not a Dirichlet condition), so its `K_n` alone has the six
//!   rigid-body modes in its kernel. `M/h²` with the physical lumped mass (`ρAℓ/2`) and an
//!   isotropic rotary inertia (`ρ(I_y+I_z)ℓ/2`) restrains those modes by the smallest honest
//!   amount — the inertia of one step — instead of an arbitrary penalty, leaves the static
//!   equilibrium unchanged (`Δx → 0` at equilibrium) and keeps `K_n + M/h²` symmetric positive
//!   definite for the Cholesky factorisation. The compliance `K⁻¹` is then large but finite
//!   along the rigid modes, which is physically right: the base constraint moves the needle.
//! - The symbolic factorisation is done once; the numeric one every step, or every
//!   `refactor_every` steps (the matrix is then a few steps old: cheaper, a less exact Newton
//!   step), or when [`FeModel::request_refactor`] is called.
//! - **Background factorisation** (`GelParams::background_factorization`): the numeric
//!   factorisation runs on a second thread while the steps go on. With `refactor_every = r`, a
//!   matrix assembled at step k is factorised during steps k … k + r − 1 and used from step
//!   k + r for r steps (r = 1: every step solves with the matrix of the step before). The
//!   right-hand side `f_ext − f_int(x)` is exact, so the equilibrium reached is the same; the
//!   Newton matrix is a few steps old. The first step, a requested refactorisation, a failed
//!   background factorisation, and a step whose elements rotated more than
//!   [`LAG_ROTATION_LIMIT`] since the matrix in use factorise at once. The worker owns a second
//!   factor buffer; the two are swapped, nothing is allocated per step.
//! - **Adaptive refresh** (`GelParams::refresh`, [`RefreshParams`]): in that pipeline a step
//!   sends its matrix to the idle worker only when the factor in use is stale — an element has
//!   rotated by `rotation` or more since its matrix, or that matrix is `ceiling` steps old — so
//!   no factorisation is spent while the tangent does not change. A job is still waited for
//!   `refactor_every` steps after its matrix: runs repeat bit for bit.
//! - **Preconditioned CG** (`GelParams::pcg`, the asynchronous preconditioner of Courtecuisse
//!   et al.): every step assembles its own matrix `A = K(x) + M/h²` and solves the exact Newton
//!   system by conjugate gradients ([`crate::linalg::pcg_solve`]: matrix-vector products with
//!   `A`, the factor in use as preconditioner) to a relative residual tolerance, within an
//!   iteration cap. The factor is refreshed from a step's matrix at most every `refactor_every`
//!   steps: sent to the worker when it is idle, and put in use at the start of the first step
//!   after it finished — the step never waits for it (without background thread it is
//!   factorised at once, after the solve). The first step, a requested refactorisation, and a
//!   step whose CG does not converge within the cap (or breaks down) factorise their own matrix
//!   at once and solve directly. The compliance and the corrective motion use the factor in use
//!   as the approximation of `K⁻¹` (consistent with each other, as before); no rotation guard
//!   is needed, since CG solves the current matrix. Which factor a step uses depends on the
//!   worker's timing: runs are not bit-for-bit repeatable in this mode.
//!   The free motion with `A` and the correction with `F` do not cancel: every step carries
//!   `(F⁻¹ − A⁻¹) Hᵀλ`, a share of the whole constraint force (see `docs/architecture.md`).
//! - **Refined step** (`GelParams::refine`): the direct mode's step, free motion, compliance and
//!   correction all with the factor in use `F`, then the gel's whole step `F⁻¹ g` (`g` the net
//!   force, free plus constraint) replaced by `A⁻¹ g` with the step's own matrix `A`, by CG from
//!   it preconditioned by `F` ([`FeModel::refine_step`], called by the corrective motion). The
//!   stale factor then errs only on the net force, as in the pipeline.
//! - All buffers are allocated at construction.
//!
//! Files: `system.rs` (the reduced system and its solves), `background.rs` (the factorisation
//! thread and its rotation guard), `gel.rs` and `needle.rs` (the elements and constructors).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]
// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

mod background;
mod gel;
mod needle;
mod system;

pub use background::{LAG_ROTATION_LIMIT, RefreshParams};
pub use gel::{FillOrdering, GelModel, GelParams, RegionMaterial, Tets};
pub use needle::{Beams, NeedleModel, NeedleParams};
pub use system::{PcgParams, PcgStats};

use crate::fem::FemError;
use crate::linalg::{PcgOutcome, Precision, SymmetricMatrix};
use background::LagGuard;
use nalgebra::{Matrix3, Vector3};
use system::{NearRefresh, ReducedSystem, SystemLayout};

/// The elements of an [`FeModel`]: what the gel's tetrahedra and the needle's beams do
/// differently — internal forces, assembly, how an increment moves the nodes.
pub trait Elements {
    /// Dofs per node: 3 (translation [mm]) or 6 (translation [mm], then a world-frame rotation
    /// increment [rad]).
    const NODE_DOFS: usize;

    /// Whether [`Elements::add_internal_forces`] is a function of the node positions alone
    /// (the tetrahedra: yes; the beams also carry node orientations). Then a model whose
    /// positions are bit for bit those of its last element pass skips the pass, and an
    /// unloaded free motion with the same factor is the last one (see
    /// [`FeModel::free_motion_unloaded`]).
    const STATE_OF_POSITIONS: bool = false;

    /// Updates the element frames at the node `positions` [mm] and adds the internal forces
    /// `f_int(x)` (`NODE_DOFS` per node) [N, N·mm] into `f_int`, which the caller zeroed.
    fn add_internal_forces(&mut self, positions: &[Vector3<f64>], f_int: &mut [f64]);

    /// The `(row, column)` global dofs of every stiffness entry, element after element, in the
    /// order [`Elements::assemble`] writes them (the assembly's slot map follows this order).
    fn entry_dofs(&self) -> impl Iterator<Item = (usize, usize)> + '_;

    /// Adds the element stiffness `K(x)` of the last update into the matrix `values` through
    /// the entry `slots` (`u32::MAX`: an entry on a fixed dof).
    fn assemble(&self, slots: &[u32], values: &mut [f64]);

    /// Adds, for each element of `elements`, its stiffness at its current rotation minus its
    /// stiffness at rotation `from[e]` into `values` (the change of the assembled matrix when
    /// those elements turn from `from` to now). Only elements with rotations implement it (the
    /// near block of the gel); the default adds nothing.
    fn add_rotation_change(
        &self,
        _slots: &[u32],
        _values: &mut [f64],
        _elements: &[usize],
        _from: &[Matrix3<f64>],
    ) {
    }

    /// Moves the nodes by the increment `dx` (global dofs), ignoring the dofs `free` rejects.
    fn displace(
        &mut self,
        positions: &mut [Vector3<f64>],
        dx: &[f64],
        free: &dyn Fn(usize) -> bool,
    );

    /// The element rotations of the last update, for the guard of the background
    /// factorisation (empty: no guard).
    fn rotations(&self) -> &[Matrix3<f64>] {
        &[]
    }
}

/// A finite-element model: node positions, its [`Elements`], and the reduced sparse system
/// `K + M/h²` it steps with. [`GelModel`] and [`NeedleModel`] are its two instances.
#[derive(Debug)]
pub struct FeModel<E: Elements> {
    elements: E,
    positions: Vec<Vector3<f64>>,
    sys: ReducedSystem,
    slots: Vec<u32>,
    f_int: Vec<f64>,
    dx: Vec<f64>,
    /// Background mode: the rotation guard.
    lag: Option<LagGuard>,
    /// With [`Elements::STATE_OF_POSITIONS`]: the positions of the last element pass (empty
    /// before it), to skip a pass at the same positions.
    pass_positions: Vec<Vector3<f64>>,
    /// The stamp of the factor the last unloaded free motion `dx` was solved with, while the
    /// element state it was solved from is still current (`None`: no such solve).
    unloaded_solve: Option<(u64, bool)>,
    /// Unloaded free motions that repeated the last one without a solve.
    repeated: u64,
    /// Steps whose deferred far rows were finished before the constraint solve
    /// ([`FeModel::record_deferral_fallback`]).
    deferral_fallbacks: u64,
}

/// Which dofs a model fixes, its regularisation, and its system settings.
struct ModelLayout<'a> {
    fixed_nodes: &'a [usize],
    regularization: Vec<f64>,
    refactor_every: usize,
    dof_coords: Option<&'a [[f64; 3]]>,
    background: bool,
    /// [`GelParams::asynchronous_factor`].
    asynchronous: bool,
    pcg: Option<PcgParams>,
    refine: Option<PcgParams>,
    refresh: Option<RefreshParams>,
    precision: Precision,
    /// The near block and its entry block (see [`GelParams::near_nodes`]); `None`: no block.
    near: Option<NearLayout>,
}

/// Global dofs of the near block and the elements all of whose nodes are near, and the same
/// for the entry block inside it (empty: none; see [`GelParams::entry_nodes`]).
struct NearLayout {
    dofs: Vec<bool>,
    elements: Vec<bool>,
    entry_dofs: Vec<bool>,
    entry_elements: Vec<bool>,
    /// [`GelParams::far_residual_tolerance`].
    far_residual_tolerance: f64,
    /// [`GelParams::defer_far`].
    defer_far: bool,
}

impl<E: Elements> FeModel<E> {
    /// Builds the model: the fixed-dof mask (all dofs of each fixed node), the reduced system
    /// and its buffers.
    fn build(
        elements: E,
        positions: Vec<Vector3<f64>>,
        layout: ModelLayout<'_>,
    ) -> Result<Self, FemError> {
        let (n, d) = (positions.len(), E::NODE_DOFS);
        let mut fixed = vec![false; d * n];
        for &node in layout.fixed_nodes {
            if node >= n {
                return Err(FemError::FixedNodeOutOfRange {
                    node,
                    node_count: n,
                });
            }
            fixed[d * node..d * node + d].fill(true);
        }
        let (sys, slots) = ReducedSystem::try_new(SystemLayout {
            fixed: &fixed,
            entries: || elements.entry_dofs(),
            regularization: &layout.regularization,
            refactor_every: layout.refactor_every,
            dof_coords: layout.dof_coords,
            background: layout.background,
            asynchronous: layout.asynchronous,
            pcg: layout.pcg,
            refine: layout.refine,
            refresh: layout.refresh,
            precision: layout.precision,
            near_dofs: layout.near.as_ref().map(|n| n.dofs.as_slice()),
            entry_dofs: (layout.near.as_ref())
                .map(|n| n.entry_dofs.as_slice())
                .filter(|d| !d.is_empty()),
            far_residual_tolerance: layout
                .near
                .as_ref()
                .map_or(0.0, |n| n.far_residual_tolerance),
            defer_far: layout.near.as_ref().is_some_and(|n| n.defer_far),
        })?;
        // CG solves the current matrix: no rotation guard on the factor's age.
        let (near_elements, entry_elements) = match layout.near {
            Some(n) if sys.has_near() => (n.elements, n.entry_elements),
            _ => (Vec::new(), Vec::new()),
        };
        let lag = (layout.background && layout.pcg.is_none())
            .then(|| LagGuard::new(elements.rotations().len(), near_elements, entry_elements));
        Ok(Self {
            elements,
            positions,
            sys,
            slots,
            f_int: vec![0.0; d * n],
            dx: vec![0.0; d * n],
            lag,
            pass_positions: Vec::new(),
            unloaded_solve: None,
            deferral_fallbacks: 0,
            repeated: 0,
        })
    }

    /// The elements.
    pub fn elements(&self) -> &E {
        &self.elements
    }

    /// The precision of the factor in use (`Double` after a fallback) and how many
    /// single-precision factorisations failed their check and were redone in double.
    pub fn factor_precision(&self) -> (Precision, u64) {
        self.sys.factor_precision()
    }

    /// Current node positions [mm].
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of dofs (`NODE_DOFS` per node).
    pub fn dof_count(&self) -> usize {
        E::NODE_DOFS * self.positions.len()
    }

    /// Number of free (non-eliminated) dofs: the size of the sparse system.
    pub fn free_dof_count(&self) -> usize {
        self.sys.free.len()
    }

    /// Whether global dof `dof` is eliminated (Dirichlet).
    pub fn is_fixed_dof(&self, dof: usize) -> bool {
        self.reduced_index(dof).is_none()
    }

    /// Reduced index of global dof `dof`, `None` if it is fixed.
    pub fn reduced_index(&self, dof: usize) -> Option<usize> {
        self.sys
            .dof_map
            .get(dof)
            .and_then(|&m| (m != system::SKIP).then_some(m as usize))
    }

    /// First global dof of `node` when its first dof is free (a free gel node; every needle
    /// node), `None` when it is fixed.
    pub fn node_dof(&self, node: usize) -> Option<usize> {
        let g = E::NODE_DOFS * node;
        self.sys.is_free(g).then_some(g)
    }

    /// The identity of the factor in use ([`crate::linalg::Cholesky::stamp`]): equal stamps,
    /// the same factor.
    pub fn factor_stamp(&self) -> u64 {
        self.sys.factor_stamp()
    }

    /// Steps since the last numeric factorisation (`None` before the first).
    pub fn factor_age(&self) -> Option<usize> {
        self.sys.factor_age
    }

    /// Forces a numeric refactorisation at the next [`FeModel::free_motion`].
    pub fn request_refactor(&mut self) {
        self.sys.refactor_requested = true;
    }

    /// The assembled reduced matrix `K + M/h²` of the last factorisation (free dofs only).
    pub fn matrix(&self) -> &SymmetricMatrix {
        &self.sys.matrix
    }

    /// Refactorisations of the near block so far ([`GelParams::near_nodes`]; 0 without one).
    pub fn near_refactorizations(&self) -> u64 {
        self.sys.near_refreshes()
    }

    /// Refactorisations of the entry block alone so far ([`GelParams::entry_nodes`]; 0 without
    /// one).
    pub fn entry_refactorizations(&self) -> u64 {
        self.sys.entry_refreshes()
    }

    /// Free motions solved with their far residual dropped
    /// ([`GelParams::far_residual_tolerance`]; 0 without a near block or with `τ = 0`).
    pub fn far_residual_drops(&self) -> u64 {
        self.sys.far_residual_drops()
    }

    /// Whether the factor has a near block ([`GelParams::near_nodes`]): the option was given
    /// and the factor allows it.
    pub fn has_near_block(&self) -> bool {
        self.sys.has_near()
    }

    /// Factorisations so far: (finished in the background and used, made at once) — `None`
    /// without background factorisation.
    pub fn background_counts(&self) -> Option<(u64, u64)> {
        self.sys
            .background
            .as_ref()
            .map(|b| (b.adopted, b.immediate))
    }

    /// Preconditioned-CG mode: its counts (iterations, fallbacks, the last step's outcome);
    /// `None` with the direct solve.
    pub fn pcg_stats(&self) -> Option<PcgStats> {
        (self.sys.pcg.as_ref().map(|p| p.stats))
            .or_else(|| self.sys.refine.as_ref().map(|r| r.stats))
    }

    /// Background mode: the largest rotation of an element between the matrix of the factor the
    /// last free motion used and its positions [rad] (0 when it factorised at once, and
    /// without background factorisation).
    pub fn lag_rotation(&self) -> f64 {
        self.lag.as_ref().map_or(0.0, |g| g.lag)
    }

    /// Updates the element frames and returns the internal forces `f_int(x)` at the current
    /// positions (including at fixed nodes, where they are the reactions) [N, N·mm].
    pub fn compute_internal_forces(&mut self) -> &[f64] {
        self.update_elements();
        &self.f_int
    }

    /// The element pass: element frames and `f_int` at the current positions, skipped when
    /// the state is a function of the positions and they are bit for bit those of the last
    /// pass (its frames and forces are then exactly what the pass would give).
    fn update_elements(&mut self) {
        if E::STATE_OF_POSITIONS && same_bits(&self.pass_positions, &self.positions) {
            return;
        }
        self.f_int.iter_mut().for_each(|v| *v = 0.0);
        self.elements
            .add_internal_forces(&self.positions, &mut self.f_int);
        if E::STATE_OF_POSITIONS {
            self.pass_positions.clone_from(&self.positions);
        }
        self.unloaded_solve = None;
    }

    /// Element update and assembly: internal forces and the values of `K(x) + M/h²` written
    /// into the fixed pattern (no factorisation).
    pub fn assemble(&mut self) {
        self.compute_internal_forces();
        let (elements, slots) = (&self.elements, &self.slots);
        self.sys.write_values(|v| elements.assemble(slots, v));
    }

    /// Numeric factorisation of the matrix last written by [`FeModel::assemble`] (resets the
    /// factor age).
    ///
    /// # Errors
    /// [`FemError::NotPositiveDefinite`].
    pub fn factorize(&mut self) -> Result<(), FemError> {
        self.sys.factorize()
    }

    /// [`FeModel::assemble`] then [`FeModel::factorize`], whatever the reuse setting.
    ///
    /// # Errors
    /// [`FemError::NotPositiveDefinite`].
    pub fn refactor(&mut self) -> Result<(), FemError> {
        self.assemble();
        self.factorize()
    }

    /// One free-motion step: updates the elements and the internal forces, refactorises if due
    /// (or adopts the background factor), and solves `(K + M/h²) Δx_free = f_ext − f_int(x)`,
    /// with `f_ext` dead loads (`NODE_DOFS` per node, world frame) [N, N·mm]. Returns `Δx_free`
    /// (zero at fixed dofs); the positions are *not* changed (see
    /// [`FeModel::apply_displacement`]).
    ///
    /// # Errors
    /// Wrong length or non-finite `f_ext`, a failed factorisation, or a stopped background
    /// thread.
    pub fn free_motion(&mut self, f_ext: &[f64]) -> Result<&[f64], FemError> {
        check_vec("external loads", f_ext, self.dof_count())?;
        self.free_motion_with(Some(f_ext), false)
    }

    /// [`FeModel::free_motion`] without external load (the needle and the gel of an insertion:
    /// every force comes through the constraints).
    ///
    /// For the gel ([`Elements::STATE_OF_POSITIONS`]), in the direct mode: when the positions
    /// are bit for bit those of the last unloaded free motion and the factor in use is the
    /// same, the right-hand side `−f_int(x)` and the solve are the same too, and the last
    /// `Δx_free` is returned without an element pass or a solve
    /// ([`FeModel::repeated_free_motions`] counts them). The factor's pipeline still counts the
    /// step. A gel at its rest positions has exactly zero internal force, so before the needle
    /// touches it every step is such a repeat.
    ///
    /// # Errors
    /// A failed factorisation, or a stopped background thread.
    pub fn free_motion_unloaded(&mut self) -> Result<&[f64], FemError> {
        self.free_motion_with(None, false)
    }

    /// Whether [`FeModel::free_motion_deferring_far`] can be used: a near block, the direct
    /// solve and [`GelParams::defer_far`].
    pub fn defers_far(&self) -> bool {
        self.sys.deferral().is_some()
    }

    /// Whether the deferred solves ([`FeModel::free_motion_deferring_far`],
    /// [`FeModel::solve_columns_near`]) are exact on global dof `dof`: the dofs eliminated from
    /// the near block's first supernode on, and the fixed ones. `false` without deferral.
    pub fn is_deferral_exact(&self, dof: usize) -> bool {
        self.sys.is_deferral_exact(dof)
    }

    /// [`FeModel::free_motion_unloaded`] with the far rows deferred: `Δx_free` exact on the
    /// dofs of [`FeModel::is_deferral_exact`] and zero on the others, which
    /// [`FeModel::complete_far`] finishes, for this free motion plus any corrective motion on
    /// those dofs, with one backward substitution over the far part of the factor instead of
    /// one per solve. The rows it gives are bit for bit the whole free motion's.
    ///
    /// # Errors
    /// No deferral ([`FeModel::defers_far`]), a failed factorisation, or a stopped
    /// background thread.
    pub fn free_motion_deferring_far(&mut self) -> Result<&[f64], FemError> {
        self.free_motion_with(None, true)
    }

    /// Finishes the last [`FeModel::free_motion_deferring_far`] into `dx`: its dofs outside
    /// [`FeModel::is_deferral_exact`] are written so that `dx` is the whole solve of the free
    /// motion's right-hand side plus the loads whose response (on those dofs, from
    /// [`FeModel::solve_columns_near`]) was added to it; the exact dofs are left as they are.
    ///
    /// # Errors
    /// No deferred free motion with the factor in use, or a wrong length.
    pub fn complete_far(&mut self, dx: &mut [f64]) -> Result<(), FemError> {
        check_vec("step", dx, self.dof_count())?;
        self.sys.complete_far(dx)
    }

    /// [`FeModel::solve_columns`] on the dofs of [`FeModel::is_deferral_exact`] only (zero on
    /// the others): for loads on those dofs, their exact rows at the cost of the near block.
    ///
    /// # Errors
    /// No deferral, a wrong length, or no factorisation yet.
    pub fn solve_columns_near(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        self.sys.solve_global_many_near(rhs, ncols)
    }

    /// Counts a step whose deferred free motion had to be finished before its constraint
    /// solve (a gel point of its frame outside the dofs the deferred solves give exactly).
    pub fn record_deferral_fallback(&mut self) {
        self.deferral_fallbacks += 1;
    }

    /// Steps counted by [`FeModel::record_deferral_fallback`].
    pub fn deferral_fallbacks(&self) -> u64 {
        self.deferral_fallbacks
    }

    fn free_motion_with(&mut self, f_ext: Option<&[f64]>, defer: bool) -> Result<&[f64], FemError> {
        self.update_elements();
        // What `dx` holds was solved from this state's `f_int` unloaded; it is overwritten
        // below unless that solve is found to repeat.
        let repeat_of = self.unloaded_solve.take().filter(|_| f_ext.is_none());
        let (elements, slots, lag) = (&self.elements, &self.slots, &mut self.lag);
        if self.sys.pcg.is_some() {
            for (i, (d, fi)) in self.dx.iter_mut().zip(&self.f_int).enumerate() {
                *d = f_ext.map_or(0.0, |f| f[i]) - fi;
            }
            self.sys
                .solve_step_pcg(|v| elements.assemble(slots, v), &mut self.dx)?;
            return Ok(&self.dx);
        }
        let event = self.sys.update_factor(
            |adopting| {
                lag.as_mut()
                    .map(|g| g.measure(adopting, elements.rotations()))
            },
            |v| elements.assemble(slots, v),
        )?;
        if let Some(g) = self.lag.as_mut() {
            g.record(event, self.elements.rotations());
            // The near block on its own, at once, when its elements rotated by the refresh's
            // angle since the factor's matrix.
            let rotations = self.elements.rotations();
            // The entry block alone when only its elements rotated so (and it is ready).
            let angle = self.sys.near_rotation();
            let entry_ready = self.sys.has_entry();
            let near_turned = self.sys.has_near()
                && (g.near_lag(rotations) >= angle
                    || (!entry_ready && g.entry_lag(rotations) >= angle));
            if near_turned {
                let (list, full) = g.near_elements_and_full();
                let change = |v: &mut [f64]| elements.add_rotation_change(slots, v, list, full);
                match self.sys.refresh_near(change)? {
                    NearRefresh::None => {}
                    NearRefresh::Block => g.record_near(rotations),
                    NearRefresh::Full => g.record_near_full(rotations),
                }
            } else if entry_ready && g.entry_lag(rotations) >= angle {
                let (list, base) = g.entry_elements_and_in_use();
                let change = |v: &mut [f64]| elements.add_rotation_change(slots, v, list, base);
                match self.sys.refresh_entry(change)? {
                    NearRefresh::None => {}
                    NearRefresh::Block => g.record_entry(rotations),
                    NearRefresh::Full => g.record_entry_full(rotations),
                }
            }
        }
        self.sys.stage_refine(|v| elements.assemble(slots, v));
        let stamp = self.sys.factor_stamp();
        if repeat_of == Some((stamp, defer)) && self.sys.refine.is_none() {
            // The same right-hand side `−f_int` (the same positions) and the same factor:
            // the solve would repeat the last one bit for bit (a gel at rest in the air).
            self.unloaded_solve = repeat_of;
            self.repeated += 1;
            return Ok(&self.dx);
        }
        for (i, (d, fi)) in self.dx.iter_mut().zip(&self.f_int).enumerate() {
            *d = f_ext.map_or(0.0, |f| f[i]) - fi;
        }
        if defer {
            self.sys.solve_free_motion_deferring_far(&mut self.dx)?;
        } else {
            self.sys.solve_free_motion(&mut self.dx)?;
        }
        if f_ext.is_none() && E::STATE_OF_POSITIONS {
            self.unloaded_solve = Some((stamp, defer));
        }
        Ok(&self.dx)
    }

    /// Refined-step mode (`GelParams::refine`): replaces the step `dx` made with the factor in
    /// use, `F⁻¹ g` (free motion plus corrective motion, `g` the step's net force), by the step
    /// with the matrix of the last free motion, `A⁻¹ g`, solved by CG preconditioned by `F`
    /// from `dx`. Returns the CG outcome; `None` in the other modes (`dx` unchanged).
    ///
    /// # Errors
    /// Wrong length or non-finite `dx`, or no factorisation yet.
    pub fn refine_step(&mut self, dx: &mut [f64]) -> Result<Option<PcgOutcome>, FemError> {
        if self.sys.refine.is_none() {
            return Ok(None);
        }
        check_vec("step", dx, self.dof_count())?;
        self.sys.refine_step(dx)
    }

    /// How many unloaded free motions were the last one repeated, without an element pass or
    /// a solve: the positions were bit for bit those of the last solve and the factor the
    /// same (a gel at rest before the needle reaches it; only for elements whose state is a
    /// function of the positions, [`Elements::STATE_OF_POSITIONS`], in the direct mode).
    pub fn repeated_free_motions(&self) -> u64 {
        self.repeated
    }

    /// The last `Δx_free`.
    pub fn last_free_motion(&self) -> &[f64] {
        &self.dx
    }

    /// Solves `(K + M/h²) x = rhs` in place with the current factor (global dofs; fixed entries
    /// ignored on input and zero on output). Used for compliance and correction.
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        self.sys.solve_checked(rhs)
    }

    /// Solves for `ncols` right-hand sides at once (column-major, each of length
    /// [`FeModel::dof_count`]).
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve_columns(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        self.sys.solve_global_many(rhs, ncols)
    }

    /// Moves the nodes by the increment `dx` (translations [mm]; for 6-dof nodes, world-frame
    /// rotation vectors [rad]); entries of fixed dofs are ignored.
    ///
    /// # Errors
    /// Wrong length or non-finite `dx`.
    pub fn apply_displacement(&mut self, dx: &[f64]) -> Result<(), FemError> {
        check_vec("displacement", dx, self.dof_count())?;
        let sys = &self.sys;
        self.elements
            .displace(&mut self.positions, dx, &|g| sys.is_free(g));
        Ok(())
    }
}

/// Whether two position lists are equal bit for bit (a NaN equals itself, −0 differs from 0).
pub(crate) fn same_bits(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(p, q)| (0..3).all(|k| p[k].to_bits() == q[k].to_bits()))
}

fn check_vec(what: &'static str, v: &[f64], expected: usize) -> Result<(), FemError> {
    if v.len() != expected {
        return Err(FemError::DimensionMismatch {
            what,
            expected,
            got: v.len(),
        });
    }
    if !v.iter().all(|x| x.is_finite()) {
        return Err(FemError::NonFinite { what });
    }
    Ok(())
}
