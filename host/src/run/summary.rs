//! The summary of a run: tracking error, clearances, stage times, solver and gel statistics —
//! gathered step by step by [`Statistics`] and written once at the end.

use super::metrics::{Outcome, PathMetrics, RunEnd};

use super::{ControllerKind, Observer, StopReason};
use crate::fem::tetra::StrainStats;
use crate::linalg::Precision;
use crate::output::OutputError;
use crate::setup::Plan;
use crate::step::StepReport;
use crate::world::World;
use needle_core::payload::StatusFlags;
use serde::Serialize;

/// The gel's strain is sampled every this many steps (≈ 1 ms for 7000 elements, outside the
/// timed stages).
pub const STRAIN_EVERY: usize = 10;

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
    /// The gel support's prescribed motion (`[gel.support_motion]`: kind, amplitude, period,
    /// direction, hidden from the controller's model or modelled); `null` in JSON when the
    /// support stays still.
    pub support_motion: Option<crate::support_motion::MotionSummary>,
    /// The needle's steering length in the gel, `(E_n I / E_gel)^(1/4)`
    /// ([`crate::setup::steering_length`]) [mm]: short (under about 17 mm), and the gel holds
    /// the shaft so that the joints barely steer the tip deep inside.
    pub steering_length_mm: f64,
    /// The horizon of the `"qp"` update's tip objective [mm]: `inverse.qp_horizon`, resolved
    /// from the steering length under `"auto"` ([`crate::scene::HorizonSpec::horizon`]; 3 mm
    /// up to 18 mm of steering length, none from 21 mm). The paper's update does not use it.
    pub qp_horizon_mm: f64,
    /// How far the target shown to the controller was straightened towards a chord of the
    /// path: `inverse.straighten` resolved (under `"auto"`, for a needle that lags its path's
    /// bend, the run's advisory: 1 towards the chord from one steering length deep, or 0.4
    /// towards the chord from the entry point where an obstacle lies nearer the first; else
    /// 0) [-].
    pub straighten: f64,
    /// Where that chord starts: path length past the entry point [mm].
    pub straighten_from_mm: f64,
    /// The lowest fraction along the path: lower than `straighten` where the chord passes
    /// nearer an obstacle than the path itself, or where the shown point would be more than
    /// `straighten_max_offset_mm` off the path [-].
    pub straighten_lowest: f64,
    /// The bound on the shown target's distance from the path (`inverse.straighten_max_offset`)
    /// [mm].
    pub straighten_max_offset_mm: f64,
    /// The distance the shown target keeps from the obstacles where the path passes nearer
    /// (`inverse.target_standoff`; 0: none) [mm].
    pub target_standoff_mm: f64,
    /// What the plan allows but makes unlikely to succeed, one sentence each
    /// ([`crate::plan_check::advisories`]: today a bending path for a needle whose steering
    /// length is under 18 mm); empty when nothing is. Said at the start, before any step.
    pub advisories: Vec<String>,
    /// The build, machine and date that made this run.
    pub provenance: crate::provenance::Provenance,
    /// Steps run (a whole insertion may add settling steps after the planned ones: the target
    /// held at the path's end until the tip is within 0.5 mm of it, up to 1.2 × planned).
    pub steps: usize,
    /// Steps planned.
    pub steps_planned: usize,
    /// Whether the run reached its last planned step.
    pub completed: bool,
    /// Why it stopped early: `step k: ` and the reason.
    pub stopped: Option<String>,
    /// Why it stopped early, typed (a divergence, a failed step, no command, the baseline's IK).
    pub stop_reason: Option<StopReason>,
    /// Step at which the tip punctured the surface.
    pub puncture_step: Option<usize>,
    /// Step after which the tip, sliding off its target on the surface before puncture, had
    /// its heading held within the friction cone (`inverse.entry_tilt`; none: it never slid off).
    pub tip_slid_step: Option<usize>,
    /// Mean tracking error over the steps with the tip inside the gel
    /// ([`StepReport::tip_inside`]) [mm].
    pub e_mean_mm: f64,
    /// Largest tracking error inside the gel [mm].
    pub e_max_mm: f64,
    /// Largest tracking error of a step that punctured the surface [mm] (`None`: no
    /// puncture): the tip on the surface it indented against the embedded target, which the
    /// gel, not yet relaxed around the tip, still carries down with the indentation. Not a step
    /// with the tip inside the gel, so not in `e_mean_mm` and `e_max_mm`.
    pub e_puncture_mm: Option<f64>,
    /// Distance from the tip to the path's end point (deformed with the gel) after the last
    /// step [mm] — not the last step's target.
    pub e_final_mm: f64,
    /// Tracking error at the last step (to that step's target) [mm].
    pub e_last_mm: f64,
    /// Final insertion depth [mm].
    pub final_depth_mm: f64,
    /// Smallest clearance per obstacle.
    pub clearances: Vec<Clearance>,
    /// Whether any obstacle was hit.
    pub obstacle_hit: bool,
    /// Stage times.
    pub timing: StageTiming,
    /// CPU time per step, summed over all threads (the gel's background factorisation
    /// included), from the process's CPU clock; the run's own bookkeeping (checks, statistics,
    /// output files) excluded [ms]. Compare with `timing.total.mean_ms`, the wall time.
    pub cpu_ms_per_step: f64,
    /// Gauss-Seidel sweeps per step (all solves): mean.
    pub gs_iterations_mean: f64,
    /// Gauss-Seidel sweeps per step: largest.
    pub gs_iterations_max: u32,
    /// Steps in which a solve hit its iteration cap.
    pub gs_not_converged_steps: usize,
    /// Largest principal strain `|σ(F) − 1|` of any gel element, sampled every
    /// [`STRAIN_EVERY`] steps and at the last; NaN once a sample was [-].
    pub max_strain: f64,
    /// Most gel elements inverted (`det F ≤ 0`) at once, same sampling.
    pub max_inverted_elements: usize,
    /// Largest bending strain at the needle's outer surface, `r_o |κ|`, after every step
    /// ([`crate::fem::beam::CorotationalBeams::max_bending_strain`]; NaN once a step's was)
    /// [-]. The needle's model is linear elastic: a strain above its material's yield strain
    /// `σ_y / E` is a bend a real needle would keep.
    pub needle_strain_max: f64,
    /// Where that strain was: its distance from the needle's tip along the needle [mm] (0 for
    /// a needle that never bent) ...
    pub needle_strain_from_tip_mm: f64,
    /// ... and the tip's depth below the entry point at that sample [mm] (0 before the
    /// puncture): a distance from the tip under the depth puts the largest bend in the gel.
    pub needle_strain_tip_depth_mm: f64,
    /// The needle's yield strain given by the scene (`needle.yield_strain`; none: not
    /// checked) [-].
    pub needle_yield_strain: Option<f64>,
    /// Whether the controller kept the needle's largest bends under that yield strain
    /// (`inverse.bound_strain`, the `"qp"` update; false without a yield strain).
    pub needle_strain_bounded: bool,
    /// Whether the needle was bent past that yield strain at its surface (or its strain went
    /// NaN): a real needle would keep the bend. False when none is given.
    pub needle_yielded: bool,
    /// How many steps ended with the needle bent past that yield strain (or its strain NaN):
    /// a brief peak or a lasting bend. 0 when none is given.
    pub needle_yield_steps: usize,
    /// Steps in which the controller reported the target unreachable (no joint update
    /// improves the objective by 1 %).
    pub unreachable_steps: usize,
    /// Steps in which a joint stopped at its limit.
    pub limit_steps: usize,
    /// Joints of the robot.
    pub joints: usize,
    /// The smallest joint-limit margin of the run: over every step, the smallest distance of a
    /// joint to one of its position limits as a fraction of that joint's half range (1:
    /// mid-range, 0: at a limit; [`StepReport::limit_margin`]). `null` in JSON without steps
    /// or without finite limits.
    pub limit_margin_min: f64,
    /// The joint of [`Self::limit_margin_min`], counted from 1 as in `steps.csv` (`q1_rad` …);
    /// none without steps.
    pub limit_margin_joint: Option<usize>,
    /// Steps whose planned joint update the constraint solve did not confirm, so that the
    /// controller shortened it or held the joints (`StatusFlags::BACKTRACKED`).
    pub shortened_steps: usize,
    /// Gel factorisations finished on the background thread and used one step later (0 without
    /// `solver.background_factorization`).
    pub background_factorizations: u64,
    /// Gel factorisations made at once in background mode (the first step, and steps whose
    /// elements rotated more than `LAG_ROTATION_LIMIT` since the previous one; with
    /// `solver.gel_solve = "pcg"`, steps whose CG did not converge).
    pub immediate_factorizations: u64,
    /// Refactorisations of the gel factor's near block alone (`solver.near_radius`; 0
    /// without it).
    pub near_factorizations: u64,
    /// Refactorisations of the near block's entry block alone (`solver.entry_radius`; 0
    /// without one).
    #[serde(default)]
    pub entry_factorizations: u64,
    /// Gel free motions solved with their far residual dropped
    /// (`solver.far_residual_tolerance`; 0 without a near block).
    #[serde(default)]
    pub far_residual_drops: u64,
    /// Steps whose gel far rows were deferred (`solver.defer_far`) but had to be solved
    /// before the constraint solve, a gel point of the frame lying outside the near block's
    /// exactly solved dofs (0 without deferral).
    #[serde(default)]
    pub deferral_fallbacks: u64,
    /// `solver.gel_solve = "pcg"` or `"refine"`: CG iterations per step solved (or refined)
    /// by CG, mean (0 with the direct solve).
    pub pcg_iterations_mean: f64,
    /// `solver.gel_solve = "pcg"` or `"refine"`: most CG iterations of a step.
    pub pcg_iterations_max: usize,
    /// `solver.gel_solve = "pcg"`: steps whose CG reached its cap (or broke down) and
    /// factorised at once; `"refine"`: steps whose refinement reached its cap and kept the
    /// factor's step.
    pub pcg_fallbacks: u64,
    /// The precision of the gel's factor at the end of the run: `"single"` or `"double"`
    /// (`solver.factor_precision`; `"double"` after a fallback).
    pub gel_factor_precision: &'static str,
    /// Single-precision gel factorisations whose probe solve failed its check and that were
    /// redone in double (the factor then stays double).
    pub precision_fallbacks: u64,
    /// Times the host held the insertion because no command arrived within the transport's
    /// deadline.
    pub holds: usize,
    /// Total time spent holding [ms].
    pub held_ms: f64,
    /// Free-running host (`needle serve --period-ms`): steps that started after their slot
    /// because the step before them took longer than the period.
    pub period_overruns: usize,
    /// The largest such delay [ms].
    pub period_overrun_max_ms: f64,
    /// Mean distance from the tip to the deformed path (polyline) over the steps inside the
    /// gel [mm].
    pub path_deviation_mean_mm: f64,
    /// Largest distance from the tip to the deformed path inside the gel [mm].
    pub path_deviation_max_mm: f64,
    /// Largest displacement of the path's end point (the target, embedded in the gel) from its
    /// rest position after the puncture, the support's motion taken out [mm]: how far the
    /// insertion pushed the target through the tissue (0 before a puncture).
    pub target_shift_max_mm: f64,
    /// Largest displacement of the entry point (the material point the needle punctured) from
    /// its rest position, the support's motion taken out [mm]: how far the needle dragged the
    /// tissue at the surface. Large beside a small path deviation: the path was followed
    /// because the tissue was moved onto it.
    pub entry_shift_max_mm: f64,
    /// Steps until the tip first came within `metrics::REACH_TOLERANCE_MM` of the path's end.
    pub steps_to_target: Option<usize>,
    /// The nominal steps of the insertion (path length / advance per step).
    pub steps_nominal: usize,
    /// Smallest clearance to any obstacle [mm] (`+∞`, written `null`, without obstacles).
    pub min_clearance_mm: f64,
    /// Times the needle left the gel after puncturing it (every sliding point released, the
    /// surface whole again). On an insertion (`insertion.mode = "insert"`) any is a miss: a
    /// needle that goes on enters the tissue a second time, off the planned entry.
    pub withdrawals: usize,
    /// How the run ended ([`Outcome`]; reached is defined in [`super::metrics`]).
    pub outcome: Outcome,
}

/// What the summary needs beyond the reports, gathered step by step: the smallest clearance
/// per obstacle, the needle's strain after every step and the gel's (sampled every
/// [`STRAIN_EVERY`] steps and at the last).
pub struct Statistics {
    min_clearance: Vec<f64>,
    max_strain: f64,
    max_inverted: usize,
    needle_strain: f64,
    /// The needle's yield strain (`needle.yield_strain`), and how many steps ended past it.
    yield_strain: Option<f64>,
    yield_steps: usize,
    /// Where the largest needle strain was: its distance from the tip and the tip's depth [mm].
    needle_bend_at: (f64, f64),
    last_step: usize,
    path: PathMetrics,
    sampled: Option<StrainStats>,
}

impl Statistics {
    /// For a run of `steps` steps of `world` whose needle yields at `yield_strain` (none: not
    /// checked).
    pub fn new<const N: usize>(world: &World<N>, steps: usize, yield_strain: Option<f64>) -> Self {
        Self {
            min_clearance: vec![f64::INFINITY; world.obstacles.len()],
            max_strain: 0.0,
            max_inverted: 0,
            needle_strain: 0.0,
            yield_strain,
            yield_steps: 0,
            needle_bend_at: (0.0, 0.0),
            last_step: steps.saturating_sub(1),
            path: PathMetrics::default(),
            sampled: None,
        }
    }

    /// Distance from the tip to the path's end point after the last step [mm] (∞ before the
    /// first).
    pub fn distance_to_end(&self) -> f64 {
        self.path.e_end
    }

    /// The strain sample of the last step (none when it was not sampled).
    pub fn sampled(&self) -> Option<StrainStats> {
        self.sampled
    }
}

impl<const N: usize> Observer<N> for Statistics {
    fn step(&mut self, world: &World<N>, r: &StepReport) -> Result<(), OutputError> {
        for (m, c) in self.min_clearance.iter_mut().zip(world.clearances()) {
            *m = m.min(c);
        }
        self.path.step(world, r);
        self.sampled = None;
        if (r.step + 1).is_multiple_of(STRAIN_EVERY) || r.step == self.last_step {
            let st = world.gel.tetra().strain_stats(world.gel.positions());
            self.sampled = Some(st);
            self.max_strain = worst(self.max_strain, st.max_strain);
            self.max_inverted = self.max_inverted.max(st.inverted);
        }
        let (bend, from_tip) = r.needle_bend;
        self.yield_steps += usize::from(yielded(bend, self.yield_strain));
        let larger = worst(self.needle_strain, bend);
        if larger.to_bits() != self.needle_strain.to_bits() {
            let depth = if r.inserted { r.depth } else { 0.0 };
            self.needle_bend_at = (from_tip, depth);
        }
        self.needle_strain = larger;
        Ok(())
    }
}

/// The larger of a running maximum and a new sample, a NaN kept from then on: `f64::max` drops
/// a NaN, and the summary would give the last finite value of a state that went bad.
fn worst(max: f64, sample: f64) -> f64 {
    if max.is_nan() || sample.is_nan() {
        f64::NAN
    } else {
        max.max(sample)
    }
}

/// Whether a needle whose largest bending strain was `strain` was bent past its `yield_strain`
/// (a NaN strain counts as past it: the state it was sampled from is not to be trusted).
fn yielded(strain: f64, yield_strain: Option<f64>) -> bool {
    yield_strain.is_some_and(|y| strain.is_nan() || strain > y)
}

/// How a run ended, for its summary.
pub struct Ending<'a> {
    /// The run's controller.
    pub controller: ControllerKind,
    /// Steps planned.
    pub steps_planned: usize,
    /// The step at which the run stopped early, and why.
    pub stopped: Option<(usize, StopReason)>,
    /// Every step's report.
    pub reports: &'a [StepReport],
    /// Holds and time held [ms].
    pub holds: (usize, f64),
    /// Period overruns and the largest delay [ms].
    pub overruns: (usize, f64),
    /// CPU time of the steps, summed over the process's threads [s].
    pub cpu_s: f64,
}

/// Steps whose solver report carries `flag`.
fn count_flag(reports: &[StepReport], flag: u32) -> usize {
    reports
        .iter()
        .filter(|r| r.solver.flags & flag != 0)
        .count()
}

/// Times the needle left the gel after puncturing it: steps not inserted right after an
/// inserted one (every sliding point released, the surface whole again).
fn withdrawals(reports: &[StepReport]) -> usize {
    reports
        .windows(2)
        .filter(|w| w[0].inserted && !w[1].inserted)
        .count()
}

/// The stage timing of `reports`.
fn stage_timing(reports: &[StepReport]) -> StageTiming {
    let times = |f: fn(&StepReport) -> f64| timing(reports.iter().map(f).collect());
    StageTiming {
        fm: times(|r| r.times.fm),
        cd: times(|r| r.times.cd),
        cc: times(|r| r.times.cc),
        sc: times(|r| r.times.sc),
        correction: times(|r| r.times.after_solve()),
        total: times(|r| r.times.total()),
    }
}

impl Statistics {
    /// The summary of a run of `world` planned by `plan` that ended as `end` says.
    pub fn summary<const N: usize>(
        &self,
        plan: &Plan,
        world: &World<N>,
        end: Ending<'_>,
    ) -> RunSummary {
        let reports = end.reports;
        let inside: Vec<&StepReport> = reports.iter().filter(|r| r.tip_inside()).collect();
        let e_mean = if inside.is_empty() {
            f64::NAN
        } else {
            inside.iter().map(|r| r.error).sum::<f64>() / inside.len() as f64
        };
        let clearances: Vec<Clearance> = plan
            .obstacle_names
            .iter()
            .zip(&self.min_clearance)
            .map(|(name, m)| Clearance {
                name: name.clone(),
                min_mm: *m,
            })
            .collect();
        let background = world.gel.background_counts().unwrap_or((0, 0));
        let pcg = world.gel.pcg_stats();
        let (precision, precision_fallbacks) = world.gel.factor_precision();
        let deviation = self.path.deviation();
        let min_clearance_mm = self
            .min_clearance
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        // A run stopped on purpose (blocked, or by its caller) did not fail: its outcome is
        // judged from where the tip is.
        let failed = (end.stopped.as_ref()).is_some_and(|(_, why)| !why.is_deliberate());
        let withdrawals = withdrawals(reports);
        let outcome = Outcome::of(&RunEnd {
            stopped: failed || reports.is_empty(),
            obstacle_hit: min_clearance_mm < 0.0,
            e_final_mm: self.path.e_end,
            steps_to_target: self.path.steps_to_target,
            steps_nominal: plan.steps,
            withdrawn: plan.insert_only && withdrawals > 0,
            path_deviation_max_mm: deviation.1,
        });
        let needle_yielded = yielded(self.needle_strain, plan.needle_yield_strain);
        let needle_yield_steps = self.yield_steps;
        if needle_yielded {
            tracing::warn!(
                "scene `{}`: the needle was bent to {:.2} % at its surface, past its yield strain \
                 {:.2} % (needle.yield_strain) after {needle_yield_steps} steps: a real needle \
                 would keep the bend",
                plan.name,
                100.0 * self.needle_strain,
                100.0 * plan.needle_yield_strain.unwrap_or(f64::NAN)
            );
        }
        RunSummary {
            scene: plan.name.clone(),
            controller: end.controller,
            gel_nodes: world.gel.node_count(),
            support_motion: plan.support_motion.clone(),
            steering_length_mm: plan.steering_length_mm,
            qp_horizon_mm: plan.qp_horizon_mm,
            straighten: plan.straighten,
            straighten_from_mm: plan.straighten_from_mm,
            straighten_lowest: plan.straighten_lowest,
            straighten_max_offset_mm: plan.straighten_max_offset_mm,
            target_standoff_mm: plan.target_standoff_mm,
            advisories: plan.advisories.clone(),
            provenance: crate::provenance::Provenance::now(),
            steps: reports.len(),
            steps_planned: end.steps_planned,
            completed: reports.len() >= end.steps_planned && end.stopped.is_none(),
            stopped: end
                .stopped
                .as_ref()
                .map(|(k, why)| format!("step {k}: {why}")),
            stop_reason: end.stopped.map(|(_, why)| why),
            puncture_step: reports.iter().find(|r| r.punctured_now).map(|r| r.step),
            tip_slid_step: reports.iter().find(|r| r.tip_slid_now).map(|r| r.step),
            e_mean_mm: e_mean,
            e_max_mm: inside.iter().map(|r| r.error).fold(f64::NAN, f64::max),
            e_puncture_mm: reports
                .iter()
                .filter(|r| r.punctured_now)
                .map(|r| r.error)
                .reduce(f64::max),
            e_final_mm: if reports.is_empty() {
                f64::NAN
            } else {
                self.path.e_end
            },
            e_last_mm: reports.last().map_or(f64::NAN, |r| r.error),
            final_depth_mm: reports.last().map_or(0.0, |r| r.depth),
            obstacle_hit: clearances.iter().any(|c| c.min_mm < 0.0),
            clearances,
            timing: stage_timing(reports),
            cpu_ms_per_step: if reports.is_empty() {
                0.0
            } else {
                end.cpu_s * 1e3 / reports.len() as f64
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
            gs_not_converged_steps: count_flag(reports, StatusFlags::NOT_CONVERGED),
            max_strain: self.max_strain,
            max_inverted_elements: self.max_inverted,
            needle_strain_max: self.needle_strain,
            needle_strain_from_tip_mm: self.needle_bend_at.0,
            needle_strain_tip_depth_mm: self.needle_bend_at.1,
            needle_yield_strain: plan.needle_yield_strain,
            needle_strain_bounded: plan.needle_strain_bounded,
            needle_yield_steps,
            needle_yielded,
            unreachable_steps: count_flag(reports, StatusFlags::TARGET_UNREACHABLE),
            limit_steps: count_flag(reports, StatusFlags::SATURATED_LIMIT),
            joints: N,
            limit_margin_min: reports
                .iter()
                .map(|r| r.limit_margin)
                .fold(f64::INFINITY, f64::min),
            limit_margin_joint: reports
                .iter()
                .min_by(|a, b| a.limit_margin.total_cmp(&b.limit_margin))
                .map(|r| r.limit_joint + 1),
            shortened_steps: count_flag(reports, StatusFlags::BACKTRACKED),
            background_factorizations: background.0,
            immediate_factorizations: background.1,
            near_factorizations: world.gel.near_refactorizations(),
            entry_factorizations: world.gel.entry_refactorizations(),
            far_residual_drops: world.gel.far_residual_drops(),
            deferral_fallbacks: world.gel.deferral_fallbacks(),
            pcg_iterations_mean: pcg.map_or(0.0, |p| {
                if p.steps == 0 {
                    0.0
                } else {
                    p.iterations as f64 / p.steps as f64
                }
            }),
            pcg_iterations_max: pcg.map_or(0, |p| p.max_iterations),
            pcg_fallbacks: pcg.map_or(0, |p| p.fallbacks),
            gel_factor_precision: match precision {
                Precision::Single => "single",
                Precision::Double => "double",
            },
            precision_fallbacks,
            holds: end.holds.0,
            held_ms: end.holds.1,
            period_overruns: end.overruns.0,
            period_overrun_max_ms: end.overruns.1,
            path_deviation_mean_mm: deviation.0,
            path_deviation_max_mm: deviation.1,
            target_shift_max_mm: self.path.target_shift_max,
            entry_shift_max_mm: self.path.entry_shift_max,
            steps_to_target: self.path.steps_to_target,
            steps_nominal: plan.steps,
            min_clearance_mm,
            withdrawals,
            outcome,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gel's and the needle's largest strain were running maxima by `f64::max`, which
    /// drops a NaN sample: a run whose state went NaN reported its last finite strain.
    #[test]
    fn a_nan_strain_sample_is_kept_in_the_summary_not_dropped() {
        assert!(f64::NAN.max(0.5) == 0.5, "what f64::max does");
        assert_eq!(worst(0.2, 0.5), 0.5);
        assert_eq!(worst(0.5, 0.2), 0.5);
        assert!(worst(0.5, f64::NAN).is_nan());
        assert!(worst(f64::NAN, 0.7).is_nan(), "kept after a NaN");
    }

    /// `needle.yield_strain`: past it is yielded, at or under it not, a NaN strain yielded,
    /// nothing without one.
    #[test]
    fn a_needle_bent_past_its_yield_strain_is_flagged() {
        assert!(yielded(0.021, Some(0.008)));
        assert!(!yielded(0.008, Some(0.008)));
        assert!(!yielded(0.002, Some(0.008)));
        assert!(yielded(f64::NAN, Some(0.008)));
        assert!(!yielded(0.5, None));
        let steps = [0.002, 0.009, 0.021, 0.007, f64::NAN, 0.0081];
        let yield_steps = |y| steps.iter().filter(|s| yielded(**s, y)).count();
        assert_eq!(yield_steps(Some(0.008)), 4, "0.009, 0.021, NaN and 0.0081");
        assert_eq!(yield_steps(None), 0);
    }

    fn at(inserted: bool) -> StepReport {
        StepReport {
            inserted,
            ..StepReport::default()
        }
    }

    /// Seed 31's `helix_full` (held-out set of `tools/gen_suite.py --seed 31`) without the
    /// refresh ceiling: the arm dragged the gel, the tip came out of it at step 406, flew free
    /// and punctured it again, and the run counted as reached with e_max 38.4 mm.
    #[test]
    fn withdrawals_count_each_exit_from_the_gel_after_the_puncture() {
        let run = |s: &str| -> Vec<StepReport> { s.chars().map(|c| at(c == 'i')).collect() };
        assert_eq!(withdrawals(&run("")), 0);
        assert_eq!(withdrawals(&run("aaaiiiii")), 0, "the puncture is not one");
        assert_eq!(withdrawals(&run("aaiiiaaiii")), 1);
        assert_eq!(
            withdrawals(&run("aiaiiaiia")),
            3,
            "one per exit, the last at the end"
        );
    }
}
