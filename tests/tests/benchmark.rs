//! The benchmark insertions of BENCHMARK.md end to end (issue 5): both scenes under the inverse
//! controller within the paper's error bounds and clear of every obstacle; the naive baseline on
//! the complex path runs without crashing and tracks worse.

use needle_host::run::{ControllerKind, RunOptions, RunSummary, run};
use needle_host::scene::Scene;

fn run_scene(name: &str, controller: ControllerKind) -> RunSummary {
    let scene = Scene::builtin(name).expect("embedded scene");
    let opts = RunOptions {
        controller,
        ..RunOptions::default()
    };
    let result = run(&scene, &opts, |_| {}).expect("the run starts");
    let s = result.summary;
    eprintln!(
        "{name} {controller:?}: {}",
        serde_json::to_string(&s).unwrap_or_default()
    );
    s
}

fn assert_tracks(s: &RunSummary, e_mean: f64, e_max: f64) {
    assert!(s.completed, "{} stopped: {:?}", s.scene, s.stopped);
    assert!(
        s.e_mean_mm <= e_mean,
        "{}: e_mean {} mm > {e_mean} mm",
        s.scene,
        s.e_mean_mm
    );
    assert!(
        s.e_max_mm <= e_max,
        "{}: e_max {} mm > {e_max} mm",
        s.scene,
        s.e_max_mm
    );
    // Inserted to the end: the tip at the path's end (issue 12's goal, 0.5 mm), most of the
    // 50 mm deep. The depth is the straight distance from the entry point, which the gel drags
    // along (45.2 mm on `complex`, 44.8 mm with `inverse.aim_ahead = 10`): the end reached is
    // the check, the depth only a bound against a run that stops short.
    assert!(
        s.e_final_mm <= 0.5,
        "{}: ends {} mm from the path's end",
        s.scene,
        s.e_final_mm
    );
    assert!(
        s.final_depth_mm > 40.0,
        "{}: only {} mm deep",
        s.scene,
        s.final_depth_mm
    );
    assert!(s.puncture_step.is_some());
}

/// The paper's simple-path figures: e_mean ≤ 0.5 mm, e_max ≤ 1.8 mm, obstacle avoided.
#[test]
#[ignore = "full benchmark insertion (release, ~15 s): run with --include-ignored"]
fn simple_path_inverse_within_the_papers_bounds() {
    let s = run_scene("simple", ControllerKind::Inverse);
    assert_tracks(&s, 0.5, 1.8);
    assert!(!s.obstacle_hit, "{:?}", s.clearances);
}

/// The paper's complex-path figures at 1500 nodes: e_mean ≤ 2.6 mm, e_max ≤ 6.0 mm, no obstacle hit.
#[test]
#[ignore = "full benchmark insertion (release, ~15 s): run with --include-ignored"]
fn complex_path_inverse_within_the_papers_bounds() {
    let s = run_scene("complex", ControllerKind::Inverse);
    assert_tracks(&s, 2.6, 6.0);
    assert!(!s.obstacle_hit, "{:?}", s.clearances);
    for c in &s.clearances {
        assert!(c.min_mm.is_finite(), "{c:?}");
    }
}

/// The naive baseline runs on the complex path without a crash, hang or NaN (it may stop
/// cleanly where the rigid model's pose leaves the robot's reach, as the paper's could not
/// finish either), and over the depth it reached it tracks worse than the paper's inverse
/// controller (`inverse.method = "paper"`: the comparison of the paper) and than the default QP
/// update. (The QP update's first version, one program weighing the angles against the tip,
/// tracked worse than the naive replay here: 0.990 against 0.708 mm; ranking the tip first
/// brought it to 0.147 mm.)
#[test]
#[ignore = "full benchmark insertion (release, ~30 s): run with --include-ignored"]
fn naive_baseline_runs_on_the_complex_path_and_tracks_worse() {
    let scene = Scene::builtin("complex").expect("embedded scene");
    let naive = run(
        &scene,
        &RunOptions {
            controller: ControllerKind::Naive,
            ..RunOptions::default()
        },
        |_| {},
    )
    .expect("the naive run starts");
    let paper_scene = scene
        .with_overrides(&[("inverse.method".into(), "\"paper\"".into())])
        .expect("override");
    let inverse =
        run(&paper_scene, &RunOptions::default(), |_| {}).expect("the inverse run starts");
    let default = run(&scene, &RunOptions::default(), |_| {}).expect("the default run starts");
    let s = &naive.summary;
    eprintln!("naive: {}", serde_json::to_string(s).unwrap_or_default());
    assert!(s.steps > 0);
    assert!(
        s.completed || s.stopped.is_some(),
        "an incomplete run says why"
    );
    assert!(
        naive
            .reports
            .iter()
            .all(|r| r.error.is_finite() && r.tip.iter().all(|v| v.is_finite()))
    );
    // Mean error inside the gel over the steps both runs made.
    let common = naive.reports.len();
    let mean = |reports: &[needle_host::step::StepReport]| {
        let inside: Vec<f64> = reports[..common]
            .iter()
            .filter(|r| r.tip_inside())
            .map(|r| r.error)
            .collect();
        assert!(!inside.is_empty(), "no step inside the gel");
        inside.iter().sum::<f64>() / inside.len() as f64
    };
    let (e_naive, e_inverse, e_default) = (
        mean(&naive.reports),
        mean(&inverse.reports),
        mean(&default.reports),
    );
    eprintln!(
        "over the first {common} steps: naive e_mean {e_naive:.3} mm, paper's update {e_inverse:.3} mm, default (QP) update {e_default:.3} mm"
    );
    assert!(
        e_naive > e_inverse,
        "naive e_mean {e_naive} ≤ the paper's update's {e_inverse}"
    );
    assert!(
        e_naive > e_default,
        "naive e_mean {e_naive} ≤ the default update's {e_default}"
    );
}

/// What broke: the step that punctures the surface counted as a step with the tip inside the
/// gel. Its corrective motion is the tip contact's, so it ends with the tip on the surface it
/// indented (depth 0), while its error is measured against the embedded target that the gel,
/// not yet relaxed, carries down with the indentation: 1.26 mm on the simple path, the e_max of
/// nearly every scene, gone one step later. It is now `e_puncture_mm`, and e_mean, e_max and the
/// path deviation are over the steps with the tip inside the gel.
#[test]
fn puncture_step_is_not_counted_inside_the_gel() {
    let scene = Scene::builtin("simple").expect("embedded scene");
    let opts = RunOptions {
        steps: Some(140),
        ..RunOptions::default()
    };
    let result = run(&scene, &opts, |_| {}).expect("the run starts");
    let (s, reports) = (&result.summary, &result.reports);
    let k = s.puncture_step.expect("the tip punctures within 140 steps");
    let at = reports
        .iter()
        .position(|r| r.step == k)
        .expect("its report");
    let (p, next) = (&reports[at], &reports[at + 1]);
    assert!(p.punctured_now && p.inserted && !p.tip_inside());
    assert!(
        p.depth < 1e-9,
        "the puncture step ends at depth {}",
        p.depth
    );
    assert!(p.error > 0.5, "error at the puncture step {} mm", p.error);
    assert_eq!(s.e_puncture_mm, Some(p.error));
    // One step later the gel has relaxed around the tip, now inside.
    assert!(
        next.tip_inside() && next.depth > 1.0,
        "{} mm deep",
        next.depth
    );
    assert!(
        next.error < 0.1,
        "error after the puncture {} mm",
        next.error
    );
    let inside: Vec<f64> = (reports.iter())
        .filter(|r| r.tip_inside())
        .map(|r| r.error)
        .collect();
    assert!(!inside.is_empty());
    assert_eq!(s.e_max_mm, inside.iter().copied().fold(f64::NAN, f64::max));
    assert!(s.e_max_mm < p.error, "e_max {} mm", s.e_max_mm);
    assert!(
        s.path_deviation_max_mm < p.error,
        "{}",
        s.path_deviation_max_mm
    );
    assert!(result.error_by_depth.iter().all(|&(d, _)| d > 0.0));
}
