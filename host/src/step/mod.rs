//! One step of the simulation (the paper's Algorithm 1), read top to bottom in
//! [`Pipeline::step`]:
//!
//! 1. **free motion (FM)** — one quasi-static Newton step of each body without constraints:
//!    `Δx_free = K⁻¹ b` for the gel and the needle ([`crate::free_motion`]);
//! 2. **proximity (CD)** — the row groups of this step ([`rows`]): the needle base χ (6
//!    bilateral rows), the sliding points ψ after puncture (2 lateral bilateral rows + 1 axial
//!    friction row each), the tip on the gel surface φ before puncture (contact with Coulomb
//!    friction), with their violations `δ_free`;
//! 3. **compliance (CC)** — `W = H K⁻¹ Hᵀ` and the observation rows `C`, `o_free`
//!    ([`crate::compliance`], [`observe`]), gel columns cached while the factor is reused; the
//!    frame for the core;
//! 4. **constraint solve (SC)** — through a [`Transport`]: the core's inverse step (8
//!    Gauss-Seidel solves: new joints `q` and the final `λ`), in this process or another, or a
//!    single solve at given joints ([`crate::open_loop::OpenLoop`]);
//! 5. **corrective motion** — `x = x_free + K⁻¹ Hᵀ λ` ([`correct`]);
//! 6. **interaction bookkeeping** ([`interact`]) — puncture when the contact's normal force
//!    reaches `p_f` (once: the contact group gives way to a sliding point at the entry), a new
//!    sliding point each time the tip has advanced `d_n` past the last one, sliding points
//!    released when the needle is withdrawn past them.
//!
//! Each stage is timed ([`StageTimes`]). The [`Pipeline`] owns the scratch of a step (the frame,
//! the command, the rows, the free-motion vectors, the cached compliance columns); the state is
//! the [`World`]'s; the tuning is one [`StepParams`].

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

pub mod correct;
pub mod interact;
pub mod observe;
mod params;
pub mod rows;

pub use correct::ConstraintForce;
pub use params::{
    ENTRY_TILT_FRACTION, EntryTilt, Insertion, Interaction, StepParams, TargetMotion,
};

use crate::compliance::{NodeColumns, PointColumns, PointMap};
use crate::constraints::{
    ClearanceKind, ClearanceObservation, ConstraintSet, GroupRole, Model, Observation,
};
use crate::error::{Body, CommandMismatch, NonFiniteAt, SimError};
use crate::joints::{Joints, MAX_JOINTS, normalised_limit_margin};
use crate::proximity::{CachedProjector, Embedded};
use crate::world::World;
use nalgebra::Vector3;
use needle_bridge::Transport;
use needle_core::kinematics::Kinematics as _;
use needle_core::payload::{Command, ComplianceFrame, SolverReport, StatusFlags, VERSION};
use std::time::Instant;

/// Row capacity of the frames a pipeline builds: 6 base rows + 3 contact rows + 3 rows for each
/// of up to 61 sliding points (50 mm of insertion at d_n ≥ 0.85 mm).
pub const ROWS: usize = 192;

/// Per-stage wall times of one step [ms].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// 1. Free motion (both bodies).
    pub fm: f64,
    /// 2. Proximity and row construction.
    pub cd: f64,
    /// 3. Compliance and frame.
    pub cc: f64,
    /// 4. Constraint solves: the transport's round trip (in process: the core's whole step).
    pub sc: f64,
    /// 5. Corrective motion.
    pub corr: f64,
    /// 6. Interaction bookkeeping (puncture, sliding points).
    pub interact: f64,
}

impl StageTimes {
    /// Sum of the stages [ms].
    pub fn total(&self) -> f64 {
        self.fm + self.cd + self.cc + self.sc + self.corr + self.interact
    }

    /// Stages 5 and 6 together [ms] (the `corr` column of the outputs).
    pub fn after_solve(&self) -> f64 {
        self.corr + self.interact
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
    /// The tip slid off its target on the surface during this step, before puncture: from the
    /// next step until it punctures, the heading shown to the controller is held within the
    /// friction cone ([`World::tip_slid`]).
    pub tip_slid_now: bool,
    /// Normal force of the tip contact [N] (0 without contact).
    pub contact_force: f64,
    /// Norms of λ per role: base, contact, sliding [N or N·mm].
    pub lambda_norms: [f64; 3],
    /// The core's report; its `delta_q` holds the robot's joints first (`q.len()` of them), zero
    /// beyond.
    pub solver: SolverReport<MAX_JOINTS>,
    /// Largest constraint violation after the step over the non-base bilateral rows [mm].
    pub residual: f64,
    /// Joints after the step [rad], one per joint of the robot.
    pub q: Joints,
    /// The smallest distance of any joint to one of its position limits after the step, as a
    /// fraction of that joint's half range (1: every joint mid-range, 0: one at a limit;
    /// `+∞` when no joint has finite limits): what keeps a redundant arm's spare joint away from
    /// its limits ([`needle_core::inverse::InverseParams::limit_avoidance`]) shows here.
    pub limit_margin: f64,
    /// The joint of [`Self::limit_margin`] (0-based).
    pub limit_joint: usize,
    /// Stage times [ms].
    pub times: StageTimes,
    /// The force of each row group on the needle, and where it acts (after the step).
    pub forces: Vec<ConstraintForce>,
    /// The constraints' forces on each needle node (translational) [N].
    pub needle_node_forces: Vec<Vector3<f64>>,
    /// When a clearance row held the step (the core's `CLEARANCE_ACTIVE`), what the row
    /// nearest its bound after it bounds: the one that held it.
    pub holding: Option<ClearanceKind>,
    /// The needle's largest bending strain at its surface after the step [-], and its
    /// distance from the tip [mm] (`crate::free_motion::NeedleModel::max_bending_strain`).
    pub needle_bend: (f64, f64),
}

impl StepReport {
    /// Whether the step's configuration has the tip inside the gel: inserted during the step
    /// and still after it. The step that punctures the surface (`punctured_now`) is not: its
    /// corrective motion was that of the tip contact, so it ends with the tip on the indented
    /// surface, at depth 0, and the tip enters the gel during the next step. Its `error` is
    /// measured against the embedded target all the same (the gel not yet relaxed around the
    /// tip): [`crate::run::RunSummary::e_puncture_mm`]. The tracking metrics inside the gel
    /// (e_mean, e_max, the path deviation, the error against depth) count only the steps for
    /// which this is true.
    ///
    /// # Example
    /// ```
    /// use needle_host::step::StepReport;
    ///
    /// let punctures = StepReport { inserted: true, punctured_now: true, ..StepReport::default() };
    /// let inside = StepReport { inserted: true, ..StepReport::default() };
    /// assert!(!punctures.tip_inside() && inside.tip_inside());
    /// assert!(!StepReport::default().tip_inside());
    /// ```
    pub fn tip_inside(&self) -> bool {
        self.inserted && !self.punctured_now
    }
}

/// Positions after free motion: `x + Δx_free` of every node [mm].
#[derive(Clone, Debug, Default)]
pub struct FreePositions {
    /// Gel nodes (fixed ones where they are).
    pub gel: Vec<Vector3<f64>>,
    /// Needle nodes.
    pub needle: Vec<Vector3<f64>>,
}

impl FreePositions {
    /// The free-motion position of a gel point [mm].
    pub fn gel_point<const N: usize>(&self, world: &World<N>, e: &Embedded) -> Vector3<f64> {
        e.position(&self.gel, &world.gel.mesh().tets)
    }
}

/// The scratch of a step, sized once for a world: the frame and the command, the rows, the
/// free-motion and correction vectors, and the gel compliance columns of the sliding points
/// (valid while the gel's factor is reused). `N`: the robot's joints.
pub struct Pipeline<const N: usize = 6> {
    frame: Box<ComplianceFrame<ROWS, N>>,
    command: Box<Command<ROWS, N>>,
    set: ConstraintSet,
    gel_dx: Vec<f64>,
    needle_dx: Vec<f64>,
    free: FreePositions,
    /// Gel columns of sliding points by id, kept from one step to the next.
    columns: Vec<(usize, PointColumns)>,
    /// Gel columns of the nodes under the tip's contact point, kept while the factor is.
    contact_nodes: NodeColumns,
    /// The gel surface's projector for the tip's contact, kept while the gel does not move.
    surface: CachedProjector,
    /// Whether this step's gel free motion has its far rows deferred
    /// ([`crate::free_motion::FeModel::free_motion_deferring_far`]): `gel_dx` is exact on the
    /// gel's near dofs only until the corrective motion finishes it.
    far_pending: bool,
    /// Whether the next step defers the gel's far rows: every gel point of the last frame lay
    /// on the near rows (a frame that reads a far point, e.g. an obstacle observed outside the
    /// near block, keeps the steps after it whole, and their columns cached, until one does
    /// not).
    defer_next: bool,
    /// This step's observations and clearance observations when the deferral check made them
    /// from the free positions the frame is then built from (taken by the compliance stage,
    /// which otherwise makes them).
    observed: Option<([Observation; 5], Vec<ClearanceObservation>)>,
    /// What each clearance row of the last frame bounds, in the frame's order.
    row_kinds: Vec<ClearanceKind>,
    /// The stage times of the last step.
    pub times: StageTimes,
}

/// Milliseconds since `t`, and restarts `t`.
fn lap(t: &mut Instant) -> f64 {
    let now = Instant::now();
    let ms = (now - *t).as_secs_f64() * 1e3;
    *t = now;
    ms
}

impl<const N: usize> Pipeline<N> {
    /// Scratch for `world`'s bodies.
    pub fn new(world: &World<N>) -> Self {
        Self {
            frame: ComplianceFrame::new_boxed(),
            command: Command::new_boxed(),
            set: ConstraintSet::default(),
            gel_dx: vec![0.0; world.gel.dof_count()],
            needle_dx: vec![0.0; world.needle.dof_count()],
            free: FreePositions {
                gel: vec![Vector3::zeros(); world.gel.node_count()],
                needle: vec![Vector3::zeros(); world.needle.node_count()],
            },
            columns: Vec::new(),
            contact_nodes: NodeColumns::default(),
            surface: CachedProjector::default(),
            far_pending: false,
            defer_next: true,
            observed: None,
            row_kinds: Vec::new(),
            times: StageTimes::default(),
        }
    }

    /// One step of `world` (Algorithm 1, see the module docs), the constraint solve through
    /// `transport`. The target moves to `params.insertion.next_arc(…)`: on schedule, or waiting
    /// for a tip that lags behind it ([`next_target`]).
    ///
    /// # Errors
    /// [`SimError`]: a failed factorisation or solve, a capacity overflow, an invalid frame, a
    /// transport failure or a command that does not answer the frame, a non-finite state.
    ///
    /// # Example
    /// ```
    /// use needle_bridge::InProcess;
    /// use needle_host::{scene::Scene, setup::Setup, step::Pipeline};
    ///
    /// let scene = Scene::builtin("simple").unwrap()
    ///     .with_overrides(&[("gel.box.nodes".into(), "300".into())]).unwrap();
    /// let s = Setup::build(&scene).unwrap();
    /// let (mut world, params) = (s.world, s.params);
    /// let mut core = InProcess::new(s.robot, s.inverse);
    /// let mut pipeline = Pipeline::new(&world);
    /// for k in 0..3 {
    ///     let r = pipeline.step(&mut world, &params, &mut core).unwrap();
    ///     assert_eq!((r.step, r.rows), (k, 6)); // in the air: the base rows only
    ///     assert!(r.error < 0.1);
    /// }
    /// assert!((world.c - 0.3).abs() < 1e-12);
    /// ```
    pub fn step(
        &mut self,
        world: &mut World<N>,
        params: &StepParams,
        transport: &mut dyn Transport<ROWS, N>,
    ) -> Result<StepReport, SimError> {
        let c = next_target(world, params);
        self.step_to(world, params, transport, c)
    }

    /// [`Pipeline::step`] with the target at arc length `c` [mm] whatever the insertion
    /// schedule says: a world driven open loop by another's joints (a model hiding the
    /// support's motion) takes that world's target.
    ///
    /// # Errors
    /// As [`Pipeline::step`].
    pub fn step_to(
        &mut self,
        world: &mut World<N>,
        params: &StepParams,
        transport: &mut dyn Transport<ROWS, N>,
        c: f64,
    ) -> Result<StepReport, SimError> {
        let mut times = StageTimes::default();
        let mut t = Instant::now();

        // 1. Free motion, the gel's support at its prescribed place at the end of the step.
        world.move_support((world.steps + 1) as f64 * params.dt);
        self.free_motion(world)?;
        times.fm = lap(&mut t);

        // 2. Proximity: the row groups χ, ψ, φ.
        rows::build(
            &mut self.set,
            world,
            &self.free,
            &params.interaction,
            &mut self.columns,
            &mut self.surface,
        );
        // With the gel's far rows deferred, every gel point of the frame must lie where the
        // deferred solves are exact; otherwise the free motion is finished now and the rows
        // built again from the whole free positions, the near-only columns dropped, and the
        // next steps solve whole until a frame lies on the near rows again.
        self.observed = None;
        let near = !world.gel.defers_far() || self.frame_is_near(world, c, params);
        self.defer_next = near;
        if self.far_pending && !near {
            // The free positions change: the observations are made again from them.
            self.observed = None;
            world
                .gel
                .complete_far(&mut self.gel_dx)
                .map_err(SimError::in_free_motion(Body::Gel))?;
            self.far_pending = false;
            world.gel.record_deferral_fallback();
            self.update_free_positions(world)?;
            self.contact_nodes = NodeColumns::default();
            rows::build(
                &mut self.set,
                world,
                &self.free,
                &params.interaction,
                &mut Vec::new(),
                &mut self.surface,
            );
        }
        let rows = self.set.rows();
        if rows > ROWS {
            return Err(SimError::Capacity {
                rows,
                capacity: ROWS,
            });
        }
        times.cd = lap(&mut t);

        // 3. Compliance and the frame.
        self.compliance(world, c, params)?;
        times.cc = lap(&mut t);

        // 4. Constraint solve: the frame to the core, the command back.
        let exchange = transport
            .exchange(&self.frame, &mut self.command)
            .map_err(SimError::Transport)?;
        check_command(&self.frame, &self.command)?;
        times.sc = exchange.round_trip.as_secs_f64() * 1e3;
        t = Instant::now();

        // 5. Corrective motion.
        let lambda = &self.command.lambda[..rows];
        correct::apply(
            world,
            &self.set,
            lambda,
            &mut self.needle_dx,
            &mut self.gel_dx,
            self.far_pending,
        )?;
        self.far_pending = false;
        world.q = self.command.q;
        world.c = c;
        times.corr = lap(&mut t);

        // 6. Interaction bookkeeping.
        let forces = interact::forces(&self.set, lambda);
        interact::keep_columns(&mut self.set, &mut self.columns);
        let slid_before = world.tip_slid;
        let punctured_now = interact::update(world, &forces, &params.interaction)?;
        times.interact = lap(&mut t);

        self.times = times;
        let slid_now = world.tip_slid && !slid_before;
        let report = self.report(world, c, forces, (punctured_now, slid_now));
        world.steps += 1;
        Ok(report)
    }

    /// Stage 1: `Δx_free` of both bodies, the free positions, and the cached gel columns dropped
    /// when the gel's factor was renewed.
    fn free_motion(&mut self, world: &mut World<N>) -> Result<(), SimError> {
        self.far_pending = world.gel.defers_far() && self.defer_next;
        let gel_dx = if self.far_pending {
            world.gel.free_motion_deferring_far()
        } else {
            world.gel.free_motion_unloaded()
        };
        self.gel_dx
            .copy_from_slice(gel_dx.map_err(SimError::in_free_motion(Body::Gel))?);
        let needle_dx = world.needle.free_motion_unloaded();
        self.needle_dx
            .copy_from_slice(needle_dx.map_err(SimError::in_free_motion(Body::Needle))?);
        if world.gel.factor_age() == Some(0) {
            self.columns.clear();
        }
        self.update_free_positions(world)
    }

    /// Whether every gel point this step's frame uses (the rows' points, the observed ones)
    /// lies on dofs the deferred solves give exactly.
    /// Keeps the observations it makes for the compliance stage.
    fn frame_is_near(&mut self, world: &World<N>, c: f64, params: &StepParams) -> bool {
        let gel = &world.gel;
        let near = |map: &PointMap| {
            map.used()
                .iter()
                .all(|&(b, _)| (b..b + 3).all(|d| gel.is_deferral_exact(d)))
        };
        let observed = observe::observations(world, &self.free, c, params.entry_tilt);
        let clearances = observe::clearance_observations(world, &self.free, params);
        let is_near = self.set.gel.points.iter().all(|p| near(&p.map))
            && (observed.iter())
                .chain(clearances.iter().flat_map(|o| o.obstacle.iter()))
                .filter(|o| o.model == Model::Gel)
                .all(|o| near(&o.map));
        self.observed = Some((observed, clearances));
        is_near
    }

    /// The free positions of both bodies from the free motions, checked finite.
    fn update_free_positions(&mut self, world: &World<N>) -> Result<(), SimError> {
        for (i, x) in world.gel.positions().iter().enumerate() {
            self.free.gel[i] = match world.gel.node_dof(i) {
                Some(d) => x + Vector3::new(self.gel_dx[d], self.gel_dx[d + 1], self.gel_dx[d + 2]),
                None => *x,
            };
        }
        for (i, x) in world.needle.positions().iter().enumerate() {
            let d = &self.needle_dx[6 * i..6 * i + 3];
            self.free.needle[i] = x + Vector3::new(d[0], d[1], d[2]);
        }
        if !self
            .gel_dx
            .iter()
            .chain(&self.needle_dx)
            .all(|v| v.is_finite())
        {
            return Err(SimError::NonFinite(NonFiniteAt::FreeMotion));
        }
        Ok(())
    }

    /// Stage 3: the Cartesian columns `K⁻¹ Pᵀ` of every constrained point (cached gel ones
    /// kept), then `W`, `δ_free`, `C`, `o_free` and the header of the frame.
    fn compliance(
        &mut self,
        world: &mut World<N>,
        c: f64,
        params: &StepParams,
    ) -> Result<(), SimError> {
        let (nn, ng) = (world.needle.dof_count(), world.gel.dof_count());
        let needle = &mut world.needle;
        self.set
            .needle
            .compute_missing(nn, |r, k| needle.solve_columns(r, k))
            .map_err(SimError::in_compliance(Body::Needle))?;
        let gel = &mut world.gel;
        // With the far rows deferred, the gel's columns on its near dofs only (all the frame
        // reads of them; the corrective motion's far rows come with the free motion's).
        let near = self.far_pending;
        // The contact point's weights change every step: its columns are sums of its nodes'.
        let contact = (self.set.groups.iter())
            .filter(|g| g.role == GroupRole::Contact)
            .flat_map(|g| &g.attachments)
            .find(|a| a.model == Model::Gel)
            .map(|a| a.point);
        if let Some(p) = contact.filter(|&p| self.set.gel.points[p].cols.is_none()) {
            let map = self.set.gel.points[p].map;
            let stamp = gel.factor_stamp();
            let (cols, _) = self
                .contact_nodes
                .point(&map, ng, stamp, |r, k| solve_gel(gel, near, r, k))
                .map_err(SimError::in_compliance(Body::Gel))?;
            self.set.gel.points[p].cols = Some(cols);
        }
        self.set
            .gel
            .compute_missing(ng, |r, k| solve_gel(gel, near, r, k))
            .map_err(SimError::in_compliance(Body::Gel))?;
        let (observations, clearances) = match self.observed.take() {
            Some(made) => made,
            None => (
                observe::observations(world, &self.free, c, params.entry_tilt),
                observe::clearance_observations(world, &self.free, params),
            ),
        };
        self.set.fill_frame(&observations, &mut self.frame);
        self.set.fill_clearances(&clearances, &mut self.frame);
        self.row_kinds = clearances.iter().map(|c| c.kind).collect();
        observe::fill_header(
            &mut self.frame,
            world,
            &self.needle_dx,
            &self.free,
            params.dt,
        )
        .map_err(SimError::InvalidFrame)
    }

    /// The report of a finished step.
    fn report(
        &self,
        world: &World<N>,
        c: f64,
        forces: interact::Forces,
        (punctured_now, tip_slid_now): (bool, bool),
    ) -> StepReport {
        let tip = world.tip();
        let target = world.target(c);
        let (limit_margin, limit_joint) = normalised_limit_margin(&world.q, world.robot.limits());
        let (group_forces, needle_node_forces) = correct::constraint_forces(
            &self.set,
            &self.command.lambda[..self.set.rows()],
            world.needle.positions(),
        );
        StepReport {
            step: world.steps,
            c,
            tip,
            target,
            error: (tip - target).norm(),
            inserted: world.punctured,
            depth: world.depth(),
            rows: self.set.rows(),
            sliding_points: world.sliding.len(),
            punctured_now,
            tip_slid_now,
            contact_force: forces.contact,
            lambda_norms: forces.norms,
            solver: widen_report(&self.command.report),
            residual: world.sliding_residual(),
            q: Joints::new(&world.q),
            limit_margin,
            limit_joint,
            times: self.times,
            forces: group_forces,
            needle_node_forces,
            holding: self.holding(),
            needle_bend: world.needle.max_bending_strain(),
        }
    }

    /// What the clearance row nearest its bound after the step (by the frame's linear model at
    /// the step's `λ`) bounds, when a clearance row held the step; none otherwise.
    fn holding(&self) -> Option<ClearanceKind> {
        if self.command.report.flags & StatusFlags::CLEARANCE_ACTIVE == 0 {
            return None;
        }
        let rows = self.frame.clearances().min(self.row_kinds.len());
        (0..rows)
            .map(|k| (self.frame.clearance(k, &self.command.lambda), k))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, k)| self.row_kinds[k])
    }

    /// The last frame handed to the core (diagnostics, transports).
    pub fn frame(&self) -> &ComplianceFrame<ROWS, N> {
        &self.frame
    }

    /// The last command received from the core.
    pub fn command(&self) -> &Command<ROWS, N> {
        &self.command
    }

    /// The force each row group of the last step applies to the needle, world frame [N] (the
    /// gel receives the opposite of every contact and sliding force); for the base group, its
    /// translational rows.
    pub fn needle_forces(&self) -> Vec<(GroupRole, Vector3<f64>)> {
        correct::needle_forces(&self.set, &self.command.lambda[..self.set.rows()])
    }
}

/// The core's report of an `N`-joint step with room for [`MAX_JOINTS`] joints.
/// The gel's compliance columns for `ncols` right-hand sides: on the near dofs only when
/// `near` (the far rows deferred), else whole.
fn solve_gel(
    gel: &mut crate::free_motion::GelModel,
    near: bool,
    rhs: &mut [f64],
    ncols: usize,
) -> Result<(), crate::fem::FemError> {
    if near {
        gel.solve_columns_near(rhs, ncols)
    } else {
        gel.solve_columns(rhs, ncols)
    }
}

fn widen_report<const N: usize>(r: &SolverReport<N>) -> SolverReport<MAX_JOINTS> {
    let mut delta_q = [0.0; MAX_JOINTS];
    for (d, v) in delta_q.iter_mut().zip(&r.delta_q) {
        *d = *v;
    }
    SolverReport {
        iterations: r.iterations,
        solves: r.solves,
        flags: r.flags,
        final_iterations: r.final_iterations,
        final_residual: r.final_residual,
        objective: r.objective,
        objective_after: r.objective_after,
        delta_q,
    }
}

/// Checks that `cmd` answers `frame`: version, sequence, row count, finite values.
fn check_command<const N: usize>(
    frame: &ComplianceFrame<ROWS, N>,
    cmd: &Command<ROWS, N>,
) -> Result<(), SimError> {
    let why = if cmd.version != VERSION {
        Some(CommandMismatch::Version)
    } else if cmd.frame_sequence != frame.sequence {
        Some(CommandMismatch::Sequence)
    } else if cmd.m != frame.m {
        Some(CommandMismatch::RowCount)
    } else if !cmd
        .q
        .iter()
        .chain(&cmd.lambda[..frame.rows()])
        .all(|v| v.is_finite())
    {
        Some(CommandMismatch::NonFinite)
    } else {
        None
    };
    why.map_or(Ok(()), |w| Err(SimError::Command(w)))
}

/// The target's arc length for the next step of `world` ([`Insertion::next_arc`]): the tip's
/// lag behind the current target is taken along the path's tangent there (rest direction).
pub fn next_target<const N: usize>(world: &World<N>, params: &StepParams) -> f64 {
    let total = world.path.total_length();
    let ins = &params.insertion;
    let lag = if ins.follows_tip() && world.steps > 0 {
        let tangent = world.path.at(world.c).1;
        (world.target(world.c) - world.tip()).dot(&tangent)
    } else {
        0.0
    };
    ins.next_arc(total, world.steps, world.c, lag)
}
