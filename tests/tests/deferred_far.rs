//! `solver.defer_far` in whole runs: the gel's far rows solved once per step, after the
//! constraint solve, for the free and the corrective motion together. In double precision the
//! steps are those of the run that solves every motion whole, to round-off amplified by the
//! contact (the tip then differs by far less than a micrometre); a near block too small for the
//! sliding points' tetrahedra makes the first such step finish its free motion before the
//! constraint solve (counted) and the steps after it solve whole, with the same result.

use needle_bridge::InProcess;
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, ROWS};
use needle_host::world::World;

/// The complex scene at 1200 nodes (a near block from 1000), double-precision factor, with
/// `overrides`.
fn scene(overrides: &[(&str, &str)]) -> Scene {
    let mut all = vec![
        ("gel.box.nodes", "1200"),
        ("solver.factor_precision", "\"double\""),
    ];
    all.extend_from_slice(overrides);
    needle_tests::builtin_scene("complex", &all)
}

/// The tip after each of `steps` steps, and the world at the end.
fn tips(scene: &Scene, steps: usize) -> (Vec<[f64; 3]>, World) {
    let s = Setup::build(scene).expect("scene builds");
    let mut world = s.world;
    let params = s.params;
    let mut core: InProcess<ROWS> = InProcess::new(s.robot, s.inverse);
    let mut pipeline = Pipeline::new(&world);
    let tips = (0..steps)
        .map(|_| {
            let r = pipeline.step(&mut world, &params, &mut core).expect("step");
            [r.tip.x, r.tip.y, r.tip.z]
        })
        .collect();
    (tips, world)
}

fn largest_gap(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max)
}

/// Past the puncture and 20 mm of insertion: sliding points, contact, refreshes.
const STEPS: usize = 300;

#[test]
fn deferred_far_rows_step_as_the_whole_solves() {
    let whole = scene(&[("solver.defer_far", "false")]);
    let (expect, w0) = tips(&whole, STEPS);
    assert!(!w0.gel.defers_far());
    let (got, w1) = tips(&scene(&[]), STEPS);
    assert!(
        w1.gel.defers_far(),
        "deferral is the default with a near block"
    );
    assert_eq!(w1.gel.deferral_fallbacks(), 0, "every gel point is near");
    let gap = largest_gap(&expect, &got);
    println!("defer_far: tip within {gap:.2e} mm of the whole solves over {STEPS} steps");
    assert!(gap < 1e-6, "{gap:e} mm");
    let positions = w0
        .gel
        .positions()
        .iter()
        .zip(w1.gel.positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(positions < 1e-6, "gel nodes {positions:e} mm apart");
}

/// A near block of 1.5 mm around the path holds the needle's nodes but not the sliding
/// points' tetrahedra: the first step that reads one finishes its free motion before the
/// constraint solve, and the steps after it solve whole (their columns cached) rather than
/// fall back at every step.
#[test]
fn a_far_gel_point_falls_back_once_not_every_step_and_steps_as_the_whole_solves() {
    let small = [
        ("solver.near_radius", "1.5"),
        ("solver.entry_radius", "\"off\""),
    ];
    let mut whole_overrides = small.to_vec();
    whole_overrides.push(("solver.defer_far", "false"));
    let (expect, _) = tips(&scene(&whole_overrides), STEPS);
    let (got, w) = tips(&scene(&small), STEPS);
    assert!(w.gel.defers_far());
    let fallbacks = w.gel.deferral_fallbacks();
    println!("near radius 1.5 mm: {fallbacks} of {STEPS} steps finished their free motion first");
    assert!(fallbacks > 0, "the test is void");
    assert!(
        fallbacks <= 3,
        "{fallbacks} fallbacks: the steps after one should solve whole"
    );
    let gap = largest_gap(&expect, &got);
    assert!(gap < 1e-6, "{gap:e} mm");
}
