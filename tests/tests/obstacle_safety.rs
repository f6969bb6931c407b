//! Obstacle safety of the default controller (issue "controller"): a run whose needle is held by
//! an obstacle's clearance margin, with its target out of reach, stops as blocked instead of
//! pushing on until the needle slips into the obstacle.

use needle_host::run::{Outcome, RunOptions, StopReason, run};
use needle_host::scene::Scene;
use std::path::Path;

#[test]
#[ignore = "scenario (release, ~5 s): run with --include-ignored"]
fn helix_half_held_at_its_clearance_margin_until_it_slipped_into_the_obstacle_is_stopped_as_blocked()
 {
    // Before: the clearance row held the needle 0.2 mm from obstacle o2 for about 90 steps
    // (3.6 s) while the target ran away; the gel loaded up until the needle slipped, and the run
    // ended at -1.594 mm (an obstacle hit), 18.7 mm from the target.
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/scenes/helix_half_seed2026.toml");
    let scene = Scene::load(&file).expect("scene");
    let r = run(&scene, &RunOptions::default(), |_| {}).expect("run");
    let s = &r.summary;
    let why = s.stop_reason.as_ref().expect("a stop reason");
    assert!(
        matches!(why, StopReason::Blocked { steps: 25, .. }),
        "{why:?}"
    );
    assert!(!why.is_divergence());
    assert_eq!(s.outcome, Outcome::MissedTarget, "{:?}", s.stopped);
    assert_eq!(s.outcome.exit_code(), 4);
    let min = s
        .clearances
        .iter()
        .map(|c| c.min_mm)
        .fold(f64::INFINITY, f64::min);
    assert!(min > 0.0, "obstacle hit: {min} mm");
    assert!(s.steps < 609, "ran to the end: {} steps", s.steps);
    assert!(s.stopped.as_deref().is_some_and(|m| m.contains("blocked")));
}
