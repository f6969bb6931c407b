//! The gel: corotational tetrahedra, 3 dofs per node, Dirichlet nodes eliminated.

use super::{Elements, FeModel, ModelLayout, NearLayout, PcgParams, RefreshParams};
use crate::fem::tetra::{CorotationalTetra, Kinematics};
use crate::fem::{Elasticity, FemError};
use crate::linalg::Precision;
use crate::mesh::TetMesh;
use nalgebra::{Matrix3, Vector3};

/// The material of one region of the gel mesh ([`TetMesh::regions`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionMaterial {
    /// The region's tag in the mesh (a Gmsh physical volume tag, a `.vtu` `region` value).
    pub tag: i32,
    /// Elastic constants (E [MPa], ν).
    pub elasticity: Elasticity,
    /// Density [t/mm³]; used only with a time step.
    pub density: f64,
}

/// Parameters of the gel model.
#[derive(Clone, Debug, PartialEq)]
pub struct GelParams {
    /// Elastic constants (E [MPa], ν) of every element whose region `regions` does not list.
    pub elasticity: Elasticity,
    /// Density [t/mm³] (water-like gel: 1e-9) of the same elements; used only with a time step.
    pub density: f64,
    /// Materials of the listed regions (a tag the mesh does not use is allowed here: the scene
    /// refuses it, naming the file).
    pub regions: Vec<RegionMaterial>,
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
    /// With the background factorisation and the direct (or refined) solve: a due factor is
    /// put in use at the first step, from `refactor_every` steps after its matrix, that finds it
    /// finished, instead of the step waiting for it. No step waits for the worker (but for the
    /// first step, a requested refactorisation and the rotation guard's factorisations at
    /// once); which step adopts a factor then depends on the machine's timing, so runs no longer
    /// repeat bit for bit.
    pub asynchronous_factor: bool,
    /// Preconditioned-CG free motion: each step solves its own matrix by CG with the factor
    /// in use (refreshed every `refactor_every` steps at most, in the background when
    /// `background_factorization`) as preconditioner; `None`: the direct solve with the factor
    /// (see the module docs).
    pub pcg: Option<PcgParams>,
    /// Refined step (`solver.gel_solve = "refine"`): the free motion, the compliance and the
    /// corrective motion use the factor in use `F` (as with `pcg: None`), then the whole step
    /// `F⁻¹ g` is replaced by `A⁻¹ g`, `A` the step's own matrix, by CG from it
    /// ([`FeModel::refine_step`]). Ignored with `pcg`.
    pub refine: Option<PcgParams>,
    /// Adaptive refresh of the background pipeline (with `background_factorization` and the
    /// direct or refined solve): a step's matrix is sent to the idle worker only when the
    /// factor in use is stale by [`RefreshParams`]' measure; `None`: whenever the worker is
    /// idle, every `refactor_every` steps.
    pub refresh: Option<RefreshParams>,
    /// The precision of the gel's factors ([`Precision::Single`]: `f32`, checked after each
    /// factorisation, see [`crate::linalg::SINGLE_PROBE_TOLERANCE`]).
    pub factor_precision: Precision,
    /// The near block (one flag per mesh node; `None`: none): the dofs of these nodes are
    /// eliminated last, and the block of the factor they span is refactorised on its own, at
    /// once, when an element all of whose nodes are near has rotated by the adaptive refresh's
    /// angle since the factor's matrix, the rest of the factor kept
    /// ([`crate::linalg::TrailingBlock`]). The other elements drive the background pipeline as
    /// before. Needs the nested-dissection ordering, the background factorisation with the
    /// adaptive refresh and the direct solve; ignored otherwise.
    pub near_nodes: Option<Vec<bool>>,
    /// The entry block inside the near block (one flag per mesh node, only near nodes count;
    /// `None` or no such node: none): its dofs are eliminated last of all, and its block of the
    /// factor is refactorised on its own, from the near block's last matrix, when only elements
    /// all of whose nodes are in it have rotated by the refresh's angle. Around the path's
    /// entry point, where the needle's base drags the gel's surface, that is most of the near
    /// block's refreshes, at a fraction of their cost. Ignored without a near block.
    pub entry_nodes: Option<Vec<bool>>,
    /// With a near block: the far residual's tolerance `τ` of the free motion (0: none, every
    /// solve exact). A step whose right-hand side `−f_int` has, on the dofs outside the near
    /// block, a norm of at most `τ` times its whole norm solves with those entries dropped:
    /// the forward substitution then skips every far supernode (the far field is left in
    /// equilibrium to that relative tolerance, and its residual is solved whole by the first
    /// step where it exceeds it). See [`super::FeModel::far_residual_drops`].
    pub far_residual_tolerance: f64,
    /// With a near block and the direct solve: the far rows of each step solved once, after
    /// the constraint solve, for the free and the corrective motion together
    /// ([`super::FeModel::free_motion_deferring_far`], [`super::FeModel::complete_far`]).
    pub defer_far: bool,
    /// With `near_nodes`: the elements not all of whose nodes are near kept linear (their
    /// rotation the identity whatever their deformation,
    /// [`crate::fem::tetra::CorotationalTetra::keep_linear`]); the near elements stay
    /// corotational. The far elements then never make the gel's factor stale, and the far
    /// field, linear and solved with its own matrix, stays in equilibrium.
    pub far_linear: bool,
}

impl Default for GelParams {
    fn default() -> Self {
        Self {
            elasticity: Elasticity {
                young_modulus: 0.005,
                poisson_ratio: 0.45,
            },
            density: 1e-9,
            regions: Vec::new(),
            time_step: None,
            kinematics: Kinematics::Corotational,
            refactor_every: 1,
            background_factorization: false,
            asynchronous_factor: false,
            pcg: None,
            refine: None,
            refresh: None,
            factor_precision: Precision::Double,
            near_nodes: None,
            entry_nodes: None,
            far_residual_tolerance: 0.0,
            defer_far: false,
            far_linear: false,
        }
    }
}

/// Fill-reducing elimination order of a sparse factorisation (chosen once, at construction).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FillOrdering {
    /// Approximate minimum degree (faer's default).
    Amd,
    /// Geometric nested dissection on the node positions
    /// ([`crate::linalg::nested_dissection_order`]).
    #[default]
    NestedDissection,
}

/// The gel's elements: the rest mesh, its corotational tetrahedra and the clamped nodes.
#[derive(Debug)]
pub struct Tets {
    mesh: TetMesh,
    tetra: CorotationalTetra,
    fixed_nodes: Vec<usize>,
}

impl Elements for Tets {
    const NODE_DOFS: usize = 3;
    const STATE_OF_POSITIONS: bool = true;

    fn add_internal_forces(&mut self, positions: &[Vector3<f64>], f_int: &mut [f64]) {
        self.tetra
            .update_rotations_and_add_internal_forces(positions, f_int);
    }

    fn entry_dofs(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.tetra.len()).flat_map(|e| self.tetra.stiffness_entry_dofs(e))
    }

    fn assemble(&self, slots: &[u32], values: &mut [f64]) {
        self.tetra.assemble(slots, values, 1.0);
    }

    fn add_rotation_change(
        &self,
        slots: &[u32],
        values: &mut [f64],
        elements: &[usize],
        from: &[Matrix3<f64>],
    ) {
        let now = self.tetra.rotations();
        for &e in elements {
            self.tetra.assemble_element(e, &now[e], slots, values, 1.0);
            self.tetra
                .assemble_element(e, &from[e], slots, values, -1.0);
        }
    }

    fn displace(
        &mut self,
        positions: &mut [Vector3<f64>],
        dx: &[f64],
        free: &dyn Fn(usize) -> bool,
    ) {
        for (i, p) in positions.iter_mut().enumerate() {
            for k in 0..3 {
                if free(3 * i + k) {
                    p[k] += dx[3 * i + k];
                }
            }
        }
    }

    fn rotations(&self) -> &[Matrix3<f64>] {
        self.tetra.rotations()
    }
}

/// The gel: corotational tetrahedra with eliminated Dirichlet nodes, and its sparse system.
pub type GelModel = FeModel<Tets>;

impl FeModel<Tets> {
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
        let region = |r: i32| params.regions.iter().find(|m| m.tag == r);
        let materials: Vec<Elasticity> = (mesh.regions.iter())
            .map(|&r| region(r).map_or(params.elasticity, |m| m.elasticity))
            .collect();
        let densities: Vec<f64> = (mesh.regions.iter())
            .map(|&r| region(r).map_or(params.density, |m| m.density))
            .collect();
        let mut tetra =
            CorotationalTetra::try_new_per_element(&mesh, &materials, params.kinematics)?;
        let n = mesh.nodes.len();
        let regularization = match params.time_step {
            None => vec![0.0; 3 * n],
            Some(h) => {
                if !(h > 0.0 && h.is_finite())
                    || !densities.iter().all(|d| *d >= 0.0 && d.is_finite())
                {
                    return Err(FemError::Parameter {
                        what: "gel time step must be positive and density non-negative",
                    });
                }
                let m = tetra.lumped_mass_per_element(n, |e| densities[e]);
                (0..3 * n).map(|g| m[g / 3] / (h * h)).collect()
            }
        };
        let coords: Vec<[f64; 3]> = (0..3 * n).map(|g| mesh.nodes[g / 3].into()).collect();
        let near = params
            .near_nodes
            .as_ref()
            .filter(|m| m.len() == n)
            .map(|m| {
                let dofs: Vec<bool> = (0..3 * n).map(|g| m[g / 3]).collect();
                let elements: Vec<bool> = (mesh.tets.iter())
                    .map(|t| t.iter().all(|&v| m[v]))
                    .collect();
                let entry: Vec<bool> = match params.entry_nodes.as_ref() {
                    Some(e) if e.len() == n => (0..n).map(|v| m[v] && e[v]).collect(),
                    _ => Vec::new(),
                };
                let (entry_dofs, entry_elements) = if entry.contains(&true) {
                    (
                        (0..3 * n).map(|g| entry[g / 3]).collect(),
                        (mesh.tets.iter())
                            .map(|t| t.iter().all(|&v| entry[v]))
                            .collect(),
                    )
                } else {
                    (Vec::new(), Vec::new())
                };
                NearLayout {
                    dofs,
                    elements,
                    entry_dofs,
                    entry_elements,
                    far_residual_tolerance: params.far_residual_tolerance,
                    defer_far: params.defer_far,
                }
            });
        if params.far_linear
            && let Some(near) = &near
        {
            tetra.keep_linear(near.elements.iter().map(|n| !n).collect())?;
        }
        let nd = (ordering == FillOrdering::NestedDissection).then_some(coords.as_slice());
        let mut sorted = fixed_nodes.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        let positions = mesh.nodes.clone();
        let elements = Tets {
            mesh,
            tetra,
            fixed_nodes: sorted,
        };
        Self::build(
            elements,
            positions,
            ModelLayout {
                fixed_nodes,
                regularization,
                refactor_every: params.refactor_every,
                dof_coords: nd,
                background: params.background_factorization,
                asynchronous: params.asynchronous_factor,
                pcg: params.pcg,
                refine: params.refine.filter(|_| params.pcg.is_none()),
                refresh: params.refresh.filter(|_| params.pcg.is_none()),
                precision: params.factor_precision,
                near,
            },
        )
    }

    /// The rest mesh.
    pub fn mesh(&self) -> &TetMesh {
        &self.elements.mesh
    }

    /// The element data (rotations, rest stiffness).
    pub fn tetra(&self) -> &CorotationalTetra {
        &self.elements.tetra
    }

    /// Sorted indices of the clamped nodes.
    pub fn fixed_nodes(&self) -> &[usize] {
        &self.elements.fixed_nodes
    }

    /// Places every clamped node at its rest position + `d` [mm] (a rigid translation of the
    /// support: an inhomogeneous Dirichlet condition). The free nodes are not moved: the next
    /// free motion carries them along, its right-hand side `−f_int(x)` holding the strain of
    /// the moved support.
    pub fn displace_support(&mut self, d: &Vector3<f64>) {
        let Tets {
            mesh, fixed_nodes, ..
        } = &self.elements;
        for &i in fixed_nodes {
            self.positions[i] = mesh.nodes[i] + d;
        }
    }

    /// Mutable node positions [mm] (e.g. to prescribe the displacement of fixed nodes).
    pub fn positions_mut(&mut self) -> &mut [Vector3<f64>] {
        &mut self.positions
    }
}
