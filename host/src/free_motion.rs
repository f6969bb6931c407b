//! Free motion (paper §III-D, step 1): one Newton iteration of static equilibrium per step,
//!
//! ```text
//! (K(x) + M/h²) Δx_free = f_ext − f_int(x)
//! ```
//!
//! for the gel ([`GelModel`], corotational tetrahedra, 3 dofs per node) and the needle
//! ([`NeedleModel`], corotational beams, 6 dofs per node) — two separate sparse systems.
//!
//! - `K` is assembled into a sparse symmetric matrix whose pattern is built once, with a map
//!   from every element-local entry to its value slot, so a step only writes values.
//! - Dirichlet dofs (fixed gel nodes, a clamped needle base) are *eliminated*: the system has
//!   one row per free dof; their displacement is zero and [`GelModel::solve`] returns zero there.
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
//!   step), or when [`GelModel::request_refactor`] is called.
//! - **Background factorisation** (`GelParams::background_factorization`): the numeric
//!   factorisation runs on a second thread while the steps go on. With `refactor_every = r`, a
//!   matrix assembled at step k is factorised during steps k … k + r − 1 and used from step
//!   k + r for r steps (r = 1: every step solves with the matrix of the step before). The
//!   right-hand side `f_ext − f_int(x)` is exact, so the equilibrium reached is the same; the
//!   Newton matrix is a few steps old. The first step, a requested refactorisation, a failed
//!   background factorisation, and a step whose elements rotated more than
//!   [`LAG_ROTATION_LIMIT`] since the matrix in use factorise at once. The worker owns a second
//!   factor buffer; the two are swapped, nothing is allocated per step.
//! - All buffers are allocated at construction.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]
// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use crate::fem::beam::{self, BeamSection, CorotationalBeams};
use crate::fem::tetra::{self, CorotationalTetra, Kinematics, largest_rotation_between};
use crate::fem::{Elasticity, FemError};
use crate::linalg::{
    Cholesky, LinalgError, SymmetricMatrix, SymmetricPattern, nested_dissection_order,
};
use crate::mesh::TetMesh;
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};

const SKIP: u32 = u32::MAX;

/// The reduced (Dirichlet-eliminated) sparse system shared by the gel and the needle.
#[derive(Debug)]
struct ReducedSystem {
    /// Global dof → reduced index, `SKIP` for fixed dofs.
    dof_map: Vec<u32>,
    /// Reduced index → global dof.
    free: Vec<usize>,
    matrix: SymmetricMatrix,
    diag_slots: Vec<usize>,
    /// Added to the diagonal after assembly (M/h² per reduced dof).
    regularization: Vec<f64>,
    chol: Cholesky,
    work: Vec<f64>,
    work_many: Vec<f64>,
    /// Steps since the factor in use was made (`None`: never factorised).
    factor_age: Option<usize>,
    refactor_every: usize,
    refactor_requested: bool,
    /// The factorisation thread (background mode).
    background: Option<Background>,
}

/// What the start of a step found of the background factorisation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Adopted {
    /// A new factor is in use.
    Yes,
    /// No job was due.
    #[default]
    Idle,
    /// The job failed (not positive definite); its result was dropped.
    Failed,
}

/// What a step's free motion did with the factors (background mode).
#[derive(Clone, Copy, Debug, Default)]
struct FactorEvent {
    /// The step factorised its own matrix at once.
    immediate: bool,
    /// The step's matrix was sent to the worker.
    submitted: bool,
}

/// A matrix to factorise and the factor buffer to do it in, passed to the worker and back.
struct Job {
    chol: Cholesky,
    matrix: SymmetricMatrix,
    result: Result<(), LinalgError>,
}

/// The background factorisation thread of a [`ReducedSystem`]: one job in flight at most.
struct Background {
    jobs: std::sync::mpsc::SyncSender<Box<Job>>,
    done: std::sync::mpsc::Receiver<Box<Job>>,
    /// The job buffer while no job is in flight.
    spare: Option<Box<Job>>,
    /// This step's matrix, written while the previous one is being factorised.
    staged: SymmetricMatrix,
    /// Factorisations finished in the background and used.
    adopted: u64,
    /// Factorisations made at once instead (see [`ReducedSystem::free_motion`]).
    immediate: u64,
    /// Steps since the job in flight was sent.
    in_flight_steps: usize,
}

impl std::fmt::Debug for Background {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Background")
            .field("in_flight", &self.spare.is_none())
            .field("adopted", &self.adopted)
            .finish()
    }
}

impl Background {
    /// Starts the worker with a second factor buffer for `pattern` (same ordering).
    fn start(pattern: &SymmetricPattern, order: Option<&[usize]>) -> Result<Self, FemError> {
        let chol = Cholesky::try_new_ordered(pattern, order, 1)?;
        let (jobs, inbox) = std::sync::mpsc::sync_channel::<Box<Job>>(1);
        let (outbox, done) = std::sync::mpsc::sync_channel::<Box<Job>>(1);
        std::thread::Builder::new()
            .name("needle-factor".into())
            .spawn(move || {
                // Ends when the system (the sender) is dropped.
                while let Ok(mut job) = inbox.recv() {
                    let Job { chol, matrix, .. } = &mut *job;
                    job.result = chol.factorize(matrix);
                    if outbox.send(job).is_err() {
                        return;
                    }
                }
            })
            .map_err(|_| FemError::Parameter {
                what: "the background factorisation thread could not be started",
            })?;
        Ok(Self {
            jobs,
            done,
            spare: Some(Box::new(Job {
                chol,
                matrix: SymmetricMatrix::zeros(pattern.clone()),
                result: Ok(()),
            })),
            staged: SymmetricMatrix::zeros(pattern.clone()),
            adopted: 0,
            immediate: 0,
            in_flight_steps: 0,
        })
    }

    /// Waits for the job in flight, if any, and returns it.
    fn finish(&mut self) -> Result<Option<Box<Job>>, FemError> {
        if self.spare.is_some() {
            return Ok(None);
        }
        match self.done.recv() {
            Ok(job) => Ok(Some(job)),
            Err(_) => Err(FemError::Parameter {
                what: "the background factorisation thread stopped",
            }),
        }
    }
}

impl ReducedSystem {
    fn try_new<I: Iterator<Item = (usize, usize)>>(
        fixed: &[bool],
        entries: impl Fn() -> I,
        regularization_global: &[f64],
        refactor_every: usize,
        dof_coords: Option<&[[f64; 3]]>,
        background: bool,
    ) -> Result<(Self, Vec<u32>), FemError> {
        let ndof = fixed.len();
        let mut dof_map = vec![SKIP; ndof];
        let mut free = Vec::new();
        for g in 0..ndof {
            if !fixed[g] {
                dof_map[g] = free.len() as u32;
                free.push(g);
            }
        }
        if free.is_empty() {
            return Err(FemError::NoFreeDof);
        }
        let reduce = |(r, c): (usize, usize)| {
            let (a, b) = (dof_map[r], dof_map[c]);
            (a != SKIP && b != SKIP).then_some((a as usize, b as usize))
        };
        let pattern = SymmetricPattern::from_entries(free.len(), entries().filter_map(reduce));
        let slots: Vec<u32> = entries()
            .map(|e| {
                reduce(e)
                    .and_then(|(a, b)| pattern.slot(a, b))
                    .map_or(SKIP, |s| s as u32)
            })
            .collect();
        let diag_slots = (0..free.len())
            .map(|k| pattern.slot(k, k).unwrap_or(0))
            .collect();
        let regularization = free.iter().map(|&g| regularization_global[g]).collect();
        let order = dof_coords.map(|c| {
            let reduced: Vec<[f64; 3]> = free.iter().map(|&g| c[g]).collect();
            nested_dissection_order(&pattern, &reduced)
        });
        let chol = Cholesky::try_new_ordered(&pattern, order.as_deref(), 1)?;
        let background = if background {
            Some(Background::start(&pattern, order.as_deref())?)
        } else {
            None
        };
        let n = free.len();
        Ok((
            Self {
                dof_map,
                free,
                matrix: SymmetricMatrix::zeros(pattern),
                diag_slots,
                regularization,
                chol,
                work: vec![0.0; n],
                work_many: Vec::new(),
                factor_age: None,
                refactor_every: refactor_every.max(1),
                refactor_requested: false,
                background,
            },
            slots,
        ))
    }

    fn needs_refactor(&self) -> bool {
        match self.factor_age {
            None => true,
            Some(age) => self.refactor_requested || age + 1 >= self.refactor_every,
        }
    }

    /// Writes `matrix`'s values: zero, the elements' contributions through `write`, then the
    /// regularisation `M/h²` on the diagonal.
    fn write_into(
        matrix: &mut SymmetricMatrix,
        diag_slots: &[usize],
        regularization: &[f64],
        write: impl FnOnce(&mut [f64]),
    ) {
        matrix.fill_zero();
        write(&mut matrix.values);
        for (&s, &r) in diag_slots.iter().zip(regularization) {
            matrix.values[s] += r;
        }
    }

    /// Writes the matrix values: zero, the elements' contributions through `write`, `M/h²`.
    fn write_values(&mut self, write: impl FnOnce(&mut [f64])) {
        Self::write_into(
            &mut self.matrix,
            &self.diag_slots,
            &self.regularization,
            write,
        );
    }

    /// Background mode, start of a step: counts the steps of the job in flight and, once it is
    /// due (`refactor_every` steps after its matrix), waits for it and puts it in use (a failed
    /// one is dropped: the step then factorises at once).
    fn adopt_background(&mut self) -> Result<Adopted, FemError> {
        let every = self.refactor_every;
        let Some(bg) = self.background.as_mut() else {
            return Ok(Adopted::Idle);
        };
        if bg.spare.is_some() {
            return Ok(Adopted::Idle);
        }
        bg.in_flight_steps += 1;
        if bg.in_flight_steps < every {
            return Ok(Adopted::Idle);
        }
        let Some(mut job) = bg.finish()? else {
            return Ok(Adopted::Idle);
        };
        let ok = job.result.is_ok();
        if ok {
            std::mem::swap(&mut self.chol, &mut job.chol);
            std::mem::swap(&mut self.matrix, &mut job.matrix);
            bg.adopted += 1;
        }
        bg.spare = Some(job);
        Ok(if ok { Adopted::Yes } else { Adopted::Failed })
    }

    /// Background mode: writes this step's matrix into the staging buffer.
    fn stage_background(&mut self, write: &impl Fn(&mut [f64])) {
        let Some(bg) = self.background.as_mut() else {
            return;
        };
        Self::write_into(
            &mut bg.staged,
            &self.diag_slots,
            &self.regularization,
            write,
        );
    }

    /// Background mode: makes the staged matrix the one to factorise at once.
    fn unstage_background(&mut self) {
        if let Some(bg) = self.background.as_mut() {
            std::mem::swap(&mut self.matrix, &mut bg.staged);
        }
    }

    /// Background mode: sends the staged matrix to the worker.
    fn submit_background(&mut self) -> Result<(), FemError> {
        let Some(bg) = self.background.as_mut() else {
            return Ok(());
        };
        let Some(mut job) = bg.spare.take() else {
            return Ok(());
        };
        std::mem::swap(&mut job.matrix, &mut bg.staged);
        bg.in_flight_steps = 0;
        bg.jobs.send(job).map_err(|_| FemError::Parameter {
            what: "the background factorisation thread stopped",
        })
    }

    /// Background mode: waits for a job in flight and drops its result (a synchronous
    /// factorisation supersedes it).
    fn discard_background(&mut self) -> Result<(), FemError> {
        if let Some(bg) = self.background.as_mut()
            && let Some(job) = bg.finish()?
        {
            bg.spare = Some(job);
        }
        Ok(())
    }

    /// The free-motion solve both models share: refactorises if due (`write` fills the
    /// elements' values), then `dx = (K + M/h²)⁻¹ (f_ext − f_int)` over global dofs.
    fn free_motion(
        &mut self,
        f_ext: &[f64],
        f_int: &[f64],
        dx: &mut [f64],
        lag_ok: impl FnOnce(Adopted) -> bool,
        write: impl Fn(&mut [f64]),
    ) -> Result<FactorEvent, FemError> {
        let mut event = FactorEvent::default();
        if let Some(bg) = self.background.as_mut() {
            // A job in flight is due after `refactor_every` steps (1: the step after its
            // matrix). Assemble this step's matrix first when it will be sent (no job in flight
            // after this step's adoption): that overlaps the tail of the running factorisation.
            let due = bg.spare.is_none() && bg.in_flight_steps + 1 >= self.refactor_every;
            let will_submit = bg.spare.is_some() || due;
            if will_submit {
                self.stage_background(&write);
            }
            let adopted = self.adopt_background()?;
            match adopted {
                Adopted::Yes => self.factor_age = Some(0),
                Adopted::Idle => {
                    if let Some(age) = self.factor_age.as_mut() {
                        *age += 1;
                    }
                }
                Adopted::Failed => self.factor_age = None,
            }
            let in_use_ok = self.factor_age.is_some() && lag_ok(adopted);
            if !in_use_ok || self.refactor_requested {
                // No factor yet, a request, a failed background factorisation, or elements
                // that rotated too far since the matrix in use: factorise now.
                if !will_submit {
                    self.stage_background(&write);
                }
                self.unstage_background();
                // A job still in flight holds an older matrix than this one: drop it.
                self.discard_background()?;
                self.factorize_now()?;
                event.immediate = true;
                if let Some(bg) = self.background.as_mut() {
                    bg.immediate += 1;
                }
            } else if self.background.as_ref().is_some_and(|b| b.spare.is_some()) {
                self.submit_background()?;
                event.submitted = true;
            }
        } else if self.needs_refactor() {
            self.write_values(write);
            self.factorize()?;
        } else if let Some(age) = self.factor_age.as_mut() {
            *age += 1;
        }
        for (d, (fe, fi)) in dx.iter_mut().zip(f_ext.iter().zip(f_int)) {
            *d = fe - fi;
        }
        self.solve_global(dx)?;
        Ok(event)
    }

    /// [`Self::solve_global`] after checking the length (one value per global dof).
    fn solve_checked(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        if rhs.len() != self.dof_map.len() {
            return Err(FemError::DimensionMismatch {
                what: "right-hand side",
                expected: self.dof_map.len(),
                got: rhs.len(),
            });
        }
        self.solve_global(rhs)
    }

    /// Numeric factorisation of the assembled values (a background job in flight is dropped).
    fn factorize(&mut self) -> Result<(), FemError> {
        self.discard_background()?;
        self.factorize_now()
    }

    fn factorize_now(&mut self) -> Result<(), FemError> {
        self.factor_age = None;
        self.chol.factorize(&self.matrix)?;
        self.factor_age = Some(0);
        self.refactor_requested = false;
        Ok(())
    }

    /// Solves in place over global dofs (fixed entries set to zero).
    fn solve_global(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        for (k, &g) in self.free.iter().enumerate() {
            self.work[k] = rhs[g];
        }
        self.chol.solve_in_place(&mut self.work)?;
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for (k, &g) in self.free.iter().enumerate() {
            rhs[g] = self.work[k];
        }
        Ok(())
    }

    /// Solves `ncols` column-major global right-hand sides in place.
    fn solve_global_many(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        let ndof = self.dof_map.len();
        if rhs.len() != ndof * ncols {
            return Err(FemError::DimensionMismatch {
                what: "right-hand sides",
                expected: ndof * ncols,
                got: rhs.len(),
            });
        }
        let n = self.free.len();
        // Grows once to the largest column count used, then reused.
        if self.work_many.len() < n * ncols {
            self.work_many.resize(n * ncols, 0.0);
        }
        let buf = &mut self.work_many[..n * ncols];
        for c in 0..ncols {
            for (k, &g) in self.free.iter().enumerate() {
                buf[c * n + k] = rhs[c * ndof + g];
            }
        }
        self.chol.solve_many_in_place(buf, ncols)?;
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for c in 0..ncols {
            for (k, &g) in self.free.iter().enumerate() {
                rhs[c * ndof + g] = buf[c * n + k];
            }
        }
        Ok(())
    }
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

/// Parameters of the gel model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GelParams {
    /// Elastic constants (E [MPa], ν).
    pub elasticity: Elasticity,
    /// Density [t/mm³] (water-like gel: 1e-9); used only with a time step.
    pub density: f64,
    /// Pseudo time step `h` [s] of the `M/h²` term; `None` for the static Newton step.
    pub time_step: Option<f64>,
    /// Corotational (the paper's model) or linear kinematics.
    pub kinematics: Kinematics,
    /// Refactorise the matrix every this many steps (1 = every step); with the background
    /// factorisation, the depth of the pipeline.
    pub refactor_every: usize,
    /// Factorise on a second thread while the steps go on, and use the factor `refactor_every`
    /// steps later (see the module docs).
    pub background_factorization: bool,
}

/// Fill-reducing elimination order of a sparse factorisation (chosen once, at construction).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FillOrdering {
    /// Approximate minimum degree (faer's default).
    Amd,
    /// Geometric nested dissection on the node positions ([`nested_dissection_order`]).
    #[default]
    NestedDissection,
}

impl Default for GelParams {
    fn default() -> Self {
        Self {
            elasticity: Elasticity {
                young_modulus: 0.005,
                poisson_ratio: 0.45,
            },
            density: 1e-9,
            time_step: None,
            kinematics: Kinematics::Corotational,
            refactor_every: 1,
            background_factorization: false,
        }
    }
}

/// Background factorisation: the largest rotation of an element [rad] between the matrix of the
/// factor in use and the current positions for which that factor is used; above it the step
/// factorises its own matrix at once. The tangent `R K0 Rᵀ` changes only through the rotations,
/// by about `2θ` relative, and a Newton step with a matrix off by ε contracts by about ε.
pub const LAG_ROTATION_LIMIT: f64 = 0.2;

/// The gel: corotational tetrahedra with eliminated Dirichlet nodes, and its sparse system.
#[derive(Debug)]
pub struct GelModel {
    mesh: TetMesh,
    positions: Vec<Vector3<f64>>,
    tetra: CorotationalTetra,
    fixed_nodes: Vec<usize>,
    sys: ReducedSystem,
    slots: Vec<u32>,
    f_int: Vec<f64>,
    dx: Vec<f64>,
    /// Background mode: the element rotations of the matrix of the factor in use, and of the
    /// matrix being factorised.
    rotations_in_use: Vec<Matrix3<f64>>,
    rotations_sent: Vec<Matrix3<f64>>,
    lag_rotation: f64,
}

impl GelModel {
    /// Builds the model on `mesh` (its nodes are the rest configuration [mm]) with the nodes
    /// `fixed_nodes` clamped (all three dofs eliminated).
    ///
    /// # Errors
    /// Invalid mesh or material, fixed node out of range, no free dof, bad time step, or the
    /// symbolic factorisation failing.
    pub fn try_new(
        mesh: TetMesh,
        fixed_nodes: &[usize],
        params: &GelParams,
    ) -> Result<Self, FemError> {
        Self::try_new_with_ordering(mesh, fixed_nodes, params, FillOrdering::default())
    }

    /// As [`GelModel::try_new`] with an explicit fill-reducing ordering.
    ///
    /// # Errors
    /// As [`GelModel::try_new`].
    pub fn try_new_with_ordering(
        mesh: TetMesh,
        fixed_nodes: &[usize],
        params: &GelParams,
        ordering: FillOrdering,
    ) -> Result<Self, FemError> {
        let tetra = CorotationalTetra::try_new(&mesh, &params.elasticity, params.kinematics)?;
        let tetra_len = tetra.len();
        let n = mesh.nodes.len();
        let mut fixed = vec![false; 3 * n];
        for &node in fixed_nodes {
            if node >= n {
                return Err(FemError::FixedNodeOutOfRange {
                    node,
                    node_count: n,
                });
            }
            fixed[3 * node..3 * node + 3]
                .iter_mut()
                .for_each(|f| *f = true);
        }
        let reg = match params.time_step {
            None => vec![0.0; 3 * n],
            Some(h) => {
                if !(h > 0.0 && h.is_finite())
                    || !(params.density >= 0.0 && params.density.is_finite())
                {
                    return Err(FemError::Parameter {
                        what: "gel time step must be positive and density non-negative",
                    });
                }
                let m = tetra.lumped_mass(n, params.density);
                (0..3 * n).map(|g| m[g / 3] / (h * h)).collect()
            }
        };
        let entries = || (0..tetra.len()).flat_map(|e| tetra.stiffness_entry_dofs(e));
        let coords: Vec<[f64; 3]> = (0..3 * n).map(|g| mesh.nodes[g / 3].into()).collect();
        let nd = (ordering == FillOrdering::NestedDissection).then_some(coords.as_slice());
        let (sys, slots) = ReducedSystem::try_new(
            &fixed,
            entries,
            &reg,
            params.refactor_every,
            nd,
            params.background_factorization,
        )?;
        let mut sorted = fixed_nodes.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        Ok(Self {
            positions: mesh.nodes.clone(),
            mesh,
            tetra,
            fixed_nodes: sorted,
            sys,
            slots,
            f_int: vec![0.0; 3 * n],
            dx: vec![0.0; 3 * n],
            rotations_in_use: if params.background_factorization {
                vec![Matrix3::identity(); tetra_len]
            } else {
                Vec::new()
            },
            rotations_sent: if params.background_factorization {
                vec![Matrix3::identity(); tetra_len]
            } else {
                Vec::new()
            },
            lag_rotation: 0.0,
        })
    }

    /// The rest mesh.
    pub fn mesh(&self) -> &TetMesh {
        &self.mesh
    }

    /// The element data (rotations, rest stiffness).
    pub fn tetra(&self) -> &CorotationalTetra {
        &self.tetra
    }

    /// Current node positions [mm].
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Mutable node positions [mm] (e.g. to prescribe the displacement of fixed nodes).
    pub fn positions_mut(&mut self) -> &mut [Vector3<f64>] {
        &mut self.positions
    }

    /// Sorted indices of the clamped nodes.
    pub fn fixed_nodes(&self) -> &[usize] {
        &self.fixed_nodes
    }

    /// Number of dofs (3 per node).
    pub fn dof_count(&self) -> usize {
        3 * self.positions.len()
    }

    /// Number of free (non-eliminated) dofs: the size of the sparse system.
    pub fn free_dof_count(&self) -> usize {
        self.sys.free.len()
    }

    /// Whether global dof `dof` is eliminated (Dirichlet).
    pub fn is_fixed_dof(&self, dof: usize) -> bool {
        self.sys.dof_map.get(dof).is_none_or(|&m| m == SKIP)
    }

    /// Steps since the last numeric factorisation (`None` before the first).
    pub fn factor_age(&self) -> Option<usize> {
        self.sys.factor_age
    }

    /// Forces a numeric refactorisation at the next [`GelModel::free_motion`].
    pub fn request_refactor(&mut self) {
        self.sys.refactor_requested = true;
    }

    /// Sets how many steps a numeric factorisation is reused (1 = refactorise every step).
    pub fn set_refactor_every(&mut self, steps: usize) {
        self.sys.refactor_every = steps.max(1);
    }

    /// The assembled reduced matrix `K + M/h²` of the last factorisation (free dofs only) [N/mm].
    pub fn matrix(&self) -> &SymmetricMatrix {
        &self.sys.matrix
    }

    /// Reduced index of global dof `dof`, `None` if it is fixed.
    pub fn reduced_index(&self, dof: usize) -> Option<usize> {
        self.sys
            .dof_map
            .get(dof)
            .and_then(|&m| (m != SKIP).then_some(m as usize))
    }

    /// Updates the element rotations and returns the internal forces `f_int(x)` at the current
    /// positions (3 per node, including at fixed nodes, where they are the reactions) [N].
    pub fn compute_internal_forces(&mut self) -> &[f64] {
        self.tetra.update_rotations(&self.positions);
        self.f_int.iter_mut().for_each(|v| *v = 0.0);
        self.tetra
            .add_internal_forces(&self.positions, &mut self.f_int);
        &self.f_int
    }

    /// Background mode: the largest rotation of an element between the matrix of the factor the
    /// last free motion used and its positions [rad] (0 when it factorised at once).
    pub fn lag_rotation(&self) -> f64 {
        self.lag_rotation
    }

    /// Factorisations so far: (finished in the background and used, made at once) — `None`
    /// without background factorisation.
    pub fn background_counts(&self) -> Option<(u64, u64)> {
        self.sys
            .background
            .as_ref()
            .map(|b| (b.adopted, b.immediate))
    }

    /// Corotational update and assembly: element rotations and internal forces at the current
    /// positions, and the values of `K(x) + M/h²` written into the fixed pattern (no factorisation).
    pub fn assemble(&mut self) {
        self.compute_internal_forces();
        self.write_matrix();
    }

    fn write_matrix(&mut self) {
        let (tetra, slots) = (&self.tetra, &self.slots);
        self.sys.write_values(|v| tetra.assemble(slots, v, 1.0));
    }

    /// Numeric factorisation of the matrix last written by [`GelModel::assemble`] (resets the
    /// factor age).
    ///
    /// # Errors
    /// [`FemError::Linalg`] if the matrix is not positive definite.
    pub fn factorize(&mut self) -> Result<(), FemError> {
        self.sys.factorize()
    }

    /// [`GelModel::assemble`] then [`GelModel::factorize`], whatever the reuse setting.
    ///
    /// # Errors
    /// [`FemError::Linalg`] if the matrix is not positive definite.
    pub fn refactor(&mut self) -> Result<(), FemError> {
        self.assemble();
        self.factorize()
    }

    /// One free-motion step: updates rotations and internal forces, refactorises if due, and
    /// solves `(K + M/h²) Δx_free = f_ext − f_int(x)`. Returns `Δx_free` (3 per node, zero at
    /// fixed nodes) [mm]; positions are *not* changed (see [`GelModel::apply_displacement`]).
    ///
    /// # Errors
    /// Wrong length or non-finite `f_ext`, or a failed factorisation.
    pub fn free_motion(&mut self, f_ext: &[f64]) -> Result<&[f64], FemError> {
        check_vec("external forces", f_ext, self.dof_count())?;
        self.compute_internal_forces();
        let (tetra, slots) = (&self.tetra, &self.slots);
        let (in_use, sent) = (&mut self.rotations_in_use, &mut self.rotations_sent);
        let lag = &mut self.lag_rotation;
        let event = self.sys.free_motion(
            f_ext,
            &self.f_int,
            &mut self.dx,
            |adopted| {
                if adopted == Adopted::Yes {
                    std::mem::swap(in_use, sent);
                }
                *lag = largest_rotation_between(tetra.rotations(), in_use);
                *lag <= LAG_ROTATION_LIMIT
            },
            |v| tetra.assemble(slots, v, 1.0),
        )?;
        if event.immediate {
            self.rotations_in_use
                .copy_from_slice(self.tetra.rotations());
            self.lag_rotation = 0.0;
        } else if event.submitted {
            self.rotations_sent.copy_from_slice(self.tetra.rotations());
        }
        Ok(&self.dx)
    }

    /// The last `Δx_free` [mm].
    pub fn last_free_motion(&self) -> &[f64] {
        &self.dx
    }

    /// Solves `(K + M/h²) x = rhs` in place with the current factor (global dofs, 3 per node;
    /// fixed entries ignored on input and zero on output). Used for compliance and correction.
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        self.sys.solve_checked(rhs)
    }

    /// Solves for `ncols` right-hand sides at once (column-major, each of length
    /// [`GelModel::dof_count`]).
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve_columns(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        self.sys.solve_global_many(rhs, ncols)
    }

    /// Moves the nodes: `x += Δx` (3 per node) [mm]; entries of fixed dofs are ignored.
    ///
    /// # Errors
    /// Wrong length or non-finite `dx`.
    pub fn apply_displacement(&mut self, dx: &[f64]) -> Result<(), FemError> {
        check_vec("displacement", dx, self.dof_count())?;
        for (i, p) in self.positions.iter_mut().enumerate() {
            for k in 0..3 {
                if self.sys.dof_map[3 * i + k] != SKIP {
                    p[k] += dx[3 * i + k];
                }
            }
        }
        Ok(())
    }
}

/// Parameters of the needle model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeedleParams {
    /// Section and material.
    pub section: BeamSection,
    /// Pseudo time step `h` [s] of the `M/h²` regularisation; required when no node is fixed.
    pub time_step: Option<f64>,
    /// Refactorise the matrix every this many steps (1 = every step).
    pub refactor_every: usize,
}

/// The needle: corotational beams, 6 dofs per node (translation [mm], world rotation
/// increment [rad]), node orientations as unit quaternions.
#[derive(Debug)]
pub struct NeedleModel {
    positions: Vec<Vector3<f64>>,
    orientations: Vec<UnitQuaternion<f64>>,
    beams: CorotationalBeams,
    sys: ReducedSystem,
    slots: Vec<u32>,
    f_int: Vec<f64>,
    dx: Vec<f64>,
    energy: f64,
}

impl NeedleModel {
    /// A straight needle of `length` [mm] with `elements` equal beams, starting at the base frame
    /// origin and pointing along its x axis; every node has the base orientation. Node 0 is the
    /// base, the last node the tip. `fixed_nodes` are clamped (all 6 dofs), e.g. `&[0]` for a cantilever.
    ///
    /// # Errors
    /// See [`NeedleModel::try_new`].
    pub fn straight(
        base: &Isometry3<f64>,
        length: f64,
        elements: usize,
        fixed_nodes: &[usize],
        params: &NeedleParams,
    ) -> Result<Self, FemError> {
        if elements == 0 || !(length > 0.0 && length.is_finite()) {
            return Err(FemError::Parameter {
                what: "needle needs a positive length and at least one element",
            });
        }
        let x = (0..=elements)
            .map(|i| base * nalgebra::Point3::new(length * i as f64 / elements as f64, 0.0, 0.0))
            .map(|p| p.coords)
            .collect();
        let q = vec![base.rotation; elements + 1];
        let conn = (0..elements).map(|i| [i, i + 1]).collect();
        Self::try_new(x, q, conn, fixed_nodes, params)
    }

    /// Builds the model from rest node positions [mm], orientations and 2-node elements.
    ///
    /// # Errors
    /// Invalid section or geometry, fixed node out of range, or a free-floating needle without
    /// regularisation (`time_step` and a positive density are then required).
    pub fn try_new(
        positions: Vec<Vector3<f64>>,
        orientations: Vec<UnitQuaternion<f64>>,
        elements: Vec<[usize; 2]>,
        fixed_nodes: &[usize],
        params: &NeedleParams,
    ) -> Result<Self, FemError> {
        let beams =
            CorotationalBeams::try_new(&positions, &orientations, elements, params.section)?;
        let n = positions.len();
        let mut fixed = vec![false; 6 * n];
        for &node in fixed_nodes {
            if node >= n {
                return Err(FemError::FixedNodeOutOfRange {
                    node,
                    node_count: n,
                });
            }
            fixed[6 * node..6 * node + 6]
                .iter_mut()
                .for_each(|f| *f = true);
        }
        let reg = match params.time_step {
            None => {
                if fixed_nodes.is_empty() {
                    return Err(FemError::Parameter {
                        what: "a needle without fixed node needs a time step (its stiffness alone is singular)",
                    });
                }
                vec![0.0; 6 * n]
            }
            Some(h) => {
                if !(h > 0.0 && h.is_finite()) {
                    return Err(FemError::Parameter {
                        what: "needle time step must be positive",
                    });
                }
                if fixed_nodes.is_empty() && !(params.section.density > 0.0) {
                    return Err(FemError::Parameter {
                        what: "a free-floating needle needs a positive density",
                    });
                }
                let (m, j) = beams.lumped_mass(n);
                (0..6 * n)
                    .map(|g| if g % 6 < 3 { m[g / 6] } else { j[g / 6] } / (h * h))
                    .collect()
            }
        };
        let entries = || (0..beams.len()).flat_map(|e| beams.stiffness_entry_dofs(e));
        let (sys, slots) =
            ReducedSystem::try_new(&fixed, entries, &reg, params.refactor_every, None, false)?;
        Ok(Self {
            positions,
            orientations,
            beams,
            sys,
            slots,
            f_int: vec![0.0; 6 * n],
            dx: vec![0.0; 6 * n],
            energy: 0.0,
        })
    }

    /// Node positions [mm] (node 0 = base).
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Node orientations (world ← node frame; the node x axis is the needle axis at rest).
    pub fn orientations(&self) -> &[UnitQuaternion<f64>] {
        &self.orientations
    }

    /// The beam elements.
    pub fn beams(&self) -> &CorotationalBeams {
        &self.beams
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of dofs (6 per node).
    pub fn dof_count(&self) -> usize {
        6 * self.positions.len()
    }

    /// Strain energy at the last force evaluation [N·mm].
    pub fn strain_energy(&self) -> f64 {
        self.energy
    }

    /// Steps since the last numeric factorisation (`None` before the first).
    pub fn factor_age(&self) -> Option<usize> {
        self.sys.factor_age
    }

    /// Forces a numeric refactorisation at the next [`NeedleModel::free_motion`].
    pub fn request_refactor(&mut self) {
        self.sys.refactor_requested = true;
    }

    /// Sets how many steps a numeric factorisation is reused (1 = refactorise every step).
    pub fn set_refactor_every(&mut self, steps: usize) {
        self.sys.refactor_every = steps.max(1);
    }

    /// Internal forces and moments at the current configuration (6 per node) [N, N·mm].
    pub fn compute_internal_forces(&mut self) -> &[f64] {
        self.energy = self.beams.update(&self.positions, &self.orientations);
        self.f_int.iter_mut().for_each(|v| *v = 0.0);
        self.beams.add_internal_forces(&mut self.f_int);
        &self.f_int
    }

    /// Element update and assembly: internal forces and the values of `K + M/h²` at the
    /// current configuration (no factorisation).
    pub fn assemble(&mut self) {
        self.compute_internal_forces();
        self.write_matrix();
    }

    fn write_matrix(&mut self) {
        let (beams, slots) = (&self.beams, &self.slots);
        self.sys.write_values(|v| beams.assemble(slots, v, 1.0));
    }

    /// Numeric factorisation of the matrix last written by [`NeedleModel::assemble`].
    ///
    /// # Errors
    /// [`FemError::Linalg`] if the matrix is not positive definite.
    pub fn factorize(&mut self) -> Result<(), FemError> {
        self.sys.factorize()
    }

    /// [`NeedleModel::assemble`] then [`NeedleModel::factorize`], whatever the reuse setting.
    ///
    /// # Errors
    /// [`FemError::Linalg`] if the matrix is not positive definite.
    pub fn refactor(&mut self) -> Result<(), FemError> {
        self.assemble();
        self.factorize()
    }

    /// One free-motion step: `(K + M/h²) Δx_free = f_ext − f_int`, with `f_ext` forces [N] and
    /// moments [N·mm] (6 per node, world frame, dead loads). Returns `Δx_free` (translations
    /// [mm], world rotation vectors [rad]; zero at fixed nodes); the state is *not* changed.
    ///
    /// # Errors
    /// Wrong length or non-finite `f_ext`, or a failed factorisation.
    pub fn free_motion(&mut self, f_ext: &[f64]) -> Result<&[f64], FemError> {
        check_vec("external loads", f_ext, self.dof_count())?;
        self.compute_internal_forces();
        let (beams, slots) = (&self.beams, &self.slots);
        self.sys.free_motion(
            f_ext,
            &self.f_int,
            &mut self.dx,
            |_| true,
            |v| beams.assemble(slots, v, 1.0),
        )?;
        Ok(&self.dx)
    }

    /// The last `Δx_free`.
    pub fn last_free_motion(&self) -> &[f64] {
        &self.dx
    }

    /// Solves `(K + M/h²) x = rhs` in place with the current factor (6 per node; fixed entries
    /// zero on output).
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        self.sys.solve_checked(rhs)
    }

    /// Solves for `ncols` column-major right-hand sides at once.
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn solve_columns(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        self.sys.solve_global_many(rhs, ncols)
    }

    /// Applies an increment: `x_i += Δx_i`, `q_i ← exp(Δθ_i/2) ⊗ q_i` (world-frame rotation
    /// vector, left multiplication); fixed dofs are ignored.
    ///
    /// # Errors
    /// Wrong length or non-finite `dx`.
    pub fn apply_displacement(&mut self, dx: &[f64]) -> Result<(), FemError> {
        check_vec("displacement", dx, self.dof_count())?;
        for i in 0..self.positions.len() {
            let free = |k: usize| self.sys.dof_map[6 * i + k] != SKIP;
            let mut t = Vector3::zeros();
            let mut w = Vector3::zeros();
            for k in 0..3 {
                if free(k) {
                    t[k] = dx[6 * i + k];
                }
                if free(3 + k) {
                    w[k] = dx[6 * i + 3 + k];
                }
            }
            self.positions[i] += t;
            let q = UnitQuaternion::from_scaled_axis(w) * self.orientations[i];
            self.orientations[i] = UnitQuaternion::new_normalize(q.into_inner());
        }
        Ok(())
    }

    /// Includes (default) or drops the geometric stiffness of the beams in the factorised
    /// matrix (see [`CorotationalBeams::set_geometric_stiffness`]).
    pub fn set_geometric_stiffness(&mut self, on: bool) {
        self.beams.set_geometric_stiffness(on);
    }

    /// Moves the whole needle rigidly so that the base node (node 0) takes the pose `base`
    /// (useful to place it; the elastic state is unchanged).
    pub fn set_base_pose_rigidly(&mut self, base: &Isometry3<f64>) {
        let current = Isometry3::from_parts(self.positions[0].into(), self.orientations[0]);
        let t = base * current.inverse();
        for (p, q) in self.positions.iter_mut().zip(self.orientations.iter_mut()) {
            *p = (t * nalgebra::Point3::from(*p)).coords;
            *q = t.rotation * *q;
        }
    }
}

/// Number of matrix entries each element writes (for callers sizing their own assembly).
pub const ENTRIES_PER_ELEMENT: (usize, usize) = (tetra::STIFFNESS_ENTRIES, beam::STIFFNESS_ENTRIES);
