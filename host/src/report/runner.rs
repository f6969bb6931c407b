//! Running the planned simulations one after the other, with a progress bar; a run that breaks
//! down, fails to start or panics is recorded, never aborts the report.

use super::ReportRun;
use crate::run::{RunOptions, planned_steps, run};
use crate::scene::Scene;
use indicatif::{ProgressBar, ProgressStyle};
use std::time::Instant;

/// Runs every planned run (at most `steps_cap` steps each), filling its summary or failure.
pub(super) fn run_all(
    runs: &mut [(ReportRun, Scene)],
    steps_cap: Option<usize>,
    bar: &ProgressBar,
    progress: bool,
) {
    let total = runs.len();
    for (r, scene) in runs.iter_mut() {
        let what = format!("{} · {}", r.label(), parameters(r));
        run_one(r, scene, steps_cap, bar, &what);
        let line = format!("[{}/{total}] {what}: {}", r.id + 1, outcome(r));
        print_line(bar, progress, line);
        bar.inc(1);
    }
}

/// The report's progress bar over `len` items (hidden without `progress`).
pub(super) fn progress_bar(len: usize, progress: bool) -> ProgressBar {
    let bar = if progress {
        ProgressBar::new(len as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len}  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// A line on a finished item: above the bar, or on stderr when the bar is hidden because
/// stderr is not a terminal (a CI log); nothing without `progress`.
pub(super) fn print_line(bar: &ProgressBar, progress: bool, line: String) {
    if bar.is_hidden() {
        if progress {
            eprintln!("{line}");
        }
    } else {
        bar.println(line);
    }
}

/// The run's distinct parameters, `a / b`.
fn parameters(r: &ReportRun) -> String {
    let mut v: Vec<&str> = Vec::new();
    for m in &r.memberships {
        if !v.contains(&m.parameter.as_str()) {
            v.push(&m.parameter);
        }
    }
    v.join(" / ")
}

/// One run: its summary and error by depth, or why it failed.
fn run_one(
    r: &mut ReportRun,
    scene: &Scene,
    steps_cap: Option<usize>,
    bar: &ProgressBar,
    what: &str,
) {
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
        Err(p) => r.failure = Some(format!("panicked: {}", panic_text(&*p))),
    }
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

/// The text of a panic's payload.
pub(super) fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
