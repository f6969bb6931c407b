//! `needle`: run an insertion, print its summary, write its outputs.
//!
//! ```sh
//! needle run                      # the embedded complex benchmark scene, inverse controller
//! needle run scenes/simple.toml --controller naive --out out/simple-naive
//! needle serve complex            # host process; the core runs in `needle-controller complex`
//! needle report --out report      # the benchmark report: every scene, controller and sweep
//! ```

use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use needle_bridge::{BridgeConfig, SharedMemoryHost, setup_fingerprint};
use needle_host::error::{SetupError, chain};
use needle_host::joints::{WithJoints, with_joints};
use needle_host::report::{ReportOptions, report};
use needle_host::run::{
    ControllerKind, RunError, RunOptions, RunResult, RunSummary, StageTiming, planned_steps, run,
    run_with,
};
use needle_host::scene::{MAX_STEPS, Scene};
use needle_host::setup;
use needle_host::step::{ROWS, StepReport};
use needle_host::suite::{self, SuiteOptions};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "needle",
    version,
    about = "Inverse real-time FE control of robotic needle insertion"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log lines on stderr (-v: set-up and run ends, -vv: debug, -vvv: trace); `RUST_LOG`
    /// (e.g. `RUST_LOG=needle_host=debug`) overrides both flags.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Only errors in the log (no warnings such as holds).
    #[arg(short = 'q', long = "log-quiet", global = true)]
    log_quiet: bool,
}

/// The log on stderr through `tracing`: warnings by default, more with `-v`, errors only with
/// `-q`, or what `RUST_LOG` says.
fn init_logs(verbose: u8, quiet: bool) {
    let level = match (quiet, verbose) {
        (true, _) => "error",
        (false, 0) => "warn",
        (false, 1) => "info",
        (false, 2) => "debug",
        _ => "trace",
    };
    needle_host::logs::init(level);
}

#[derive(Subcommand)]
enum Command {
    /// Run one insertion and print its summary (error, clearances, stage times).
    Run(RunArgs),
    /// Host process of a two-process run: publishes each step's compliance frame over iceoryx2
    /// shared memory and applies the command of `needle-controller` (run it with the same scene).
    Serve(ServeArgs),
    /// The public suite: the two benchmark scenes and every scene of a folder, run with one
    /// configuration under this project's controller and the paper's; writes suite.md,
    /// suite.csv, suite.json and a chart (exit, from the first controller: 0 all reached, 4 a
    /// scene missed its target, 5 an obstacle hit, 3 a run diverged, 1 a scene could not run).
    Suite(SuiteArgs),
    /// Two runs of the suite scene by scene (the `suite.json` of two `needle suite` runs, e.g.
    /// before and after a change of configuration): targets gained and lost, scenes moved by
    /// more than a tolerance on e_mean, e_max, e_final or smallest clearance, scenes that came
    /// closer to an obstacle, scenes equal in every compared field, and each run's means and
    /// worst cases (exit 4 with `--fail-on-loss` when a target was
    /// lost, 2 when a file cannot be compared).
    Compare(CompareArgs),
    /// The benchmark report: both scenes under both controllers plus the mesh, δq, blend
    /// distance and constraint-spacing sweeps; writes summary.md, CSVs and SVG/PNG charts.
    Report {
        /// Output folder (created if missing).
        #[arg(long, default_value = "report")]
        out: PathBuf,
        /// The reduced set: 600-node meshes, one point per sweep, at most 250 steps per run.
        #[arg(long)]
        quick: bool,
        /// Cap on the steps of every run (default: the whole path; 250 with --quick).
        #[arg(long, value_parser = steps_arg)]
        steps: Option<usize>,
        /// No progress on stderr.
        #[arg(long)]
        quiet: bool,
        /// The scene folder whose scenes the accuracy-cost section measures beside the
        /// benchmarks [default: scenes/suite when it exists, else the benchmarks only; the
        /// quick set: the benchmarks only].
        #[arg(long, value_name = "DIR")]
        suite: Option<PathBuf>,
    },
}

/// A step count: from 1 to the scenes' own limit ([`MAX_STEPS`]).
fn steps_arg(text: &str) -> Result<usize, String> {
    let n: usize = text
        .parse()
        .map_err(|e| format!("`{text}` is not a step count: {e}"))?;
    if (1..=MAX_STEPS).contains(&n) {
        Ok(n)
    } else {
        Err(format!("must be between 1 and {MAX_STEPS} (got {n})"))
    }
}

/// The scene of a run and its overrides.
#[derive(Args)]
struct SceneArgs {
    /// A scene file, or the name of an embedded scene (`simple`, `complex`).
    #[arg(default_value = "complex")]
    scene: String,
    /// Gel mesh size (overrides the scene's box node count).
    #[arg(long)]
    nodes: Option<usize>,
    /// Override a scene field, e.g. `--set inverse.delta_q=0.001` or
    /// `--set 'inverse.jacobian="solve"'` (repeatable; the value is TOML).
    #[arg(long = "set", value_name = "FIELD=VALUE")]
    set: Vec<String>,
}

/// What a run writes and prints.
#[derive(Args)]
struct OutputArgs {
    /// Output folder (steps.csv, summary.json, VTK files); none: print only.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Number of steps (default: to the end of the path; at most 10 000 000).
    #[arg(long, value_parser = steps_arg)]
    steps: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct RunArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Controller driving the robot.
    #[arg(long, value_enum, default_value_t = Ctl::Inverse)]
    controller: Ctl,
    /// Write ParaView files (.vtu frames, .pvd collections) every N steps and at the end
    /// (needs --out; default: the scene's `output.vtk_every`).
    #[arg(long)]
    vtk_every: Option<usize>,
    #[command(flatten)]
    output: OutputArgs,
}

#[derive(Args)]
struct SuiteArgs {
    /// Folder of scene files (`*.toml`).
    #[arg(long, default_value = "scenes/suite")]
    dir: PathBuf,
    /// Output folder (created if missing).
    #[arg(long, default_value = "suite")]
    out: PathBuf,
    /// Only the folder's scenes, without the two benchmark scenes.
    #[arg(long)]
    no_benchmarks: bool,
    /// The controllers compared on every scene, comma-separated: `default` (the scenes' own
    /// settings) and `paper` (the paper's joint update); the first one's outcomes make the
    /// exit code.
    #[arg(long, value_delimiter = ',', default_value = "default,paper")]
    controllers: Vec<String>,
    /// Override a field of every scene (repeatable; the value is TOML).
    #[arg(long = "set", value_name = "FIELD=VALUE")]
    set: Vec<String>,
    /// Nodes of every generated box gel (`gel.box.nodes`, e.g. 5000 for the suite on larger
    /// gels); gels read from mesh files keep their own.
    #[arg(long)]
    nodes: Option<usize>,
    /// Cap on the steps of every run (default: the whole path).
    #[arg(long, value_parser = steps_arg)]
    steps: Option<usize>,
    /// No progress on stderr.
    #[arg(long)]
    quiet: bool,
}

#[derive(Args)]
struct CompareArgs {
    /// The first run's `suite.json` (or its output folder).
    before: PathBuf,
    /// The second run's `suite.json` (or its output folder).
    after: PathBuf,
    /// The controller compared (the suite's `--controllers` name).
    #[arg(long, default_value = "default")]
    controller: String,
    /// A scene moves when e_mean, e_max, e_final or its smallest clearance changes by more than
    /// this [mm].
    #[arg(long, default_value_t = 0.05)]
    tolerance: f64,
    /// Exit 4 when a scene that reached its target before does not after.
    #[arg(long)]
    fail_on_loss: bool,
}

#[derive(Args)]
struct ServeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Service-name prefix shared with `needle-controller --instance`.
    #[arg(long, default_value = "needle")]
    instance: String,
    /// Hold the insertion when no command answered the frame within this long [ms].
    #[arg(long, default_value_t = 50.0)]
    deadline_ms: f64,
    /// Free-running: start a step at most every this many ms (default: lock-step, as fast
    /// as the commands come).
    #[arg(long)]
    period_ms: Option<f64>,
    /// Stop when no command came for this many seconds (default: hold for ever).
    #[arg(long)]
    give_up_s: Option<f64>,
    #[command(flatten)]
    output: OutputArgs,
}

#[derive(Clone, Copy, ValueEnum)]
enum Ctl {
    /// The inverse FE controller (the paper's method).
    Inverse,
    /// A rigid needle in a rigid gel following the rest path by IK, replayed in the FE simulation.
    Naive,
}

/// Applies `--nodes` and `--set FIELD=VALUE` overrides to a scene (validated again).
fn customize(scene: Scene, nodes: Option<usize>, set: &[String]) -> Result<Scene, String> {
    let mut overrides = Vec::new();
    if let Some(n) = nodes {
        if scene.gel.box_mesh.is_none() {
            return Err("--nodes needs a scene with a generated `gel.box` mesh".into());
        }
        overrides.push(("gel.box.nodes".to_owned(), n.to_string()));
    }
    for kv in set {
        let (k, v) = kv.split_once('=').ok_or_else(|| {
            format!("--set `{kv}`: expected FIELD=VALUE, e.g. inverse.delta_q=0.001")
        })?;
        overrides.push((k.trim().to_owned(), v.trim().to_owned()));
    }
    if overrides.is_empty() {
        return Ok(scene);
    }
    scene.with_overrides(&overrides).map_err(|e| e.to_string())
}

/// The scene of the arguments, or the exit code of a usage error (printed).
fn scene_of(a: &SceneArgs) -> Result<Scene, ExitCode> {
    Scene::open(&a.scene)
        .map_err(|e| e.to_string())
        .and_then(|s| customize(s, a.nodes, &a.set))
        .map_err(|e| {
            eprintln!("error: {e}");
            ExitCode::from(2)
        })
}

/// Runs `f` with a progress bar over the steps of `scene` (hidden with `quiet`) as its
/// observer.
fn with_progress<R>(
    scene: &Scene,
    out: &OutputArgs,
    f: impl FnOnce(&mut dyn FnMut(&StepReport)) -> R,
) -> R {
    let total = out.steps.unwrap_or_else(|| planned_steps(scene)) as u64;
    // A spinner while the scene is set up (a large mesh takes a while), then the step bar.
    let bar = if out.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new_spinner()
    };
    bar.set_message("setting up: mesh, FE models, first factorisation");
    bar.enable_steady_tick(Duration::from_millis(200));
    let mut stepping = false;
    let result = f(&mut |r: &StepReport| {
        if !stepping {
            stepping = true;
            bar.disable_steady_tick();
            bar.set_length(total);
            bar.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {pos}/{len} steps  {msg}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
        }
        bar.set_position(r.step as u64 + 1);
        bar.set_message(format!(
            "depth {:5.1} mm  error {:6.3} mm",
            r.depth, r.error
        ));
    });
    bar.finish_and_clear();
    result
}

/// A length with 3 decimals, or `—` when there is none (NaN: the tip never entered the gel).
fn mm3(v: f64) -> String {
    if v.is_nan() {
        "—".to_owned()
    } else {
        format!("{v:.3}")
    }
}

/// Prints the summary of a run (exit code by its outcome: 0 reached, 3 stopped early, 4 missed
/// the target, 5 hit an obstacle; README "Exit codes") or its error (1).
fn finish(result: Result<RunResult, RunError>, json: bool) -> ExitCode {
    match result {
        Ok(r) => print_summary(&r.summary, json),
        Err(e) => {
            eprintln!("error: {}", chain(&e));
            ExitCode::FAILURE
        }
    }
}

fn print_summary(s: &RunSummary, json: bool) -> ExitCode {
    if json {
        match serde_json::to_string_pretty(s) {
            Ok(t) => println!("{t}"),
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::FAILURE;
            }
        }
    } else {
        print_text(s);
    }
    if s.holds > 0 {
        println!(
            "held the insertion {} time(s), {:.0} ms in total (no command within the deadline)",
            s.holds, s.held_ms
        );
    }
    if s.period_overruns > 0 {
        println!(
            "{} step(s) started late: the step before took longer than the period (up to {:.0} ms late; a step that waits for the gel's background factor does not with `solver.asynchronous_factor = true`)",
            s.period_overruns, s.period_overrun_max_ms
        );
    }
    ExitCode::from(s.outcome.exit_code())
}

fn print_text(s: &RunSummary) {
    println!(
        "scene {} · controller {:?} · {} gel nodes · needle steering length {:.1} mm · tip horizon {:.1} mm",
        s.scene, s.controller, s.gel_nodes, s.steering_length_mm, s.qp_horizon_mm
    );
    for a in &s.advisories {
        println!("advisory: {a}");
    }
    if s.straighten > 0.0 {
        let lowest = if s.straighten_lowest < s.straighten {
            format!(
                ", down to {:.0} % where an obstacle or the {} mm bound on its offset from the path limits it",
                100.0 * s.straighten_lowest,
                s.straighten_max_offset_mm
            )
        } else {
            String::new()
        };
        println!(
            "the target shown to the controller is straightened {:.0} % of the way towards the \
             path's chord from {:.1} mm past the entry point{lowest} (inverse.straighten, \
             inverse.straighten_from, inverse.straighten_max_offset); errors are measured against the planned path",
            100.0 * s.straighten,
            s.straighten_from_mm
        );
    }
    if s.target_standoff_mm > 0.0 {
        println!(
            "the target shown to the controller keeps {} mm from every obstacle where the path \
             passes nearer, within {} mm of the path (inverse.target_standoff, \
             inverse.straighten_max_offset)",
            s.target_standoff_mm, s.straighten_max_offset_mm
        );
    }
    if let Some(m) = &s.support_motion {
        println!("support motion: {m}");
    }
    println!(
        "steps {}/{}{}{}",
        s.steps,
        s.steps_planned,
        if s.steps > s.steps_planned {
            format!(
                " (+{} settling: the target held at the path's end)",
                s.steps - s.steps_planned
            )
        } else {
            String::new()
        },
        match &s.stopped {
            Some(r) => format!(" — stopped: {r}"),
            None => String::new(),
        }
    );
    println!(
        "tracking error inside the gel: mean {} mm, max {} mm, final (to the path's end) {:.3} mm (depth {:.1} mm, puncture at step {}{})",
        mm3(s.e_mean_mm),
        mm3(s.e_max_mm),
        s.e_final_mm,
        s.final_depth_mm,
        s.puncture_step.map_or("—".to_string(), |k| k.to_string()),
        s.e_puncture_mm.map_or(String::new(), |e| format!(
            ", {e:.3} mm from its target on the indented surface"
        ))
    );
    println!(
        "outcome: {} · distance to the path's end {:.3} mm (last step's error {:.3} mm) · reached within 1 mm at step {} of {} nominal · path deviation mean {} mm, max {} mm",
        s.outcome.name(),
        s.e_final_mm,
        s.e_last_mm,
        s.steps_to_target.map_or("—".to_string(), |k| k.to_string()),
        s.steps_nominal,
        mm3(s.path_deviation_mean_mm),
        mm3(s.path_deviation_max_mm),
    );
    if let Some(k) = s.tip_slid_step {
        println!(
            "before puncture the tip slid off its target on the surface at step {k}: from then until it punctured, the heading shown to the controller was held within inverse.entry_tilt of the surface's normal"
        );
    }
    if s.puncture_step.is_some() {
        println!(
            "tissue moved by the insertion (largest, the support's motion taken out): the target {:.3} mm, the entry point {:.3} mm",
            s.target_shift_max_mm, s.entry_shift_max_mm
        );
    }
    if s.outcome == needle_host::run::Outcome::LeftPath {
        println!(
            "the tip reached the path's end but went {:.3} mm from the path on the way (more than {} mm): the target was reached off the planned route",
            s.path_deviation_max_mm,
            needle_host::run::metrics::PATH_TOLERANCE_MM
        );
    }
    if s.withdrawals > 0 {
        println!(
            "the needle left the gel {} time(s) after puncturing it (on an insertion, not a \
             back-and-forth schedule, such a run is not counted as reached)",
            s.withdrawals
        );
    }
    for c in &s.clearances {
        println!(
            "clearance to {}: {:.3} mm{}",
            c.name,
            c.min_mm,
            if c.min_mm < 0.0 { "  (HIT)" } else { "" }
        );
    }
    print_timing(&s.timing, s.cpu_ms_per_step);
    println!(
        "Gauss-Seidel sweeps per step: mean {:.1}, max {} ({} steps hit the cap)",
        s.gs_iterations_mean, s.gs_iterations_max, s.gs_not_converged_steps
    );
    println!(
        "gel: largest principal strain {:.1} %, at most {} inverted elements",
        100.0 * s.max_strain,
        s.max_inverted_elements
    );
    let (from_tip, depth) = (s.needle_strain_from_tip_mm, s.needle_strain_tip_depth_mm);
    let bend_at = if s.needle_strain_max > 0.0 {
        format!(
            ", {from_tip:.1} mm from its tip with the tip {depth:.1} mm deep ({})",
            if from_tip < depth {
                "in the gel"
            } else {
                "outside the gel"
            }
        )
    } else {
        String::new()
    };
    let bound = if s.needle_strain_bounded {
        " under the controller's bound (inverse.bound_strain)"
    } else {
        ""
    };
    let yield_note = match s.needle_yield_strain {
        Some(y) if s.needle_yielded => format!(
            ": past its yield strain {:.2} % (needle.yield_strain) after {} of its steps{bound}, \
             a bend a real needle would keep",
            100.0 * y,
            s.needle_yield_steps
        ),
        Some(y) => format!(", within its yield strain {:.2} %{bound}", 100.0 * y),
        None => {
            " (its model is linear elastic: compare with its material's yield strain, σ_y / E, \
                 or give it as needle.yield_strain)"
                .to_owned()
        }
    };
    println!(
        "needle: largest bending strain {:.2} % at its surface{bend_at}{yield_note}",
        100.0 * s.needle_strain_max
    );
    if s.background_factorizations + s.immediate_factorizations > 0 {
        let near = if s.near_factorizations > 0 {
            format!(
                ", {} of the near block alone, {} of its entry block alone; {} free motions \
                 with the far residual dropped; {} steps whose far rows could not wait",
                s.near_factorizations,
                s.entry_factorizations,
                s.far_residual_drops,
                s.deferral_fallbacks
            )
        } else {
            String::new()
        };
        println!(
            "gel factorisations: {} on the background thread, {} at once{near}",
            s.background_factorizations, s.immediate_factorizations
        );
    }
    if s.precision_fallbacks > 0 {
        println!(
            "gel factor: {} single-precision factorisation(s) failed the probe check and were redone in double (double from then on)",
            s.precision_fallbacks
        );
    }
    if s.pcg_iterations_max > 0 {
        println!(
            "gel CG iterations per step: mean {:.2}, max {} ({} steps did not converge: factorised at once with \"pcg\", the factor's step kept with \"refine\")",
            s.pcg_iterations_mean, s.pcg_iterations_max, s.pcg_fallbacks
        );
    }
    if let Some(j) = s.limit_margin_joint
        && s.limit_margin_min.is_finite()
    {
        println!(
            "joints ({}): closest to a limit joint {j}, at {:.1} % of its half range from it{}",
            s.joints,
            100.0 * s.limit_margin_min,
            if s.joints > 6 {
                " (the redundant joint kept away from the limits in the null space)"
            } else {
                ""
            }
        );
    }
    if s.unreachable_steps + s.limit_steps + s.shortened_steps > 0 {
        println!(
            "target unreachable in {} steps, a joint at its limit in {} steps, \
             the planned update shortened in {} steps",
            s.unreachable_steps, s.limit_steps, s.shortened_steps
        );
    }
}

fn print_timing(t: &StageTiming, cpu_ms: f64) {
    println!(
        "time per step [ms] median / p99: total {:.2} / {:.2} · FM {:.2} / {:.2} · CD {:.2} / {:.2} · CC {:.2} / {:.2} · SC {:.2} / {:.2} · corr {:.2} / {:.2}",
        t.total.median_ms,
        t.total.p99_ms,
        t.fm.median_ms,
        t.fm.p99_ms,
        t.cd.median_ms,
        t.cd.p99_ms,
        t.cc.median_ms,
        t.cc.p99_ms,
        t.sc.median_ms,
        t.sc.p99_ms,
        t.correction.median_ms,
        t.correction.p99_ms
    );
    println!(
        "mean time per step: {:.2} ms wall (FM {:.2} · CC {:.2}), {:.2} ms CPU summed over threads",
        t.total.mean_ms, t.fm.mean_ms, t.cc.mean_ms, cpu_ms
    );
}

fn compare_cmd(a: &CompareArgs) -> ExitCode {
    use needle_host::suite::compare;
    if !(a.tolerance.is_finite() && a.tolerance >= 0.0) {
        eprintln!(
            "error: --tolerance {}: must be a finite number ≥ 0 [mm]",
            a.tolerance
        );
        return ExitCode::from(2);
    }
    // A folder stands for the suite.json in it.
    let file = |p: &PathBuf| {
        if p.is_dir() {
            p.join("suite.json")
        } else {
            p.clone()
        }
    };
    let (before, after) = match (
        compare::load(&file(&a.before), &a.controller),
        compare::load(&file(&a.after), &a.controller),
    ) {
        (Ok(b), Ok(a)) => (b, a),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let c = compare::compare(&before, &after, a.tolerance);
    print!("{}", c.text);
    if a.fail_on_loss && !c.lost.is_empty() {
        eprintln!("{} target(s) lost", c.lost.len());
        return ExitCode::from(4);
    }
    ExitCode::SUCCESS
}

fn suite_cmd(a: &SuiteArgs) -> ExitCode {
    let mut overrides = Vec::new();
    for kv in &a.set {
        let Some((k, v)) = kv.split_once('=') else {
            eprintln!("error: --set `{kv}`: expected FIELD=VALUE, e.g. inverse.delta_q=0.001");
            return ExitCode::from(2);
        };
        overrides.push((k.trim().to_owned(), v.trim().to_owned()));
    }
    let mut variants = Vec::new();
    for name in &a.controllers {
        let Some(v) = suite::Variant::named(name.trim()) else {
            eprintln!("error: --controllers `{name}`: expected `default` or `paper`");
            return ExitCode::from(2);
        };
        variants.push(v);
    }
    let opts = SuiteOptions {
        dir: a.dir.clone(),
        benchmarks: !a.no_benchmarks,
        overrides,
        nodes: a.nodes,
        steps: a.steps,
        variants,
    };
    let scenes = match suite::scene_list(&opts) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {}: {e}", a.dir.display());
            return ExitCode::from(2);
        }
    };
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new((scenes.len() * opts.variants.len()) as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} scenes  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let mut rows = Vec::new();
    for ((name, file), variant) in scenes
        .iter()
        .flat_map(|s| opts.variants.iter().map(move |v| (s, v)))
    {
        let who = format!("{name} ({})", variant.name);
        let row = suite::run_scene(name, file.as_deref(), &opts, variant, |k| {
            if k % 20 == 0 {
                bar.set_message(format!("{who}: step {k}"));
            }
        });
        let what = match (&row.summary, &row.failure) {
            (Some(s), _) => format!(
                "{} · e_mean {} · e_max {} · e_final {:.3} mm",
                s.outcome.name(),
                mm3(s.e_mean_mm),
                mm3(s.e_max_mm),
                s.e_final_mm
            ),
            (None, Some(why)) => format!("failed: {why}"),
            (None, None) => String::new(),
        };
        bar.println(format!("{who}: {what}"));
        bar.inc(1);
        rows.push(row);
    }
    bar.finish_and_clear();
    for line in suite::worst_case(&rows) {
        println!("{line}");
    }
    // The table names the box gels' size with the overrides (mesh files keep their own).
    let shown: Vec<(String, String)> = (a.nodes)
        .map(|n| ("gel.box.nodes".to_owned(), format!("{n} (box gels)")))
        .into_iter()
        .chain(opts.overrides.iter().cloned())
        .collect();
    if let Err(e) = suite::write_outputs(&rows, &shown, &a.out) {
        eprintln!("error: {}", chain(&e));
        return ExitCode::FAILURE;
    }
    println!("wrote {}/suite.md, suite.csv, suite.json", a.out.display());
    ExitCode::from(suite::exit_code(&rows))
}

fn report_cmd(opts: &ReportOptions) -> ExitCode {
    match report(opts) {
        Ok(r) => {
            let broke = r.runs.iter().filter(|x| !x.completed()).count();
            println!(
                "report: {} runs ({} did not complete) in {:.0} s, written to {}",
                r.runs.len(),
                broke,
                r.wall_s,
                r.out_dir.display()
            );
            for line in needle_host::report::accuracy_summary(&r.accuracy) {
                println!("accuracy cost, {line}");
            }
            for f in &r.files {
                println!("  {}", f.display());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {}", chain(&e));
            ExitCode::FAILURE
        }
    }
}

fn run_cmd(a: RunArgs) -> ExitCode {
    if a.vtk_every.is_some() && a.output.out.is_none() {
        eprintln!("error: --vtk-every writes VTK files into the --out folder: give --out DIR");
        return ExitCode::from(2);
    }
    let scene = match scene_of(&a.scene) {
        Ok(s) => s,
        Err(code) => return code,
    };
    let opts = RunOptions {
        controller: match a.controller {
            Ctl::Inverse => ControllerKind::Inverse,
            Ctl::Naive => ControllerKind::Naive,
        },
        steps: a.output.steps,
        out_dir: a.output.out.clone(),
        vtk_every: a.vtk_every,
        ..RunOptions::default()
    };
    let result = with_progress(&scene, &a.output, |observe| run(&scene, &opts, observe));
    finish(result, a.output.json)
}

fn serve_cmd(a: ServeArgs) -> ExitCode {
    let scene = match scene_of(&a.scene) {
        Ok(s) => s,
        Err(code) => return code,
    };
    let positive = |x: f64| x.is_finite() && x > 0.0;
    if !positive(a.deadline_ms)
        || a.period_ms.is_some_and(|p| !positive(p))
        || a.give_up_s.is_some_and(|g| !positive(g))
    {
        eprintln!("error: --deadline-ms, --period-ms and --give-up-s must be positive");
        return ExitCode::from(2);
    }
    let n = match scene.joint_count() {
        Ok(n) => n,
        Err((field, reason)) => {
            eprintln!("error: {}", chain(&SetupError::Robot { field, reason }));
            return ExitCode::FAILURE;
        }
    };
    let cfg = BridgeConfig {
        instance: a.instance.clone(),
        deadline: Duration::from_secs_f64(a.deadline_ms * 1e-3),
        handle_signals: true,
        ..BridgeConfig::default()
    };
    with_joints(
        n,
        Serve {
            scene: &scene,
            cfg: &cfg,
            args: &a,
        },
    )
    .unwrap_or_else(|| {
        eprintln!(
            "error: robot: a robot of {n} joints; the two-process mode runs arms of 6 or 7 joints"
        );
        ExitCode::FAILURE
    })
}

/// `needle serve` for the scene's robot of `N` joints.
struct Serve<'a> {
    scene: &'a Scene,
    cfg: &'a BridgeConfig,
    args: &'a ServeArgs,
}

impl WithJoints for Serve<'_> {
    type Output = ExitCode;
    fn with<const N: usize>(self) -> ExitCode {
        let Serve {
            scene,
            cfg,
            args: a,
        } = self;
        let (robot, inverse) = match setup::core::<N>(scene) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("error: {}", chain(&e));
                return ExitCode::FAILURE;
            }
        };
        needle_bridge::shm::quiet_logs();
        let mut host =
            match SharedMemoryHost::<ROWS, N>::connect(cfg, setup_fingerprint(&robot, &inverse)) {
                Ok(h) => h,
                Err(e) => {
                    eprintln!("error: {}", chain(&e));
                    return ExitCode::FAILURE;
                }
            };
        eprintln!(
            "needle serve: scene {} · {N} joints · session {:016x} · frames on {} · commands from {} · {} dead node(s) cleaned, {} half-created service(s) removed",
            scene.name,
            host.session(),
            cfg.frame_service_name(),
            cfg.command_service_name(),
            host.stats().dead_nodes_cleaned,
            host.stats().hung_services_removed
        );
        eprintln!(
            "needle serve: waiting for `needle-controller {} --instance {}`",
            scene.name, cfg.instance
        );
        let opts = RunOptions {
            controller: ControllerKind::Inverse,
            steps: a.output.steps,
            out_dir: a.output.out.clone(),
            period: a.period_ms.map(|p| Duration::from_secs_f64(p * 1e-3)),
            give_up_after: a.give_up_s.map(Duration::from_secs_f64),
            ..RunOptions::default()
        };
        let result = with_progress(scene, &a.output, |observe| {
            run_with(scene, &opts, &mut host, observe)
        });
        let st = host.stats();
        eprintln!(
            "needle serve: frames published {}, commands accepted {}, rejected {}, stale {}, timeouts {}",
            st.frames_published,
            st.commands_accepted,
            st.commands_rejected,
            st.commands_stale,
            st.timeouts
        );
        finish(result, a.output.json)
    }
}

fn main() -> ExitCode {
    quiet_broken_pipe();
    let cli = Cli::parse();
    init_logs(cli.verbose, cli.log_quiet);
    match cli.command {
        Command::Report {
            out,
            quick,
            steps,
            quiet,
            suite,
        } => report_cmd(&ReportOptions {
            out_dir: out,
            quick,
            steps,
            progress: !quiet,
            suite: suite.or_else(needle_host::report::default_suite),
        }),
        Command::Run(a) => run_cmd(a),
        Command::Suite(a) => suite_cmd(&a),
        Command::Compare(a) => compare_cmd(&a),
        Command::Serve(a) => serve_cmd(a),
    }
}

/// A closed standard output (`needle run --json | head -1`) ends the process quietly, as for
/// any Unix filter, instead of a panic in `println!` (Rust ignores SIGPIPE by default).
fn quiet_broken_pipe() {
    // SAFETY: restoring a signal's default disposition at start-up, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
