//! From a scene to what a run needs — the one reader of [`Scene`]: the [`World`] at its start
//! (gel mesh and model, needle at the start pose, path, obstacles), the typed parameters of the
//! step ([`StepParams`]), of the FE models ([`GelParams`], [`NeedleParams`]) and of the core
//! ([`InverseParams`], with the robot), and the run's [`Plan`]. A parameter walks one way: scene
//! file → [`Scene`] → here → typed parameters → step.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::error::{Body, SetupError};
use crate::fem::Elasticity;
use crate::fem::beam::BeamSection;
use crate::fem::tetra::Kinematics;
use crate::free_motion::{
    GelModel, GelParams, NeedleModel, NeedleParams, PcgParams, RefreshParams, RegionMaterial,
};
use crate::joints::{WithJoints, with_joints};
use crate::linalg::Precision;
use crate::mesh::{TetMesh, box_mesh, read_mesh};
use crate::scene::{
    ENTRY_AUTO_FACTOR, FactorPrecisionSpec, FarElementsSpec, GelSolveSpec, InsertionMode,
    NearRadiusSpec, SampledPath, Scene,
};
use crate::step::{Insertion, Interaction, StepParams, TargetMotion};
use crate::support_motion::SupportMotion;
use crate::world::{ObstacleShape, World, WorldParts, node_frame_offset};
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use needle_core::ik::{IkParams, solve_ik};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::{Kinematics as _, Robot};

/// What a run of a scene plans, besides the simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Scene name.
    pub name: String,
    /// Obstacle labels (`obstacle k` when the scene gives none).
    pub obstacle_names: Vec<String>,
    /// Steps of the run: the scene's `insertion.steps`, else a whole insertion.
    pub steps: usize,
    /// Write VTK files every this many steps (0: never).
    pub vtk_every: usize,
    /// The gel's support motion, as the summary gives it (`gel.support_motion`; none: the
    /// support stays still).
    pub support_motion: Option<crate::support_motion::MotionSummary>,
    /// The target only goes in (`insertion.mode = "insert"`): a needle that leaves the gel
    /// after puncturing it did not follow the path ([`crate::run::metrics::Outcome::of`]).
    pub insert_only: bool,
    /// The needle's steering length in the gel, [`steering_length`] of the scene's needle and
    /// gel [mm].
    pub steering_length_mm: f64,
    /// The horizon of the `"qp"` update's tip objective, `inverse.qp_horizon` resolved
    /// ([`crate::scene::HorizonSpec::horizon`] of the steering length under `"auto"`) [mm].
    pub qp_horizon_mm: f64,
    /// How far the target shown to the controller is straightened towards a chord of the path,
    /// `inverse.straighten` resolved ([`crate::straighten::Straightening::for_scene`]) [-].
    pub straighten: f64,
    /// Where that chord starts: path length past the entry point [mm].
    pub straighten_from_mm: f64,
    /// The lowest fraction along the path: lower than [`Plan::straighten`] where the chord
    /// passes nearer an obstacle than the path, or the shown point would be more than
    /// [`Plan::straighten_max_offset_mm`] off it ([`crate::straighten::Straightening`]) [-].
    pub straighten_lowest: f64,
    /// The bound on the shown point's distance from the path (`inverse.straighten_max_offset`)
    /// [mm].
    pub straighten_max_offset_mm: f64,
    /// The distance the shown target keeps from the obstacles (`inverse.target_standoff`; 0
    /// for the paper's update, shown the planned path) [mm].
    pub target_standoff_mm: f64,
    /// The needle's yield strain (`needle.yield_strain`; none: not checked) [-].
    pub needle_yield_strain: Option<f64>,
    /// Whether the controller keeps the needle's bends under it ([`strain_bounded`]).
    pub needle_strain_bounded: bool,
    /// What the plan allows but makes unlikely to succeed
    /// ([`crate::plan_check::advisories`]); empty when nothing is.
    pub advisories: Vec<String>,
}

/// The length over which a needle bends as a beam on an elastic foundation, the gel:
/// `ℓ = (E_n I / E_gel)^(1/4)`, `I = π d⁴ / 64` (diameter `d` [mm], moduli [MPa]) [mm]. How far
/// into the gel a motion of the needle's base still turns its tip: a base rotation's effect
/// decays over about `ℓ`, so that deeper than a few `ℓ` the gel holds the shaft and the joints
/// barely steer the tip sideways. On the public suite and seven held-out sets (201 runs,
/// `docs/benchmark.md`), 26 of the 28 scenes with `ℓ` under 17.5 mm miss their target, and 6 of
/// the other 173. It counts the gel's Young modulus only (not its Poisson ratio, nor the
/// regions of a gel of several materials: the gel's own modulus is used).
///
/// # Example
/// ```
/// use needle_host::setup::steering_length;
///
/// // The benchmark's needle (Ø 1 mm steel) in its 20 kPa gel.
/// let l = steering_length(1.0, 200_000.0, 0.02);
/// assert!((l - (200_000.0 * std::f64::consts::PI / 64.0 / 0.02_f64).powf(0.25)).abs() < 1e-12);
/// assert!((l - 26.5).abs() < 0.05);
/// ```
pub fn steering_length(diameter: f64, needle_modulus: f64, gel_modulus: f64) -> f64 {
    let inertia = std::f64::consts::PI * diameter.powi(4) / 64.0;
    (needle_modulus * inertia / gel_modulus).powf(0.25)
}

/// A scene, set up: the world at its start and every typed parameter; a robot of `N` joints
/// (6 by default; [`AnySetup`] sets a scene up with its own count).
pub struct Setup<const N: usize = 6> {
    /// The world at its start.
    pub world: World<N>,
    /// The step's tuning.
    pub params: StepParams,
    /// The robot (as the core sees it).
    pub robot: Robot<N>,
    /// The core's tuning.
    pub inverse: InverseParams,
    /// What a run plans.
    pub plan: Plan,
    /// With `gel.support_motion.hidden`: the controller's model, the same world without the
    /// support motion (the controller steers on it, its joints drive `world`); none otherwise.
    pub model: Option<Box<World<N>>>,
}

impl Setup {
    /// Sets `scene` up with a 6-joint robot (the RV-1A, a DH table, a 6-joint URDF): gel at
    /// rest, needle straight at the start pose. [`AnySetup::build`] sets up any robot this host
    /// runs.
    ///
    /// # Errors
    /// As [`Setup::for_joints`]; a robot of another count is refused ([`SetupError::Robot`]).
    ///
    /// # Example
    /// ```
    /// use needle_host::{scene::Scene, setup::Setup};
    ///
    /// let scene = Scene::builtin("simple").unwrap()
    ///     .with_overrides(&[("gel.box.nodes".into(), "300".into())]).unwrap();
    /// let s = Setup::build(&scene).unwrap();
    /// assert_eq!(s.plan.steps, 609); // 60.9 mm of path at 0.1 mm per step
    /// assert!(!s.world.punctured && s.world.gel.node_count() < 400);
    /// assert_eq!(s.params.interaction.puncture_force, scene.interaction.puncture_force);
    /// ```
    pub fn build(scene: &Scene) -> Result<Self, SetupError> {
        Self::for_joints(scene)
    }
}

/// Code generic over the joint count, called by [`with_setup`] on a scene set up with its
/// robot's own count.
pub trait WithSetup {
    /// What the call gives.
    type Output;
    /// The call on a set-up of `N` joints.
    fn with<const N: usize>(self, setup: Setup<N>) -> Self::Output;
}

/// Sets `scene` up with as many joints as its robot has (6 or 7, [`Scene::joint_count`]) and
/// calls `f` on it: how a run reaches the const generic `N` of the world, the step and the
/// core from a scene (through [`with_joints`], the one place where a count becomes `N`).
///
/// # Errors
/// As [`Setup::for_joints`]; a URDF chain of another count is refused naming its joints
/// ([`SetupError::Robot`], field `robot.urdf`).
pub fn with_setup<F: WithSetup>(scene: &Scene, f: F) -> Result<F::Output, SetupError> {
    struct Build<'a, F>(&'a Scene, F);
    impl<F: WithSetup> WithJoints for Build<'_, F> {
        type Output = Result<F::Output, SetupError>;
        fn with<const N: usize>(self) -> Self::Output {
            Ok(self.1.with(Setup::<N>::for_joints(self.0)?))
        }
    }
    let n = scene.joint_count().map_err(robot_error)?;
    with_joints(n, Build(scene, f)).unwrap_or_else(|| {
        Err(SetupError::Robot {
            field: "robot".into(),
            reason: format!("a robot of {n} joints; this host runs arms of 6 or 7 joints"),
        })
    })
}

impl<const N: usize> Setup<N> {
    /// Sets `scene` up with an `N`-joint robot: gel at rest, needle straight at the start pose.
    ///
    /// # Errors
    /// [`SetupError`]: an invalid mesh, an unreachable start, a path or obstacle outside the gel,
    /// a model that cannot be built.
    ///
    pub fn for_joints(scene: &Scene) -> Result<Self, SetupError> {
        let t0 = std::time::Instant::now();
        let path = scene.sampled_path().map_err(SetupError::Path)?;
        let mesh = gel_mesh(scene)?;
        tracing::debug!(
            nodes = mesh.node_count(),
            elements = mesh.tet_count(),
            "scene `{}`: gel mesh ready after {:.2} s",
            scene.name,
            t0.elapsed().as_secs_f64()
        );
        let fixed = fixed_nodes(scene, &mesh)?;
        let (near, entry) = near_and_entry_nodes(scene, &mesh, &path);
        let params = GelParams {
            near_nodes: near,
            entry_nodes: entry,
            ..gel_params(scene, mesh.node_count())
        };
        let gel = GelModel::try_new(mesh, &fixed, &params).map_err(|source| SetupError::Model {
            body: Body::Gel,
            source,
        })?;
        let robot = scene.robot_n::<N>().map_err(robot_error)?;
        let q = start_joints_n(scene, &robot)?;
        let needle = start_needle(scene, &robot, &q)?;
        let obstacles = obstacle_shapes(scene)?;
        let lags = crate::plan_check::lags_its_bend(
            scene.steering_length(),
            crate::plan_check::path_bend(&path),
        );
        let straightening = crate::straighten::Straightening::for_scene(
            &path,
            (
                scene.inverse.straighten,
                scene.inverse.straighten_from,
                scene.inverse.straighten_max_offset,
            ),
            scene.inverse.method,
            (lags, scene.steering_length()),
            &obstacles,
        );
        // The paper's update is shown the planned path.
        let straightening = match scene.inverse.method {
            crate::scene::MethodSpec::Paper => straightening,
            _ => straightening.with_standoff(&path, scene.inverse.target_standoff, &obstacles),
        };
        let mut world = World::try_new(WorldParts {
            robot,
            gel,
            needle,
            needle_length: scene.needle.length,
            path,
            obstacles,
            q,
            support_motion: support_motion(scene)?,
        })?;
        crate::plan_check::check(scene, &world)?;
        let model = match &scene.gel.support_motion {
            Some(m) if m.hidden => {
                let mut still = scene.clone();
                still.gel.support_motion = None;
                Some(Box::new(Self::for_joints(&still)?.world))
            }
            _ => None,
        };
        let mut plan = plan(scene);
        plan.support_motion = (world.support_motion.as_ref()).map(|m| m.summary(model.is_some()));
        plan.advisories = crate::plan_check::advisories(scene, &world);
        plan.straighten = straightening.fraction;
        plan.straighten_from_mm = straightening.from;
        plan.straighten_lowest = straightening.lowest();
        plan.straighten_max_offset_mm = scene.inverse.straighten_max_offset;
        plan.target_standoff_mm = straightening.standoff;
        world.straightening = straightening;
        for a in &plan.advisories {
            tracing::warn!("scene `{}`: {a}", scene.name);
        }
        tracing::info!(
            "scene `{}` set up in {:.2} s: {} gel nodes, needle of {} beams",
            scene.name,
            t0.elapsed().as_secs_f64(),
            world.gel.node_count(),
            scene.needle.beams
        );
        Ok(Self {
            world,
            params: step_params(scene),
            robot,
            inverse: scene.inverse_params(),
            plan,
            model,
        })
    }
}

/// The support motion of `scene` (`gel.support_motion`), its CSV file read.
///
/// # Errors
/// [`SetupError::Plan`] naming the field, and for a CSV file the file, the line and the reason.
pub fn support_motion(scene: &Scene) -> Result<Option<SupportMotion>, SetupError> {
    let Some(m) = &scene.gel.support_motion else {
        return Ok(None);
    };
    match (&m.breathing, &m.csv) {
        (Some(b), _) => SupportMotion::breathing(b.amplitude, b.period, b.direction, b.phase)
            .map(Some)
            .map_err(|reason| SetupError::Plan {
                field: "gel.support_motion.breathing".into(),
                reason,
            }),
        (None, Some(file)) => {
            SupportMotion::from_csv(file)
                .map(Some)
                .map_err(|e| SetupError::Plan {
                    field: "gel.support_motion.csv".into(),
                    reason: e.to_string(),
                })
        }
        (None, None) => Err(SetupError::Plan {
            field: "gel.support_motion".into(),
            reason: "give `breathing` or `csv`".into(),
        }),
    }
}

/// The robot of `N` joints and the core's tuning of `scene` (what `needle-controller` needs,
/// and what `needle serve` fingerprints): call it with the scene's own count
/// ([`Scene::joint_count`], through [`with_joints`]).
///
/// # Errors
/// [`SetupError::Robot`] naming the field when the robot cannot be built, or is not a chain of
/// `N` joints.
pub fn core<const N: usize>(scene: &Scene) -> Result<(Robot<N>, InverseParams), SetupError> {
    let robot = scene.robot_n::<N>().map_err(robot_error)?;
    Ok((robot, scene.inverse_params()))
}

/// The error of [`Scene::robot`] as a setup error.
fn robot_error((field, reason): (String, String)) -> SetupError {
    SetupError::Robot { field, reason }
}

/// The step's tuning of `scene`.
pub fn step_params(scene: &Scene) -> StepParams {
    let i = &scene.interaction;
    StepParams {
        interaction: Interaction {
            puncture_force: i.puncture_force,
            surface_friction: i.surface_friction,
            shaft_friction: i.shaft_friction,
            shaft_resistance: i.shaft_resistance,
            constraint_spacing: i.constraint_spacing,
        },
        insertion: Insertion {
            advance_per_step: scene.insertion.advance_per_step,
            motion: match scene.insertion.mode {
                InsertionMode::Insert => TargetMotion::Insert,
                InsertionMode::BackAndForth => TargetMotion::BackAndForth,
            },
            max_lead: scene.insertion.max_lead,
        },
        dt: scene.robot.dt,
        max_base_step: scene.inverse.max_base_step,
        max_entry_shift: scene.inverse.max_entry_shift.unwrap_or(f64::INFINITY),
        yield_strain: match scene.needle.yield_strain {
            Some(y) if strain_bounded(scene) => y,
            _ => f64::INFINITY,
        },
        entry_tilt: scene.inverse.entry_tilt.angle(i.surface_friction),
    }
}

/// Whether the controller keeps the needle's bends under its yield strain: a `"qp"` update
/// with `needle.yield_strain` given and `inverse.bound_strain` on.
pub fn strain_bounded(scene: &Scene) -> bool {
    scene.needle.yield_strain.is_some()
        && scene.inverse.bound_strain
        && scene.inverse.method == crate::scene::MethodSpec::Qp
}

/// The gel model's parameters of `scene` for a gel of `nodes` nodes (the defaults that depend
/// on the gel's size, such as `solver.far_refresh_rotation`'s, follow it).
pub fn gel_params(scene: &Scene, nodes: usize) -> GelParams {
    GelParams {
        elasticity: Elasticity {
            young_modulus: scene.gel.young_modulus,
            poisson_ratio: scene.gel.poisson_ratio,
        },
        density: scene.gel.density,
        regions: (scene.gel.regions.iter())
            .map(|r| RegionMaterial {
                tag: r.tag,
                elasticity: Elasticity {
                    young_modulus: r.young_modulus,
                    poisson_ratio: r.poisson_ratio.unwrap_or(scene.gel.poisson_ratio),
                },
                density: r.density.unwrap_or(scene.gel.density),
            })
            .collect(),
        time_step: Some(scene.solver.time_step),
        kinematics: Kinematics::Corotational,
        refactor_every: scene.solver.refactor_every() as usize,
        background_factorization: scene.solver.background_factorization,
        asynchronous_factor: scene.solver.asynchronous_factor,
        pcg: (scene.solver.gel_solve == GelSolveSpec::Pcg).then_some(PcgParams {
            tolerance: scene.solver.pcg_tolerance,
            max_iterations: scene.solver.pcg_max_iterations as usize,
        }),
        refine: (scene.solver.gel_solve == GelSolveSpec::Refine).then_some(PcgParams {
            tolerance: scene.solver.pcg_tolerance,
            max_iterations: scene.solver.pcg_max_iterations as usize,
        }),
        refresh: (scene.solver.refresh_rotation > 0.0).then_some(RefreshParams {
            rotation: scene.solver.refresh_rotation,
            far_rotation: scene.solver.far_refresh_rotation(nodes),
            ceiling: scene
                .solver
                .refresh_ceiling
                .map_or(usize::MAX, |c| c as usize),
        }),
        factor_precision: match scene.solver.factor_precision {
            FactorPrecisionSpec::Single => Precision::Single,
            FactorPrecisionSpec::Double => Precision::Double,
        },
        far_residual_tolerance: scene.solver.far_residual_tolerance,
        defer_far: scene.solver.defer_far,
        far_linear: scene.solver.far_elements == FarElementsSpec::Linear,
        near_nodes: None,
        entry_nodes: None,
    }
}

/// The near block's nodes ([`near_nodes`]) with the entry block's added, and the entry block's
/// nodes: those within `solver.entry_radius` of the path's entry point (`"auto"`:
/// [`ENTRY_AUTO_FACTOR`] times the near radius). `(None, None)` without a near
/// block; `(near, None)` without an entry block.
pub fn near_and_entry_nodes(
    scene: &Scene,
    mesh: &TetMesh,
    path: &SampledPath,
) -> (Option<Vec<bool>>, Option<Vec<bool>>) {
    let Some(mut near) = near_nodes(scene, mesh, path) else {
        return (None, None);
    };
    let near_radius = scene
        .solver
        .near_radius
        .radius(mesh.node_count(), mesh.total_volume());
    let radius = match scene.solver.entry_radius {
        NearRadiusSpec::Auto => near_radius.map(|r| ENTRY_AUTO_FACTOR * r),
        NearRadiusSpec::Off => None,
        NearRadiusSpec::Radius(r) => Some(r),
    };
    let Some(radius) = radius else {
        return (Some(near), None);
    };
    tracing::debug!(
        radius,
        "the gel's entry block: nodes within {radius:.1} mm of the entry point"
    );
    let entry_point = path.entry();
    let entry: Vec<bool> = (mesh.nodes.iter())
        .map(|p| (p - entry_point).norm() <= radius)
        .collect();
    for (n, e) in near.iter_mut().zip(&entry) {
        *n |= *e;
    }
    (Some(near), Some(entry))
}

/// The gel's nodes within `solver.near_radius` (as [`crate::scene::NearRadiusSpec::radius`] resolves it for
/// this mesh) of the planned path at rest or of its straight
/// approach above the entry point (`None` without the option): the near block of
/// [`GelParams::near_nodes`].
pub fn near_nodes(scene: &Scene, mesh: &TetMesh, path: &SampledPath) -> Option<Vec<bool>> {
    let radius = scene
        .solver
        .near_radius
        .radius(mesh.node_count(), mesh.total_volume())?;
    tracing::debug!(
        radius,
        "the gel's near block: nodes within {radius:.1} mm of the path"
    );
    let entry = path.entry();
    let back = -path.entry_tangent() * path.approach;
    let segments = path
        .points
        .windows(2)
        .map(|w| (w[0], w[1]))
        .chain(std::iter::once((entry + back, entry)));
    let segments: Vec<(Vector3<f64>, Vector3<f64>)> = segments.collect();
    let distance = |p: &Vector3<f64>| {
        segments
            .iter()
            .map(|(a, b)| {
                let ab = b - a;
                let t = if ab.norm_squared() > 0.0 {
                    ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (a + ab * t - p).norm()
            })
            .fold(f64::INFINITY, f64::min)
    };
    Some(mesh.nodes.iter().map(|p| distance(p) <= radius).collect())
}

/// The needle model's parameters of `scene`.
pub fn needle_params(scene: &Scene) -> NeedleParams {
    let n = &scene.needle;
    NeedleParams {
        section: BeamSection {
            elasticity: Elasticity {
                young_modulus: n.young_modulus,
                poisson_ratio: n.poisson_ratio,
            },
            outer_diameter: n.diameter,
            inner_diameter: 0.0,
            density: n.density,
        },
        time_step: Some(scene.solver.time_step),
        refactor_every: 1,
    }
}

/// Steps a scene plans: its `insertion.steps`, else a whole insertion (to the end of the path,
/// or there and back).
pub fn planned_steps(scene: &Scene) -> usize {
    scene.insertion.steps.unwrap_or_else(|| {
        let total = scene
            .sampled_path()
            .map(|p| p.total_length())
            .unwrap_or(0.0);
        step_params(scene).insertion.default_steps(total)
    })
}

fn plan(scene: &Scene) -> Plan {
    Plan {
        name: scene.name.clone(),
        obstacle_names: scene
            .obstacles
            .iter()
            .enumerate()
            .map(|(k, o)| {
                if o.name.is_empty() {
                    format!("obstacle {k}")
                } else {
                    o.name.clone()
                }
            })
            .collect(),
        steps: planned_steps(scene),
        vtk_every: scene.output.vtk_every,
        support_motion: None,
        insert_only: scene.insertion.mode == crate::scene::InsertionMode::Insert,
        steering_length_mm: scene.steering_length(),
        qp_horizon_mm: scene.inverse_params().qp_horizon,
        straighten: 0.0,
        straighten_from_mm: 0.0,
        straighten_lowest: 0.0,
        straighten_max_offset_mm: scene.inverse.straighten_max_offset,
        target_standoff_mm: 0.0,
        needle_yield_strain: scene.needle.yield_strain,
        needle_strain_bounded: strain_bounded(scene),
        advisories: Vec::new(),
    }
}

/// The gel mesh of a scene (generated box, or a Gmsh, `.vtu` or `.vtk` file), validated.
///
/// # Errors
/// [`SetupError::MeshFile`] naming the file, [`SetupError::Mesh`], [`SetupError::NoMesh`].
pub fn gel_mesh(scene: &Scene) -> Result<TetMesh, SetupError> {
    let mesh = match (&scene.gel.box_mesh, &scene.gel.mesh) {
        (_, Some(path)) => read_mesh(path).map_err(|source| SetupError::MeshFile {
            file: path.clone(),
            source,
        })?,
        (Some(b), None) => box_mesh(Vector3::from(b.min), Vector3::from(b.max), b.nodes),
        (None, None) => return Err(SetupError::NoMesh),
    };
    mesh.validate().map_err(SetupError::Mesh)?;
    metres_hint(&mesh)?;
    listed_regions_exist(scene, &mesh)?;
    Ok(mesh)
}

/// Every region `gel.regions` lists is a region of the mesh (a tag that matches no element is
/// most likely a typo, and would leave the region it meant at the gel's default material).
fn listed_regions_exist(scene: &Scene, mesh: &TetMesh) -> Result<(), SetupError> {
    let present = mesh.region_tags();
    for (i, r) in scene.gel.regions.iter().enumerate() {
        if present.binary_search(&r.tag).is_ok() {
            continue;
        }
        let file = match &scene.gel.mesh {
            Some(path) => format!("mesh {}", path.display()),
            None => "the generated box (one region, tag 0)".to_owned(),
        };
        let label = if r.name.is_empty() {
            String::new()
        } else {
            format!(" (`{}`)", r.name)
        };
        return Err(SetupError::Plan {
            field: format!("gel.regions[{i}].tag"),
            reason: format!(
                "region {}{label} is not in {file}, whose elements have region tags {present:?}",
                r.tag
            ),
        });
    }
    Ok(())
}

/// A gel smaller than 2 mm across is refused with a hint: coordinates are read in mm, and such a
/// mesh was most likely written in metres.
fn metres_hint(mesh: &TetMesh) -> Result<(), SetupError> {
    let (lo, hi) = mesh.bounds();
    let size = (hi - lo).norm();
    if size >= 2.0 {
        return Ok(());
    }
    Err(SetupError::Plan {
        field: "gel.mesh".into(),
        reason: format!(
            "the gel is only {size:.3} mm across; coordinates are read in mm (a mesh in metres? scale it by 1000)"
        ),
    })
}

/// The fixed gel nodes of a scene: below `fixed.below_z` and the listed ones.
///
/// # Errors
/// [`SetupError::FixedNodeMissing`], [`SetupError::NothingFixed`].
pub fn fixed_nodes(scene: &Scene, mesh: &TetMesh) -> Result<Vec<usize>, SetupError> {
    let mut fixed: Vec<usize> = match scene.gel.fixed.below_z {
        Some(z) => {
            let tol = 1e-9 * (1.0 + z.abs());
            (0..mesh.nodes.len())
                .filter(|&i| mesh.nodes[i].z <= z + tol)
                .collect()
        }
        None => Vec::new(),
    };
    for &node in &scene.gel.fixed.nodes {
        if node >= mesh.nodes.len() {
            return Err(SetupError::FixedNodeMissing {
                node,
                nodes: mesh.nodes.len(),
            });
        }
        fixed.push(node);
    }
    fixed.sort_unstable();
    fixed.dedup();
    if fixed.is_empty() {
        return Err(SetupError::NothingFixed);
    }
    Ok(fixed)
}

/// The starting joints: the scene's `robot.start_joints_deg` when given, else the needle straight
/// along the path's entry tangent, its tip `approach` before the entry point (damped
/// least-squares IK from `robot.ik_seed_deg`, else from mid-range).
///
/// # Errors
/// [`SetupError::StartPose`], [`SetupError::StartOutOfReach`], [`SetupError::Path`].
pub fn start_joints(scene: &Scene) -> Result<[f64; 6], SetupError> {
    start_joints_n(scene, &scene.robot().map_err(robot_error)?)
}

/// [`start_joints`] of an `N`-joint `chain` (the scene's robot).
///
/// # Errors
/// As [`start_joints`].
pub fn start_joints_n<const N: usize>(
    scene: &Scene,
    chain: &Robot<N>,
) -> Result<[f64; N], SetupError> {
    if let Some(q) = &scene.robot.start_joints_deg {
        let mut out = [0.0; N];
        for (o, v) in out.iter_mut().zip(q) {
            *o = v.to_radians();
        }
        return Ok(out);
    }
    let seed = match &scene.robot.ik_seed_deg {
        Some(v) => {
            let mut seed = [0.0; N];
            for (o, d) in seed.iter_mut().zip(v) {
                *o = d.to_radians();
            }
            seed
        }
        None => chain.mid_range(),
    };
    let path = scene.sampled_path().map_err(SetupError::Path)?;
    let t = path.entry_tangent();
    let base = path.start_tip() - scene.needle.length * t;
    let rep = solve_ik(
        chain,
        [base.x, base.y, base.z],
        [t.x, t.y, t.z],
        &seed,
        &IkParams::default(),
    )
    .map_err(SetupError::StartPose)?;
    // The benchmark pose is at the wrist singularity (needle vertical, J5 ≈ 0), where the damped
    // IK creeps: accept a start within 1 µm and 0.1 mrad.
    if !(rep.position_error <= 1e-3 && rep.angle_error <= 1e-4) {
        return Err(SetupError::StartOutOfReach {
            base,
            axis: t,
            position_error: rep.position_error,
            angle_error: rep.angle_error,
        });
    }
    Ok(rep.q)
}

/// The needle of `scene` straight at the pose `B(q)` of the robot, free-floating (held by the
/// base constraint only), with the material stiffness only (see
/// `CorotationalBeams::set_geometric_stiffness`).
fn start_needle<const N: usize>(
    scene: &Scene,
    robot: &Robot<N>,
    q: &[f64; N],
) -> Result<NeedleModel, SetupError> {
    let b = robot.tool_pose(q);
    let r_node = b.rotation * node_frame_offset(&Vector3::x());
    let iso = Isometry3::from_parts(
        Translation3::from(b.translation),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_node)),
    );
    let n = &scene.needle;
    let mut needle = NeedleModel::straight(&iso, n.length, n.beams, &[], &needle_params(scene))
        .map_err(|source| SetupError::Model {
            body: Body::Needle,
            source,
        })?;
    needle.set_geometric_stiffness(false);
    Ok(needle)
}

/// The scene's obstacles in the rest configuration: spheres, and surface meshes read from
/// their files and placed (`scale`, then `translation`).
///
/// # Errors
/// [`SetupError::ObstacleMesh`] for a mesh file that cannot be read or is not a closed surface.
pub fn obstacle_shapes(scene: &Scene) -> Result<Vec<ObstacleShape>, SetupError> {
    scene
        .obstacles
        .iter()
        .enumerate()
        .map(|(index, o)| match (&o.mesh, o.center, o.radius) {
            (Some(file), _, _) => {
                crate::obstacle_mesh::read_surface_mesh(file, o.physical_group.as_ref())
                    .map(|m| {
                        ObstacleShape::Mesh(m.placed(
                            o.scale.unwrap_or(1.0),
                            &Vector3::from(o.translation.unwrap_or_default()),
                        ))
                    })
                    .map_err(|e| SetupError::ObstacleMesh {
                        index,
                        file: file.clone(),
                        reason: e.reason,
                    })
            }
            (None, Some(center), Some(radius)) => Ok(ObstacleShape::Sphere {
                center: Vector3::from(center),
                radius,
            }),
            // Refused by the scene's validation.
            (None, _, _) => Err(SetupError::ObstacleMesh {
                index,
                file: Default::default(),
                reason: "neither a sphere (`center`, `radius`) nor a mesh (`mesh`)".into(),
            }),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene that sets nothing gets the typed parameters' own defaults.
    #[test]
    fn a_scene_with_defaults_gives_the_default_step_params() {
        let s = Scene::from_toml_str(
            "name = \"d\"\n[path]\npoints = [[300.0, 0.0, 60.0], [300.0, 0.0, 20.0]]\n",
            "d.toml",
        )
        .expect("scene");
        assert_eq!(step_params(&s), StepParams::default());
    }

    /// The entry block: the nodes within `solver.entry_radius` of the entry point, added to the
    /// near block; `"auto"` is 1.5 near radii; none without a near block.
    #[test]
    fn entry_nodes_are_a_ball_at_the_entry_point_inside_the_near_block() {
        let text = "name = \"d\"\n[gel.box]\nmin = [260.0, -30.0, 0.0]\nmax = [340.0, 30.0, 60.0]\nnodes = 5000\n\
                    [path]\npoints = [[300.0, 0.0, 60.0], [300.0, 0.0, 20.0]]\n";
        let scene = Scene::from_toml_str(text, "d.toml").expect("scene");
        let mesh = gel_mesh(&scene).expect("mesh");
        let path = scene.sampled_path().expect("path");
        let radius = (scene.solver.near_radius)
            .radius(mesh.node_count(), mesh.total_volume())
            .expect("a near block at 5000 nodes");
        let (near, entry) = near_and_entry_nodes(&scene, &mesh, &path);
        let (near, entry) = (near.expect("near"), entry.expect("entry"));
        let plain = near_nodes(&scene, &mesh, &path).expect("near");
        let entry_point = Vector3::new(300.0, 0.0, 60.0);
        let mut added = 0;
        for (i, p) in mesh.nodes.iter().enumerate() {
            let d = (p - entry_point).norm();
            assert_eq!(entry[i], d <= 1.5 * radius, "node {i} at {d} mm");
            assert_eq!(near[i], plain[i] || entry[i], "node {i}");
            added += usize::from(entry[i] && !plain[i]);
        }
        assert!(entry.iter().filter(|e| **e).count() > 10);
        assert!(added > 0, "the ball reaches beyond the path's radius");
        let off = Scene {
            solver: crate::scene::SolverSpec {
                entry_radius: NearRadiusSpec::Off,
                ..scene.solver
            },
            ..scene.clone()
        };
        assert_eq!(
            near_and_entry_nodes(&off, &mesh, &path),
            (Some(plain), None)
        );
        let no_near = Scene {
            solver: crate::scene::SolverSpec {
                near_radius: NearRadiusSpec::Off,
                ..scene.solver
            },
            ..scene
        };
        assert_eq!(near_and_entry_nodes(&no_near, &mesh, &path), (None, None));
    }
}
