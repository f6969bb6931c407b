//! `summary.md`: how the report was made, the paper's figures in a table of their own, one table
//! per group, the charts and the files.

use super::{Group, QUICK_STEPS, ReportRun, ReportSummary, controller_name, fmt_f, paper_time};
use crate::run::RunSummary;
use std::fmt::Write as _;
use std::path::PathBuf;

/// The markdown of `summary.md`; `files` are the files written so far, `charts` whether the
/// charts were drawn.
pub(super) fn summary_markdown(s: &ReportSummary, files: &[PathBuf], charts: bool) -> String {
    let mut md = String::new();
    intro(&mut md, s);
    paper_figures(&mut md);
    for g in Group::ALL {
        group_table(&mut md, s, g);
    }
    super::accuracy::markdown(&mut md, &s.accuracy, s.suite.as_deref(), s.quick);
    if charts {
        chart_list(&mut md);
    }
    file_list(&mut md, files);
    md
}

/// The command, the run count, the quick-set warning and how to read the tables.
fn intro(md: &mut String, s: &ReportSummary) {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let _ = writeln!(md, "# Benchmark report\n");
    let _ = writeln!(
        md,
        "Produced by `needle report{}{}` — {} simulation runs, {:.0} s, and the accuracy cost \
         of the gel pipeline on {} scenes, {:.0} s. Every figure in the \
         tables below is measured by that command; **the paper's figures are only in the table \
         \"The paper's figures\"** and are marked as the paper's wherever they appear.\n",
        if s.quick { " --quick" } else { "" },
        match (s.quick, s.steps_cap) {
            (false, Some(c)) => format!(" --steps {c}"),
            _ => String::new(),
        },
        s.runs.len(),
        s.runs.iter().map(|r| r.wall_s).sum::<f64>(),
        s.accuracy.len(),
        s.accuracy.iter().map(|r| r.wall_s).sum::<f64>(),
    );
    let _ = writeln!(md, "{}\n", crate::provenance::Provenance::now().sentence());
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
         run), medians and 99th percentiles over the run's steps, and the mean; CPU per step is \
         the process's CPU time summed over its threads (the background factorisation \
         included) per step; FM free motion, CD proximity, \
         CC compliance, SC the core's constraint solves (the inverse step: 8–13 Gauss-Seidel \
         solves), corr corrective motion. Errors are `|tip − target|` in the deformed gel over \
         the steps with the tip inside the gel. Clearance: the smallest distance from the \
         needle to any obstacle surface over the run (**hit** when negative).\n"
    );
}

/// The paper's figures, in a table of their own.
fn paper_figures(md: &mut String) {
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
}

/// The columns of a group's table after `scene | controller | parameter`.
const COLUMNS: &str = " nodes | steps | completed | e_mean [mm] | e_max [mm] | final [mm] | \
     at puncture [mm] | min clearance [mm] | step median [ms] | step p99 [ms] | step mean [ms] | \
     CPU per step [ms] | FM | CD | CC | SC | corr | GS sweeps |";
/// How many of [`COLUMNS`] there are.
const COLUMN_COUNT: usize = 18;

/// The table of one group (nothing when no run belongs to it), with the notes on the runs that
/// did not complete.
fn group_table(md: &mut String, s: &ReportSummary, g: Group) {
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
        return;
    }
    let mesh = g == Group::Mesh;
    let _ = writeln!(md, "## {}\n", g.title());
    let _ = write!(md, "| scene | controller | parameter |{COLUMNS}");
    if mesh {
        let _ = write!(md, " paper's time/step [ms] |");
    }
    let _ = writeln!(md);
    let _ = writeln!(
        md,
        "|{}",
        "---|".repeat(3 + COLUMN_COUNT + usize::from(mesh))
    );
    let mut notes = Vec::new();
    for (_, r) in rows {
        let _ = write!(
            md,
            "| {} | {} | {} |",
            r.scene,
            controller_name(r.controller),
            r.parameter(g).unwrap_or("")
        );
        match &r.summary {
            Some(sm) => summary_cells(md, r, sm, &mut notes),
            None => {
                let _ = write!(
                    md,
                    " — | 0 | **failed** ({}) |{}",
                    notes.len() + 1,
                    " — |".repeat(COLUMN_COUNT - 3)
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
            let paper = paper_time(r.nodes_target).map_or("—".into(), |t| format!("{t}"));
            let _ = write!(md, " {paper} |");
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
    let _ = writeln!(
        md,
        "e_mean, e_max: over the steps with the tip inside the gel; at puncture: the error of \
         the step that punctured the surface, the tip still on the surface it indented.\n"
    );
    if mesh {
        let _ = writeln!(
            md,
            "FM, CD, CC, SC, corr: stage medians [ms]. The paper's time per step is its \
             figure (SOFA, compliance on a GPU), not a measurement of this code. \n"
        );
    }
}

/// The cells of a run that started; a note when it did not complete.
fn summary_cells(md: &mut String, r: &ReportRun, sm: &RunSummary, notes: &mut Vec<String>) {
    let t = &sm.timing;
    let completed = if sm.completed {
        "yes".to_owned()
    } else {
        format!("**no** ({})", notes.len() + 1)
    };
    let clearance = r.min_clearance().map_or("—".into(), |(c, n)| {
        if c < 0.0 {
            format!("**hit** {c:.2} ({n})")
        } else {
            format!("{c:.2} ({n})")
        }
    });
    let _ = write!(
        md,
        " {} | {}/{} | {completed} | {} | {} | {} | {} | {clearance} |",
        sm.gel_nodes,
        sm.steps,
        sm.steps_planned,
        fmt_f(sm.e_mean_mm, 3),
        fmt_f(sm.e_max_mm, 3),
        fmt_f(sm.e_final_mm, 3),
        fmt_f(sm.e_puncture_mm.unwrap_or(f64::NAN), 3),
    );
    for x in [
        t.total.median_ms,
        t.total.p99_ms,
        t.total.mean_ms,
        sm.cpu_ms_per_step,
        t.fm.median_ms,
        t.cd.median_ms,
        t.cc.median_ms,
        t.sc.median_ms,
        t.correction.median_ms,
    ] {
        let _ = write!(md, " {} |", fmt_f(x, 2));
    }
    let _ = write!(md, " {} |", fmt_f(sm.gs_iterations_mean, 0));
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

/// The charts, with their SVG links and PNG images.
fn chart_list(md: &mut String) {
    let _ = writeln!(md, "## Charts\n");
    let _ = writeln!(
        md,
        "- Tracking error against insertion depth, inverse and naive (the paper's Fig. 7), the \
         paper's e_mean and e_max as dashed lines: \
         [`error_vs_depth.svg`](error_vs_depth.svg)\n\n  ![error against depth](error_vs_depth.png)\n"
    );
    let _ = writeln!(
        md,
        "- Wall time per step per mesh size, the stage means stacked (they add up to the mean \
         step), with the paper's time per step (Fig. 8): \
         [`stage_times.svg`](stage_times.svg)\n\n  ![stage times](stage_times.png)\n"
    );
    let _ = writeln!(
        md,
        "- Speed against error: CPU time per step (all threads) against e_mean, every run a \
         point labelled with its mesh size and setting, the paper's points and e_mean as \
         references; the complex path's runs enlarged below: \
         [`speed_vs_error.svg`](speed_vs_error.svg)\n\n  ![speed against error](speed_vs_error.png)\n"
    );
}

/// The data files.
fn file_list(md: &mut String, files: &[PathBuf]) {
    let _ = writeln!(md, "## Files\n");
    for f in files {
        if let Some(n) = f.file_name() {
            let n = n.to_string_lossy();
            let what = match n.as_ref() {
                "runs.csv" => {
                    "one row per run: parameters, errors, clearances, tissue shift, stage times"
                }
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
}
