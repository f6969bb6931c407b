//! The benchmark report (`needle report`): both benchmark scenes under both controllers plus the
//! parameter sweeps of `shared/BENCHMARK.md`, written into one folder.
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
//! Files: `summary.md` (a table per group, the paper's reference figures in a table of their own),
//! `runs.csv` (one row per run), `error_vs_depth.csv` (every run's error at every step inside the
//! gel), `report.json` (everything above as JSON), and three charts as SVG and PNG:
//! `error_vs_depth` (the paper's Fig. 7), `stage_times` (Fig. 8: the stage split of a step per
//! mesh size) and `speed_vs_error` (time per step against e_mean over every run).
//!
//! A run that breaks down (the naive baseline may) or cannot even start is reported as such, with
//! the steps it ran; it never aborts the report. The charts draw their text with DejaVu Sans,
//! embedded in the binary (no system font is needed).

use crate::run::{ControllerKind, RunOptions, RunSummary, planned_steps, run};
use crate::scene::Scene;
use indicatif::{ProgressBar, ProgressStyle};
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::collections::HashMap;
use std::fmt::Write as _;
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
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            out_dir: PathBuf::from("report"),
            quick: false,
            steps: None,
            progress: true,
        }
    }
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
    /// The gel's factorisation: in the background (one step old) or synchronous.
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
                "Gel factorisation: background pipelines against synchronous (inverse)"
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
    /// Every file written.
    pub files: Vec<PathBuf>,
    /// Wall time of the whole report [s].
    pub wall_s: f64,
}

/// Why the report could not be written. (A run that breaks down is not an error.)
#[derive(Debug)]
pub struct ReportError {
    /// The file or folder concerned.
    pub file: PathBuf,
    /// What went wrong.
    pub reason: String,
}

impl std::fmt::Display for ReportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.file.display(), self.reason)
    }
}

impl std::error::Error for ReportError {}

fn err(file: &Path, reason: impl std::fmt::Display) -> ReportError {
    ReportError {
        file: file.to_path_buf(),
        reason: reason.to_string(),
    }
}

fn controller_name(c: ControllerKind) -> &'static str {
    match c {
        ControllerKind::Inverse => "inverse",
        ControllerKind::Naive => "naive",
    }
}

/// One planned run before de-duplication.
struct Spec {
    scene: &'static str,
    controller: ControllerKind,
    overrides: Vec<(String, String)>,
    group: Group,
    parameter: String,
}

fn plan(quick: bool) -> Vec<Spec> {
    let base: Vec<(String, String)> = if quick {
        vec![("gel.box.nodes".into(), "600".into())]
    } else {
        Vec::new()
    };
    let with = |field: &str, value: String| {
        let mut o = base.clone();
        o.retain(|(f, _)| f != field);
        o.push((field.to_owned(), value));
        o
    };
    let mut specs = Vec::new();
    for scene in ["simple", "complex"] {
        for controller in [ControllerKind::Inverse, ControllerKind::Naive] {
            specs.push(Spec {
                scene,
                controller,
                overrides: base.clone(),
                group: Group::Controllers,
                parameter: if quick {
                    "600 nodes".into()
                } else {
                    "scene defaults (1500 nodes)".into()
                },
            });
        }
    }
    let meshes: &[usize] = if quick {
        &[600]
    } else {
        &[600, 1100, 1500, 1800]
    };
    for scene in ["simple", "complex"] {
        for &n in meshes {
            specs.push(Spec {
                scene,
                controller: ControllerKind::Inverse,
                overrides: with("gel.box.nodes", n.to_string()),
                group: Group::Mesh,
                parameter: format!("{n} nodes"),
            });
        }
    }
    // (group, scene field, parameter text, full set, quick set)
    type Sweep<'a> = (Group, &'a str, &'a str, &'a [f64], &'a [f64]);
    let sweeps: [Sweep; 3] = [
        (
            Group::DeltaQ,
            "inverse.delta_q",
            "δq = {} rad",
            &[0.001, 0.01, 0.1],
            &[0.001],
        ),
        (
            Group::BlendDistance,
            "inverse.blend_distance",
            "d = {} mm",
            &[6.0, 12.0, 18.0, 30.0],
            &[6.0],
        ),
        (
            Group::ConstraintSpacing,
            "interaction.constraint_spacing",
            "d_n = {} mm",
            &[5.0, 10.0, 20.0],
            &[5.0],
        ),
    ];
    for (group, field, fmt, full, short) in sweeps {
        for &v in if quick { short } else { full } {
            specs.push(Spec {
                scene: "complex",
                controller: ControllerKind::Inverse,
                overrides: with(field, format!("{v:?}")),
                group,
                parameter: fmt.replace("{}", &format!("{v}")),
            });
        }
    }
    let scenes: &[&'static str] = if quick {
        &["complex"]
    } else {
        &["simple", "complex"]
    };
    for &scene in scenes {
        // (overrides beyond the base, parameter text)
        let variants: [(&[(&str, &str)], &str); 4] = [
            (
                &[("solver.refactor_every", "1")],
                "background, a factor 1 step old",
            ),
            (&[], "background, pipeline of 2 steps (default)"),
            (
                &[("solver.refactor_every", "3")],
                "background, pipeline of 3 steps",
            ),
            (
                &[("solver.background_factorization", "false")],
                "synchronous, every step (the paper's)",
            ),
        ];
        for (extra, text) in variants {
            if quick && extra.len() == 1 && extra[0].0 == "solver.refactor_every" {
                continue;
            }
            let mut overrides = base.clone();
            overrides.extend(extra.iter().map(|(f, v)| (f.to_string(), v.to_string())));
            specs.push(Spec {
                scene,
                controller: ControllerKind::Inverse,
                overrides,
                group: Group::Factorization,
                parameter: text.into(),
            });
        }
    }
    specs
}

/// Runs the benchmark set and writes the report into `opts.out_dir`.
///
/// # Errors
/// [`ReportError`] when a scene override is invalid or a file cannot be written. A run that
/// breaks down or fails to start is reported, not an error.
pub fn report(opts: &ReportOptions) -> Result<ReportSummary, ReportError> {
    let start = Instant::now();
    std::fs::create_dir_all(&opts.out_dir)
        .map_err(|e| err(&opts.out_dir, format!("cannot create the folder: {e}")))?;
    let steps_cap = opts
        .steps
        .or(if opts.quick { Some(QUICK_STEPS) } else { None });

    // Plan, then merge the specs that are the same simulation.
    let mut runs: Vec<ReportRun> = Vec::new();
    let mut scenes: Vec<Scene> = Vec::new();
    let mut index: HashMap<(String, &'static str), usize> = HashMap::new();
    for (order, spec) in plan(opts.quick).into_iter().enumerate() {
        let base = Scene::builtin(spec.scene)
            .ok_or_else(|| err(Path::new(spec.scene), "no such embedded scene"))?;
        let scene = base
            .with_overrides(&spec.overrides)
            .map_err(|e| err(Path::new(spec.scene), e))?;
        let key = toml::to_string(&scene).map_err(|e| err(Path::new(spec.scene), e))?;
        let membership = Membership {
            group: spec.group,
            parameter: spec.parameter,
            order,
        };
        if let Some(&i) = index.get(&(key.clone(), controller_name(spec.controller))) {
            runs[i].memberships.push(membership);
            continue;
        }
        index.insert((key, controller_name(spec.controller)), runs.len());
        runs.push(ReportRun {
            id: runs.len(),
            scene: scene.name.clone(),
            controller: spec.controller,
            nodes_target: scene.gel.box_mesh.as_ref().map_or(0, |b| b.nodes),
            delta_q: scene.inverse.delta_q,
            blend_distance_mm: scene.inverse.blend_distance,
            constraint_spacing_mm: scene.interaction.constraint_spacing,
            overrides: spec.overrides,
            memberships: vec![membership],
            summary: None,
            failure: None,
            wall_s: 0.0,
            error_by_depth: Vec::new(),
        });
        scenes.push(scene);
    }

    let bar = if opts.progress {
        ProgressBar::new(runs.len() as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} runs  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let total = runs.len();
    for (r, scene) in runs.iter_mut().zip(&scenes) {
        let t0 = Instant::now();
        let planned = planned_steps(scene);
        let steps = steps_cap.map_or(planned, |c| c.min(planned));
        let ropts = RunOptions {
            controller: r.controller,
            steps: Some(steps),
            out_dir: None,
            vtk_every: Some(0),
            ..RunOptions::default()
        };
        let what = format!(
            "{} · {}",
            r.label(),
            r.memberships
                .iter()
                .map(|m| m.parameter.as_str())
                .fold(Vec::<&str>::new(), |mut v, p| {
                    if !v.contains(&p) {
                        v.push(p);
                    }
                    v
                })
                .join(" / ")
        );
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run(scene, &ropts, |s| {
                if s.step % 10 == 0 {
                    bar.set_message(format!("{what}: step {}/{steps}", s.step + 1));
                }
            })
        }));
        r.wall_s = t0.elapsed().as_secs_f64();
        match result {
            Ok(Ok(res)) => {
                r.summary = Some(res.summary);
                r.error_by_depth = res.error_by_depth;
            }
            Ok(Err(e)) => r.failure = Some(format!("could not start: {e}")),
            Err(p) => {
                let msg = p
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| p.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                r.failure = Some(format!("panicked: {msg}"));
            }
        }
        let line = format!("[{}/{total}] {what}: {}", r.id + 1, outcome(r));
        if bar.is_hidden() {
            if opts.progress {
                eprintln!("{line}");
            }
        } else {
            bar.println(line);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();

    let mut summary = ReportSummary {
        out_dir: opts.out_dir.clone(),
        quick: opts.quick,
        steps_cap,
        runs,
        files: Vec::new(),
        wall_s: 0.0,
    };
    write_outputs(&mut summary)?;
    summary.wall_s = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// One line on a finished run.
fn outcome(r: &ReportRun) -> String {
    match (&r.summary, &r.failure) {
        (_, Some(f)) => format!("FAILED — {f} ({:.1} s)", r.wall_s),
        (Some(s), None) => format!(
            "{} {}/{} steps, e_mean {:.3} mm, e_max {:.3} mm, clearance {}, {:.2} ms/step median ({:.1} s)",
            if s.completed {
                "completed"
            } else {
                "STOPPED early after"
            },
            s.steps,
            s.steps_planned,
            s.e_mean_mm,
            s.e_max_mm,
            r.min_clearance()
                .map_or("—".into(), |(c, n)| clearance_text(c, n)),
            s.timing.total.median_ms,
            r.wall_s
        ),
        (None, None) => "not run".into(),
    }
}

fn clearance_text(c: f64, name: &str) -> String {
    if c < 0.0 {
        format!("hit {c:.2} mm ({name})")
    } else {
        format!("{c:.2} mm ({name})")
    }
}

fn write_outputs(s: &mut ReportSummary) -> Result<(), ReportError> {
    let dir = s.out_dir.clone();
    let mut files = Vec::new();

    let p = dir.join("runs.csv");
    write_runs_csv(&p, &s.runs)?;
    files.push(p);
    let p = dir.join("error_vs_depth.csv");
    write_error_csv(&p, &s.runs)?;
    files.push(p);

    register_fonts();
    for (name, chart) in [
        ("error_vs_depth", Chart::ErrorVsDepth(&s.runs)),
        ("stage_times", Chart::StageTimes(&s.runs)),
        ("speed_vs_error", Chart::SpeedVsError(&s.runs)),
    ] {
        let svg = dir.join(format!("{name}.svg"));
        chart
            .draw(SVGBackend::new(&svg, CHART_SIZE).into_drawing_area())
            .map_err(|e| err(&svg, e))?;
        files.push(svg);
        let png = dir.join(format!("{name}.png"));
        chart
            .draw(BitMapBackend::new(&png, CHART_SIZE).into_drawing_area())
            .map_err(|e| err(&png, e))?;
        files.push(png);
    }

    let p = dir.join("summary.md");
    let md = summary_markdown(s, &files);
    std::fs::write(&p, md).map_err(|e| err(&p, e))?;
    files.push(p);

    let p = dir.join("report.json");
    files.push(p.clone());
    s.files = files;
    let json = serde_json::to_string_pretty(&*s).map_err(|e| err(&p, e))?;
    std::fs::write(&p, json).map_err(|e| err(&p, e))?;
    Ok(())
}

fn fmt_f(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "—".into()
    }
}

fn write_runs_csv(path: &Path, runs: &[ReportRun]) -> Result<(), ReportError> {
    let n = |x: f64| {
        if x.is_finite() {
            x.to_string()
        } else {
            String::new()
        }
    };
    let mut w = csv::Writer::from_path(path).map_err(|e| err(path, e))?;
    let header = [
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
        "step_median_ms",
        "step_p99_ms",
        "step_mean_ms",
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
    w.write_record(header).map_err(|e| err(path, e))?;
    for r in runs {
        let groups: Vec<&str> = r.memberships.iter().map(|m| m.group.name()).collect();
        let params: Vec<&str> = r.memberships.iter().map(|m| m.parameter.as_str()).collect();
        let mut row = vec![
            r.id.to_string(),
            r.scene.clone(),
            controller_name(r.controller).to_owned(),
            groups.join(";"),
            params.join(";"),
            r.nodes_target.to_string(),
        ];
        row.extend([
            r.summary
                .as_ref()
                .map_or(String::new(), |s| s.gel_nodes.to_string()),
            r.delta_q.to_string(),
            r.blend_distance_mm.to_string(),
            r.constraint_spacing_mm.to_string(),
        ]);
        if let Some(s) = &r.summary {
            let (cmin, cname) = r.min_clearance().unwrap_or((f64::NAN, ""));
            let t = &s.timing;
            row.extend([
                s.steps.to_string(),
                s.steps_planned.to_string(),
                s.completed.to_string(),
                s.stopped.clone().unwrap_or_default(),
                s.puncture_step.map_or(String::new(), |k| k.to_string()),
                n(s.e_mean_mm),
                n(s.e_max_mm),
                n(s.e_final_mm),
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
                n(t.total.median_ms),
                n(t.total.p99_ms),
                n(t.total.mean_ms),
                n(t.fm.median_ms),
                n(t.fm.p99_ms),
                n(t.cd.median_ms),
                n(t.cd.p99_ms),
                n(t.cc.median_ms),
                n(t.cc.p99_ms),
                n(t.sc.median_ms),
                n(t.sc.p99_ms),
                n(t.correction.median_ms),
                n(t.correction.p99_ms),
                n(s.gs_iterations_mean),
                s.gs_iterations_max.to_string(),
                s.gs_not_converged_steps.to_string(),
            ]);
        } else {
            row.resize(header.len() - 2, String::new());
        }
        row.push(format!("{:.3}", r.wall_s));
        row.push(r.failure.clone().unwrap_or_default());
        debug_assert_eq!(row.len(), header.len());
        w.write_record(&row).map_err(|e| err(path, e))?;
    }
    w.flush().map_err(|e| err(path, e))
}

fn write_error_csv(path: &Path, runs: &[ReportRun]) -> Result<(), ReportError> {
    let mut w = csv::Writer::from_path(path).map_err(|e| err(path, e))?;
    w.write_record([
        "run",
        "scene",
        "controller",
        "parameters",
        "depth_mm",
        "error_mm",
    ])
    .map_err(|e| err(path, e))?;
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
            .map_err(|e| err(path, e))?;
        }
    }
    w.flush().map_err(|e| err(path, e))
}

/// The paper's figures (`shared/BENCHMARK.md`, "The paper's figures to beat").
const PAPER_TIME_PER_STEP: [(usize, f64); 4] =
    [(600, 8.85), (1100, 13.24), (1500, 12.92), (1800, 24.43)];
/// The paper's complex-path e_mean per mesh size [mm] (600 and 1800 nodes: mesh sensitivity;
/// 1500: the accuracy run).
const PAPER_COMPLEX_E_MEAN: [(usize, f64); 3] = [(600, 3.2), (1500, 2.6), (1800, 1.0)];

fn paper_time(nodes: usize) -> Option<f64> {
    PAPER_TIME_PER_STEP
        .iter()
        .find(|(n, _)| *n == nodes)
        .map(|(_, t)| *t)
}

fn summary_markdown(s: &ReportSummary, files: &[PathBuf]) -> String {
    let mut md = String::new();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let _ = writeln!(md, "# Benchmark report\n");
    let _ = writeln!(
        md,
        "Produced by `needle report{}{}` — {} simulation runs, {:.0} s. Every figure in the \
         tables below is measured by that command; **the paper's figures are only in the table \
         \"The paper's figures\"** and are marked as the paper's wherever they appear.\n",
        if s.quick { " --quick" } else { "" },
        match (s.quick, s.steps_cap) {
            (false, Some(c)) => format!(" --steps {c}"),
            _ => String::new(),
        },
        s.runs.len(),
        s.runs.iter().map(|r| r.wall_s).sum::<f64>(),
    );
    if s.quick {
        let _ = writeln!(
            md,
            "> **Quick set**: 600-node meshes only, one point per sweep, at most {} steps per run \
             (the insertion stops ≈ 15 mm into the gel). Not comparable with the full report.\n",
            s.steps_cap.unwrap_or(QUICK_STEPS)
        );
    }
    let _ = writeln!(
        md,
        "Times are wall-clock per step on this machine ({cores} logical cores, one thread per \
         run), medians and 99th percentiles over the run's steps; FM free motion, CD proximity, \
         CC compliance, SC the core's constraint solves (the inverse step: 7–8 Gauss-Seidel \
         solves), corr corrective motion. Errors are `|tip − target|` in the deformed gel over \
         the steps with the tip inside the gel. Clearance: the smallest distance from the \
         needle to any obstacle surface over the run (**hit** when negative).\n"
    );

    let _ = writeln!(
        md,
        "## The paper's figures (IROS 2016, SOFA + GPU compliance — not measured here)\n"
    );
    let _ = writeln!(md, "| | the paper's figure |\n|---|---|");
    let _ = writeln!(md, "| simple path | e_mean 0.5 mm, e_max 1.8 mm |");
    let _ = writeln!(
        md,
        "| complex path | e_mean 2.6 mm, e_max 6.0 mm (mesh of 1500 nodes) |"
    );
    let _ = writeln!(
        md,
        "| mesh sensitivity | e_mean 3.2 mm at 600 nodes, 1 mm at 1800 nodes |"
    );
    let _ = writeln!(
        md,
        "| naive baseline | could not finish: numerical instability |"
    );
    let _ = writeln!(
        md,
        "| time per step | 8.85 ms (600 nodes), 13.24 (1100), 12.92 (1500), 24.43 (1800) |\n"
    );

    for g in Group::ALL {
        let mut rows: Vec<(usize, &ReportRun)> = s
            .runs
            .iter()
            .filter_map(|r| {
                let m = r.memberships.iter().find(|m| m.group == g)?;
                Some((m.order, r))
            })
            .collect();
        rows.sort_by_key(|(order, _)| *order);
        if rows.is_empty() {
            continue;
        }
        let _ = writeln!(md, "## {}\n", g.title());
        let mesh = g == Group::Mesh;
        let _ = write!(
            md,
            "| scene | controller | parameter | nodes | steps | completed | e_mean [mm] | e_max [mm] | final [mm] | min clearance [mm] | step median [ms] | step p99 [ms] | step mean [ms] | FM | CD | CC | SC | corr | GS sweeps |"
        );
        if mesh {
            let _ = write!(md, " paper's time/step [ms] |");
        }
        let _ = writeln!(md);
        let cols = 19 + usize::from(mesh);
        let _ = writeln!(md, "|{}", "---|".repeat(cols));
        let mut notes = Vec::new();
        for (_, r) in rows {
            let param = r.parameter(g).unwrap_or("");
            let _ = write!(
                md,
                "| {} | {} | {} |",
                r.scene,
                controller_name(r.controller),
                param
            );
            match &r.summary {
                Some(sm) => {
                    let t = &sm.timing;
                    let _ = write!(
                        md,
                        " {} | {}/{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                        sm.gel_nodes,
                        sm.steps,
                        sm.steps_planned,
                        if sm.completed {
                            "yes".to_owned()
                        } else {
                            format!("**no** ({})", notes.len() + 1)
                        },
                        fmt_f(sm.e_mean_mm, 3),
                        fmt_f(sm.e_max_mm, 3),
                        fmt_f(sm.e_final_mm, 3),
                        r.min_clearance().map_or("—".into(), |(c, n)| if c < 0.0 {
                            format!("**hit** {c:.2} ({n})")
                        } else {
                            format!("{c:.2} ({n})")
                        }),
                        fmt_f(t.total.median_ms, 2),
                        fmt_f(t.total.p99_ms, 2),
                        fmt_f(t.total.mean_ms, 2),
                        fmt_f(t.fm.median_ms, 2),
                        fmt_f(t.cd.median_ms, 2),
                        fmt_f(t.cc.median_ms, 2),
                        fmt_f(t.sc.median_ms, 2),
                        fmt_f(t.correction.median_ms, 2),
                        fmt_f(sm.gs_iterations_mean, 0),
                    );
                    if !sm.completed {
                        notes.push(format!(
                            "{} {}: stopped after {} of {} steps{}",
                            r.scene,
                            controller_name(r.controller),
                            sm.steps,
                            sm.steps_planned,
                            sm.stopped
                                .as_ref()
                                .map_or(String::new(), |w| format!(" — {w}"))
                        ));
                    }
                }
                None => {
                    let _ = write!(
                        md,
                        " — | 0 | **failed** ({}) |{}",
                        notes.len() + 1,
                        " — |".repeat(12)
                    );
                    notes.push(format!(
                        "{} {}: {}",
                        r.scene,
                        controller_name(r.controller),
                        r.failure.as_deref().unwrap_or("")
                    ));
                }
            }
            if mesh {
                let _ = write!(
                    md,
                    " {} |",
                    paper_time(r.nodes_target).map_or("—".into(), |t| format!("{t}"))
                );
            }
            let _ = writeln!(md);
        }
        let _ = writeln!(md);
        for (i, n) in notes.iter().enumerate() {
            let _ = writeln!(md, "{}. {}", i + 1, n.replace('|', "\\|"));
        }
        if !notes.is_empty() {
            let _ = writeln!(md);
        }
        if g == Group::Mesh {
            let _ = writeln!(
                md,
                "FM, CD, CC, SC, corr: stage medians [ms]. The paper's time per step is its \
                 figure (SOFA, compliance on a GPU), not a measurement of this code. \n"
            );
        }
    }

    let _ = writeln!(md, "## Charts\n");
    let _ = writeln!(
        md,
        "- Tracking error against insertion depth, inverse and naive (the paper's Fig. 7): \
         [`error_vs_depth.svg`](error_vs_depth.svg)\n\n  ![error against depth](error_vs_depth.png)\n"
    );
    let _ = writeln!(
        md,
        "- Stage times per mesh size, stacked medians, with the paper's time per step (Fig. 8): \
         [`stage_times.svg`](stage_times.svg)\n\n  ![stage times](stage_times.png)\n"
    );
    let _ = writeln!(
        md,
        "- Time per step against e_mean over every run (speed against error), with the paper's \
         complex-path points: [`speed_vs_error.svg`](speed_vs_error.svg)\n\n  ![speed against error](speed_vs_error.png)\n"
    );
    let _ = writeln!(md, "## Files\n");
    for f in files {
        if let Some(n) = f.file_name() {
            let n = n.to_string_lossy();
            let what = match n.as_ref() {
                "runs.csv" => "one row per run: parameters, errors, clearances, stage times",
                "error_vs_depth.csv" => "every run's error at every step inside the gel",
                _ => continue,
            };
            let _ = writeln!(md, "- [`{n}`]({n}): {what}");
        }
    }
    let _ = writeln!(
        md,
        "- [`report.json`](report.json): every run's full summary as JSON"
    );
    md
}

// ---------------------------------------------------------------------------------------------
// Charts

const CHART_SIZE: (u32, u32) = (1400, 560);

const COLORS: [RGBColor; 7] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

fn register_fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans ships inside the `dejavu` crate: no system font or fontconfig needed.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

/// A chart and its data.
enum Chart<'a> {
    ErrorVsDepth(&'a [ReportRun]),
    StageTimes(&'a [ReportRun]),
    SpeedVsError(&'a [ReportRun]),
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

impl Chart<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let r = match self {
            Chart::ErrorVsDepth(runs) => error_vs_depth(&root, runs),
            Chart::StageTimes(runs) => stage_times(&root, runs),
            Chart::SpeedVsError(runs) => speed_vs_error(&root, runs),
        };
        r.and_then(|()| root.present().map_err(Into::into))
            .map_err(|e| e.to_string())
    }
}

fn nice_max(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    x * 1.1
}

/// Fig. 7: error against depth, one panel per scene, inverse and naive.
fn error_vs_depth<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    runs: &[ReportRun],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Tracking error against insertion depth (the paper's Fig. 7)",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    for (panel, scene) in panels.iter().zip(["simple", "complex"]) {
        let lines: Vec<&ReportRun> = runs
            .iter()
            .filter(|r| r.scene == scene && r.parameter(Group::Controllers).is_some())
            .collect();
        let max_d = lines
            .iter()
            .flat_map(|r| r.error_by_depth.iter().map(|p| p.0))
            .fold(0.0, f64::max);
        let hi = lines
            .iter()
            .flat_map(|r| r.error_by_depth.iter().map(|p| p.1))
            .filter(|e| e.is_finite())
            .fold(0.0, f64::max);
        let hi = nice_max(hi);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{scene} path"), ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..nice_max(max_d).max(1.0), 0.0..hi)?;
        chart
            .configure_mesh()
            .x_desc("insertion depth [mm]")
            .y_desc("tracking error |tip − target| [mm]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        for r in &lines {
            let color = match r.controller {
                ControllerKind::Inverse => COLORS[0],
                ControllerKind::Naive => COLORS[1],
            };
            let mut label = controller_name(r.controller).to_owned();
            if let Some(s) = &r.summary {
                let _ = write!(label, ": e_mean {:.2} mm", s.e_mean_mm);
                if !s.completed {
                    label.push_str(&format!(" (stopped at step {}: see summary.md)", s.steps));
                }
            }
            chart
                .draw_series(LineSeries::new(
                    r.error_by_depth.iter().filter(|p| p.1.is_finite()).copied(),
                    color.stroke_width(1),
                ))?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
    }
    Ok(())
}

/// Fig. 8: stacked stage medians per mesh size, one panel per scene, with the paper's totals.
fn stage_times<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, runs: &[ReportRun]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Time per step by stage and mesh size (medians; the paper's Fig. 8)",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    let ymax = runs
        .iter()
        .filter(|r| r.parameter(Group::Mesh).is_some())
        .filter_map(|r| r.summary.as_ref())
        .map(|s| {
            let t = &s.timing;
            t.fm.median_ms
                + t.cd.median_ms
                + t.cc.median_ms
                + t.sc.median_ms
                + t.correction.median_ms
        })
        .chain(PAPER_TIME_PER_STEP.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    for (panel, scene) in panels.iter().zip(["simple", "complex"]) {
        let mut bars: Vec<(f64, [f64; 5])> = runs
            .iter()
            .filter(|r| r.scene == scene && r.parameter(Group::Mesh).is_some())
            .filter_map(|r| {
                let s = r.summary.as_ref()?;
                let t = &s.timing;
                Some((
                    r.nodes_target as f64,
                    [
                        t.fm.median_ms,
                        t.cd.median_ms,
                        t.cc.median_ms,
                        t.sc.median_ms,
                        t.correction.median_ms,
                    ],
                ))
            })
            .collect();
        bars.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!("{scene} path, inverse controller"),
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(300.0..2100.0, 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("gel nodes (mesher target)")
            .y_desc("time per step [ms]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        let names = [
            "FM free motion",
            "CD proximity",
            "CC compliance",
            "SC constraint solves",
            "corr correction",
        ];
        let half = 90.0;
        for (k, name) in names.iter().enumerate() {
            let color = COLORS[k];
            chart
                .draw_series(bars.iter().map(|(x, t)| {
                    let y0: f64 = t[..k].iter().sum();
                    let y1 = y0 + t[k];
                    Rectangle::new([(x - half, y0), (x + half, y1)], color.filled())
                }))?
                .label(*name)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                });
        }
        chart
            .draw_series(
                PAPER_TIME_PER_STEP
                    .iter()
                    .map(|&(n, t)| Cross::new((n as f64, t), 7, BLACK.stroke_width(2))),
            )?
            .label("the paper's time per step (SOFA + GPU)")
            .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
    }
    Ok(())
}

/// Speed against error: mean time per step (the throughput) against e_mean, every run, coloured by group.
fn speed_vs_error<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    runs: &[ReportRun],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let pts: Vec<(&ReportRun, f64, f64)> = runs
        .iter()
        .filter_map(|r| {
            let s = r.summary.as_ref()?;
            (s.e_mean_mm.is_finite() && s.e_mean_mm > 0.0 && s.timing.total.mean_ms > 0.0)
                .then_some((r, s.e_mean_mm, s.timing.total.mean_ms))
        })
        .collect();
    let (xlo, xhi) = pts
        .iter()
        .map(|p| p.1)
        .chain(PAPER_COMPLEX_E_MEAN.iter().map(|p| p.1))
        .fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
    let ymax = pts
        .iter()
        .map(|p| p.2)
        .chain(PAPER_TIME_PER_STEP.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    let (xlo, xhi) = if xlo.is_finite() && xhi > xlo {
        (xlo, xhi)
    } else {
        (0.1, 10.0)
    };
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(
            "Speed against error: mean time per step against e_mean, every run",
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60);
    // Log scale only when the errors span more than two decades (a naive run that
    // drifts far away); its tick labels are sparse, so the x label says so.
    if xhi / xlo > 100.0 {
        let mut chart =
            builder.build_cartesian_2d((xlo * 0.7..xhi * 1.4).log_scale(), 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("e_mean [mm] (log scale)")
            .y_desc("time per step, mean [ms]")
            .x_labels(8)
            .x_label_formatter(&|x| format!("{x:.2}"))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        speed_series(&mut chart, &pts)
    } else {
        let pad = 0.08 * (xhi - xlo);
        let mut chart =
            builder.build_cartesian_2d((xlo - pad).max(0.0)..xhi + pad, 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("e_mean [mm]")
            .y_desc("time per step, mean [ms]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        speed_series(&mut chart, &pts)
    }
}

/// Points of [`speed_vs_error`] and the paper's, on either x scale.
fn speed_series<'a, DB: DrawingBackend + 'a, X>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, plotters::coord::types::RangedCoordf64>>,
    pts: &[(&ReportRun, f64, f64)],
) -> DrawResult
where
    DB::ErrorType: 'static,
    X: Ranged<ValueType = f64>,
{
    // One series per (group, controller, scene) so that every marker has a legend entry: the
    // colour says the group (the controllers group splits into inverse and naive), the shape the
    // scene (circle: complex, triangle: simple); a hollow marker is a run that did not complete.
    // (legend, colour index, simple scene, points (e_mean, time, completed))
    type Series = (String, usize, bool, Vec<(f64, f64, bool)>);
    let mut series: Vec<Series> = Vec::new();
    for (r, x, y) in pts {
        for m in &r.memberships {
            let (name, colour) = match (m.group, r.controller) {
                // After every group's colour.
                (Group::Controllers, ControllerKind::Naive) => {
                    ("controllers (naive)".to_owned(), Group::ALL.len())
                }
                (Group::Controllers, ControllerKind::Inverse) => {
                    ("controllers (inverse)".to_owned(), 0)
                }
                (g, _) => (
                    g.name().to_owned(),
                    Group::ALL.iter().position(|a| *a == g).unwrap_or(0),
                ),
            };
            let key = format!("{name}, {}", r.scene);
            let done = r.completed();
            match series.iter_mut().find(|s| s.0 == key) {
                Some(s) => s.3.push((*x, *y, done)),
                None => series.push((key, colour, r.scene == "simple", vec![(*x, *y, done)])),
            }
        }
    }
    series.sort_by_key(|s| (s.1, s.2));
    for (name, colour, simple, p) in &series {
        let color = COLORS[colour % COLORS.len()];
        let style = move |done: bool| {
            if done {
                color.filled()
            } else {
                color.stroke_width(2)
            }
        };
        if *simple {
            chart
                .draw_series(
                    p.iter()
                        .map(move |&(x, y, done)| TriangleMarker::new((x, y), 7, style(done))),
                )?
                .label(name.clone())
                .legend(move |(x, y)| TriangleMarker::new((x + 7, y), 6, color.filled()));
        } else {
            chart
                .draw_series(
                    p.iter()
                        .map(move |&(x, y, done)| Circle::new((x, y), 6, style(done))),
                )?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 7, y), 5, color.filled()));
        }
    }
    chart
        .draw_series(
            PAPER_COMPLEX_E_MEAN.iter().filter_map(|&(n, e)| {
                Some(Cross::new((e, paper_time(n)?), 8, BLACK.stroke_width(2)))
            }),
        )?
        .label("the paper, complex path (600 / 1500 / 1800 nodes)")
        .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}
