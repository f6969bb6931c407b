//! The benchmark report (`needle report`): both benchmark scenes under both controllers plus the
//! parameter sweeps of `docs/benchmark.md`, written into one folder.
//!
//! | group | runs |
//! |---|---|
//! | controllers | simple and complex, inverse and naive, the scenes' own mesh (1500 nodes) |
//! | mesh | 600 / 1100 / 1500 / 1800 gel nodes, both scenes, inverse (the paper's Fig. 8) |
//! | δq | 0.001, 0.01, 0.1 rad (complex, inverse) |
//! | blend distance d | 6, 12, 18, 30 mm: 10–50 % of the 60 mm gel depth (complex, inverse) |
//! | constraint spacing d_n | 5, 10, 20 mm (complex, inverse) |
//!
//! Runs that are the same simulation (e.g. the complex scene at 1500 nodes and δq = 0.01 in the
//! controllers, mesh and δq groups) run once and appear in every group they belong to.
//!
//! Beside the groups, the gel pipeline's **accuracy cost** ([`crate::accuracy`]): the benchmarks
//! and the scenes of [`ReportOptions::suite`] each run closed loop with the exact step, their
//! joints replayed open loop through the default pipeline and the linear far field (the quick
//! set: the benchmarks, the default only).
//!
//! Files: `summary.md` (a table per group, the paper's reference figures in a table of their own,
//! the accuracy cost), `runs.csv` (one row per run), `error_vs_depth.csv` (every run's error at
//! every step inside the gel), `accuracy_cost.csv` (a row per scene and pipeline),
//! `report.json` (everything above as JSON), and (with the default `charts` feature) three
//! charts as SVG and PNG:
//! `error_vs_depth` (the paper's Fig. 7, with its e_mean and e_max as reference lines),
//! `stage_times` (Fig. 8: the stage means of a step stacked per mesh size, adding up to the mean
//! step, with the paper's time per step) and `speed_vs_error` (CPU time per step against e_mean,
//! every run a point labelled with its mesh size and setting, the paper's figures beside).
//!
//! A run that breaks down (the naive baseline may) or cannot even start is reported as such, with
//! the steps it ran; it never aborts the report. The charts draw their text with DejaVu Sans,
//! embedded in the binary (no system font is needed).

mod accuracy;
#[cfg(feature = "charts")]
pub(crate) mod charts;
mod csv;
mod plan;
mod runner;
mod tables;

pub use accuracy::{
    AccuracyRow, PipelineCost, SECTION_TITLE as ACCURACY_SECTION_TITLE,
    summary_lines as accuracy_summary,
};

use crate::output::{OutputError, OutputFailure};
use crate::run::{ControllerKind, RunSummary};
use crate::scene::SceneError;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of [`report`].
#[derive(Clone, Debug)]
pub struct ReportOptions {
    /// The folder the report is written into (created if missing).
    pub out_dir: PathBuf,
    /// The reduced set: the 600-node mesh only, one point per sweep, at most
    /// [`QUICK_STEPS`] steps per run (a smoke test of the whole pipeline).
    pub quick: bool,
    /// Cap on the steps of every run (default: the whole path; [`QUICK_STEPS`] with `quick`).
    pub steps: Option<usize>,
    /// Progress on stderr: a bar, and one line per finished run.
    pub progress: bool,
    /// The suite folder whose scenes, beside the benchmarks, the accuracy-cost section
    /// measures (the quick set: the benchmarks only). Default: `scenes/suite` when that
    /// folder exists, else none.
    pub suite: Option<PathBuf>,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            out_dir: PathBuf::from("report"),
            quick: false,
            steps: None,
            progress: true,
            suite: default_suite(),
        }
    }
}

/// `scenes/suite` when it is a folder (the report run from the repository), else none.
pub fn default_suite() -> Option<PathBuf> {
    let dir = PathBuf::from("scenes/suite");
    dir.is_dir().then_some(dir)
}

/// Steps per run of the quick report: 25 mm of path, i.e. ≈ 15 mm into the gel.
pub const QUICK_STEPS: usize = 250;

/// A group of runs: one table in `summary.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Group {
    /// Both scenes under both controllers.
    Controllers,
    /// Gel mesh size.
    Mesh,
    /// Finite-difference step of the Jacobian δq.
    DeltaQ,
    /// Blend distance d.
    BlendDistance,
    /// Sliding-constraint spacing d_n.
    ConstraintSpacing,
    /// The gel's factorisation: in the background (pipelines), preconditioned CG with an
    /// asynchronous factor, or synchronous.
    Factorization,
}

impl Group {
    /// Every group, in report order.
    pub const ALL: [Group; 6] = [
        Group::Controllers,
        Group::Mesh,
        Group::DeltaQ,
        Group::BlendDistance,
        Group::ConstraintSpacing,
        Group::Factorization,
    ];

    /// Title of the group's table.
    pub fn title(self) -> &'static str {
        match self {
            Group::Controllers => "Controllers: inverse against the naive baseline",
            Group::Mesh => "Mesh size (inverse; the paper's Fig. 8)",
            Group::DeltaQ => "Jacobian step δq (complex, inverse)",
            Group::BlendDistance => {
                "Blend distance d (complex, inverse; 10–50 % of the 60 mm gel depth)"
            }
            Group::ConstraintSpacing => "Sliding-constraint spacing d_n (complex, inverse)",
            Group::Factorization => {
                "Gel factorisation: background pipelines and preconditioned CG against synchronous (inverse)"
            }
        }
    }

    /// Short name (CSV, charts).
    pub fn name(self) -> &'static str {
        match self {
            Group::Controllers => "controllers",
            Group::Mesh => "mesh",
            Group::DeltaQ => "delta_q",
            Group::BlendDistance => "blend_distance",
            Group::ConstraintSpacing => "constraint_spacing",
            Group::Factorization => "factorization",
        }
    }
}

/// A run's place in a group.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Membership {
    /// The group.
    pub group: Group,
    /// The swept parameter's value as shown in the table (e.g. `δq = 0.001 rad`).
    pub parameter: String,
    /// Position in the planned order (rows of a group's table follow it).
    #[serde(skip)]
    order: usize,
}

/// One simulation of the report.
#[derive(Clone, Debug, Serialize)]
pub struct ReportRun {
    /// Index (the row of `runs.csv`, the `run` column of `error_vs_depth.csv`).
    pub id: usize,
    /// Scene name.
    pub scene: String,
    /// Controller.
    pub controller: ControllerKind,
    /// Gel node count requested (the mesher's target).
    pub nodes_target: usize,
    /// δq [rad].
    pub delta_q: f64,
    /// Blend distance d [mm].
    pub blend_distance_mm: f64,
    /// Sliding-constraint spacing d_n [mm].
    pub constraint_spacing_mm: f64,
    /// The scene overrides of this run (`field`, TOML value).
    pub overrides: Vec<(String, String)>,
    /// The groups the run belongs to.
    pub memberships: Vec<Membership>,
    /// The run's summary; none when it could not start (see `failure`).
    pub summary: Option<RunSummary>,
    /// Why the run could not start or panicked (a breakdown during the run is in the summary's
    /// `stopped` instead).
    pub failure: Option<String>,
    /// Wall time of the run, set-up included [s].
    pub wall_s: f64,
    /// Error against insertion depth `(depth, error)` at the steps inside the gel [mm].
    #[serde(skip)]
    pub error_by_depth: Vec<(f64, f64)>,
}

impl ReportRun {
    /// `scene · controller`.
    pub fn label(&self) -> String {
        format!("{} · {}", self.scene, controller_name(self.controller))
    }

    /// Whether the run reached its last step.
    pub fn completed(&self) -> bool {
        self.summary.as_ref().is_some_and(|s| s.completed)
    }

    /// Smallest clearance over the obstacles and the obstacle's name.
    pub fn min_clearance(&self) -> Option<(f64, &str)> {
        self.summary.as_ref().and_then(|s| {
            s.clearances
                .iter()
                .filter(|c| c.min_mm.is_finite())
                .min_by(|a, b| a.min_mm.total_cmp(&b.min_mm))
                .map(|c| (c.min_mm, c.name.as_str()))
        })
    }

    /// The parameter shown for `group`.
    pub fn parameter(&self, group: Group) -> Option<&str> {
        self.memberships
            .iter()
            .find(|m| m.group == group)
            .map(|m| m.parameter.as_str())
    }
}

/// What [`report`] did.
#[derive(Clone, Debug, Serialize)]
pub struct ReportSummary {
    /// The folder written.
    pub out_dir: PathBuf,
    /// Whether it was the quick set.
    pub quick: bool,
    /// Step cap applied to every run (none: the whole path).
    pub steps_cap: Option<usize>,
    /// Every run, in order.
    pub runs: Vec<ReportRun>,
    /// The suite folder of the accuracy-cost section (none: the benchmarks only).
    pub suite: Option<PathBuf>,
    /// The accuracy-cost section: a row per scene.
    pub accuracy: Vec<AccuracyRow>,
    /// Every file written.
    pub files: Vec<PathBuf>,
    /// Wall time of the whole report [s].
    pub wall_s: f64,
}

/// Why the report could not be written. (A run that breaks down is not an error.)
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// A planned scene is not embedded.
    #[error("no embedded scene `{0}`")]
    NoScene(String),
    /// A planned scene with its overrides is invalid.
    #[error("scene `{scene}` with the report's overrides")]
    Scene {
        /// The embedded scene.
        scene: String,
        /// Why.
        #[source]
        source: SceneError,
    },
    /// A file or folder could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The suite folder of the accuracy-cost section cannot be listed.
    #[error("suite folder {}", dir.display())]
    Suite {
        /// The folder.
        dir: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A chart could not be drawn (the plotting backend's error, as text: it is not `Send`).
    #[error("chart {}: {reason}", file.display())]
    Chart {
        /// The chart's file.
        file: PathBuf,
        /// The backend's message.
        reason: String,
    },
}

/// `OutputError` for `file` as a [`ReportError`].
fn out_err(file: &Path, e: impl Into<OutputFailure>) -> ReportError {
    ReportError::Output(OutputError::new(file, e))
}

fn controller_name(c: ControllerKind) -> &'static str {
    match c {
        ControllerKind::Inverse => "inverse",
        ControllerKind::Naive => "naive",
    }
}

/// Runs the benchmark set and writes the report into `opts.out_dir`.
///
/// # Errors
/// [`ReportError`] when a scene override is invalid or a file cannot be written. A run that
/// breaks down or fails to start is reported, not an error.
pub fn report(opts: &ReportOptions) -> Result<ReportSummary, ReportError> {
    let start = Instant::now();
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| out_err(&opts.out_dir, e))?;
    let steps_cap = opts
        .steps
        .or(if opts.quick { Some(QUICK_STEPS) } else { None });
    let mut runs = plan::planned_runs(opts.quick)?;
    let suite = if opts.quick { None } else { opts.suite.clone() };
    let accuracy_scenes = accuracy::scenes(suite.as_deref())?;
    let bar = runner::progress_bar(runs.len() + accuracy_scenes.len(), opts.progress);
    runner::run_all(&mut runs, steps_cap, &bar, opts.progress);
    let accuracy = accuracy::run_accuracy(
        &accuracy_scenes,
        opts.quick,
        &plan::base(opts.quick),
        steps_cap,
        &bar,
        opts.progress,
    );
    bar.finish_and_clear();
    let mut summary = ReportSummary {
        out_dir: opts.out_dir.clone(),
        quick: opts.quick,
        steps_cap,
        runs: runs.into_iter().map(|(r, _)| r).collect(),
        suite,
        accuracy,
        files: Vec::new(),
        wall_s: 0.0,
    };
    write_outputs(&mut summary)?;
    summary.wall_s = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// Writes the CSV files, the charts (with the `charts` feature), `summary.md` and `report.json`.
fn write_outputs(s: &mut ReportSummary) -> Result<(), ReportError> {
    let dir = s.out_dir.clone();
    let mut files = Vec::new();

    let p = dir.join("runs.csv");
    csv::write_runs_csv(&p, &s.runs)?;
    files.push(p);
    let p = dir.join("error_vs_depth.csv");
    csv::write_error_csv(&p, &s.runs)?;
    files.push(p);
    let p = dir.join("accuracy_cost.csv");
    accuracy::write_csv(&p, &s.accuracy)?;
    files.push(p);

    #[cfg(feature = "charts")]
    files.extend(charts::write_charts(&dir, &s.runs)?);

    let p = dir.join("summary.md");
    let md = tables::summary_markdown(s, &files, cfg!(feature = "charts"));
    std::fs::write(&p, md).map_err(|e| out_err(&p, e))?;
    files.push(p);

    let p = dir.join("report.json");
    files.push(p.clone());
    s.files = files;
    let json = serde_json::to_string_pretty(&*s).map_err(|e| out_err(&p, e))?;
    std::fs::write(&p, json).map_err(|e| out_err(&p, e))?;
    Ok(())
}

/// A number with `digits` decimals, or `—` when it is not finite.
fn fmt_f(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "—".into()
    }
}

/// The paper's time per step per mesh size [ms] (the benchmark's "figures to beat").
const PAPER_TIME_PER_STEP: [(usize, f64); 4] =
    [(600, 8.85), (1100, 13.24), (1500, 12.92), (1800, 24.43)];
/// The paper's complex-path e_mean per mesh size [mm] (600 and 1800 nodes: mesh sensitivity;
/// 1500: the accuracy run).
#[cfg_attr(not(feature = "charts"), allow(dead_code))]
const PAPER_COMPLEX_E_MEAN: [(usize, f64); 3] = [(600, 3.2), (1500, 2.6), (1800, 1.0)];

/// The paper's bounds per scene: (scene, e_mean, e_max) [mm].
#[cfg_attr(not(feature = "charts"), allow(dead_code))]
const PAPER_BOUNDS: [(&str, f64, f64); 2] = [("simple", 0.5, 1.8), ("complex", 2.6, 6.0)];

/// The paper's time per step at `nodes` gel nodes, when it gives one [ms].
fn paper_time(nodes: usize) -> Option<f64> {
    PAPER_TIME_PER_STEP
        .iter()
        .find(|(n, _)| *n == nodes)
        .map(|(_, t)| *t)
}
