//! The FE models as the step sees them, and a world built from a scene.

use crate::fem::beam::BeamSection;
use crate::fem::tetra::Kinematics;
use crate::fem::{Elasticity, FemError};
use crate::free_motion::{GelModel, GelParams, NeedleModel, NeedleParams};
use crate::mesh::{TetMesh, box_mesh, read_gmsh};
use crate::scene::Scene;
use crate::world::{FeBody, GelBody, NeedleBody, SimError, World, node_frame_offset};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use needle_core::ik::{IkParams, solve_ik};

impl From<FemError> for SimError {
    fn from(e: FemError) -> Self {
        SimError::Linear(e.to_string())
    }
}

/// The gel: a [`GelModel`] with no external load.
pub struct Gel {
    /// The FE model.
    pub model: GelModel,
    zeros: Vec<f64>,
    dof: Vec<Option<usize>>,
}

impl Gel {
    /// Wraps a model.
    pub fn new(model: GelModel) -> Self {
        let n = model.positions().len();
        let dof = (0..n)
            .map(|i| model.reduced_index(3 * i).map(|_| 3 * i))
            .collect();
        Self {
            zeros: vec![0.0; 3 * n],
            dof,
            model,
        }
    }
}

/// `FeBody` for a wrapper `{ model, zeros }` around a model with the shared free-motion API
/// (`GelModel`, `NeedleModel`): no external load, factor renewal read from `factor_age`.
macro_rules! fe_body {
    ($t:ty) => {
        impl FeBody for $t {
            fn dofs(&self) -> usize {
                self.model.dof_count()
            }

            fn free_motion(&mut self, dx: &mut [f64]) -> Result<bool, SimError> {
                let out = self.model.free_motion(&self.zeros)?;
                dx.copy_from_slice(out);
                Ok(self.model.factor_age() == Some(0))
            }

            fn solve_many(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), SimError> {
                Ok(self.model.solve_columns(rhs, ncols)?)
            }

            fn apply(&mut self, dx: &[f64]) {
                // Finite by the world's check before the call; the length is the model's own.
                let _ = self.model.apply_displacement(dx);
            }
        }
    };
}

fe_body!(Gel);
fe_body!(Needle);

impl GelBody for Gel {
    fn nodes(&self) -> &[Vector3<f64>] {
        self.model.positions()
    }

    fn rest(&self) -> &[Vector3<f64>] {
        &self.model.mesh().nodes
    }

    fn tets(&self) -> &[[usize; 4]] {
        &self.model.mesh().tets
    }

    fn dof(&self, node: usize) -> Option<usize> {
        self.dof[node]
    }
}

/// The needle: a free-floating [`NeedleModel`] held by the base constraint only.
pub struct Needle {
    /// The FE model.
    pub model: NeedleModel,
    zeros: Vec<f64>,
}

impl Needle {
    /// Wraps a model.
    pub fn new(model: NeedleModel) -> Self {
        Self {
            zeros: vec![0.0; model.dof_count()],
            model,
        }
    }
}

impl NeedleBody for Needle {
    fn nodes(&self) -> &[Vector3<f64>] {
        self.model.positions()
    }

    fn rotation(&self, node: usize) -> Matrix3<f64> {
        self.model.orientations()[node]
            .to_rotation_matrix()
            .into_inner()
    }

    fn axis(&self) -> Vector3<f64> {
        Vector3::x()
    }
}

/// The simulation of a scene: the gel and needle FE models in a [`World`].
pub type Simulation = World<Gel, Needle>;

/// The gel mesh of a scene (generated box or Gmsh file), validated.
///
/// # Errors
/// [`SimError::Setup`] naming the mesh file for an unreadable or invalid mesh.
pub fn gel_mesh(scene: &Scene) -> Result<TetMesh, SimError> {
    let mesh = match (&scene.gel.box_mesh, &scene.gel.mesh) {
        (_, Some(path)) => {
            read_gmsh(path).map_err(|e| SimError::Setup(format!("{}: {e}", path.display())))?
        }
        (Some(b), None) => box_mesh(Vector3::from(b.min), Vector3::from(b.max), b.nodes),
        (None, None) => return Err(SimError::Setup("the scene has no gel mesh".into())),
    };
    mesh.validate()
        .map_err(|e| SimError::Setup(format!("gel mesh: {e}")))?;
    Ok(mesh)
}

/// The fixed gel nodes of a scene: below `fixed.below_z` and the listed ones.
///
/// # Errors
/// [`SimError::Setup`] when a listed node does not exist or no node is fixed.
pub fn fixed_nodes(scene: &Scene, mesh: &TetMesh) -> Result<Vec<usize>, SimError> {
    let mut fixed: Vec<usize> = match scene.gel.fixed.below_z {
        Some(z) => {
            let tol = 1e-9 * (1.0 + z.abs());
            (0..mesh.nodes.len())
                .filter(|&i| mesh.nodes[i].z <= z + tol)
                .collect()
        }
        None => Vec::new(),
    };
    for &n in &scene.gel.fixed.nodes {
        if n >= mesh.nodes.len() {
            return Err(SimError::Setup(format!(
                "gel.fixed.nodes: node {n} does not exist ({} nodes)",
                mesh.nodes.len()
            )));
        }
        fixed.push(n);
    }
    fixed.sort_unstable();
    fixed.dedup();
    if fixed.is_empty() {
        return Err(SimError::Setup(
            "gel.fixed: no node of the mesh is fixed".into(),
        ));
    }
    Ok(fixed)
}

/// The starting joints: the scene's `robot.start_joints_deg` when given, else the needle straight
/// along the path's entry tangent, its tip `approach` before the entry point (damped
/// least-squares IK from mid-range).
///
/// # Errors
/// [`SimError::Setup`] when the pose is out of reach.
pub fn start_joints(scene: &Scene) -> Result<[f64; 6], SimError> {
    if let Some(q) = &scene.robot.start_joints_deg {
        let mut out = [0.0; 6];
        for (o, v) in out.iter_mut().zip(q) {
            *o = v.to_radians();
        }
        return Ok(out);
    }
    let chain = scene.robot();
    let path = scene
        .sampled_path()
        .map_err(|e| SimError::Setup(e.to_string()))?;
    let t = path.entry_tangent();
    let base = path.start_tip() - scene.needle.length * t;
    let rep = solve_ik(
        &chain,
        [base.x, base.y, base.z],
        [t.x, t.y, t.z],
        &chain.mid_range(),
        &IkParams::default(),
    )
    .map_err(|e| SimError::Setup(format!("start pose: {e}")))?;
    // The benchmark pose is at the wrist singularity (needle vertical, J5 ≈ 0), where the damped
    // IK creeps: accept a start within 1 µm and 0.1 mrad.
    if !(rep.position_error <= 1e-3 && rep.angle_error <= 1e-4) {
        return Err(SimError::Setup(format!(
            "start pose out of reach: needle base ({:.3}, {:.3}, {:.3}) mm along ({:.4}, {:.4}, {:.4}): \
             IK stopped {:.3} mm / {:.2e} rad away",
            base.x, base.y, base.z, t.x, t.y, t.z, rep.position_error, rep.angle_error
        )));
    }
    Ok(rep.q)
}

/// Builds the simulation of `scene` at its start: gel at rest, needle straight at the IK pose.
///
/// # Errors
/// [`SimError::Setup`] for an invalid mesh, an unreachable start, or a path outside the gel;
/// [`SimError::Linear`] if a model cannot be built.
pub fn build(scene: &Scene) -> Result<Simulation, SimError> {
    let mesh = gel_mesh(scene)?;
    let fixed = fixed_nodes(scene, &mesh)?;
    let h = scene.solver.time_step;
    let gel = GelModel::try_new(
        mesh,
        &fixed,
        &GelParams {
            elasticity: Elasticity {
                young_modulus: scene.gel.young_modulus,
                poisson_ratio: scene.gel.poisson_ratio,
            },
            density: scene.gel.density,
            time_step: Some(h),
            kinematics: Kinematics::Corotational,
            refactor_every: scene.solver.refactor_every() as usize,
            background_factorization: scene.solver.background_factorization,
        },
    )?;
    let q0 = start_joints(scene)?;
    let chain = scene.robot();
    let b = chain.tool_pose(&q0);
    let r_node = b.rotation * node_frame_offset(&Vector3::x());
    let iso = Isometry3::from_parts(
        Translation3::from(b.translation),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_node)),
    );
    let n = &scene.needle;
    let needle = NeedleModel::straight(
        &iso,
        n.length,
        n.beams,
        &[],
        &NeedleParams {
            section: BeamSection {
                elasticity: Elasticity {
                    young_modulus: n.young_modulus,
                    poisson_ratio: n.poisson_ratio,
                },
                outer_diameter: n.diameter,
                inner_diameter: 0.0,
                density: n.density,
            },
            time_step: Some(h),
            refactor_every: 1,
        },
    )?;
    let mut needle = needle;
    // The free-floating needle needs the material stiffness only (see
    // `CorotationalBeams::set_geometric_stiffness`).
    needle.set_geometric_stiffness(false);
    World::from_parts(
        scene.clone(),
        chain,
        scene.inverse_params(),
        Gel::new(gel),
        Needle::new(needle),
        q0,
    )
}
