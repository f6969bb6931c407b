//! The public suite (`needle suite`): the two benchmark scenes and every scene file of a folder
//! (`scenes/suite/` by default), each run to the end with one configuration (the scenes' own
//! settings and the same overrides for all) under each controller compared (by default this
//! project's joint update and the paper's, [`Variant`]), and what issue "controller" measures of each —
//! outcome, e_mean, e_max, e_final, path deviation, min clearance, the tissue's shift at the
//! target and the entry, steps to the target against
//! the nominal steps, Gauss-Seidel cap hits, CPU and wall time per step — in `suite.md`,
//! `suite.csv` and `suite.json`, with the worst case over all scenes against the targets, and a
//! chart of the errors per scene (`suite.svg`, `suite.png`).
//!
//! A scene that cannot be loaded or set up, or whose run fails or panics, is recorded with its
//! reason and never stops the suite.

// Units are written in brackets ([mm], [s]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

#[cfg(feature = "charts")]
mod chart;
pub mod compare;

use crate::output::OutputError;
use crate::run::{Outcome, RunOptions, RunSummary, run};
use crate::scene::Scene;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `needle suite` runs and where it writes.
#[derive(Clone, Debug)]
pub struct SuiteOptions {
    /// The folder of scene files (`*.toml`, in name order).
    pub dir: PathBuf,
    /// Also run the embedded benchmark scenes `simple` and `complex` (first).
    pub benchmarks: bool,
    /// Overrides applied to every scene (`("inverse.delta_q", "0.001")`).
    pub overrides: Vec<(String, String)>,
    /// Nodes of every generated box gel (`gel.box.nodes`, set before `overrides`); gels read
    /// from mesh files keep their own. `None`: each scene's own.
    pub nodes: Option<usize>,
    /// Cap on the steps of every run (default: the whole path).
    pub steps: Option<usize>,
    /// The controllers compared, each on every scene; the first one's outcomes make the exit
    /// code.
    pub variants: Vec<Variant>,
}

/// A controller of the comparison: a name and the overrides that select it (applied after
/// [`SuiteOptions::overrides`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Variant {
    /// Its name in the tables.
    pub name: String,
    /// The scene fields that make it.
    pub overrides: Vec<(String, String)>,
}

impl Variant {
    /// The named controllers: `default` (the scenes' own settings: the QP update) and `paper`
    /// (`inverse.method = "paper"`, the paper's update).
    pub fn named(name: &str) -> Option<Self> {
        let overrides = match name {
            "default" => Vec::new(),
            "paper" => vec![("inverse.method".to_owned(), "\"paper\"".to_owned())],
            _ => return None,
        };
        Some(Self {
            name: name.to_owned(),
            overrides,
        })
    }
}

/// One scene of the suite: its summary, or why it has none.
#[derive(Clone, Debug, Serialize)]
pub struct SuiteRow {
    /// The scene's name (its file stem, or the embedded scene's name).
    pub scene: String,
    /// The controller's name ([`Variant::name`]).
    pub controller: String,
    /// The run's summary.
    pub summary: Option<RunSummary>,
    /// Why the scene could not be loaded, set up or run.
    pub failure: Option<String>,
    /// Wall time of the whole run, set-up included [s].
    pub wall_s: f64,
}

/// The scenes of `opts`: the benchmarks, then the folder's files in name order.
///
/// # Errors
/// An I/O error when the folder cannot be listed.
pub fn scene_list(opts: &SuiteOptions) -> std::io::Result<Vec<(String, Option<PathBuf>)>> {
    let mut out: Vec<(String, Option<PathBuf>)> = Vec::new();
    if opts.benchmarks {
        out.extend(["simple", "complex"].map(|s| (s.to_owned(), None)));
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(&opts.dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    for f in files {
        let name = f
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        out.push((name, Some(f)));
    }
    Ok(out)
}

/// The overrides of one scene under `variant`: the box gel's nodes ([`SuiteOptions::nodes`],
/// when the scene generates a box), then [`SuiteOptions::overrides`], then the variant's.
pub fn scene_overrides(
    scene: &Scene,
    opts: &SuiteOptions,
    variant: &Variant,
) -> Vec<(String, String)> {
    let nodes = opts
        .nodes
        .filter(|_| scene.gel.box_mesh.is_some())
        .map(|n| ("gel.box.nodes".to_owned(), n.to_string()));
    (nodes.into_iter())
        .chain(opts.overrides.iter().cloned())
        .chain(variant.overrides.iter().cloned())
        .collect()
}

/// A scene of [`scene_list`]: the file, or (`file` none) the embedded scene `name`; the error as
/// text.
///
/// # Errors
/// The file's [`crate::scene::SceneError`], or no embedded scene of that name.
pub fn load_scene(name: &str, file: Option<&Path>) -> Result<Scene, String> {
    match file {
        Some(f) => Scene::load(f).map_err(|e| e.to_string()),
        None => Scene::builtin(name).ok_or_else(|| format!("no embedded scene `{name}`")),
    }
}

/// Runs one scene of the suite (`file` none: the embedded scene `name`) with the controller
/// `variant`; `observe` sees every step.
pub fn run_scene(
    name: &str,
    file: Option<&Path>,
    opts: &SuiteOptions,
    variant: &Variant,
    mut observe: impl FnMut(usize),
) -> SuiteRow {
    let t0 = Instant::now();
    let result = load_scene(name, file)
        .and_then(|s| {
            s.with_overrides(&scene_overrides(&s, opts, variant))
                .map_err(|e| e.to_string())
        })
        .and_then(|scene| {
            let ropts = RunOptions {
                steps: opts.steps,
                vtk_every: Some(0),
                ..RunOptions::default()
            };
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                run(&scene, &ropts, |r| observe(r.step))
            }))
            .map_err(|_| "the run panicked".to_owned())?
            .map_err(|e| crate::error::chain(&e))
        });
    let (summary, failure) = match result {
        Ok(r) => (Some(r.summary), None),
        Err(e) => (None, Some(e)),
    };
    SuiteRow {
        scene: name.to_owned(),
        controller: variant.name.clone(),
        summary,
        failure,
        wall_s: t0.elapsed().as_secs_f64(),
    }
}

/// The suite's exit code, from the first controller's rows (the comparison's others are
/// reported, not judged): 1 when a scene could not be run, else the worst outcome's
/// ([`Outcome::exit_code`]: diverged 3, obstacle hit 5, missed 4, reached off the path 6, all
/// reached 0).
pub fn exit_code(rows: &[SuiteRow]) -> u8 {
    let first = rows.first().map(|r| r.controller.clone());
    let rows: Vec<&SuiteRow> = rows
        .iter()
        .filter(|r| Some(&r.controller) == first.as_ref())
        .collect();
    if rows.iter().any(|r| r.summary.is_none()) {
        return 1;
    }
    let has = |o: Outcome| rows.iter().flat_map(|r| &r.summary).any(|s| s.outcome == o);
    [
        Outcome::Diverged,
        Outcome::ObstacleHit,
        Outcome::MissedTarget,
        Outcome::LeftPath,
    ]
    .into_iter()
    .find(|o| has(*o))
    .map_or(0, Outcome::exit_code)
}

/// Steps to the target over the nominal steps (none when never reached).
fn steps_ratio(s: &RunSummary) -> Option<f64> {
    s.steps_to_target
        .map(|k| k as f64 / s.steps_nominal.max(1) as f64)
}

fn cell(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else if v == f64::INFINITY {
        "∞".to_owned()
    } else {
        "—".to_owned()
    }
}

/// The worst case over the rows that ran, with the targets ("must"): e_mean ≤ 1.0,
/// e_max ≤ 3.0, e_final ≤ 1.0 mm, clearance > 0, steps ≤ 1.2 × nominal, no GS cap hit.
fn worst_lines(rows: &[SuiteRow]) -> Vec<String> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.controller.as_str()) {
            names.push(&r.controller);
        }
    }
    names
        .iter()
        .flat_map(|name| {
            let mine: Vec<&SuiteRow> = rows.iter().filter(|r| r.controller == *name).collect();
            worst_of(&mine)
                .into_iter()
                .map(move |line| format!("{name}: {line}"))
        })
        .collect()
}

/// [`worst_lines`] of one controller's rows.
fn worst_of(rows: &[&SuiteRow]) -> Vec<String> {
    let s: Vec<&RunSummary> = rows.iter().flat_map(|r| &r.summary).collect();
    let worst = |f: fn(&RunSummary) -> f64| s.iter().map(|x| f(x)).fold(f64::NAN, f64::max);
    let reached = s.iter().filter(|x| x.outcome == Outcome::Reached).count();
    let never = s.iter().filter(|x| x.steps_to_target.is_none()).count();
    let ratio = s
        .iter()
        .filter_map(|x| steps_ratio(x))
        .fold(f64::NAN, f64::max);
    vec![
        format!(
            "scenes run: {} of {}; reached: {reached}",
            s.len(),
            rows.len()
        ),
        format!(
            "worst e_mean {} mm (must ≤ 1.0), e_max {} mm (≤ 3.0), e_final {} mm (≤ 1.0)",
            cell(worst(|x| x.e_mean_mm), 3),
            cell(worst(|x| x.e_max_mm), 3),
            cell(worst(|x| x.e_final_mm), 3)
        ),
        format!(
            "smallest clearance {} mm (must > 0); steps to the target at most {} × nominal \
             (≤ 1.2), {never} runs never within 1 mm of the end; Gauss-Seidel cap hits {} (must 0)",
            cell(
                s.iter()
                    .map(|x| x.min_clearance_mm)
                    .fold(f64::INFINITY, f64::min),
                3
            ),
            cell(ratio, 2),
            s.iter().map(|x| x.gs_not_converged_steps).sum::<usize>()
        ),
    ]
}

const HEADER: [&str; 21] = [
    "scene",
    "controller",
    "outcome",
    "e_mean_mm",
    "e_max_mm",
    "e_final_mm",
    "e_puncture_mm",
    "path_dev_mean_mm",
    "path_dev_max_mm",
    "min_clearance_mm",
    "target_shift_mm",
    "entry_shift_mm",
    "needle_strain_pct",
    "steps_to_target",
    "steps_nominal",
    "gs_cap_hits",
    "cpu_ms_per_step",
    "wall_ms_per_step",
    "steering_length_mm",
    "qp_horizon_mm",
    "straighten",
];

/// The cells of one row, in [`HEADER`]'s order.
fn cells(r: &SuiteRow) -> Vec<String> {
    let Some(s) = &r.summary else {
        let mut v = vec![r.scene.clone(), r.controller.clone(), "failed".to_owned()];
        v.resize(HEADER.len(), String::new());
        return v;
    };
    vec![
        r.scene.clone(),
        r.controller.clone(),
        s.outcome.name().to_owned(),
        cell(s.e_mean_mm, 3),
        cell(s.e_max_mm, 3),
        cell(s.e_final_mm, 3),
        cell(s.e_puncture_mm.unwrap_or(f64::NAN), 3),
        cell(s.path_deviation_mean_mm, 3),
        cell(s.path_deviation_max_mm, 3),
        cell(s.min_clearance_mm, 3),
        cell(s.target_shift_max_mm, 2),
        cell(s.entry_shift_max_mm, 2),
        cell(100.0 * s.needle_strain_max, 2),
        s.steps_to_target.map_or("—".to_owned(), |k| k.to_string()),
        s.steps_nominal.to_string(),
        s.gs_not_converged_steps.to_string(),
        cell(s.cpu_ms_per_step, 2),
        cell(s.timing.total.mean_ms, 2),
        cell(s.steering_length_mm, 1),
        cell(s.qp_horizon_mm, 1),
        cell(s.straighten, 2),
    ]
}

/// The suite's table in Markdown, with the worst case and the failures.
pub fn markdown(rows: &[SuiteRow], overrides: &[(String, String)]) -> String {
    let mut md = String::from("# The public suite\n\n");
    let set: Vec<String> = overrides
        .iter()
        .map(|(k, v)| format!("`{k}={v}`"))
        .collect();
    let _ = writeln!(
        md,
        "One configuration for every scene: the scenes' own settings{}. Written by `needle \
         suite`, every scene under each controller compared (`default`: the scenes' own \
         settings; `paper`: the paper's joint update, `inverse.method = \"paper\"`). Errors in \
         mm; steps to the target: the step at which the tip was within 1 mm of the path's end \
         (as in `needle run`); CPU per step summed over threads.\n",
        if set.is_empty() {
            String::new()
        } else {
            format!(", with {}", set.join(", "))
        }
    );
    let _ = writeln!(md, "{}\n", crate::provenance::Provenance::now().sentence());
    let _ = writeln!(md, "| {} |", HEADER.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(HEADER.len()));
    for r in rows {
        let _ = writeln!(md, "| {} |", cells(r).join(" | "));
    }
    md.push('\n');
    for line in worst_lines(rows) {
        let _ = writeln!(md, "- {line}");
    }
    for r in rows {
        if let Some(why) = &r.failure {
            let _ = writeln!(md, "- `{}` ({}) failed: {why}", r.scene, r.controller);
        }
        if let Some(why) = r.summary.as_ref().and_then(|s| s.stopped.as_ref()) {
            let _ = writeln!(md, "- `{}` ({}) stopped: {why}", r.scene, r.controller);
        }
        for a in r.summary.iter().flat_map(|s| &s.advisories) {
            let _ = writeln!(md, "- `{}` ({}) advisory: {a}", r.scene, r.controller);
        }
    }
    md
}

/// Writes `suite.md`, `suite.csv`, `suite.json` and (with the `charts` feature) the chart
/// `suite.svg` / `suite.png` into `dir`.
///
/// # Errors
/// [`OutputError`] naming the file.
pub fn write_outputs(
    rows: &[SuiteRow],
    overrides: &[(String, String)],
    dir: &Path,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(|e| OutputError::new(dir, e))?;
    let md = dir.join("suite.md");
    std::fs::write(&md, markdown(rows, overrides)).map_err(|e| OutputError::new(&md, e))?;
    let csv_path = dir.join("suite.csv");
    let mut w = csv::Writer::from_path(&csv_path).map_err(|e| OutputError::new(&csv_path, e))?;
    w.write_record(HEADER)
        .map_err(|e| OutputError::new(&csv_path, e))?;
    for r in rows {
        w.write_record(cells(r))
            .map_err(|e| OutputError::new(&csv_path, e))?;
    }
    w.flush().map_err(|e| OutputError::new(&csv_path, e))?;
    let json = dir.join("suite.json");
    let text = serde_json::to_string_pretty(rows).map_err(|e| OutputError::new(&json, e))?;
    std::fs::write(&json, text).map_err(|e| OutputError::new(&json, e))?;
    #[cfg(feature = "charts")]
    chart::write_chart(rows, dir)?;
    Ok(())
}

/// The worst case over the suite, one line each (for the terminal).
pub fn worst_case(rows: &[SuiteRow]) -> Vec<String> {
    worst_lines(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `needle suite --nodes N` resizes generated box gels and leaves gels from mesh files
    /// alone; the other overrides and the controller's come after it.
    #[test]
    fn nodes_resize_box_gels_only() {
        let opts = SuiteOptions {
            dir: PathBuf::from("scenes/suite"),
            benchmarks: true,
            overrides: vec![("solver.near_radius".into(), "\"off\"".into())],
            nodes: Some(5000),
            steps: None,
            variants: Vec::new(),
        };
        let paper = Variant::named("paper").unwrap();
        let boxed = Scene::builtin("complex").unwrap();
        let o = scene_overrides(&boxed, &opts, &paper);
        assert_eq!(o[0], ("gel.box.nodes".to_owned(), "5000".to_owned()));
        assert_eq!(o[1].0, "solver.near_radius");
        assert_eq!(&o[2..], &paper.overrides[..]);
        let resized = boxed.with_overrides(&o).unwrap();
        assert_eq!(resized.gel.box_mesh.unwrap().nodes, 5000);
        let from_file = Scene::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../scenes/suite/gmsh_box.toml"
        )))
        .unwrap();
        let o = scene_overrides(&from_file, &opts, &paper);
        assert!(o.iter().all(|(k, _)| k != "gel.box.nodes"), "{o:?}");
        assert!(from_file.with_overrides(&o).is_ok());
    }
}
