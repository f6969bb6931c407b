//! Obstacle safety of the default controller (issue "controller"): a run whose needle is held by
//! an obstacle's clearance margin, with its target out of reach, stops as blocked instead of
//! pushing on until the needle slips into the obstacle.

use needle_host::run::{Outcome, RunOptions, StopReason, run};
use needle_host::scene::Scene;
use std::path::Path;

/// Runs `scene` (a path relative to this crate) with the default configuration.
fn run_scene(rel: &str) -> needle_host::run::RunSummary {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    let scene = Scene::load(&file).expect("scene");
    run(&scene, &RunOptions::default(), |_| {})
        .expect("run")
        .summary
}

#[test]
#[ignore = "scenario (release, ~5 s): run with --include-ignored"]
fn helix_half_held_at_its_clearance_margin_until_it_slipped_into_the_obstacle_no_longer_hits_it() {
    // Before the blocked stop: the clearance row held the needle 0.2 mm from obstacle o2 for
    // about 90 steps (3.6 s) while the target ran away; the gel loaded up until the needle
    // slipped, and the run ended at -1.594 mm (an obstacle hit), 18.7 mm from the target. The
    // blocked stop then ended it at the margin. Since the heading is kept and each step is
    // confirmed by the constraint solve, the needle is no longer held there: it runs to the end
    // (8.6 mm from the target) and stays clear of both obstacles.
    let s = run_scene("data/scenes/helix_half_seed2026.toml");
    let min = s.min_clearance_mm;
    assert!(min > 0.0, "obstacle hit: {min} mm");
    assert_ne!(s.outcome, Outcome::ObstacleHit);
}

/// The blocked stop on the public scene that met it: `needle_thin`'s path curves towards its
/// obstacle faster than the thin needle can be steered, and the clearance row holds the needle
/// 0.2 mm from it while the target runs on. With the angles' stage damped by at most 5 mm/rad
/// (the default since 2026-12-02) the heading steers the needle past the obstacle (missed, 3.96
/// mm from the end, not blocked), and with the horizon the default gives this needle since
/// 2026-12-05 (`inverse.qp_horizon = "auto"`: 3 mm) it ends 3.46 mm from the end, not blocked
/// either, nor with the target straightened towards the path's chord (the default for this
/// needle since 2026-12-07: 1.74 mm; from one steering length deep, later that day: reached,
/// 0.56 mm); so this test runs the update before all three
/// (`inverse.qp_angle_damping_max = 21`, `inverse.qp_horizon = 0`, `inverse.straighten = 0`)
/// to keep a needle that meets the margin.
#[test]
#[ignore = "scenario (release, ~5 s): run with --include-ignored"]
fn needle_thin_held_at_its_clearance_margin_is_stopped_as_blocked() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/suite/needle_thin.toml");
    let scene = Scene::load(&file)
        .expect("scene")
        .with_overrides(&[
            ("inverse.qp_angle_damping_max".into(), "21".into()),
            ("inverse.qp_horizon".into(), "0".into()),
            ("inverse.straighten".into(), "0".into()),
        ])
        .expect("override");
    let s = run(&scene, &RunOptions::default(), |_| {})
        .expect("run")
        .summary;
    let why = s.stop_reason.as_ref().expect("a stop reason");
    assert!(
        matches!(why, StopReason::Blocked { steps: 25, .. }),
        "{why:?}"
    );
    assert!(!why.is_divergence());
    assert_eq!(s.outcome, Outcome::MissedTarget, "{:?}", s.stopped);
    assert_eq!(s.outcome.exit_code(), 4);
    let min = s.min_clearance_mm;
    assert!(min > 0.0, "obstacle hit: {min} mm");
    assert!(s.steps < 617, "ran to the end: {} steps", s.steps);
    assert!(s.stopped.as_deref().is_some_and(|m| m.contains("blocked")));
    // It says what held it: the row nearest its bound at the held steps.
    assert!(
        matches!(why, StopReason::Blocked { by, .. } if by == "the margin of obstacle `o1`"),
        "{why:?}"
    );
}

/// The clearance rows behind the needle point nearest to an obstacle reach as far as the needle
/// may advance in one step (`inverse.max_base_step`): before, they stopped at 4.5 mm whatever the
/// trust region, so with a larger one a needle point could reach the nearest point's place
/// within a step unseen by any row. At the default 5 mm (and the benchmarks' 3 mm) the rows are
/// the three they were; at 9 mm six, every 1.5 mm; without a trust region as many as the frame
/// holds.
#[test]
#[ignore = "two insertions (release, ~1 s): run with --include-ignored"]
fn clearance_rows_behind_the_nearest_point_reach_the_trust_region() {
    use needle_bridge::InProcess;
    use needle_host::setup::Setup;
    use needle_host::step::Pipeline;
    use needle_host::step::observe::rows_behind;
    assert_eq!(
        [3.0, 5.0, 9.0, f64::INFINITY].map(rows_behind),
        [3, 3, 6, needle_core::payload::NCLEAR - 1]
    );
    for (max_base_step, rows) in [(5.0, 3), (9.0, 6)] {
        let scene = Scene::builtin("simple")
            .expect("the simple scene")
            .with_overrides(&[
                ("gel.box.nodes".into(), "600".into()),
                ("inverse.max_base_step".into(), format!("{max_base_step}")),
            ])
            .expect("overrides");
        let s = Setup::build(&scene).expect("set-up");
        assert_eq!(s.params.max_base_step, max_base_step);
        let (mut world, params) = (s.world, s.params);
        assert_eq!(world.obstacles.len(), 1, "one obstacle");
        let mut core = InProcess::new(s.robot, s.inverse);
        let mut pipeline = Pipeline::new(&world);
        let mut most = 0;
        for _ in 0..s.plan.steps {
            pipeline
                .step(&mut world, &params, &mut core)
                .expect("a step");
            most = most.max(pipeline.frame().clearances());
        }
        assert_eq!(
            most,
            1 + rows,
            "max_base_step {max_base_step}: the nearest point's row and {rows} behind it"
        );
    }
}
