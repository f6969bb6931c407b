//! Scene files: everything one insertion needs, in TOML.
//!
//! A scene names the robot, the gel, the needle, the interaction parameters, the inverse
//! controller's tuning, the planned path (in the gel's rest configuration) and the obstacles.
//! Every field and its unit is documented in `docs/scene-format.md`; units are mm, N, MPa, s, rad.
//!
//! Loading is two-stage: [`serde`] parses the TOML into [`Scene`] (unknown fields are errors,
//! missing fields take the documented defaults), then [`Scene::validate`] checks every value
//! against its physical meaning. Both stages report the file, the dotted field path and the reason
//! ([`SceneError`]).
//!
//! The two benchmark scenes of `BENCHMARK.md` are embedded ([`Scene::builtin`]) so the CLI runs
//! without any file.

mod convert;
mod defaults;
mod load;
mod path;
mod validate;

use defaults::*;
pub use load::SceneError;

pub use path::{MAX_FORMULA_CHARS, MAX_PATH_POINTS, PathError, SampledPath};
pub use validate::{MAX_OBSTACLES, MAX_STEPS};

pub use crate::step::EntryTilt;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The `simple` benchmark scene (BENCHMARK.md, Fig. 5), as shipped in `scenes/simple.toml`.
pub const SIMPLE_TOML: &str = include_str!("../../../scenes/simple.toml");
/// The `complex` benchmark scene (BENCHMARK.md, Fig. 6), as shipped in `scenes/complex.toml`.
pub const COMPLEX_TOML: &str = include_str!("../../../scenes/complex.toml");

/// A whole scene.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Short name used in reports and output folders.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// The robot holding the needle.
    #[serde(default)]
    pub robot: RobotSpec,
    /// The deformable gel (tissue phantom).
    #[serde(default)]
    pub gel: GelSpec,
    /// The flexible needle.
    #[serde(default)]
    pub needle: NeedleSpec,
    /// Needle-gel interaction (puncture, friction, sliding constraints).
    #[serde(default)]
    pub interaction: InteractionSpec,
    /// Inverse controller tuning.
    #[serde(default)]
    pub inverse: InverseSpec,
    /// Numerical settings of the host and the constraint solver.
    #[serde(default)]
    pub solver: SolverSpec,
    /// The planned path in the gel's rest configuration.
    pub path: PathSpec,
    /// Spherical obstacles embedded in the gel.
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    /// How the target advances along the path.
    #[serde(default)]
    pub insertion: InsertionSpec,
    /// What a run writes.
    #[serde(default)]
    pub output: OutputSpec,
}

/// A rigid transform given as a translation and roll-pitch-yaw angles.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    /// Translation [mm].
    #[serde(default)]
    pub translation: [f64; 3],
    /// Rotation as roll, pitch, yaw about the fixed x, y, z axes (R = Rz·Ry·Rx) [rad].
    #[serde(default)]
    pub rpy: [f64; 3],
}

/// One standard Denavit-Hartenberg row, `T = Rz(q + theta) Tz(d) Tx(a) Rx(alpha)`.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhRowSpec {
    /// Joint angle offset θ [rad].
    pub theta: f64,
    /// Link offset d [mm].
    pub d: f64,
    /// Link length a [mm].
    pub a: f64,
    /// Link twist α [rad].
    pub alpha: f64,
}

/// The robot: a preset or a DH table, its placement, the tool and the limits.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Name of a built-in robot (`"rv1a"`); ignored when `dh` is given.
    #[serde(default = "default_preset")]
    pub preset: String,
    /// A DH table of six rows, replacing the preset's.
    #[serde(default)]
    pub dh: Option<Vec<DhRowSpec>>,
    /// A URDF file (relative to the scene file) whose joints from `base_link` to `tip_link`
    /// replace the preset: kinematics, joint limits and velocities (lengths converted from
    /// metres to mm; meshes ignored). `tool` is then given in the tip link's frame.
    #[serde(default)]
    pub urdf: Option<std::path::PathBuf>,
    /// With `urdf`: the link placed at `base` (the robot's base).
    #[serde(default)]
    pub base_link: Option<String>,
    /// With `urdf`: the link that holds the needle (`tool` is given in its frame).
    #[serde(default)]
    pub tip_link: Option<String>,
    /// Robot base in the world frame.
    #[serde(default)]
    pub base: PoseSpec,
    /// Needle base B in the flange frame E (`B = E · tool`).
    #[serde(default)]
    pub tool: PoseSpec,
    /// Lower joint limits [deg] (one value per joint; default: the preset's).
    #[serde(default)]
    pub joint_min_deg: Option<Vec<f64>>,
    /// Upper joint limits [deg] (one value per joint; default: the preset's).
    #[serde(default)]
    pub joint_max_deg: Option<Vec<f64>>,
    /// Joint speed limits [deg/s] (one value per joint; default: the preset's).
    #[serde(default)]
    pub speed_limit_deg_s: Option<Vec<f64>>,
    /// Control period: time between two steps [s].
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Start joints [deg] (one value per joint, within the limits); default: the IK of the start pose
    /// (tip `path.approach` before the entry point, needle along the entry tangent).
    #[serde(default)]
    pub start_joints_deg: Option<Vec<f64>>,
    /// Where the IK of the start pose starts [deg] (one value per joint within the limits;
    /// default: mid-range). On a redundant arm it picks the arm's posture among the many that
    /// put the needle at its start (elbow up or down, which way the spare joint turns).
    #[serde(default)]
    pub ik_seed_deg: Option<Vec<f64>>,
}

impl Default for RobotSpec {
    fn default() -> Self {
        Self {
            preset: default_preset(),
            dh: None,
            urdf: None,
            base_link: None,
            tip_link: None,
            base: PoseSpec::default(),
            tool: PoseSpec::default(),
            joint_min_deg: None,
            joint_max_deg: None,
            speed_limit_deg_s: None,
            dt: default_dt(),
            start_joints_deg: None,
            ik_seed_deg: None,
        }
    }
}

/// An axis-aligned box meshed into tetrahedra.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Lower corner [mm].
    pub min: [f64; 3],
    /// Upper corner [mm].
    pub max: [f64; 3],
    /// Target number of nodes (the mesher picks divisions near it).
    pub nodes: usize,
}

/// Which gel nodes are fixed (Dirichlet conditions, the paper's screws).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FixedSpec {
    /// Fix every node with z ≤ this height [mm] (the gel's bottom face: 0).
    #[serde(default)]
    pub below_z: Option<f64>,
    /// Fix these node indices (0-based) as well.
    #[serde(default)]
    pub nodes: Vec<usize>,
}

/// The gel: its mesh, material and fixed region.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GelSpec {
    /// A generated box mesh (exclusive with `mesh`; the benchmark's 80×60×60 mm box of 1500 nodes
    /// when neither is given).
    #[serde(default, rename = "box")]
    pub box_mesh: Option<BoxSpec>,
    /// A tetrahedral mesh file, relative to the scene file (exclusive with `box`): Gmsh `.msh`
    /// (2.2 or 4.1), VTK `.vtu` or legacy `.vtk`.
    #[serde(default)]
    pub mesh: Option<PathBuf>,
    /// Young's modulus [MPa].
    #[serde(default = "default_gel_e")]
    pub young_modulus: f64,
    /// Poisson's ratio [-], in (−1, 0.5).
    #[serde(default = "default_gel_nu")]
    pub poisson_ratio: f64,
    /// Mass density [t/mm³] (1000 kg/m³ = 1e-9 t/mm³).
    #[serde(default = "default_gel_rho")]
    pub density: f64,
    /// Fixed nodes.
    #[serde(default = "default_fixed")]
    pub fixed: FixedSpec,
    /// Materials of the mesh's regions (`[[gel.regions]]`); elements of an unlisted region take
    /// the gel's own `young_modulus`, `poisson_ratio` and `density`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub regions: Vec<RegionSpec>,
    /// A prescribed motion of the fixed nodes (`[gel.support_motion]`): breathing or a CSV
    /// table; none: the support never moves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub support_motion: Option<SupportMotionSpec>,
}

/// A prescribed displacement of the gel's fixed nodes over time (every fixed node moves by the
/// same `d(t)`): exactly one of `breathing` and `csv`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SupportMotionSpec {
    /// A periodic breathing motion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub breathing: Option<BreathingSpec>,
    /// A CSV file of `t, dx, dy, dz` [s, mm] rows, relative to the scene file (linear
    /// interpolation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub csv: Option<PathBuf>,
    /// Hide the motion from the controller's model: the controller steers on a model whose
    /// support does not move (the scene without the motion), and its joints drive the moving
    /// world, where the error is measured.
    #[serde(default)]
    pub hidden: bool,
}

/// `d(t) = amplitude · (1 − cos(2π t / period + phase)) / 2 · direction / |direction|`.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BreathingSpec {
    /// Peak-to-peak travel of the support [mm].
    pub amplitude: f64,
    /// Period [s].
    pub period: f64,
    /// Direction of the travel (normalised; any non-zero vector).
    pub direction: [f64; 3],
    /// Phase [rad] (0: the motion starts at rest, at zero velocity).
    #[serde(default)]
    pub phase: f64,
}

/// The material of one region of the gel mesh: the elements whose Gmsh physical volume tag (or
/// `.vtu` / `.vtk` cell value `region`) is `tag`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// The region's tag in the mesh.
    pub tag: i32,
    /// A label (e.g. `"lesion"`), for messages and outputs.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
    /// Young's modulus [MPa].
    pub young_modulus: f64,
    /// Poisson's ratio [-], in (−1, 0.5); the gel's when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_ratio: Option<f64>,
    /// Mass density [t/mm³]; the gel's when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
}

impl Default for GelSpec {
    fn default() -> Self {
        Self {
            box_mesh: Some(BoxSpec {
                min: [260.0, -30.0, 0.0],
                max: [340.0, 30.0, 60.0],
                nodes: 1500,
            }),
            mesh: None,
            young_modulus: default_gel_e(),
            poisson_ratio: default_gel_nu(),
            density: default_gel_rho(),
            fixed: default_fixed(),
            regions: Vec::new(),
            support_motion: None,
        }
    }
}

/// The needle: a straight rod of beams, clamped at its base to the robot's tool frame.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NeedleSpec {
    /// Length from base to tip [mm].
    #[serde(default = "default_needle_length")]
    pub length: f64,
    /// Outer diameter of the solid circular section [mm].
    #[serde(default = "default_needle_diameter")]
    pub diameter: f64,
    /// Young's modulus [MPa].
    #[serde(default = "default_needle_e")]
    pub young_modulus: f64,
    /// Poisson's ratio [-].
    #[serde(default = "default_needle_nu")]
    pub poisson_ratio: f64,
    /// Mass density [t/mm³] (steel: 7.85e-9).
    #[serde(default = "default_needle_rho")]
    pub density: f64,
    /// Number of beam elements.
    #[serde(default = "default_needle_beams")]
    pub beams: usize,
    /// The material's yield strain `σ_y / E` [-]: a run whose needle is bent past it at its
    /// surface says so (`needle_yielded` in the summary, a warning, the `needle:` line).
    /// Absent (the default): not checked.
    #[serde(default)]
    pub yield_strain: Option<f64>,
}

impl Default for NeedleSpec {
    fn default() -> Self {
        Self {
            length: default_needle_length(),
            diameter: default_needle_diameter(),
            young_modulus: default_needle_e(),
            poisson_ratio: default_needle_nu(),
            density: default_needle_rho(),
            beams: default_needle_beams(),
            yield_strain: None,
        }
    }
}

/// Needle-gel interaction: the paper's constraints φ (contact, puncture) and ψ (sliding).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InteractionSpec {
    /// Puncture threshold p_f: the tip's normal contact force above which the surface gives way [N].
    #[serde(default = "default_pf")]
    pub puncture_force: f64,
    /// Coulomb friction coefficient μ_s of the tip on the gel surface [-].
    #[serde(default = "default_mu_s")]
    pub surface_friction: f64,
    /// Shaft friction coefficient μ_n of each sliding point (axial force ≤ μ_n·lateral force + r_0) [-].
    #[serde(default = "default_mu_n")]
    pub shaft_friction: f64,
    /// Constant axial resistance r_0 of each sliding point [N].
    #[serde(default)]
    pub shaft_resistance: f64,
    /// Spacing d_n between sliding points along the cut [mm].
    #[serde(default = "default_dn")]
    pub constraint_spacing: f64,
}

impl Default for InteractionSpec {
    fn default() -> Self {
        Self {
            puncture_force: default_pf(),
            surface_friction: default_mu_s(),
            shaft_friction: default_mu_n(),
            shaft_resistance: 0.0,
            constraint_spacing: default_dn(),
        }
    }
}

/// Tuning of the inverse controller (paper §IV).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InverseSpec {
    /// Joint perturbation δq for the numerical Jacobian [rad].
    #[serde(default = "default_dq")]
    pub delta_q: f64,
    /// Blend distance d: θ1 in the air, θ2 beyond this insertion depth, linear in between [mm].
    #[serde(default = "default_blend")]
    pub blend_distance: f64,
    /// Damping ε of the pseudo-inverse `Jᵀ(JJᵀ + ε²I)⁻¹` away from singularities [mm/rad]
    /// (the core raises it near a singularity).
    #[serde(default = "default_damping")]
    pub damping: f64,
    /// Weight of the angular objective against the position error [mm/rad].
    #[serde(default = "default_angle_weight")]
    pub angle_weight: f64,
    /// Objective tolerance: no Newton step while |T|² ≤ this [mm²].
    #[serde(default = "default_inverse_tol")]
    pub tolerance: f64,
    /// How the Jacobian columns are computed: `"solve"` (a Gauss-Seidel solve at each perturbed
    /// joint vector, the paper's eq. 14), `"linearized"` (the same solve with the active set
    /// of the unperturbed solve frozen: no contact flips inside a finite difference) or
    /// `"hybrid"` (linearized before puncture, solve once inserted; the default).
    #[serde(default = "default_jacobian")]
    pub jacobian: JacobianSpec,
    /// Trust region of the Newton step: the needle base moves at most this far per step [mm].
    #[serde(default = "default_max_base_step")]
    pub max_base_step: f64,
    /// How the joint update is chosen: `"qp"` (a quadratic program with the joint limits and
    /// speeds as bounds, the trust region and every obstacle clearance as linear rows; the
    /// default) or `"paper"` (the paper's damped least squares, scaled and clamped after the
    /// fact, blind to obstacles).
    #[serde(default = "default_method")]
    pub method: MethodSpec,
    /// Smallest clearance the `"qp"` update plans between the needle's centre line and an
    /// obstacle's surface [mm].
    #[serde(default = "default_clearance_margin")]
    pub clearance_margin: f64,
    /// Weight of the angles in the `"qp"` update's second stage, against the damping [mm/rad].
    #[serde(default = "default_qp_angle_weight")]
    pub qp_angle_weight: f64,
    /// Keep the tip's heading in the `"qp"` update at every depth (not only within the blend
    /// distance).
    #[serde(default = "default_qp_heading")]
    pub qp_heading: bool,
    /// Look-ahead of the tip's heading once inserted [mm] (0: the path's tangent alone).
    #[serde(default = "default_aim_ahead")]
    pub aim_ahead: f64,
    /// Largest shift of the entry point from its rest position the `"qp"` update plans [mm]:
    /// how far the shaft may drag the tissue at the surface (the support's motion taken out).
    /// A linearised row of the update like an obstacle's clearance, so the same margin
    /// (`clearance_margin`) applies. Absent (the default): no bound.
    #[serde(default)]
    pub max_entry_shift: Option<f64>,
    /// Horizon of the tip's position objective once inserted: a distance [mm] (0: the error
    /// now) or `"auto"` (the default: [`HorizonSpec::horizon`] of the scene's steering length).
    #[serde(default)]
    pub qp_horizon: HorizonSpec,
    /// How far the target shown to the `"qp"` update is straightened towards a chord of the
    /// path (the line from its point `straighten_from` past the entry point to its end): a
    /// fraction in [0, 1] (0: the planned path, 1: the chord) or `"auto"` (the default:
    /// [`crate::straighten::Straightening::for_scene`]). The errors are measured against the
    /// planned path either way.
    #[serde(default)]
    pub straighten: StraightenSpec,
    /// Where that chord starts: path length past the entry point [mm] (0: the entry point) or
    /// `"auto"` (the default: one steering length).
    #[serde(default)]
    pub straighten_from: StraightenFromSpec,
    /// The largest distance of the shown target from the path's own point [mm], in (0,
    /// [`crate::run::metrics::PATH_TOLERANCE_MM`]] (default
    /// [`crate::straighten::MAX_OFFSET_MM`]): where the chord runs farther from the path, the
    /// fraction is lowered there.
    #[serde(default = "default_straighten_max_offset")]
    pub straighten_max_offset: f64,
    /// The distance [mm] the target shown to the `"qp"` update keeps from every obstacle's
    /// surface where the path passes nearer, within `straighten_max_offset` of the path's own
    /// point ([`crate::straighten::Straightening::with_standoff`]); 0: none.
    #[serde(default = "default_target_standoff")]
    pub target_standoff: f64,
    /// With a yield strain for the needle (`needle.yield_strain`), the `"qp"` update keeps the
    /// needle's largest bends under it, as clearance rows
    /// ([`crate::step::observe::bending_rows`]); false: the strain is only checked (default
    /// true).
    #[serde(default = "default_bound_strain")]
    pub bound_strain: bool,
    /// Re-plan a `"qp"` step that its confirming solve rejected, with the Jacobian corrected by
    /// the secant along the rejected step (default false).
    #[serde(default = "default_replan_rejected")]
    pub replan_rejected: bool,
    /// A `"qp"` step at the joints the last step held goes on halving the first stage's step
    /// from where that step stopped instead of repeating its candidates (default true).
    #[serde(default = "default_resume_held")]
    pub resume_held: bool,
    /// A `"qp"` step that its confirming solve rejected is planned once more with the
    /// linearised Jacobian (the frozen active set of the base solve) and that candidate
    /// confirmed too, before the first stage's step and its halvings.
    #[serde(default = "default_second_opinion")]
    pub second_opinion: bool,
    /// Largest damping of the `"qp"` update's second stage (the angles), which is otherwise
    /// the first stage's, raised towards `damping_max` near a singularity of the Jacobian
    /// [mm/rad].
    #[serde(default = "default_qp_angle_damping_max")]
    pub qp_angle_damping_max: f64,
    /// Gain of the `"qp"` update's third stage for arms of more than 6 joints: each joint is
    /// moved towards the middle of its range in the null space of the task (0: off; no effect
    /// on 6-joint arms) [-].
    #[serde(default = "default_limit_avoidance")]
    pub limit_avoidance: f64,
    /// Widen a `"qp"` step's obstacle margin by the recent shortfall of the frames' clearances
    /// against the steps' predictions (the gel settling, the needle ringing at held joints).
    #[serde(default = "default_settling_margin")]
    pub settling_margin: bool,
    /// Weight of the needle's spin about its own axis in every stage of the `"qp"` update
    /// (0: off) [mm/rad].
    #[serde(default = "default_qp_spin_weight")]
    pub qp_spin_weight: f64,
    /// Once the tip has slid on the gel's surface before puncture, the largest angle between
    /// the target's heading shown to the controller and the surface's inward normal at the
    /// entry point: an angle [rad] (π/2 or more: never turned) or `"auto"` (the default:
    /// [`crate::step::ENTRY_TILT_FRACTION`] of the friction cone's half-angle `atan μ_s`).
    #[serde(default)]
    pub entry_tilt: EntryTilt,
}

/// How the inverse controller chooses the joint update.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum MethodSpec {
    /// Damped least squares with bounds, trust region and obstacle clearances as rows.
    Qp,
    /// The paper's damped least squares, scaled and clamped after the fact.
    Paper,
}

/// How the inverse controller's Jacobian columns are computed.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum JacobianSpec {
    /// A constraint solve at each perturbed joint vector (the paper's eq. 14).
    Solve,
    /// The frozen-active-set solve (exact one-sided derivative at the same δq).
    Linearized,
    /// Linearized before puncture, a full solve once inserted.
    Hybrid,
}

impl Default for InverseSpec {
    fn default() -> Self {
        Self {
            delta_q: default_dq(),
            blend_distance: default_blend(),
            damping: default_damping(),
            angle_weight: default_angle_weight(),
            tolerance: default_inverse_tol(),
            jacobian: default_jacobian(),
            max_base_step: default_max_base_step(),
            method: default_method(),
            clearance_margin: default_clearance_margin(),
            qp_angle_weight: default_qp_angle_weight(),
            qp_heading: default_qp_heading(),
            aim_ahead: default_aim_ahead(),
            max_entry_shift: None,
            qp_horizon: HorizonSpec::Auto,
            straighten: StraightenSpec::Auto,
            straighten_from: StraightenFromSpec::Auto,
            straighten_max_offset: default_straighten_max_offset(),
            target_standoff: default_target_standoff(),
            bound_strain: default_bound_strain(),
            replan_rejected: default_replan_rejected(),
            second_opinion: default_second_opinion(),
            qp_angle_damping_max: default_qp_angle_damping_max(),
            resume_held: default_resume_held(),
            limit_avoidance: default_limit_avoidance(),
            settling_margin: default_settling_margin(),
            qp_spin_weight: default_qp_spin_weight(),
            entry_tilt: EntryTilt::Auto,
        }
    }
}

/// With `solver.gel_solve = "pcg"`, the default `refactor_every`: the preconditioner is
/// refreshed at most every this many steps.
pub const PCG_REFACTOR_EVERY: u32 = 8;

/// Numerical settings of the host's FE solve and the core's Gauss-Seidel.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// Gauss-Seidel tolerance: stop when the largest `|W_ii Δλ_i|` of a sweep is below this
    /// times `‖δ‖∞` [-].
    #[serde(default = "default_gs_tol")]
    pub gs_tolerance: f64,
    /// Gauss-Seidel iteration cap.
    #[serde(default = "default_gs_iter")]
    pub gs_max_iterations: u32,
    /// Over-relaxation ω of the Gauss-Seidel updates of bilateral, unilateral and sliding
    /// rows (projected SOR; 1 = plain Gauss-Seidel; contact groups always use 1) [-].
    #[serde(default = "default_gs_relaxation")]
    pub gs_relaxation: f64,
    /// Time step h of the quasi-static implicit step (mass term M/h²) [s].
    #[serde(default = "default_h")]
    pub time_step: f64,
    /// Factorise the gel's stiffness every this many steps; with the background
    /// factorisation, the depth of its pipeline (a matrix is factorised while this many steps
    /// run, then used for as many). Unset: [`SolverSpec::refactor_every`] picks 2 with the
    /// background factorisation, 1 (every step, the paper's) without.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refactor_every: Option<u32>,
    /// Factorise the gel's stiffness on a second thread while the steps go on, and use it
    /// `refactor_every` steps later (the Newton matrix is then a few steps old).
    #[serde(default = "default_background")]
    pub background_factorization: bool,
    /// With `background_factorization` and `gel_solve = "direct"` or `"refine"`: a due factor
    /// is put in use by the first step, from `refactor_every` steps after its matrix, that
    /// finds it finished, and no step waits for it (the first step, a requested refactorisation
    /// and the rotation guard's factorisations at once excepted). For a loop with a deadline:
    /// which step adopts a factor then follows the machine's timing, so runs no longer repeat
    /// bit for bit. Default `false`: the step waits for its due factor.
    #[serde(default)]
    pub asynchronous_factor: bool,
    /// How the gel's free motion solves its Newton system: `"direct"` with the factor
    /// (refreshed as `refactor_every` and `background_factorization` say), or `"pcg"`:
    /// conjugate gradients on each step's own matrix, preconditioned by the factor in use,
    /// which is refreshed at most every `refactor_every` steps (in the background, never waited
    /// for, with `background_factorization`).
    #[serde(default = "default_gel_solve")]
    pub gel_solve: GelSolveSpec,
    /// `"pcg"`: stop when the relative residual `‖b − A Δx‖ / ‖b‖` is below this [-].
    #[serde(default = "default_pcg_tolerance")]
    pub pcg_tolerance: f64,
    /// `"pcg"`: iteration cap; a step that reaches it factorises its own matrix at once.
    #[serde(default = "default_pcg_max_iterations")]
    pub pcg_max_iterations: u32,
    /// Adaptive refresh of the background pipeline (`"direct"` or `"refine"` with
    /// `background_factorization`): a step sends its matrix to be factorised only when an
    /// element has rotated by this much or more since the matrix of the factor in use [rad], or
    /// that matrix is `refresh_ceiling` steps old. 0: whenever the worker is idle (every
    /// `refactor_every` steps, the fixed pipeline).
    #[serde(default = "default_refresh_rotation")]
    pub refresh_rotation: f64,
    /// With `refresh_rotation > 0`: the largest interval between the matrices of two
    /// consecutive factors [steps]; absent (the default): none, a factor whose elements have
    /// not rotated by `refresh_rotation` is kept however old it is (the tangent `R K0 Rᵀ`
    /// changes only through the rotations).
    #[serde(default)]
    pub refresh_ceiling: Option<u32>,
    /// The precision the gel's factor is stored and solved in: `"single"` (`f32`: half the
    /// memory and memory traffic; each factor is checked by a probe solve and redone in `f64`,
    /// for good, when its relative error exceeds 1e-3) or `"double"`. The needle's factor is
    /// always double.
    #[serde(default = "default_factor_precision")]
    pub factor_precision: FactorPrecisionSpec,
    /// The near block: the gel's nodes within a distance [mm] of the planned path (and of its
    /// straight approach) are eliminated last in the gel's factor, and the block they span is
    /// refactorised on its own, at once, when one of its elements has rotated by
    /// `refresh_rotation`; the elements elsewhere drive the background factorisation as before
    /// (unless `far_elements = "linear"`).
    /// A distance, `"off"`, or `"auto"` (the default): on gels of [`NEAR_AUTO_MIN_NODES`]
    /// nodes or more, [`NEAR_AUTO_REACH`] plus [`NEAR_AUTO_SPACINGS`] node spacings; none on
    /// smaller ones. Needs
    /// `background_factorization`, `refresh_rotation > 0` and `gel_solve = "direct"`; ignored
    /// otherwise.
    #[serde(default)]
    pub near_radius: NearRadiusSpec,
    /// With a near block (`near_radius`): the rotation of an element not all of whose nodes
    /// are near, since the matrix of the factor in use, that sends a matrix to the background
    /// factorisation [rad], at most [`crate::free_motion::LAG_ROTATION_LIMIT`]. Absent (the
    /// default): on gels of [`FAR_REFRESH_AUTO_MIN_NODES`] nodes or more that limit (the far
    /// elements then send no matrix; one turned by the limit factorises at once), on smaller
    /// ones and with `asynchronous_factor` `refresh_rotation`
    /// ([`SolverSpec::far_refresh_rotation`]). The near elements refresh
    /// the block at `refresh_rotation`. A larger value factorises the whole gel less often, at
    /// some cost in accuracy on heavily loaded gels (measured in `docs/architecture.md`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub far_refresh_rotation: Option<f64>,
    /// Where the gel has a near block (`near_radius`; with any solver): how its elements not
    /// all of whose nodes are near move: `"corotational"` (the default: the paper's model, as
    /// the near elements) or `"linear"` (small-strain elasticity about the rest state). Linear
    /// far elements never make the factor stale, and the far field is then solved with its own
    /// matrix: the whole gel is factorised once (faster on large gels, at a cost in accuracy
    /// measured in `docs/architecture.md`).
    #[serde(default)]
    pub far_elements: FarElementsSpec,
    /// With a near block (`near_radius`): the entry block, the gel's nodes within this distance
    /// [mm] of the path's entry point, added to the near block and eliminated last of all. Its
    /// block of the factor is refactorised on its own (from the near block's last matrix) when
    /// only its elements have rotated by `refresh_rotation`: where the needle's base drags the
    /// gel's surface, which fires most of the near block's refreshes and, just outside the
    /// path's radius, most of the full ones. A distance, `"off"`, or `"auto"` (the default):
    /// [`ENTRY_AUTO_FACTOR`] times the near block's radius.
    #[serde(default)]
    pub entry_radius: NearRadiusSpec,
    /// With a near block (`near_radius`): the free motion's far-residual tolerance `τ`, at most
    /// [`FAR_RESIDUAL_MAX`]. A step whose right-hand side `−f_int` has, outside the near
    /// block, a norm of at most `τ` times its whole norm solves with those entries dropped,
    /// skipping the forward substitution over every far supernode; the first step where the
    /// far residual exceeds it solves it whole. 0: every solve exact.
    #[serde(default = "default_far_residual_tolerance")]
    pub far_residual_tolerance: f64,
    /// With a near block (`near_radius`) and the direct solve: the far rows of the gel's step
    /// are solved once per step, after the constraint solve, for the free and the corrective
    /// motion together; the free motion, the compliance columns and the corrective motion are
    /// solved on the near block's rows only (a step whose constrained or observed gel points
    /// reach outside them solves them whole, as with `false`). The same step to round-off.
    #[serde(default = "default_defer_far")]
    pub defer_far: bool,
}

/// The largest `solver.far_residual_tolerance`.
pub const FAR_RESIDUAL_MAX: f64 = 0.1;

/// `solver.entry_radius = "auto"`: the entry block's radius over the near block's. Traced on the
/// complex scene at 19 800 nodes (near radius 7.7 mm), the elements that fired the full
/// factorisations lay within 6 mm of the surface and 5.8–7 mm of the entry axis.
pub const ENTRY_AUTO_FACTOR: f64 = 1.5;

/// `solver.near_radius = "auto"`: how far from the planned path the elements that turn most
/// lie [mm]. Traced on the complex scene at 5040 nodes, the elements whose rotation since the
/// factor's matrix reached `refresh_rotation` had their centroids within 2.5 mm of the path
/// (3.8 mm in a few steps).
pub const NEAR_AUTO_REACH: f64 = 4.0;

/// `solver.near_radius = "auto"`: the near block's radius is [`NEAR_AUTO_REACH`] plus this many
/// node spacings, so that an element whose centroid is that close has all its nodes inside.
pub const NEAR_AUTO_SPACINGS: f64 = 1.5;

/// `solver.near_radius = "auto"`: the smallest gel (nodes) given a near block. With the entry
/// block and the far residual's tolerance, the block cuts the complex scene's CPU per step by
/// about a fifth at 1485 and 1815 nodes and a tenth at 1000; at 600 nodes it saves nothing
/// measurable (see `docs/architecture.md`).
pub const NEAR_AUTO_MIN_NODES: usize = 1000;

/// `solver.far_refresh_rotation` absent: the smallest gel (nodes) whose far elements refresh
/// the whole factor only at [`crate::free_motion::LAG_ROTATION_LIMIT`]. A full factorisation
/// takes about 0.85 s at 19 800 nodes (many steps of CPU on the second core, and the step
/// that adopts it waits); there the complex scene's CPU per step falls by a fifth with the
/// same errors within 0.004 mm. On the 1500-node suites the same setting lost targets and hit
/// an obstacle (`docs/architecture.md`). With `asynchronous_factor` the far elements keep
/// `refresh_rotation` at any size ([`SolverSpec::far_refresh_rotation`]).
pub const FAR_REFRESH_AUTO_MIN_NODES: usize = 10_000;

/// The near block's radius, or when to have one (`solver.near_radius`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum NearRadiusSpec {
    /// On gels of [`NEAR_AUTO_MIN_NODES`] nodes or more, [`NEAR_AUTO_REACH`] plus
    /// [`NEAR_AUTO_SPACINGS`] node spacings; none on smaller gels.
    #[default]
    Auto,
    /// No near block.
    Off,
    /// This radius [mm] whatever the gel.
    Radius(f64),
}

impl NearRadiusSpec {
    /// The radius [mm] for a gel of `nodes` nodes and `volume` mm³, or `None` for no near
    /// block. The node spacing is `∛(volume / nodes)` (3.85 mm for the benchmark box at 5040
    /// nodes, giving 9.8 mm; 2.44 mm at 19 800 nodes, giving 7.7 mm).
    pub fn radius(self, nodes: usize, volume: f64) -> Option<f64> {
        match self {
            Self::Auto => (nodes >= NEAR_AUTO_MIN_NODES && volume > 0.0)
                .then(|| NEAR_AUTO_REACH + NEAR_AUTO_SPACINGS * (volume / nodes as f64).cbrt()),
            Self::Off => None,
            Self::Radius(r) => Some(r),
        }
    }
}

/// A field that is a number or a word (`"auto"`, `"off"`), before its own type reads it.
#[derive(Deserialize)]
#[serde(untagged)]
enum NumberOrWord {
    Number(f64),
    Word(String),
}

/// A number, or `"auto"` (`None`); anything else is an error saying `expected`.
fn number_or_auto<'de, D: serde::Deserializer<'de>>(
    d: D,
    expected: &str,
) -> Result<Option<f64>, D::Error> {
    match NumberOrWord::deserialize(d).map_err(|_| serde::de::Error::custom(expected))? {
        NumberOrWord::Number(r) => Ok(Some(r)),
        NumberOrWord::Word(w) if w == "auto" => Ok(None),
        NumberOrWord::Word(w) => Err(serde::de::Error::custom(format!("{expected}, got \"{w}\""))),
    }
}

/// A number, or `"auto"` for `None`.
fn serialize_number_or_auto<S: serde::Serializer>(v: Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    match v {
        Some(r) => s.serialize_f64(r),
        None => s.serialize_str("auto"),
    }
}

/// `Serialize` and `Deserialize` of a setting that is `"auto"` (its `Auto` variant) or a number
/// (its one-number variant), refused otherwise with `expected`.
macro_rules! number_or_auto_spec {
    ($ty:ident, $number:ident, $expected:expr) => {
        impl Serialize for $ty {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                let v = match self {
                    Self::Auto => None,
                    Self::$number(x) => Some(*x),
                };
                serialize_number_or_auto(v, s)
            }
        }

        impl<'de> Deserialize<'de> for $ty {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                Ok(number_or_auto(d, $expected)?.map_or(Self::Auto, Self::$number))
            }
        }
    };
}

impl Serialize for NearRadiusSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Auto => s.serialize_str("auto"),
            Self::Off => s.serialize_str("off"),
            Self::Radius(r) => s.serialize_f64(*r),
        }
    }
}

impl<'de> Deserialize<'de> for NearRadiusSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        const EXPECTED: &str = "expected a distance [mm], \"auto\" or \"off\"";
        match NumberOrWord::deserialize(d).map_err(|_| serde::de::Error::custom(EXPECTED))? {
            NumberOrWord::Number(r) => Ok(Self::Radius(r)),
            NumberOrWord::Word(w) => match w.as_str() {
                "auto" => Ok(Self::Auto),
                "off" => Ok(Self::Off),
                other => Err(serde::de::Error::custom(format!(
                    "{EXPECTED}, got \"{other}\""
                ))),
            },
        }
    }
}

/// The horizon of the `"qp"` update's tip objective (`inverse.qp_horizon`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum HorizonSpec {
    /// From the needle's steering length in the gel ([`HorizonSpec::horizon`]).
    #[default]
    Auto,
    /// This horizon [mm] whatever the needle and gel (0: the error now).
    Mm(f64),
}

/// `inverse.qp_horizon = "auto"`: the horizon [mm] where the needle's steering length is at most
/// [`HORIZON_AUTO_FULL_BELOW`].
pub const HORIZON_AUTO_MM: f64 = 3.0;
/// `"auto"`: steering lengths [mm] up to which the whole [`HORIZON_AUTO_MM`] applies.
pub const HORIZON_AUTO_FULL_BELOW: f64 = 18.0;
/// `"auto"`: steering lengths [mm] from which there is no horizon (linear in between).
pub const HORIZON_AUTO_NONE_ABOVE: f64 = 21.0;

impl HorizonSpec {
    /// The horizon [mm] for a needle of steering length `steering_length` [mm]
    /// ([`crate::setup::steering_length`]). `Auto`: [`HORIZON_AUTO_MM`] up to
    /// [`HORIZON_AUTO_FULL_BELOW`], none from [`HORIZON_AUTO_NONE_ABOVE`], linear in between.
    /// Where the gel holds the shaft (a short steering length) the tip goes where it points and its
    /// heading cannot be turned back in time, so the tip's error is taken ahead along the heading;
    /// where the joints still turn the tip freely, the error now tracks the path more closely
    /// (`docs/benchmark.md`, "The horizon from the steering length").
    ///
    /// # Example
    /// ```
    /// use needle_host::scene::HorizonSpec;
    ///
    /// assert_eq!(HorizonSpec::Auto.horizon(13.0), 3.0); // a thin needle in a stiff gel
    /// assert_eq!(HorizonSpec::Auto.horizon(26.5), 0.0); // the benchmark's needle and gel
    /// assert!((HorizonSpec::Auto.horizon(19.5) - 1.5).abs() < 1e-12);
    /// assert_eq!(HorizonSpec::Mm(2.0).horizon(26.5), 2.0);
    /// ```
    pub fn horizon(self, steering_length: f64) -> f64 {
        match self {
            Self::Mm(s) => s,
            Self::Auto => {
                let (lo, hi) = (HORIZON_AUTO_FULL_BELOW, HORIZON_AUTO_NONE_ABOVE);
                let t = ((hi - steering_length) / (hi - lo)).clamp(0.0, 1.0);
                // A non-finite length (a zero gel modulus is refused earlier) gets none.
                if t.is_finite() {
                    HORIZON_AUTO_MM * t
                } else {
                    0.0
                }
            }
        }
    }
}

number_or_auto_spec!(HorizonSpec, Mm, "expected a horizon [mm] or \"auto\"");

/// How far the target shown to the `"qp"` update is straightened towards a chord of the path
/// (`inverse.straighten`; [`crate::straighten::Straightening::for_scene`]).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum StraightenSpec {
    /// Where the needle lags its path's bend ([`crate::plan_check::lags_its_bend`]: the run's
    /// advisory) the whole way to the chord from one steering length deep, or part of the way
    /// to the chord from the entry point near an obstacle
    /// ([`crate::straighten::Straightening::for_scene`]); elsewhere none.
    #[default]
    Auto,
    /// This fraction [0, 1] whatever the needle, gel and path.
    Fraction(f64),
}

number_or_auto_spec!(EntryTilt, Angle, "expected an angle [rad] or \"auto\"");

number_or_auto_spec!(
    StraightenSpec,
    Fraction,
    "expected a fraction in [0, 1] or \"auto\""
);

/// Where the chord that the shown target is straightened towards starts
/// (`inverse.straighten_from`): path length past the entry point.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum StraightenFromSpec {
    /// One steering length: the depth down to which the joints still turn the tip.
    #[default]
    Auto,
    /// This path length [mm] past the entry point (0: the chord from the entry point).
    Mm(f64),
}

number_or_auto_spec!(
    StraightenFromSpec,
    Mm,
    "expected a path length [mm] or \"auto\""
);

impl StraightenFromSpec {
    /// The chord's start [mm] past the entry point for a needle of `steering_length` [mm].
    ///
    /// # Example
    /// ```
    /// use needle_host::scene::StraightenFromSpec;
    ///
    /// assert_eq!(StraightenFromSpec::Auto.from(13.0), 13.0);
    /// assert_eq!(StraightenFromSpec::Mm(0.0).from(13.0), 0.0);
    /// ```
    pub fn from(self, steering_length: f64) -> f64 {
        match self {
            Self::Mm(d) => d,
            Self::Auto if steering_length.is_finite() => steering_length,
            Self::Auto => 0.0,
        }
    }
}

/// The precision of the gel's factor (`solver.factor_precision`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum FactorPrecisionSpec {
    /// `f32` factor, checked after each factorisation.
    Single,
    /// `f64` factor.
    Double,
}

/// How the gel's free motion solves its Newton system (`solver.gel_solve`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum GelSolveSpec {
    /// A solve with the factor (the exact Newton step when it is factorised every step,
    /// synchronously).
    Direct,
    /// Preconditioned conjugate gradients with the factor in use as preconditioner.
    Pcg,
    /// The direct solve's step (free motion, compliance and correction with the factor in
    /// use, refreshed as `refactor_every` and `background_factorization` say), then refined to
    /// the step's own matrix by CG from it, preconditioned by the factor.
    Refine,
}

/// How the gel's elements outside the near block move (`solver.far_elements`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum FarElementsSpec {
    /// Corotational, as the near elements (the paper's model of the whole gel): the default.
    #[default]
    Corotational,
    /// Small-strain linear elasticity (the rest state's rotation for good).
    Linear,
}

impl SolverSpec {
    /// `far_refresh_rotation` as set, or its default for a gel of `nodes` nodes: from
    /// [`FAR_REFRESH_AUTO_MIN_NODES`] nodes on [`crate::free_motion::LAG_ROTATION_LIMIT`] (or
    /// `refresh_rotation` if that is larger), below it `refresh_rotation`. With
    /// `asynchronous_factor` (a loop with a deadline) always `refresh_rotation`: a far element
    /// at the limit factorises at once, in the step (0.6 s at 19 800 nodes), where a background
    /// refresh is adopted without a wait.
    pub fn far_refresh_rotation(&self, nodes: usize) -> f64 {
        self.far_refresh_rotation.unwrap_or(
            if nodes >= FAR_REFRESH_AUTO_MIN_NODES && !self.asynchronous_factor {
                crate::free_motion::LAG_ROTATION_LIMIT.max(self.refresh_rotation)
            } else {
                self.refresh_rotation
            },
        )
    }

    /// `refactor_every` as set, or its default: with `gel_solve = "direct"`, 2 with the
    /// background factorisation and 1 without; with `"pcg"`, [`PCG_REFACTOR_EVERY`].
    pub fn refactor_every(&self) -> u32 {
        self.refactor_every
            .unwrap_or(match (self.gel_solve, self.background_factorization) {
                (GelSolveSpec::Pcg, _) => PCG_REFACTOR_EVERY,
                (GelSolveSpec::Direct | GelSolveSpec::Refine, true) => 2,
                (GelSolveSpec::Direct | GelSolveSpec::Refine, false) => 1,
            })
    }
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            gs_tolerance: default_gs_tol(),
            gs_max_iterations: default_gs_iter(),
            gs_relaxation: default_gs_relaxation(),
            time_step: default_h(),
            refactor_every: None,
            background_factorization: default_background(),
            asynchronous_factor: false,
            gel_solve: default_gel_solve(),
            pcg_tolerance: default_pcg_tolerance(),
            pcg_max_iterations: default_pcg_max_iterations(),
            refresh_rotation: default_refresh_rotation(),
            refresh_ceiling: None,
            factor_precision: default_factor_precision(),
            near_radius: NearRadiusSpec::Auto,
            far_refresh_rotation: None,
            far_elements: FarElementsSpec::default(),
            entry_radius: NearRadiusSpec::Auto,
            far_residual_tolerance: default_far_residual_tolerance(),
            defer_far: default_defer_far(),
        }
    }
}

/// Parametric coordinates of a path given by formulas of `s ∈ [0, 1]`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FormulaSpec {
    /// x(s) [mm], e.g. `"300 + 8*s^2"`.
    pub x: String,
    /// y(s) [mm].
    pub y: String,
    /// z(s) [mm].
    pub z: String,
}

/// The planned path inside the gel, in the rest configuration, from the entry point on.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PathSpec {
    /// Polyline points [mm] (exclusive with `formula`); the first is the entry point.
    #[serde(default)]
    pub points: Option<Vec<[f64; 3]>>,
    /// Formulas of `s` (exclusive with `points`); `s = 0` is the entry point.
    #[serde(default)]
    pub formula: Option<FormulaSpec>,
    /// Number of samples of the formula (segments = samples − 1).
    #[serde(default = "default_samples")]
    pub samples: usize,
    /// Length of the straight approach in the air before the entry point, along the entry tangent [mm].
    #[serde(default = "default_approach")]
    pub approach: f64,
}

/// An obstacle embedded in the gel at its rest position: a sphere (`center`, `radius`) or a
/// closed surface mesh (`mesh`, placed by `scale` then `translation`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// Label used in reports.
    #[serde(default)]
    pub name: String,
    /// A sphere's centre in the rest configuration [mm].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    /// A sphere's radius [mm].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// A closed surface mesh file (`.stl`, binary or ASCII, `.obj` or Gmsh `.msh`), relative to the scene
    /// file, its coordinates in mm in the rest configuration.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<PathBuf>,
    /// Scale applied to the mesh's coordinates (about the file's origin) before `translation`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Translation added to the mesh's (scaled) coordinates [mm].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<[f64; 3]>,
    /// A Gmsh mesh only: the physical surface group to read (its tag or its name); needed when
    /// the file's surface elements lie in several groups.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub physical_group: Option<crate::mesh::PhysicalGroup>,
}

impl ObstacleSpec {
    /// A sphere.
    pub fn sphere(name: &str, center: [f64; 3], radius: f64) -> Self {
        Self {
            name: name.to_owned(),
            center: Some(center),
            radius: Some(radius),
            mesh: None,
            scale: None,
            translation: None,
            physical_group: None,
        }
    }
}

/// How the target moves along the path.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InsertionSpec {
    /// Advance of the target parameter c per step, as path length [mm].
    #[serde(default = "default_advance")]
    pub advance_per_step: f64,
    /// Number of steps; default: until the target reaches the end of the path (`insert`), or
    /// one insertion and withdrawal (`back-and-forth`).
    #[serde(default)]
    pub steps: Option<usize>,
    /// How the target moves along the path.
    #[serde(default)]
    pub mode: InsertionMode,
    /// How far the target may lead the tip along the path before it waits for it [mm]
    /// (`inf`: on schedule whatever the tip does).
    #[serde(default = "default_max_lead")]
    pub max_lead: f64,
}

impl Default for InsertionSpec {
    fn default() -> Self {
        Self {
            advance_per_step: default_advance(),
            steps: None,
            mode: InsertionMode::default(),
            max_lead: default_max_lead(),
        }
    }
}

/// How the target parameter `c` moves along the path (the schedule itself is
/// [`crate::step::Insertion::target_arc`]).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum InsertionMode {
    /// From the start to the end of the path, then held there.
    #[default]
    Insert,
    /// To the end of the path and back to the start (the tip in the air again), repeated.
    BackAndForth,
}

/// Outputs of a run.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Write VTK files every this many steps (0: never).
    #[serde(default = "default_vtk_every")]
    pub vtk_every: usize,
}

impl Default for OutputSpec {
    fn default() -> Self {
        Self {
            vtk_every: default_vtk_every(),
        }
    }
}

#[cfg(test)]
mod tests;
