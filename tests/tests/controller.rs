//! The QP update of the inverse controller on real frames (issue 12): the obstacle clearance
//! rows the host writes predict the clearance after the step (a first-order check of their
//! derivative against the simulation), and a full insertion past two obstacles 1.5 mm from the
//! path stays clear of both.

use needle_bridge::InProcess;
use needle_host::run::{RunOptions, run};
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::Pipeline;

fn suite_scene(name: &str) -> Scene {
    let path = format!("{}/../scenes/suite/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    Scene::load(std::path::Path::new(&path)).expect("suite scene")
}

/// After every step with the needle inserted, `clearance_free + clearance_c λ` of the frame
/// (the controller's linear model) against the clearances the simulation measures after the
/// step's corrective motion: the nearest obstacle within 0.05 mm (first order: the rows hold the
/// nearest needle point of the free motion fixed, the measurement takes the nearest point after
/// the correction), and the rows present once the needle is in.
#[test]
#[ignore = "an insertion of 300 steps (release, ~5 s): run with --include-ignored"]
fn clearance_rows_predict_the_clearance_after_the_step() {
    let scene = suite_scene("obstacles_tight")
        .with_overrides(&[("gel.box.nodes".into(), "600".into())])
        .expect("override");
    let s = Setup::build(&scene).expect("set-up");
    let (mut world, params) = (s.world, s.params);
    let mut core = InProcess::new(s.robot, s.inverse);
    let mut pipeline = Pipeline::new(&world);
    let (mut checked, mut worst) = (0, 0.0_f64);
    for _ in 0..s.plan.steps {
        pipeline
            .step(&mut world, &params, &mut core)
            .expect("a step");
        let (frame, cmd) = (pipeline.frame(), pipeline.command());
        let k = frame.clearances();
        if !world.punctured || world.depth() < 5.0 {
            continue;
        }
        assert_eq!(
            k, 3,
            "the three obstacles in the frame once the needle is in"
        );
        let mut predicted: Vec<f64> = (0..k).map(|j| frame.clearance(j, &cmd.lambda)).collect();
        let mut measured = world.clearances();
        predicted.sort_by(f64::total_cmp);
        measured.sort_by(f64::total_cmp);
        worst = worst.max((predicted[0] - measured[0]).abs());
        checked += 1;
    }
    eprintln!("{checked} steps checked, worst |predicted − measured| {worst:.4} mm");
    assert!(checked > 100, "{checked} steps with the needle in");
    assert!(worst < 0.05, "worst {worst} mm");
}

/// The suite's `obstacles_tight` (three obstacles whose surfaces are 0.64 to 0.81 mm from the
/// rest path's centre line): the default controller ends clear of all three. (The paper's update hit the
/// first at −0.185 mm: `needle run scenes/suite/obstacles_tight.toml --set
/// 'inverse.method="paper"'`.)
#[test]
#[ignore = "a full insertion (release, ~5 s): run with --include-ignored"]
fn qp_update_keeps_the_needle_clear_of_obstacles_near_the_path() {
    let scene = suite_scene("obstacles_tight");
    let result = run(&scene, &RunOptions::default(), |_| {}).expect("the run starts");
    let s = result.summary;
    eprintln!("{:?}", s.clearances);
    assert!(s.completed, "stopped: {:?}", s.stopped);
    assert!(!s.obstacle_hit, "{:?}", s.clearances);
    for c in &s.clearances {
        assert!(c.min_mm > 0.0, "{c:?}");
    }
}
