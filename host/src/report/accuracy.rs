//! The report's accuracy-cost section: every scene run closed loop with the exact step, its
//! joints replayed open loop through the default pipeline and through the linear far field
//! ([`crate::accuracy`]); `accuracy_cost.csv` and a table in `summary.md`.

use super::{ReportError, fmt_f, out_err};
use crate::accuracy::{AccuracyCost, ExactRun, TOLERANCE_MM, exact_run, replayed};
use crate::scene::Scene;
use crate::suite::{SuiteOptions, load_scene, scene_list};
use indicatif::ProgressBar;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The pipelines compared with the exact step: (name, overrides). The quick set's 600-node
/// gels have no near block, hence no far elements: it compares the default only.
const PIPELINES: [(&str, &[(&str, &str)]); 2] = [
    ("default pipeline", &[]),
    ("linear far field", &[("solver.far_elements", "\"linear\"")]),
];

/// A scene of the section: the exact step's errors and each pipeline's on its joints.
#[derive(Clone, Debug, Serialize)]
pub struct AccuracyRow {
    /// Scene name.
    pub scene: String,
    /// The scene's file (none for an embedded benchmark).
    pub file: Option<PathBuf>,
    /// One entry per pipeline compared (the default, then the linear far field; the quick set:
    /// the default only): its name and its cost, or why it could not run.
    pub pipelines: Vec<PipelineCost>,
    /// Why the exact closed loop could not run (then no pipeline ran).
    pub failure: Option<String>,
    /// Wall time of the scene's runs [s].
    pub wall_s: f64,
}

/// One pipeline on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineCost {
    /// The pipeline's name (`default pipeline`, `linear far field`).
    pub pipeline: String,
    /// Its errors beside the exact step's.
    pub cost: Option<AccuracyCost>,
    /// Why it could not run.
    pub failure: Option<String>,
}

/// The scenes of the section: the benchmarks, then the suite folder's scenes (none with
/// `suite = None`).
///
/// # Errors
/// [`ReportError::Suite`] when the folder cannot be listed.
pub(super) fn scenes(suite: Option<&Path>) -> Result<Vec<(String, Option<PathBuf>)>, ReportError> {
    let Some(dir) = suite else {
        return Ok(["simple", "complex"].map(|s| (s.to_owned(), None)).to_vec());
    };
    let opts = SuiteOptions {
        dir: dir.to_owned(),
        benchmarks: true,
        overrides: Vec::new(),
        nodes: None,
        steps: None,
        variants: Vec::new(),
    };
    scene_list(&opts).map_err(|source| ReportError::Suite {
        dir: dir.to_owned(),
        source,
    })
}

/// Runs `f`, a panic turned into an error.
fn guarded<T>(f: impl FnOnce() -> Result<T, String>) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .unwrap_or_else(|p| Err(format!("panicked: {}", super::runner::panic_text(&*p))))
}

/// Every scene of `list` (from [`scenes`]) with `base` overrides and at most `steps` steps,
/// each a row; a scene that cannot be loaded or run is a row with its failure, never an error.
/// The quick set compares the default pipeline only.
pub(super) fn run_accuracy(
    list: &[(String, Option<PathBuf>)],
    quick: bool,
    base: &[(String, String)],
    steps: Option<usize>,
    bar: &ProgressBar,
    progress: bool,
) -> Vec<AccuracyRow> {
    let pipelines = if quick {
        &PIPELINES[..1]
    } else {
        &PIPELINES[..]
    };
    let mut rows = Vec::with_capacity(list.len());
    for (k, (name, file)) in list.iter().enumerate() {
        let t0 = Instant::now();
        bar.set_message(format!(
            "accuracy cost · {name}: the exact step, closed loop"
        ));
        let scene = load_scene(name, file.as_deref())
            .and_then(|s| s.with_overrides(base).map_err(|e| e.to_string()));
        let exact: Result<(Scene, ExactRun), String> = scene.and_then(|s| {
            guarded(|| exact_run(&s, steps).map_err(|e| e.to_string())).map(|x| (s, x))
        });
        let mut row = AccuracyRow {
            scene: name.clone(),
            file: file.clone(),
            pipelines: Vec::new(),
            failure: None,
            wall_s: 0.0,
        };
        match exact {
            Err(e) => row.failure = Some(e),
            Ok((scene, exact)) => {
                for (pipeline, overrides) in pipelines {
                    bar.set_message(format!("accuracy cost · {name}: {pipeline}, replayed"));
                    let overrides: Vec<(String, String)> = (overrides.iter())
                        .map(|(f, v)| (f.to_string(), v.to_string()))
                        .collect();
                    let cost = guarded(|| {
                        let s = scene
                            .with_overrides(&overrides)
                            .map_err(|e| e.to_string())?;
                        replayed(&s, &exact).map_err(|e| e.to_string())
                    });
                    row.pipelines.push(PipelineCost {
                        pipeline: (*pipeline).to_owned(),
                        failure: cost.as_ref().err().cloned(),
                        cost: cost.ok(),
                    });
                }
            }
        }
        row.wall_s = t0.elapsed().as_secs_f64();
        let line = format!(
            "[accuracy {}/{}] {name}: {} ({:.1} s)",
            k + 1,
            list.len(),
            row_outcome(&row),
            row.wall_s
        );
        super::runner::print_line(bar, progress, line);
        bar.inc(1);
        rows.push(row);
    }
    rows
}

/// One line on a finished row.
fn row_outcome(row: &AccuracyRow) -> String {
    if let Some(f) = &row.failure {
        return format!("FAILED — {f}");
    }
    (row.pipelines.iter())
        .map(|p| match (&p.cost, &p.failure) {
            (Some(c), _) => format!("{} {:.3} mm off", p.pipeline, c.largest_difference_mm()),
            (None, f) => format!("{} FAILED — {}", p.pipeline, f.as_deref().unwrap_or("")),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The pipelines' names, in column order (from the first row that ran).
fn pipeline_names(rows: &[AccuracyRow]) -> Vec<String> {
    (rows.iter())
        .find(|r| !r.pipelines.is_empty())
        .map(|r| r.pipelines.iter().map(|p| p.pipeline.clone()).collect())
        .unwrap_or_default()
}

/// `e_mean / e_max / e_final` with 3 decimals.
fn triple(e: &crate::accuracy::Errors) -> String {
    format!(
        "{} / {} / {}",
        fmt_f(e.e_mean_mm, 3),
        fmt_f(e.e_max_mm, 3),
        fmt_f(e.e_final_mm, 3)
    )
}

/// The section of `summary.md`.
pub(super) fn markdown(md: &mut String, rows: &[AccuracyRow], suite: Option<&Path>, quick: bool) {
    if rows.is_empty() {
        return;
    }
    let names = pipeline_names(rows);
    let _ = writeln!(md, "## {}\n", SECTION_TITLE);
    let _ = writeln!(
        md,
        "Each scene runs closed loop with the exact step (the whole corotational gel factorised \
         at every step, in double precision); its joints are then replayed open loop through each \
         pipeline, so both take the same joints and the closed loop's chaos is left out. Issue \
         \"speed\" allows {TOLERANCE_MM} mm on e_mean, e_max and e_final. Scenes: {}.\n",
        match (quick, suite) {
            (true, _) => "the two benchmarks (quick set)".to_owned(),
            (false, Some(d)) => format!("the two benchmarks and `{}`", d.display()),
            (false, None) => "the two benchmarks (no suite folder found)".to_owned(),
        }
    );
    let _ = write!(md, "| scene | exact e_mean / e_max / e_final [mm] |");
    for n in &names {
        let _ = write!(md, " {n}, same joints | largest difference |");
    }
    let _ = writeln!(md);
    let _ = writeln!(md, "|---|---|{}", "---|---|".repeat(names.len()));
    for r in rows {
        let exact = (r.pipelines.iter()).find_map(|p| p.cost.as_ref().map(|c| c.exact));
        let _ = write!(
            md,
            "| `{}` | {} |",
            r.scene,
            match (&r.failure, exact) {
                (Some(f), _) => format!("**failed**: {}", f.replace('|', "\\|")),
                (None, Some(e)) => triple(&e),
                (None, None) => "—".into(),
            }
        );
        for n in &names {
            match r.pipelines.iter().find(|p| &p.pipeline == n) {
                Some(PipelineCost { cost: Some(c), .. }) => {
                    let bold = if c.within(TOLERANCE_MM) { "" } else { "**" };
                    let _ = write!(
                        md,
                        " {} | {bold}{}{bold} |",
                        triple(&c.pipeline),
                        fmt_f(c.largest_difference_mm(), 3)
                    );
                }
                Some(PipelineCost {
                    failure: Some(f), ..
                }) => {
                    let _ = write!(md, " **failed**: {} | — |", f.replace('|', "\\|"));
                }
                _ => {
                    let _ = write!(md, " — | — |");
                }
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md);
    for line in summary_lines(rows) {
        let _ = writeln!(md, "- {line}.");
    }
    let _ = writeln!(md);
}

/// One line per pipeline: how many scenes it keeps within [`TOLERANCE_MM`] of the exact step
/// on e_mean, e_max and e_final, and its largest difference (`default pipeline: 33 of 33
/// scenes within 0.05 mm of the exact step on all three; the largest difference 0.007 mm
/// (`arc_xy`)`).
pub fn summary_lines(rows: &[AccuracyRow]) -> Vec<String> {
    (pipeline_names(rows).iter())
        .map(|n| {
            let (mut within, mut ran) = (0usize, 0usize);
            let mut worst = (0.0f64, String::new());
            for r in rows {
                let Some(c) = (r.pipelines.iter())
                    .find(|p| &p.pipeline == n)
                    .and_then(|p| p.cost.as_ref())
                else {
                    continue;
                };
                ran += 1;
                if c.within(TOLERANCE_MM) {
                    within += 1;
                }
                let d = c.largest_difference_mm();
                if d.is_nan() || d > worst.0 {
                    worst = (d, r.scene.clone());
                }
            }
            format!(
                "{n}: {within} of {} scenes within {TOLERANCE_MM} mm of the exact step on all \
                 three; the largest difference {} mm (`{}`){}",
                rows.len(),
                fmt_f(worst.0, 3),
                worst.1,
                if ran < rows.len() {
                    format!("; {} scenes could not run", rows.len() - ran)
                } else {
                    String::new()
                }
            )
        })
        .collect()
}

/// The section's title in `summary.md`.
pub const SECTION_TITLE: &str =
    "Accuracy cost of the gel pipeline: the exact step's joints replayed open loop";

/// The columns of `accuracy_cost.csv`.
const HEADER: [&str; 15] = [
    "scene",
    "pipeline",
    "steps",
    "exact_completed",
    "exact_e_mean_mm",
    "exact_e_max_mm",
    "exact_e_final_mm",
    "pipeline_e_mean_mm",
    "pipeline_e_max_mm",
    "pipeline_e_final_mm",
    "largest_difference_mm",
    "within_tolerance",
    "agreeing_steps",
    "tip_difference_max_mm",
    "failure",
];

/// Writes `accuracy_cost.csv`: a row per scene and pipeline (a scene whose exact run failed:
/// one row with its failure).
pub(super) fn write_csv(path: &Path, rows: &[AccuracyRow]) -> Result<(), ReportError> {
    let n = super::csv::n;
    let mut w = ::csv::Writer::from_path(path).map_err(|e| out_err(path, e))?;
    w.write_record(HEADER).map_err(|e| out_err(path, e))?;
    for r in rows {
        if let Some(f) = &r.failure {
            let mut rec = vec![r.scene.clone(), "exact step".into()];
            rec.resize(HEADER.len() - 1, String::new());
            rec.push(f.clone());
            w.write_record(rec).map_err(|e| out_err(path, e))?;
        }
        for p in &r.pipelines {
            let mut rec = vec![r.scene.clone(), p.pipeline.clone()];
            match &p.cost {
                Some(c) => rec.extend([
                    c.steps.to_string(),
                    c.exact_completed.to_string(),
                    n(c.exact.e_mean_mm),
                    n(c.exact.e_max_mm),
                    n(c.exact.e_final_mm),
                    n(c.pipeline.e_mean_mm),
                    n(c.pipeline.e_max_mm),
                    n(c.pipeline.e_final_mm),
                    n(c.largest_difference_mm()),
                    c.within(TOLERANCE_MM).to_string(),
                    c.agreeing_steps.to_string(),
                    n(c.tip_difference_max_mm),
                    String::new(),
                ]),
                None => {
                    rec.resize(HEADER.len() - 1, String::new());
                    rec.push(p.failure.clone().unwrap_or_default());
                }
            }
            w.write_record(rec).map_err(|e| out_err(path, e))?;
        }
    }
    w.flush().map_err(|e| out_err(path, e))
}
