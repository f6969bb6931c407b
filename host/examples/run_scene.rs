//! Runs the embedded `simple` scene from code, step by step, with the core in this process:
//! set up the scene, step it through the puncture, and check that the tip followed the target.
//!
//! ```sh
//! cargo run --release -p needle-host --example run_scene
//! ```

use needle_bridge::InProcess;
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, ROWS};

/// Steps to run: 15 mm of target motion, through the 10 mm approach and the puncture.
const STEPS: usize = 150;

fn main() {
    // The benchmark's straight path on a coarser gel (600 nodes), so that it runs in seconds.
    let scene = Scene::builtin("simple")
        .expect("embedded scene")
        .with_overrides(&[("gel.box.nodes".into(), "600".into())])
        .expect("valid override");
    let setup = Setup::build(&scene).expect("the scene sets up");
    let (mut world, params) = (setup.world, setup.params);
    let mut core = InProcess::<ROWS>::new(setup.robot, setup.inverse);
    let mut pipeline = Pipeline::new(&world);

    let start = world.tip();
    let mut worst = 0.0f64;
    let mut puncture = None;
    for _ in 0..STEPS {
        let r = pipeline
            .step(&mut world, &params, &mut core)
            .expect("the step succeeds");
        worst = worst.max(r.error);
        if r.punctured_now {
            puncture = Some(r.step);
        }
        if r.step.is_multiple_of(25) {
            println!(
                "step {:3}: c {:5.1} mm, depth {:4.1} mm, error {:.3} mm, {} rows, {:.2} ms",
                r.step,
                r.c,
                r.depth,
                r.error,
                r.rows,
                r.times.total()
            );
        }
    }
    let moved = (world.tip() - start).norm();
    println!(
        "after {STEPS} steps: tip moved {moved:.2} mm for a target at c = {:.1} mm, \
         punctured at step {puncture:?}, depth {:.2} mm, largest error {worst:.3} mm",
        world.c,
        world.depth()
    );
    // The tip followed the target along the path, into the gel, within the simple path's
    // error bound of the benchmark (1.8 mm).
    assert!(puncture.is_some() && world.punctured, "no puncture");
    assert!(world.depth() > 2.0, "depth {}", world.depth());
    assert!(
        (moved - world.c).abs() < 1.0,
        "moved {moved} mm, c = {}",
        world.c
    );
    assert!(worst < 1.8, "largest error {worst} mm");
}
