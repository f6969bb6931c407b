//! The forward simulation of one insertion (paper §III) and its step (Algorithm 1).
//!
//! [`World::step`] reads top to bottom:
//!
//! 1. **free motion (FM)** — one quasi-static Newton step of each body without constraints:
//!    `Δx_free = K⁻¹ b` for the gel and the needle ([`FeBody::free_motion`]);
//! 2. **proximity (CD)** — the row groups of this step: the needle base χ (6 bilateral rows), the tip
//!    on the gel surface φ before puncture (contact with Coulomb friction), the sliding points ψ
//!    after (2 lateral bilateral rows + 1 axial friction row each), with their violations `δ_free`;
//! 3. **compliance (CC)** — `W = H K⁻¹ Hᵀ` and the observation rows `C`, `o_free` from three solves
//!    per constrained point ([`crate::compliance`]), gel columns cached while the factor is reused;
//! 4. **constraint solves (SC)** — the core's inverse step over the frame (8 Gauss-Seidel solves):
//!    new joints `q` and the final `λ`; in open-loop mode a single solve at the given joints;
//! 5. **corrective motion** — `x = x_free + K⁻¹ Hᵀ λ` ([`ConstraintSet::add_correction`]);
//!
//! then the interaction bookkeeping: puncture when the contact's normal force reaches `p_f`
//! (once: the contact group is replaced by a sliding point at the entry, and never comes back while
//! the needle is inside), a new sliding point each time the tip has advanced `d_n` past the last
//! one, sliding points released when the needle is withdrawn past them.

use crate::compliance::PointColumns;
use crate::compliance::PointMap;
use crate::constraints::{
    Attachment, ConstraintGroup, ConstraintSet, GroupRole, Model, Observation, group,
    orthonormal_pair,
};
use crate::proximity::{Embedded, SurfaceProjector, TetLocator};
use crate::scene::{SampledPath, Scene};
use nalgebra::{Matrix3, Rotation3, Vector3};
use needle_core::inverse::base_violation;
use needle_core::inverse::{Controller, InverseParams, StepError};
use needle_core::kinematics::{DhChain, Pose};
use needle_core::payload::{Command, ComplianceFrame, GroupKind, JOINTS, SolverReport};
use std::fmt;
use std::time::Instant;

/// Row capacity of the frames a world builds: 6 base rows + 3 contact rows + 3 rows for each of up
/// to 61 sliding points (50 mm of insertion at d_n ≥ 0.85 mm).
pub const ROWS: usize = 192;

/// Why a step or the set-up failed.
#[derive(Debug)]
#[non_exhaustive]
pub enum SimError {
    /// A linear solve or factorisation failed (e.g. the stiffness is not positive definite).
    Linear(String),
    /// The core rejected the frame or its parameters.
    Core(StepError),
    /// More constraint rows than the frame holds.
    Capacity {
        /// Rows needed.
        rows: usize,
        /// Capacity.
        capacity: usize,
    },
    /// The state became non-finite.
    NonFinite(&'static str),
    /// The set-up is impossible (e.g. the start pose is out of the robot's reach).
    Setup(String),
    /// A command from a remote core does not answer the current frame (what differs).
    Command(&'static str),
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Linear(s) => write!(f, "linear solve failed: {s}"),
            Self::Core(e) => write!(f, "inverse step rejected: {e}"),
            Self::Capacity { rows, capacity } => write!(
                f,
                "{rows} constraint rows exceed the capacity of {capacity}"
            ),
            Self::NonFinite(what) => write!(f, "the simulation became non-finite ({what})"),
            Self::Setup(s) => write!(f, "set-up failed: {s}"),
            Self::Command(why) => write!(f, "the command does not answer the frame: {why}"),
        }
    }
}

impl std::error::Error for SimError {}

impl From<StepError> for SimError {
    fn from(e: StepError) -> Self {
        Self::Core(e)
    }
}

/// A finite-element body as the step sees it: reduced dofs, a quasi-static free motion, solves
/// with the current factor, and the update.
pub trait FeBody {
    /// Number of (reduced) dofs.
    fn dofs(&self) -> usize;
    /// Assembles at the current state, factorises (or reuses the factor) and writes the free
    /// motion `Δx_free = K⁻¹ b` into `dx`. Returns whether the factor was renewed.
    ///
    /// # Errors
    /// A failed factorisation or solve.
    fn free_motion(&mut self, dx: &mut [f64]) -> Result<bool, SimError>;
    /// `K⁻¹ rhs` in place for `ncols` column-major right-hand sides, with the current factor.
    ///
    /// # Errors
    /// A failed solve.
    fn solve_many(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), SimError>;
    /// Moves the body by `dx` (positions; rotation increments for rotational dofs).
    fn apply(&mut self, dx: &[f64]);
}

/// The gel as the step sees it.
pub trait GelBody: FeBody {
    /// Current node positions [mm].
    fn nodes(&self) -> &[Vector3<f64>];
    /// Rest node positions [mm].
    fn rest(&self) -> &[Vector3<f64>];
    /// Tetrahedra.
    fn tets(&self) -> &[[usize; 4]];
    /// Start of node `i`'s 3 dofs in the reduced vector, `None` if the node is fixed.
    fn dof(&self, node: usize) -> Option<usize>;
}

/// The needle as the step sees it: nodes `0..n`, base first, 6 dofs each (translation, then a
/// world-frame rotation increment), dofs of node `i` at `6 i`.
pub trait NeedleBody: FeBody {
    /// Current node positions [mm].
    fn nodes(&self) -> &[Vector3<f64>];
    /// Current orientation of node `i` (node frame → world); the needle's axis is the node
    /// frame's `axis()`.
    fn rotation(&self, node: usize) -> Matrix3<f64>;
    /// The needle's axis in a node's own frame (e.g. `x` for beams along their local x).
    fn axis(&self) -> Vector3<f64>;
}

/// A sliding point ψ: a gel material point the shaft must pass through.
#[derive(Clone, Debug)]
pub struct SlidingPoint {
    /// Identifier, increasing in creation order.
    pub id: usize,
    /// The gel point.
    pub at: Embedded,
    /// Cached Cartesian columns of the gel point with the current gel factor.
    cols: Option<PointColumns>,
}

/// What [`World::prepare`] leaves for [`World::finish`].
#[derive(Clone, Copy, Debug, Default)]
struct Pending {
    c: f64,
    times: StageTimes,
}

/// Per-stage wall times of one step [ms].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Free motion (both bodies).
    pub fm: f64,
    /// Proximity and row construction.
    pub cd: f64,
    /// Compliance and frame.
    pub cc: f64,
    /// Constraint solves (the core's whole inverse step).
    pub sc: f64,
    /// Corrective motion and bookkeeping.
    pub corr: f64,
}

impl StageTimes {
    /// Sum of the stages [ms].
    pub fn total(&self) -> f64 {
        self.fm + self.cd + self.cc + self.sc + self.corr
    }
}

/// What one step did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepReport {
    /// Step index (0-based).
    pub step: usize,
    /// Target's arc length from the start tip [mm].
    pub c: f64,
    /// Tip after the step [mm].
    pub tip: Vector3<f64>,
    /// Target point after the step (moves with the gel) [mm].
    pub target: Vector3<f64>,
    /// `|tip − target|` [mm].
    pub error: f64,
    /// Whether the tip has punctured the surface.
    pub inserted: bool,
    /// Tip distance past the entry point [mm].
    pub depth: f64,
    /// Constraint rows.
    pub rows: usize,
    /// Sliding points.
    pub sliding_points: usize,
    /// The puncture happened during this step.
    pub punctured_now: bool,
    /// Normal force of the tip contact [N] (0 without contact).
    pub contact_force: f64,
    /// Norms of λ per role: base, contact, sliding [N or N·mm].
    pub lambda_norms: [f64; 3],
    /// The core's report.
    pub solver: needle_core::payload::SolverReport,
    /// Largest constraint violation after the step over the non-base bilateral rows [mm].
    pub residual: f64,
    /// Joints after the step [rad].
    pub q: [f64; JOINTS],
    /// Stage times [ms].
    pub times: StageTimes,
}

/// The whole simulated system and its interaction state.
pub struct World<G: GelBody, N: NeedleBody> {
    /// The scene it was built from.
    pub scene: Scene,
    /// The planned path.
    pub path: SampledPath,
    /// The robot.
    pub chain: DhChain<JOINTS>,
    /// The inverse controller (owns the core's scratch).
    pub controller: Box<Controller<ROWS>>,
    /// The gel.
    pub gel: G,
    /// The needle.
    pub needle: N,
    /// Surface triangles of the gel (outward).
    pub surface: Vec<[usize; 3]>,
    rest_locator: TetLocator,
    /// The entry point (planned before puncture, actual after), embedded in the gel.
    pub entry: Embedded,
    /// Obstacle centres embedded in the gel, with radii [mm].
    pub obstacles: Vec<(Embedded, f64)>,
    /// Whether the tip has punctured the surface.
    pub punctured: bool,
    /// Whether the tip pushed on the surface in the last step (contact force > 0).
    pub in_contact: bool,
    /// Sliding points, oldest first.
    pub sliding: Vec<SlidingPoint>,
    next_sliding_id: usize,
    last_sliding_depth: f64,
    /// Smallest rest element size of the gel [mm] (see [`element_size`]).
    min_element_size: f64,
    /// Joints [rad].
    pub q: [f64; JOINTS],
    /// Target arc length from the start tip [mm].
    pub c: f64,
    /// Steps done.
    pub steps: usize,
    /// Needle node frame → needle-base frame `B` offset: `R_node = R_B · r_off`.
    r_off: Matrix3<f64>,
    frame: Box<ComplianceFrame<ROWS>>,
    command: Box<Command<ROWS>>,
    pending: Pending,
    set: ConstraintSet,
    gel_dx: Vec<f64>,
    needle_dx: Vec<f64>,
    gel_free: Vec<Vector3<f64>>,
    needle_free: Vec<Vector3<f64>>,
    /// The last step's λ (first `rows` used).
    pub lambda: Vec<f64>,
}

fn boxed_frame() -> Box<ComplianceFrame<ROWS>> {
    let mut b = Box::<ComplianceFrame<ROWS>>::new_uninit();
    ComplianceFrame::init_in_place(&mut b);
    // SAFETY: `init_in_place` initialised every field.
    unsafe { b.assume_init() }
}

fn boxed_command() -> Box<Command<ROWS>> {
    let mut b = Box::<Command<ROWS>>::new_uninit();
    Command::init_in_place(&mut b);
    // SAFETY: `init_in_place` initialised every field.
    unsafe { b.assume_init() }
}

/// Rotation exp([θ]×).
fn exp_so3(theta: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*theta).into_inner()
}

/// The fixed rotation `r_off` between the needle-base frame `B` (needle along its z axis) and the
/// needle's node frame (needle along `axis`): `R_node = R_B · r_off`, so `r_off · axis = z`.
pub fn node_frame_offset(axis: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::rotation_between(axis, &Vector3::z())
        .map(|r| r.into_inner())
        // axis = −z: a half turn about x.
        .unwrap_or_else(|| Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0))
}

/// Closest point of the polyline `x` to `p`: segment index and fraction in [0, 1].
fn closest_on_polyline(x: &[Vector3<f64>], p: &Vector3<f64>) -> (usize, f64) {
    let mut best = (f64::INFINITY, 0, 0.0);
    for e in 0..x.len() - 1 {
        let d = x[e + 1] - x[e];
        let l2 = d.norm_squared();
        let f = if l2 > 0.0 {
            ((p - x[e]).dot(&d) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let dist = (x[e] + f * d - p).norm_squared();
        if dist < best.0 {
            best = (dist, e, f);
        }
    }
    (best.1, best.2)
}

/// Distance from `p` to the segment `[a, b]`.
fn distance_point_segment(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 {
        ((p - a).dot(&d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + f * d - p).norm()
}

impl<G: GelBody, N: NeedleBody> World<G, N> {
    /// Assembles a world from its parts. `q` is the starting joint vector (from IK), the needle
    /// and gel are built by the caller at their start configuration.
    ///
    /// # Errors
    /// [`SimError::Setup`] when the path's entry point or an obstacle is not inside the gel.
    pub fn from_parts(
        scene: Scene,
        chain: DhChain<JOINTS>,
        params: InverseParams,
        gel: G,
        needle: N,
        q: [f64; JOINTS],
    ) -> Result<Self, SimError> {
        let path = scene
            .sampled_path()
            .map_err(|e| SimError::Setup(e.to_string()))?;
        let min_element_size = gel
            .tets()
            .iter()
            .map(|t| element_size(gel.rest(), t))
            .fold(f64::INFINITY, f64::min);
        let rest = gel.rest().to_vec();
        let tets = gel.tets().to_vec();
        let rest_locator = TetLocator::new(&rest, &tets);
        let reach = 1.0;
        let entry = rest_locator
            .locate(&rest, &tets, &path.entry(), reach)
            .ok_or_else(|| {
                SimError::Setup(format!(
                    "the path's entry point {} is not on the gel",
                    path.entry()
                ))
            })?;
        let mut obstacles = Vec::new();
        for (k, o) in scene.obstacles.iter().enumerate() {
            let c = Vector3::from(o.center);
            let e = rest_locator.locate(&rest, &tets, &c, 0.0).ok_or_else(|| {
                SimError::Setup(format!("obstacles[{k}]: centre {c} is not inside the gel"))
            })?;
            obstacles.push((e, o.radius));
        }
        let surface = {
            let mesh = crate::mesh::TetMesh {
                nodes: rest.clone(),
                tets: tets.clone(),
            };
            mesh.surface_triangles()
        };
        let r_off = node_frame_offset(&needle.axis());
        let mut controller = Box::new(Controller::new(chain, params));
        controller.reset_warm_start();
        let (ng, nn) = (gel.dofs(), needle.dofs());
        let (gn, nnodes) = (gel.nodes().len(), needle.nodes().len());
        Ok(Self {
            scene,
            path,
            chain,
            controller,
            gel,
            needle,
            surface,
            rest_locator,
            entry,
            obstacles,
            punctured: false,
            in_contact: false,
            min_element_size,
            sliding: Vec::new(),
            next_sliding_id: 0,
            last_sliding_depth: 0.0,
            q,
            c: 0.0,
            steps: 0,
            r_off,
            frame: boxed_frame(),
            command: boxed_command(),
            pending: Pending::default(),
            set: ConstraintSet::default(),
            gel_dx: vec![0.0; ng],
            needle_dx: vec![0.0; nn],
            gel_free: vec![Vector3::zeros(); gn],
            needle_free: vec![Vector3::zeros(); nnodes],
            lambda: vec![0.0; ROWS],
        })
    }

    /// The last frame handed to the core (diagnostics, transports).
    pub fn frame(&self) -> &ComplianceFrame<ROWS> {
        &self.frame
    }

    /// The last command received from the core.
    pub fn command(&self) -> &Command<ROWS> {
        &self.command
    }

    /// The force each row group of the last step applies to the needle, world frame [N]
    /// (the gel receives the opposite of every contact and sliding force); for the base group,
    /// its translational rows.
    pub fn needle_forces(&self) -> Vec<(GroupRole, Vector3<f64>)> {
        let starts = self.set.starts();
        self.set
            .groups
            .iter()
            .zip(starts)
            .map(|(g, s)| {
                let a = &g.attachments[0];
                let mut l = Vector3::zeros();
                for r in 0..a.rows.min(3) {
                    l[r] = self.lambda[s + a.row_offset + r];
                }
                (g.role, a.sign * a.d.transpose() * l)
            })
            .collect()
    }

    /// Needle-base pose `B(q)` in the world.
    pub fn base_pose(&self, q: &[f64; JOINTS]) -> Pose {
        self.chain.tool_pose(q)
    }

    /// Current needle tip [mm].
    pub fn tip(&self) -> Vector3<f64> {
        *self.needle.nodes().last().unwrap_or(&Vector3::zeros())
    }

    /// The target point for arc length `c`: in the air on the approach segment (fixed in the
    /// world), inside the gel embedded at its rest barycentric coordinates (moves with the gel).
    ///
    /// Until the tip has punctured the surface the target stays the rest-configuration path
    /// point, fixed in the world: the tip pressing on the surface indents the gel, and a target
    /// embedded below it would recede with that indentation — the controller would chase it
    /// sideways instead of pushing through. Once punctured, the target is embedded.
    pub fn target_embedding(&self, c: f64) -> Option<Embedded> {
        if c < self.path.approach || !self.punctured {
            return None;
        }
        let (p, _) = self.path.at(c);
        self.rest_locator
            .locate(self.gel.rest(), self.gel.tets(), &p, 1.0)
    }

    /// Current target point [mm].
    pub fn target(&self, c: f64) -> Vector3<f64> {
        match self.target_embedding(c) {
            Some(e) => e.position(self.gel.nodes(), self.gel.tets()),
            None => self.path.at(c).0,
        }
    }

    /// Current entry point [mm].
    pub fn entry_point(&self) -> Vector3<f64> {
        self.entry.position(self.gel.nodes(), self.gel.tets())
    }

    /// Insertion depth: tip distance past the entry point, 0 before puncture [mm].
    pub fn depth(&self) -> f64 {
        if self.punctured {
            (self.tip() - self.entry_point()).norm()
        } else {
            0.0
        }
    }

    fn gel_map(&self, e: &Embedded) -> PointMap {
        let t = self.gel.tets()[e.tet];
        PointMap::weighted((0..4).map(|k| (self.gel.dof(t[k]), e.weights[k])))
    }

    /// Advances the target by the scene's step and runs one step of the inverse controller.
    ///
    /// # Errors
    /// [`SimError`] for a failed solve, a rejected frame, a capacity overflow or a non-finite state.
    pub fn step(&mut self) -> Result<StepReport, SimError> {
        let c = (self.c + self.scene.insertion.advance_per_step).min(self.path.total_length());
        self.step_with(c, None)
    }

    /// One step with target `c`; `joints`: open-loop (the joints are given, a single constraint
    /// solve) instead of the inverse update. Runs the core in-process; a transport uses
    /// [`Self::prepare`] and [`Self::apply_command`] instead.
    ///
    /// # Errors
    /// As [`Self::step`].
    pub fn step_with(
        &mut self,
        c: f64,
        joints: Option<[f64; JOINTS]>,
    ) -> Result<StepReport, SimError> {
        self.prepare(c)?;
        // 4. Constraint solves: the core's inverse step, or one solve at given joints.
        let t3 = Instant::now();
        let report = match joints {
            None => self.controller.step(&self.frame, &mut self.command)?,
            Some(q) => self
                .controller
                .solve_open_loop(&self.frame, &q, &mut self.command)?,
        };
        self.pending.times.sc = ms(t3);
        self.finish(report)
    }

    /// Stages 1–3 of a step with target `c`: free motion, proximity, compliance. Returns the
    /// frame for the core (stage 4), whose answer goes to [`Self::apply_command`].
    ///
    /// # Errors
    /// A failed solve, a capacity overflow, a non-finite state or an invalid frame.
    pub fn prepare(&mut self, c: f64) -> Result<&ComplianceFrame<ROWS>, SimError> {
        let mut times = StageTimes::default();

        // 1. Free motion.
        let t0 = Instant::now();
        let renewed = self.gel.free_motion(&mut self.gel_dx)?;
        self.needle.free_motion(&mut self.needle_dx)?;
        if renewed {
            for s in &mut self.sliding {
                s.cols = None;
            }
        }
        for (i, x) in self.gel.nodes().iter().enumerate() {
            self.gel_free[i] = match self.gel.dof(i) {
                Some(d) => x + Vector3::new(self.gel_dx[d], self.gel_dx[d + 1], self.gel_dx[d + 2]),
                None => *x,
            };
        }
        for (i, x) in self.needle.nodes().iter().enumerate() {
            self.needle_free[i] = x + Vector3::new(
                self.needle_dx[6 * i],
                self.needle_dx[6 * i + 1],
                self.needle_dx[6 * i + 2],
            );
        }
        if !self
            .gel_dx
            .iter()
            .chain(&self.needle_dx)
            .all(|v| v.is_finite())
        {
            return Err(SimError::NonFinite("free motion"));
        }
        times.fm = ms(t0);

        // 2. Proximity: the row groups.
        let t1 = Instant::now();
        self.build_rows()?;
        let rows = self.set.rows();
        if rows > ROWS {
            return Err(SimError::Capacity {
                rows,
                capacity: ROWS,
            });
        }
        times.cd = ms(t1);

        // 3. Compliance and the frame.
        let t2 = Instant::now();
        let nn = self.needle.dofs();
        let ng = self.gel.dofs();
        let needle = &mut self.needle;
        self.set
            .needle
            .compute_missing(nn, |r, k| needle.solve_many(r, k))?;
        let gel = &mut self.gel;
        self.set
            .gel
            .compute_missing(ng, |r, k| gel.solve_many(r, k))?;
        let observations = self.observations(c);
        self.set.fill_frame(&observations, &mut self.frame);
        self.fill_frame_header()?;
        times.cc = ms(t2);
        self.pending = Pending { c, times };
        Ok(&self.frame)
    }

    /// Stage 5 for a command received from a core elsewhere (another thread or process):
    /// checks that it answers the current frame, then applies it.
    ///
    /// # Errors
    /// [`SimError::Command`] when the command does not answer the frame (version, sequence,
    /// row count) or carries non-finite values; the state is then unchanged.
    pub fn apply_command(
        &mut self,
        cmd: &Command<ROWS>,
        sc_ms: f64,
    ) -> Result<StepReport, SimError> {
        let f = &self.frame;
        let why = if cmd.version != needle_core::payload::VERSION {
            Some("version")
        } else if cmd.frame_sequence != f.sequence {
            Some("sequence")
        } else if cmd.m != f.m {
            Some("row count")
        } else if !cmd
            .q
            .iter()
            .chain(&cmd.lambda[..f.rows()])
            .all(|v| v.is_finite())
        {
            Some("non-finite value")
        } else {
            None
        };
        if let Some(why) = why {
            return Err(SimError::Command(why));
        }
        *self.command = *cmd;
        self.pending.times.sc = sc_ms;
        let report = cmd.report;
        self.finish(report)
    }

    /// Stage 5 and the interaction bookkeeping, with the command in `self.command`.
    fn finish(&mut self, report: SolverReport) -> Result<StepReport, SimError> {
        let Pending { c, mut times } = self.pending;
        let rows = self.set.rows();

        // 5. Corrective motion.
        let t4 = Instant::now();
        let lambda = &self.command.lambda[..rows];
        if !lambda.iter().all(|v| v.is_finite()) {
            return Err(SimError::NonFinite("constraint forces"));
        }
        self.set
            .add_correction(lambda, &mut self.needle_dx, &mut self.gel_dx);
        self.needle.apply(&self.needle_dx);
        self.gel.apply(&self.gel_dx);
        self.lambda[..rows].copy_from_slice(lambda);
        self.q = self.command.q;
        self.c = c;
        if !self
            .needle
            .nodes()
            .iter()
            .chain(self.gel.nodes())
            .all(|p| p.iter().all(|v| v.is_finite()))
        {
            return Err(SimError::NonFinite("positions after correction"));
        }

        // Interaction bookkeeping.
        let mut lambda_norms = [0.0f64; 3];
        let mut contact_force = 0.0;
        let starts = self.set.starts();
        for (g, s) in self.set.groups.iter().zip(&starts) {
            let l = &self.lambda[*s..*s + g.rows];
            let n2: f64 = l.iter().map(|v| v * v).sum();
            match g.role {
                GroupRole::Base => lambda_norms[0] += n2,
                GroupRole::Contact => {
                    lambda_norms[1] += n2;
                    contact_force = l[0];
                }
                GroupRole::Sliding(_) => lambda_norms[2] += n2,
            }
        }
        let lambda_norms = lambda_norms.map(f64::sqrt);
        // Cache the gel columns of the sliding points for the next step.
        for g in &self.set.groups {
            if let GroupRole::Sliding(id) = g.role
                && let Some(a) = g.attachments.iter().find(|a| a.model == Model::Gel)
                && let Some(s) = self.sliding.iter_mut().find(|s| s.id == id)
            {
                s.cols = self.set.gel.points[a.point].cols.take();
            }
        }
        self.in_contact = contact_force > 0.0;
        let mut punctured_now = false;
        if !self.punctured && contact_force >= self.scene.interaction.puncture_force {
            self.puncture()?;
            punctured_now = true;
        }
        if self.punctured {
            self.update_sliding_points()?;
        }
        times.corr = ms(t4);

        let tip = self.tip();
        let target = self.target(c);
        let residual = self.residual();
        let rep = StepReport {
            step: self.steps,
            c,
            tip,
            target,
            error: (tip - target).norm(),
            inserted: self.punctured,
            depth: self.depth(),
            rows,
            sliding_points: self.sliding.len(),
            punctured_now,
            contact_force,
            lambda_norms,
            solver: report,
            residual,
            q: self.q,
            times,
        };
        self.steps += 1;
        Ok(rep)
    }

    /// Builds `self.set` from the current and free-motion positions.
    fn build_rows(&mut self) -> Result<(), SimError> {
        let inter = self.scene.interaction;
        let nodes = self.needle.nodes().to_vec();
        let n_last = nodes.len() - 1;
        let mut set = ConstraintSet::default();
        std::mem::swap(&mut set, &mut self.set);
        set.needle.points.clear();
        set.gel.points.clear();
        set.groups.clear();
        let eye = Matrix3::identity();

        // χ: the needle base, 6 bilateral rows on node 0 (the core recomputes δ from q).
        let bt = set.needle.push(PointMap::single(0));
        let br = set.needle.push(PointMap::single(3));
        set.groups.push(ConstraintGroup {
            kind: group(GroupKind::Bilateral, 0.0, 0.0),
            role: GroupRole::Base,
            rows: 6,
            attachments: vec![
                Attachment {
                    model: Model::Needle,
                    point: bt,
                    row_offset: 0,
                    rows: 3,
                    d: eye,
                    sign: 1.0,
                },
                Attachment {
                    model: Model::Needle,
                    point: br,
                    row_offset: 3,
                    rows: 3,
                    d: eye,
                    sign: 1.0,
                },
            ],
            delta: [0.0; 6],
        });

        // ψ: sliding points, oldest first (stable row order for the core's warm start).
        for s in &mut self.sliding {
            let t = self.gel.tets()[s.at.tet];
            let g = s.at.position(self.gel.nodes(), self.gel.tets());
            let g_free = s.at.position(&self.gel_free, self.gel.tets());
            let (e, f) = closest_on_polyline(&nodes, &g);
            let n = nodes[e] * (1.0 - f) + nodes[e + 1] * f;
            let n_free = self.needle_free[e] * (1.0 - f) + self.needle_free[e + 1] * f;
            let tdir = (nodes[e + 1] - nodes[e]).normalize();
            let (l1, l2) = orthonormal_pair(&tdir);
            let d = Matrix3::from_rows(&[l1.transpose(), l2.transpose(), tdir.transpose()]);
            let np = set.needle.push(PointMap::weighted([
                (Some(6 * e), 1.0 - f),
                (Some(6 * (e + 1)), f),
            ]));
            let gmap = PointMap::weighted((0..4).map(|k| (self.gel.dof(t[k]), s.at.weights[k])));
            let gp = set.gel.push(gmap);
            set.gel.points[gp].cols = s.cols.take();
            let friction = inter.shaft_friction > 0.0 || inter.shaft_resistance > 0.0;
            let rows = if friction { 3 } else { 2 };
            let rel = (n_free - n) - (g_free - g);
            let mut delta = [0.0; 6];
            delta[0] = -l1.dot(&(n_free - g_free));
            delta[1] = -l2.dot(&(n_free - g_free));
            delta[2] = -tdir.dot(&rel);
            let kind = if friction {
                group(
                    GroupKind::Sliding,
                    inter.shaft_friction,
                    inter.shaft_resistance,
                )
            } else {
                group(GroupKind::Bilateral, 0.0, 0.0)
            };
            set.groups.push(ConstraintGroup::pair(
                kind,
                GroupRole::Sliding(s.id),
                rows,
                (np, gp),
                d,
                delta,
            ));
        }

        // φ: the tip on the gel surface, before puncture.
        if !self.punctured {
            let projector = SurfaceProjector::new(self.gel.nodes(), &self.surface);
            let tip = nodes[n_last];
            // A tip that pushed on the surface last step keeps its contact rows however deep the
            // dimple under it (a point load on a coarse mesh can indent by more than
            // CONTACT_DISTANCE): a contact is never lost by looking too close.
            let reach = if self.in_contact {
                f64::MAX
            } else {
                CONTACT_DISTANCE
            };
            if let Some(hit) = projector.project(self.gel.nodes(), &self.surface, &tip, reach)
                && hit.signed_distance < CONTACT_DISTANCE
            {
                let tri = self.surface[hit.triangle];
                let s_free: Vector3<f64> =
                    (0..3).map(|k| hit.weights[k] * self.gel_free[tri[k]]).sum();
                let tip_free = self.needle_free[n_last];
                // The smooth normal: continuous as the closest point crosses edges and vertices
                // of the faceted, indented surface (the face normal flips between steep faces
                // around the pushed node and makes the tip chatter sideways).
                let nrm = hit.smooth_normal;
                let (t1, t2) = orthonormal_pair(&nrm);
                let d = Matrix3::from_rows(&[nrm.transpose(), t1.transpose(), t2.transpose()]);
                let friction = inter.surface_friction > 0.0;
                let rows = if friction { 3 } else { 1 };
                let rel = (tip_free - tip) - (s_free - hit.point);
                let mut delta = [0.0; 6];
                delta[0] = -nrm.dot(&(tip_free - s_free));
                delta[1] = -t1.dot(&rel);
                delta[2] = -t2.dot(&rel);
                let np = set.needle.push(PointMap::single(6 * n_last));
                let gp = set.gel.push(PointMap::weighted(
                    (0..3).map(|k| (self.gel.dof(tri[k]), hit.weights[k])),
                ));
                let kind = if friction {
                    group(GroupKind::Contact, inter.surface_friction, 0.0)
                } else {
                    group(GroupKind::Unilateral, 0.0, 0.0)
                };
                set.groups.push(ConstraintGroup::pair(
                    kind,
                    GroupRole::Contact,
                    rows,
                    (np, gp),
                    d,
                    delta,
                ));
            }
        }
        self.set = set;
        Ok(())
    }

    /// The five observations of the frame (tip, tip direction, target, target tangent, entry).
    fn observations(&self, c: f64) -> [Observation; 5] {
        let nodes = self.needle.nodes();
        let n_last = nodes.len() - 1;
        let eye = Matrix3::identity();
        let tip = Observation {
            model: Model::Needle,
            map: PointMap::single(6 * n_last),
            a: eye,
            free: self.needle_free[n_last],
        };
        // Tip direction from the last segment: linear in the two nodes (the core normalises).
        let len = (nodes[n_last] - nodes[n_last - 1])
            .norm()
            .max(f64::MIN_POSITIVE);
        let dir = Observation {
            model: Model::Needle,
            map: PointMap::weighted([
                (Some(6 * n_last), 1.0 / len),
                (Some(6 * (n_last - 1)), -1.0 / len),
            ]),
            a: eye,
            free: (self.needle_free[n_last] - self.needle_free[n_last - 1]) / len,
        };
        let tets = self.gel.tets();
        let (target, tangent) = match (
            self.target_embedding(c),
            self.target_embedding(c + TANGENT_STEP),
        ) {
            (Some(a), Some(b)) => {
                let (ma, mb) = (self.gel_map(&a), self.gel_map(&b));
                let target = Observation {
                    model: Model::Gel,
                    map: ma,
                    a: eye,
                    free: a.position(&self.gel_free, tets),
                };
                let inv = 1.0 / TANGENT_STEP;
                let map = PointMap::weighted(
                    ma.used()
                        .iter()
                        .map(|&(d, w)| (Some(d), w * -inv))
                        .chain(mb.used().iter().map(|&(d, w)| (Some(d), w * inv))),
                );
                let free =
                    (b.position(&self.gel_free, tets) - a.position(&self.gel_free, tets)) * inv;
                (
                    target,
                    Observation {
                        model: Model::Gel,
                        map,
                        a: eye,
                        free,
                    },
                )
            }
            (a, _) => {
                let (p, t) = self.path.at(c);
                let target = match a {
                    Some(a) => Observation {
                        model: Model::Gel,
                        map: self.gel_map(&a),
                        a: eye,
                        free: a.position(&self.gel_free, tets),
                    },
                    None => Observation {
                        model: Model::Gel,
                        map: PointMap::weighted([]),
                        a: eye,
                        free: p,
                    },
                };
                (
                    target,
                    Observation {
                        model: Model::Gel,
                        map: PointMap::weighted([]),
                        a: eye,
                        free: t,
                    },
                )
            }
        };
        let entry = Observation {
            model: Model::Gel,
            map: self.gel_map(&self.entry),
            a: eye,
            free: self.entry.position(&self.gel_free, tets),
        };
        [tip, dir, target, tangent, entry]
    }

    /// Header fields of the frame: base pose after free motion, joints, depth, sequence.
    fn fill_frame_header(&mut self) -> Result<(), SimError> {
        let depth = self.depth();
        let f = &mut self.frame;
        let p0 = self.needle_free[0];
        let r0 = exp_so3(&Vector3::new(
            self.needle_dx[3],
            self.needle_dx[4],
            self.needle_dx[5],
        )) * self.needle.rotation(0);
        // The frame carries the needle base as a B-frame orientation: R_B = R_node · r_offᵀ.
        let rb = r0 * self.r_off.transpose();
        f.p_free = [p0.x, p0.y, p0.z];
        for i in 0..3 {
            for j in 0..3 {
                f.r_free[i][j] = rb[(i, j)];
            }
        }
        let base = self.chain.tool_pose(&self.q);
        let d = base_violation(&base, &f.p_free, &f.r_free);
        f.delta_free[..6].copy_from_slice(&d);
        f.q = self.q;
        f.dt = self.scene.robot.dt;
        f.inserted = u32::from(self.punctured);
        f.insertion_depth = depth;
        f.sequence = self.steps as u64;
        f.version = needle_core::payload::VERSION;
        f.validate()
            .map_err(|e| SimError::Core(StepError::InvalidFrame(e)))
    }

    /// The tip punctured the surface: the contact gives way to a sliding point at the entry.
    fn puncture(&mut self) -> Result<(), SimError> {
        let tip = self.tip();
        let loc = TetLocator::new(self.gel.nodes(), self.gel.tets());
        let at = loc
            .locate(self.gel.nodes(), self.gel.tets(), &tip, 2.0)
            .ok_or_else(|| {
                SimError::Setup(format!("punctured at {tip}, which is not on the gel"))
            })?;
        self.punctured = true;
        self.entry = at;
        self.add_sliding(at);
        self.last_sliding_depth = 0.0;
        Ok(())
    }

    fn add_sliding(&mut self, at: Embedded) {
        self.sliding.push(SlidingPoint {
            id: self.next_sliding_id,
            at,
            cols: None,
        });
        self.next_sliding_id += 1;
    }

    /// New sliding point every `d_n` of advance; release the ones the tip has been withdrawn past.
    fn update_sliding_points(&mut self) -> Result<(), SimError> {
        let nodes = self.needle.nodes();
        let n = nodes.len();
        let tip = nodes[n - 1];
        let tdir = (nodes[n - 1] - nodes[n - 2]).normalize();
        let (gel_nodes, tets) = (self.gel.nodes(), self.gel.tets());
        // Released once the tip is withdrawn past the point by more than a margin (half the
        // spacing, at most 1 mm): without it, the point created at the tip itself would flicker
        // in and out with the tip's sub-millimetre back-and-forth.
        let margin = (0.5 * self.scene.interaction.constraint_spacing).min(1.0);
        self.sliding.retain(|s| {
            let g = s.at.position(gel_nodes, tets);
            (g - tip).dot(&tdir) <= margin
        });
        if self.sliding.is_empty() {
            // Fully withdrawn: the surface is whole again for contact purposes.
            self.punctured = false;
            self.last_sliding_depth = 0.0;
            return Ok(());
        }
        let depth = self.depth();
        if depth < self.last_sliding_depth {
            self.last_sliding_depth = depth;
        }
        let gate = self
            .scene
            .interaction
            .constraint_spacing
            .max(self.min_element_size);
        if depth - self.last_sliding_depth >= gate {
            let (gel_nodes, tets) = (self.gel.nodes(), self.gel.tets());
            let loc = TetLocator::new(gel_nodes, tets);
            if let Some(at) = loc.locate(gel_nodes, tets, &tip, 1.0) {
                // Sliding points no closer than the element size: the gel is linear in an element,
                // so two points closer than an element are nearly the same constraint. With a stiff
                // needle their rows are almost parallel: Gauss-Seidel stalls (d_n = 1 mm on a
                // 1500-node box: every step at the sweep cap), and the pair clamps the shaft like a
                // lever — large opposite lateral forces whose μ_n-bounds lock it, so the shaft
                // drags the gel instead of sliding (the tip stuck at 4–6 mm depth, 40–75 N of
                // sliding force). The spacing actually used is `max(d_n, h)`, `h` the rest size of
                // the tetrahedron the tip is in (see `element_size`).
                let h = element_size(self.gel.rest(), &tets[at.tet]);
                if depth - self.last_sliding_depth >= h {
                    self.add_sliding(at);
                    self.last_sliding_depth = depth;
                }
            }
        }
        Ok(())
    }

    /// Largest lateral violation of the sliding points after the step (distance across the
    /// shaft) [mm].
    fn residual(&self) -> f64 {
        let nodes = self.needle.nodes();
        self.sliding
            .iter()
            .map(|s| {
                let g = s.at.position(self.gel.nodes(), self.gel.tets());
                let (e, f) = closest_on_polyline(nodes, &g);
                let p = nodes[e] * (1.0 - f) + nodes[e + 1] * f;
                // Lateral: across the segment's axis. A point the tip is being withdrawn past
                // (kept until it is a margin beyond the tip) is measured against the shaft's
                // line, not against the tip itself.
                let t = (nodes[e + 1] - nodes[e]).normalize();
                let d = g - p;
                (d - t * d.dot(&t)).norm()
            })
            .fold(0.0, f64::max)
    }

    /// Clearance of the inserted needle to each deformed obstacle surface (negative: hit) [mm].
    ///
    /// The inserted part is the needle within `depth` of arc length from the tip; before
    /// puncture nothing is inserted and every clearance is `+∞`.
    pub fn clearances(&self) -> Vec<f64> {
        let nodes = self.needle.nodes();
        let depth = self.depth();
        // Arc length from the tip to each node.
        let mut arc = vec![0.0; nodes.len()];
        for k in (0..nodes.len() - 1).rev() {
            arc[k] = arc[k + 1] + (nodes[k + 1] - nodes[k]).norm();
        }
        self.obstacles
            .iter()
            .map(|(e, r)| {
                let c = e.position(self.gel.nodes(), self.gel.tets());
                let mut best = f64::INFINITY;
                for k in 0..nodes.len() - 1 {
                    if self.punctured && arc[k + 1] < depth {
                        // Clip the segment to the inserted part.
                        let f = if arc[k] > depth {
                            (arc[k] - depth) / (arc[k] - arc[k + 1])
                        } else {
                            0.0
                        };
                        let a = nodes[k] + f * (nodes[k + 1] - nodes[k]);
                        best = best.min(distance_point_segment(&c, &a, &nodes[k + 1]));
                    }
                }
                best - r
            })
            .collect()
    }
}

/// Tip-to-surface distance under which the contact rows are built [mm].
const CONTACT_DISTANCE: f64 = 5.0;
/// Arc length between the target and the second point that defines the target tangent [mm].
const TANGENT_STEP: f64 = 1.0;

/// Size of a tetrahedron: the edge of the regular tetrahedron of the same volume,
/// `(6√2 V)^(1/3)` [mm] (a cube of side a split into 6 tetrahedra: 2^(1/6) a ≈ 1.12 a).
pub fn element_size(nodes: &[Vector3<f64>], t: &[usize; 4]) -> f64 {
    let v = (nodes[t[1]] - nodes[t[0]])
        .cross(&(nodes[t[2]] - nodes[t[0]]))
        .dot(&(nodes[t[3]] - nodes[t[0]]))
        .abs()
        / 6.0;
    (6.0 * std::f64::consts::SQRT_2 * v).cbrt()
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
