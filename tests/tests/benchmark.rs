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
    assert!(
        s.final_depth_mm > 45.0,
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

/// The naive baseline runs on the complex path without a crash, hang or NaN, and its error is
/// larger than the inverse controller's.
#[test]
#[ignore = "full benchmark insertion (release, ~30 s): run with --include-ignored"]
fn naive_baseline_runs_on_the_complex_path_and_tracks_worse() {
    let naive = run_scene("complex", ControllerKind::Naive);
    let inverse = run_scene("complex", ControllerKind::Inverse);
    assert!(naive.steps > 0);
    if naive.stopped.is_some() {
        assert!(!naive.completed, "a stopped run is not complete");
    }
    assert!(
        naive.e_max_mm.is_finite() && naive.e_mean_mm.is_finite(),
        "{naive:?}"
    );
    assert!(
        naive.e_mean_mm > inverse.e_mean_mm,
        "naive e_mean {} ≤ inverse {}",
        naive.e_mean_mm,
        inverse.e_mean_mm
    );
}
