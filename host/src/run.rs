//! One insertion from start to end: the inverse controller (Algorithm 1) or the naive baseline,
//! with outputs and a summary.
//!
//! - **Inverse** (the paper's method): every step the world's free motion, proximity and
//!   compliance, the core's inverse update and final solve, the corrective motion.
//! - **Naive** (the paper's baseline): the joints a *rigid* needle in a *rigid* gel would need to
//!   follow the rest path — tip on the target, needle along the path tangent, by IK — computed
//!   up front and replayed open-loop in the full deformable simulation. Where the replay breaks
//!   down (IK out of reach, a failed solve, a non-finite state) the run stops cleanly and says so.
//!
//! The inverse controller is reached through a [`Transport`]: [`run`] uses
//! [`InProcess`] (the core called directly), [`run_with`] any transport — `needle serve` passes a
//! [`needle_bridge::SharedMemoryHost`] and the core runs in another process. The loop is the
//! same code either way: [`World::prepare`](crate::world::World::prepare) builds the frame,
//! the transport brings back the command answering it,
//! [`World::apply_command`](crate::world::World::apply_command) applies it. When no command
//! arrives within the transport's deadline the host *holds the insertion*: it does not apply
//! anything, does not advance the target `c`, says so on stderr, and hands the same frame over
//! again until an answer arrives (or [`RunOptions::give_up_after`] has passed).

use crate::bodies::{Simulation, build};
use crate::output::{
    MetricsWriter, OutputError, StepMetrics, write_points, write_polyline, write_tet_mesh,
};
use crate::scene::Scene;
use crate::world::{ROWS, SimError, StepReport};
use needle_bridge::{InProcess, Transport, TransportError};
use needle_core::ik::{IkParams, solve_ik};
use needle_core::payload::{Command, StatusFlags};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Which controller drives the robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ControllerKind {
    /// The inverse FE controller (paper §IV).
    Inverse,
    /// Rigid-model IK replayed in the deformable simulation (paper §V-A baseline).
    Naive,
}

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The controller.
    pub controller: ControllerKind,
    /// Number of steps (default: the scene's, else to the end of the path).
    pub steps: Option<usize>,
    /// Output folder for the CSV, the VTK files and the JSON summary (none: no files).
    pub out_dir: Option<PathBuf>,
    /// Write VTK files every this many steps (0: never; default: the scene's).
    pub vtk_every: Option<usize>,
    /// Free-running host: start a step at most every `period` (none: as fast as the answers
    /// come — lock-step).
    pub period: Option<Duration>,
    /// Stop the run when no command has answered the current frame for this long (none: hold
    /// for ever). Only a remote transport can time out.
    pub give_up_after: Option<Duration>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            controller: ControllerKind::Inverse,
            steps: None,
            out_dir: None,
            vtk_every: None,
            period: None,
            give_up_after: None,
        }
    }
}

/// Median and 99th percentile [ms].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Timing {
    /// Median [ms].
    pub median_ms: f64,
    /// 99th percentile [ms].
    pub p99_ms: f64,
    /// Mean [ms] (with a factorisation pipeline of several steps, the steps alternate between
    /// short ones and ones that wait for a factor: the mean is the throughput).
    pub mean_ms: f64,
}

/// The gel's strain is sampled every this many steps (≈ 1 ms for 7000 elements, outside the
/// timed stages).
pub const STRAIN_EVERY: usize = 10;

/// Steps whose solver report carries `flag`.
fn count_flag(reports: &[StepReport], flag: u32) -> usize {
    reports
        .iter()
        .filter(|r| r.solver.flags & flag != 0)
        .count()
}

fn timing(mut v: Vec<f64>) -> Timing {
    if v.is_empty() {
        return Timing::default();
    }
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    Timing {
        median_ms: at(0.5),
        p99_ms: at(0.99),
        mean_ms: v.iter().sum::<f64>() / v.len() as f64,
    }
}

/// Per-stage timing of a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTiming {
    /// Free motion.
    pub fm: Timing,
    /// Proximity.
    pub cd: Timing,
    /// Compliance.
    pub cc: Timing,
    /// Constraint solves (the core's inverse step: 8 solves).
    pub sc: Timing,
    /// Corrective motion and bookkeeping.
    pub correction: Timing,
    /// Whole step.
    pub total: Timing,
}

/// Smallest clearance to one obstacle over the run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Clearance {
    /// Obstacle name.
    pub name: String,
    /// Smallest distance from the inserted needle to the deformed sphere (negative: hit) [mm].
    pub min_mm: f64,
}

/// The summary of a run (also written as `summary.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RunSummary {
    /// Scene name.
    pub scene: String,
    /// Controller.
    pub controller: ControllerKind,
    /// Gel nodes.
    pub gel_nodes: usize,
    /// Steps run.
    pub steps: usize,
    /// Steps planned.
    pub steps_planned: usize,
    /// Whether the run reached its last step.
    pub completed: bool,
    /// Why it stopped early.
    pub stopped: Option<String>,
    /// Step at which the tip punctured the surface.
    pub puncture_step: Option<usize>,
    /// Mean tracking error over the steps with the tip inside the gel [mm].
    pub e_mean_mm: f64,
    /// Largest tracking error inside the gel [mm].
    pub e_max_mm: f64,
    /// Tracking error at the last step [mm].
    pub e_final_mm: f64,
    /// Final insertion depth [mm].
    pub final_depth_mm: f64,
    /// Smallest clearance per obstacle.
    pub clearances: Vec<Clearance>,
    /// Whether any obstacle was hit.
    pub obstacle_hit: bool,
    /// Stage times.
    pub timing: StageTiming,
    /// Gauss-Seidel sweeps per step (all solves): mean.
    pub gs_iterations_mean: f64,
    /// Gauss-Seidel sweeps per step: largest.
    pub gs_iterations_max: u32,
    /// Steps in which a solve hit its iteration cap.
    pub gs_not_converged_steps: usize,
    /// Largest principal strain `|σ(F) − 1|` of any gel element, sampled every
    /// [`STRAIN_EVERY`] steps and at the last [-].
    pub max_strain: f64,
    /// Most gel elements inverted (`det F ≤ 0`) at once, same sampling.
    pub max_inverted_elements: usize,
    /// Steps in which the controller reported the target unreachable (no joint update
    /// improves the objective by 1 %).
    pub unreachable_steps: usize,
    /// Steps in which a joint stopped at its limit.
    pub limit_steps: usize,
    /// Gel factorisations finished on the background thread and used one step later (0 without
    /// `solver.background_factorization`).
    pub background_factorizations: u64,
    /// Gel factorisations made at once in background mode (the first step, and steps whose
    /// elements rotated more than `LAG_ROTATION_LIMIT` since the previous one).
    pub immediate_factorizations: u64,
    /// Times the host held the insertion because no command arrived within the transport's
    /// deadline.
    pub holds: usize,
    /// Total time spent holding [ms].
    pub held_ms: f64,
}

/// What a run produces.
pub struct RunResult {
    /// The summary.
    pub summary: RunSummary,
    /// Every step's report.
    pub reports: Vec<StepReport>,
    /// Error against insertion depth `(depth, error)` for the steps inside the gel [mm].
    pub error_by_depth: Vec<(f64, f64)>,
}

/// Why a run could not start or write its outputs. (A breakdown during the run is not an error:
/// it ends the run and is reported in [`RunSummary::stopped`].)
#[derive(Debug)]
pub enum RunError {
    /// The simulation could not be set up.
    Setup(SimError),
    /// An output file could not be written.
    Output(OutputError),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Setup(e) => write!(f, "{e}"),
            Self::Output(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RunError {}

impl From<OutputError> for RunError {
    fn from(e: OutputError) -> Self {
        Self::Output(e)
    }
}

/// Steps a scene plans: its `insertion.steps`, else until the target reaches the path's end.
pub fn planned_steps(scene: &Scene) -> usize {
    scene.insertion.steps.unwrap_or_else(|| {
        let total = scene
            .sampled_path()
            .map(|p| p.total_length())
            .unwrap_or(0.0);
        scene.insertion.default_steps(total)
    })
}

/// The naive baseline's joints: for each step, IK of a rigid straight needle with its tip on the
/// rest path and its axis along the rest path's tangent. Stops at the first unreachable pose.
///
/// # Errors
/// The step index and reason of the first pose the IK cannot reach.
pub fn naive_trajectory(
    scene: &Scene,
    q0: [f64; 6],
    steps: usize,
) -> (Vec<[f64; 6]>, Option<String>) {
    let chain = scene.robot();
    let Ok(path) = scene.sampled_path() else {
        return (Vec::new(), Some("the path is invalid".into()));
    };
    let mut q = q0;
    let mut out = Vec::with_capacity(steps);
    for k in 0..steps {
        let c = scene.insertion.target_arc(path.total_length(), k);
        let (tip, t) = path.at(c);
        let base = tip - scene.needle.length * t;
        let ik = IkParams {
            max_iterations: 2000,
            ..IkParams::default()
        };
        match solve_ik(&chain, [base.x, base.y, base.z], [t.x, t.y, t.z], &q, &ik) {
            // A rigid model needs no better than 10 µm / 1 mrad; the wrist is near singular along
            // these paths, where the damped IK creeps towards tighter tolerances.
            Ok(r) if r.position_error <= 1e-2 && r.angle_error <= 1e-3 => {
                q = r.q;
                out.push(q);
            }
            Ok(r) => {
                return (
                    out,
                    Some(format!(
                        "step {k}: rigid IK out of reach ({:.3} mm away)",
                        r.position_error
                    )),
                );
            }
            Err(e) => return (out, Some(format!("step {k}: rigid IK failed: {e}"))),
        }
    }
    (out, None)
}

fn vtk_frame(sim: &Simulation, dir: &Path, k: usize) -> Result<(), OutputError> {
    let gel = &sim.gel.model;
    write_tet_mesh(
        &dir.join(format!("gel_{k:05}.vtk")),
        gel.positions(),
        &gel.mesh().nodes,
        &gel.mesh().tets,
    )?;
    write_polyline(
        &dir.join(format!("needle_{k:05}.vtk")),
        "needle",
        sim.needle.model.positions(),
    )?;
    let path: Vec<_> = (0..=200)
        .map(|i| sim.target(sim.path.approach + sim.path.length() * i as f64 / 200.0))
        .collect();
    write_polyline(&dir.join(format!("path_{k:05}.vtk")), "path", &path)?;
    let (centres, radii): (Vec<_>, Vec<_>) = sim
        .obstacles
        .iter()
        .map(|(e, r)| (e.position(gel.positions(), &gel.mesh().tets), *r))
        .unzip();
    write_points(
        &dir.join(format!("obstacles_{k:05}.vtk")),
        "obstacles",
        &centres,
        "radius",
        &radii,
    )?;
    let pts: Vec<_> = sim
        .sliding
        .iter()
        .map(|s| s.at.position(gel.positions(), &gel.mesh().tets))
        .collect();
    let ids: Vec<f64> = sim.sliding.iter().map(|s| s.id as f64).collect();
    write_points(
        &dir.join(format!("constraints_{k:05}.vtk")),
        "sliding points",
        &pts,
        "id",
        &ids,
    )
}

/// Runs a scene to the end (or its breakdown) with the core in this process ([`InProcess`]),
/// calling `observe` after every step.
///
/// # Errors
/// [`RunError`] if the simulation cannot be built or an output cannot be written.
pub fn run(
    scene: &Scene,
    opts: &RunOptions,
    observe: impl FnMut(&StepReport),
) -> Result<RunResult, RunError> {
    let mut core = InProcess::<ROWS>::new(scene.robot(), scene.inverse_params());
    run_with(scene, opts, &mut core, observe)
}

/// What the host does while the core is silent (see the module docs).
enum Exchange {
    /// The command answering the frame is in the buffer.
    Answered(Duration),
    /// The run must stop (reason).
    Stop(String),
}

/// Hands the current frame to the core until an answer comes back, holding the insertion
/// meanwhile.
fn exchange_holding(
    sim: &crate::bodies::Simulation,
    transport: &mut dyn Transport<ROWS>,
    cmd: &mut Command<ROWS>,
    opts: &RunOptions,
    k: usize,
    holds: &mut usize,
    held: &mut Duration,
) -> Exchange {
    let start = Instant::now();
    let mut holding = false;
    loop {
        match transport.exchange(sim.frame(), cmd) {
            Ok(r) => {
                if holding {
                    let h = start.elapsed();
                    *held += h;
                    eprintln!(
                        "needle: command received after {:.0} ms: resuming at step {k}",
                        h.as_secs_f64() * 1e3
                    );
                }
                return Exchange::Answered(r.round_trip);
            }
            Err(TransportError::Timeout { waited }) => {
                if !holding {
                    holding = true;
                    *holds += 1;
                    eprintln!(
                        "needle: no command within {:.0} ms: holding the insertion at step {k} (c = {:.2} mm)",
                        waited.as_secs_f64() * 1e3,
                        sim.c
                    );
                }
                if let Some(limit) = opts.give_up_after
                    && start.elapsed() >= limit
                {
                    *held += start.elapsed();
                    return Exchange::Stop(format!(
                        "step {k}: no command for {:.1} s",
                        start.elapsed().as_secs_f64()
                    ));
                }
            }
            Err(e) => return Exchange::Stop(format!("step {k}: {e}")),
        }
    }
}

/// [`run`] with the inverse controller reached through `transport` (in process, or in another
/// process over shared memory). The naive baseline does not use the transport.
///
/// # Errors
/// [`RunError`] if the simulation cannot be built or an output cannot be written.
pub fn run_with(
    scene: &Scene,
    opts: &RunOptions,
    transport: &mut dyn Transport<ROWS>,
    mut observe: impl FnMut(&StepReport),
) -> Result<RunResult, RunError> {
    let mut sim = build(scene).map_err(RunError::Setup)?;
    let mut cmd = {
        let mut b = Box::<Command<ROWS>>::new_uninit();
        Command::init_in_place(&mut b);
        // SAFETY: `init_in_place` initialised every field.
        unsafe { b.assume_init() }
    };
    let (mut holds, mut held) = (0usize, Duration::ZERO);
    let mut next_start = Instant::now();
    let steps = opts.steps.unwrap_or_else(|| planned_steps(scene));
    let vtk_every = opts.vtk_every.unwrap_or(scene.output.vtk_every);
    let mut csv = match &opts.out_dir {
        Some(d) => {
            std::fs::create_dir_all(d).map_err(|e| OutputError {
                file: d.clone(),
                reason: format!("cannot create the folder: {e}"),
            })?;
            Some(MetricsWriter::create(
                &d.join("steps.csv"),
                sim.obstacles.len(),
            )?)
        }
        None => None,
    };
    let (joints, mut stopped) = match opts.controller {
        ControllerKind::Inverse => (Vec::new(), None),
        ControllerKind::Naive => naive_trajectory(scene, sim.q, steps),
    };
    let n_steps = match opts.controller {
        ControllerKind::Inverse => steps,
        ControllerKind::Naive => joints.len(),
    };
    let mut reports = Vec::with_capacity(n_steps);
    let mut min_clear = vec![f64::INFINITY; sim.obstacles.len()];
    let (mut max_strain, mut max_inverted) = (0.0f64, 0usize);
    if let (Some(d), true) = (&opts.out_dir, vtk_every > 0) {
        vtk_frame(&sim, d, 0)?;
    }
    for k in 0..n_steps {
        if let Some(p) = opts.period {
            let now = Instant::now();
            if next_start > now {
                std::thread::sleep(next_start - now);
            }
            next_start = next_start.max(now) + p;
        }
        let c = scene.insertion.target_arc(sim.path.total_length(), k);
        let step = match opts.controller {
            ControllerKind::Inverse => match sim.prepare(c) {
                Err(e) => Err(e),
                Ok(_) => match exchange_holding(
                    &sim, transport, &mut cmd, opts, k, &mut holds, &mut held,
                ) {
                    Exchange::Answered(rt) => sim.apply_command(&cmd, rt.as_secs_f64() * 1e3),
                    Exchange::Stop(why) => {
                        stopped = Some(why);
                        break;
                    }
                },
            },
            ControllerKind::Naive => sim.step_with(c, Some(joints[k])),
        };
        let rep = match step {
            Ok(r) => r,
            Err(e) => {
                stopped = Some(format!("step {k}: {e}"));
                break;
            }
        };
        if !(rep.error.is_finite() && rep.tip.iter().all(|v| v.is_finite())) {
            stopped = Some(format!("step {k}: the state became non-finite"));
            break;
        }
        let clear = sim.clearances();
        for (m, c) in min_clear.iter_mut().zip(&clear) {
            *m = m.min(*c);
        }
        if let Some(w) = csv.as_mut() {
            w.write(&StepMetrics {
                step: rep.step,
                c: rep.c,
                tip: rep.tip,
                target: rep.target,
                error: rep.error,
                depth: rep.depth,
                clearance: clear,
                lambda_base: rep.lambda_norms[0],
                lambda_contact: rep.lambda_norms[1],
                lambda_sliding: rep.lambda_norms[2],
                gs_iterations: rep.solver.iterations,
                gs_residual: rep.solver.final_residual,
                rows: rep.rows,
                time_ms: [
                    rep.times.fm,
                    rep.times.cd,
                    rep.times.cc,
                    rep.times.sc,
                    rep.times.corr,
                ],
                q: rep.q,
            })?;
        }
        if let (Some(d), true) = (
            &opts.out_dir,
            vtk_every > 0 && (k + 1) % vtk_every.max(1) == 0,
        ) {
            vtk_frame(&sim, d, k + 1)?;
        }
        if (k + 1) % STRAIN_EVERY == 0 || k + 1 == n_steps {
            let st = sim
                .gel
                .model
                .tetra()
                .strain_stats(sim.gel.model.positions());
            max_strain = max_strain.max(st.max_strain);
            max_inverted = max_inverted.max(st.inverted);
        }
        observe(&rep);
        reports.push(rep);
    }
    if let Some(w) = csv.as_mut() {
        w.flush()?;
    }
    let inside: Vec<&StepReport> = reports.iter().filter(|r| r.inserted).collect();
    let e_mean = if inside.is_empty() {
        f64::NAN
    } else {
        inside.iter().map(|r| r.error).sum::<f64>() / inside.len() as f64
    };
    let e_max = inside.iter().map(|r| r.error).fold(f64::NAN, f64::max);
    let times = |f: fn(&StepReport) -> f64| timing(reports.iter().map(f).collect());
    let clearances: Vec<Clearance> = scene
        .obstacles
        .iter()
        .zip(&min_clear)
        .enumerate()
        .map(|(k, (o, m))| Clearance {
            name: if o.name.is_empty() {
                format!("obstacle {k}")
            } else {
                o.name.clone()
            },
            min_mm: *m,
        })
        .collect();
    let background = sim.gel.model.background_counts().unwrap_or((0, 0));
    let summary = RunSummary {
        scene: scene.name.clone(),
        controller: opts.controller,
        gel_nodes: sim.gel.model.positions().len(),
        steps: reports.len(),
        steps_planned: steps,
        completed: reports.len() == steps && stopped.is_none(),
        stopped,
        puncture_step: reports.iter().find(|r| r.punctured_now).map(|r| r.step),
        e_mean_mm: e_mean,
        e_max_mm: e_max,
        e_final_mm: reports.last().map_or(f64::NAN, |r| r.error),
        final_depth_mm: reports.last().map_or(0.0, |r| r.depth),
        obstacle_hit: clearances.iter().any(|c| c.min_mm < 0.0),
        clearances,
        timing: StageTiming {
            fm: times(|r| r.times.fm),
            cd: times(|r| r.times.cd),
            cc: times(|r| r.times.cc),
            sc: times(|r| r.times.sc),
            correction: times(|r| r.times.corr),
            total: times(|r| r.times.total()),
        },
        gs_iterations_mean: if reports.is_empty() {
            0.0
        } else {
            reports
                .iter()
                .map(|r| f64::from(r.solver.iterations))
                .sum::<f64>()
                / reports.len() as f64
        },
        gs_iterations_max: reports
            .iter()
            .map(|r| r.solver.iterations)
            .max()
            .unwrap_or(0),
        gs_not_converged_steps: count_flag(&reports, StatusFlags::NOT_CONVERGED),
        max_strain,
        max_inverted_elements: max_inverted,
        unreachable_steps: count_flag(&reports, StatusFlags::TARGET_UNREACHABLE),
        limit_steps: count_flag(&reports, StatusFlags::SATURATED_LIMIT),
        background_factorizations: background.0,
        immediate_factorizations: background.1,
        holds,
        held_ms: held.as_secs_f64() * 1e3,
    };
    if let Some(d) = &opts.out_dir {
        let file = d.join("summary.json");
        let text = serde_json::to_string_pretty(&summary).map_err(|e| OutputError {
            file: file.clone(),
            reason: e.to_string(),
        })?;
        std::fs::write(&file, text).map_err(|e| OutputError {
            file,
            reason: e.to_string(),
        })?;
    }
    let error_by_depth = inside.iter().map(|r| (r.depth, r.error)).collect();
    Ok(RunResult {
        summary,
        reports,
        error_by_depth,
    })
}
