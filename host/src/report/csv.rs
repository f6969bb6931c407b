//! The report's CSV files: `runs.csv` (one row per run) and `error_vs_depth.csv` (every run's
//! error at every step inside the gel).

use super::{ReportError, ReportRun, controller_name, out_err};
use crate::run::RunSummary;
use std::path::Path;

/// The columns of `runs.csv`.
const RUNS_HEADER: [&str; 57] = [
    "run",
    "scene",
    "controller",
    "groups",
    "parameters",
    "gel_nodes_target",
    "gel_nodes",
    "delta_q_rad",
    "blend_distance_mm",
    "constraint_spacing_mm",
    "steps",
    "steps_planned",
    "completed",
    "stopped",
    "puncture_step",
    "e_mean_mm",
    "e_max_mm",
    "e_final_mm",
    "e_puncture_mm",
    "path_deviation_mean_mm",
    "path_deviation_max_mm",
    "steps_to_target",
    "steps_nominal",
    "outcome",
    "final_depth_mm",
    "clearance_min_mm",
    "clearance_min_obstacle",
    "obstacle_hit",
    "clearances_mm",
    "steering_length_mm",
    "qp_horizon_mm",
    "straighten",
    "target_shift_max_mm",
    "entry_shift_max_mm",
    "max_strain",
    "max_inverted_elements",
    "needle_strain_max",
    "advisories",
    "step_median_ms",
    "step_p99_ms",
    "step_mean_ms",
    "step_cpu_ms",
    "fm_median_ms",
    "fm_p99_ms",
    "cd_median_ms",
    "cd_p99_ms",
    "cc_median_ms",
    "cc_p99_ms",
    "sc_median_ms",
    "sc_p99_ms",
    "corr_median_ms",
    "corr_p99_ms",
    "gs_iterations_mean",
    "gs_iterations_max",
    "gs_not_converged_steps",
    "wall_s",
    "failure",
];

/// A number, or an empty field when it is not finite.
pub(super) fn n(x: f64) -> String {
    if x.is_finite() {
        x.to_string()
    } else {
        String::new()
    }
}

/// The columns of a run that come from its summary (`steps` … `gs_not_converged_steps`): its
/// errors and outcome, its clearances, the needle's steering length and the horizon it set, how
/// far the tissue moved, the gel's strain, the set-up's advisories, the stage times and the
/// solves.
fn summary_fields(r: &ReportRun, s: &RunSummary) -> Vec<String> {
    let (cmin, cname) = r.min_clearance().unwrap_or((f64::NAN, ""));
    let t = &s.timing;
    let mut row = vec![
        s.steps.to_string(),
        s.steps_planned.to_string(),
        s.completed.to_string(),
        s.stopped.clone().unwrap_or_default(),
        s.puncture_step.map_or(String::new(), |k| k.to_string()),
        n(s.e_mean_mm),
        n(s.e_max_mm),
        n(s.e_final_mm),
        s.e_puncture_mm.map_or(String::new(), n),
        n(s.path_deviation_mean_mm),
        n(s.path_deviation_max_mm),
        s.steps_to_target.map_or(String::new(), |k| k.to_string()),
        s.steps_nominal.to_string(),
        s.outcome.name().to_owned(),
        n(s.final_depth_mm),
        n(cmin),
        cname.to_owned(),
        s.obstacle_hit.to_string(),
        s.clearances
            .iter()
            .map(|c| format!("{}={}", c.name, c.min_mm))
            .collect::<Vec<_>>()
            .join(";"),
        n(s.steering_length_mm),
        n(s.qp_horizon_mm),
        n(s.straighten),
        n(s.target_shift_max_mm),
        n(s.entry_shift_max_mm),
        n(s.max_strain),
        s.max_inverted_elements.to_string(),
        n(s.needle_strain_max),
        s.advisories.join(" | "),
    ];
    row.extend([
        n(t.total.median_ms),
        n(t.total.p99_ms),
        n(t.total.mean_ms),
        n(s.cpu_ms_per_step),
    ]);
    for stage in [&t.fm, &t.cd, &t.cc, &t.sc, &t.correction] {
        row.extend([n(stage.median_ms), n(stage.p99_ms)]);
    }
    row.extend([
        n(s.gs_iterations_mean),
        s.gs_iterations_max.to_string(),
        s.gs_not_converged_steps.to_string(),
    ]);
    row
}

/// One row of `runs.csv`.
fn run_row(r: &ReportRun) -> Vec<String> {
    let groups: Vec<&str> = r.memberships.iter().map(|m| m.group.name()).collect();
    let params: Vec<&str> = r.memberships.iter().map(|m| m.parameter.as_str()).collect();
    let mut row = vec![
        r.id.to_string(),
        r.scene.clone(),
        controller_name(r.controller).to_owned(),
        groups.join(";"),
        params.join(";"),
        r.nodes_target.to_string(),
        r.summary
            .as_ref()
            .map_or(String::new(), |s| s.gel_nodes.to_string()),
        r.delta_q.to_string(),
        r.blend_distance_mm.to_string(),
        r.constraint_spacing_mm.to_string(),
    ];
    match &r.summary {
        Some(s) => row.extend(summary_fields(r, s)),
        None => row.resize(RUNS_HEADER.len() - 2, String::new()),
    }
    row.push(format!("{:.3}", r.wall_s));
    row.push(r.failure.clone().unwrap_or_default());
    debug_assert_eq!(row.len(), RUNS_HEADER.len());
    row
}

/// Writes `runs.csv`: one row per run.
pub(super) fn write_runs_csv(path: &Path, runs: &[ReportRun]) -> Result<(), ReportError> {
    let mut w = ::csv::Writer::from_path(path).map_err(|e| out_err(path, e))?;
    w.write_record(RUNS_HEADER).map_err(|e| out_err(path, e))?;
    for r in runs {
        w.write_record(run_row(r)).map_err(|e| out_err(path, e))?;
    }
    w.flush().map_err(|e| out_err(path, e))
}

/// Writes `error_vs_depth.csv`: every run's error at every step inside the gel.
pub(super) fn write_error_csv(path: &Path, runs: &[ReportRun]) -> Result<(), ReportError> {
    let mut w = ::csv::Writer::from_path(path).map_err(|e| out_err(path, e))?;
    w.write_record([
        "run",
        "scene",
        "controller",
        "parameters",
        "depth_mm",
        "error_mm",
    ])
    .map_err(|e| out_err(path, e))?;
    for r in runs {
        let params: Vec<&str> = r.memberships.iter().map(|m| m.parameter.as_str()).collect();
        let params = params.join(";");
        for (d, e) in &r.error_by_depth {
            w.write_record([
                r.id.to_string(),
                r.scene.clone(),
                controller_name(r.controller).to_owned(),
                params.clone(),
                format!("{d:.4}"),
                format!("{e:.5}"),
            ])
            .map_err(|e| out_err(path, e))?;
        }
    }
    w.flush().map_err(|e| out_err(path, e))
}
