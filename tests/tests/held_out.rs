//! Scenes of held-out sets (made by `tools/gen_suite.py` with other seeds) that once failed in
//! a way the public suite did not show.

use needle_host::run::{RunOptions, RunSummary, run};
use needle_host::scene::Scene;
use std::path::Path;

/// The summary of a whole run of the kept scene `tests/data/scenes/NAME`.
fn run_kept(name: &str) -> RunSummary {
    run_kept_with(name, &[])
}

/// [`run_kept`] with scene fields overridden (`needle run --set FIELD=VALUE`).
fn run_kept_with(name: &str, overrides: &[(&str, &str)]) -> RunSummary {
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data/scenes")
        .join(name);
    let overrides: Vec<(String, String)> = (overrides.iter())
        .map(|(f, v)| (f.to_string(), v.to_string()))
        .collect();
    let scene = Scene::load(&file)
        .and_then(|s| s.with_overrides(&overrides))
        .expect("scene");
    run(&scene, &RunOptions::default(), |_| {})
        .expect("run")
        .summary
}

/// `place_right` of seed 31: near the end of its path, with a joint at its limit, the Jacobian's
/// column solves of 4 steps ran into the Gauss-Seidel cap (the active-set rounds of their
/// polishes cycled: `core/tests/stiff_sliding.rs` has one of those problems), and the run
/// missed its target by 1.92 mm. The feasible polish of a solve the first polish left
/// unconverged ends every solve now.
#[test]
#[ignore = "an insertion of 690 steps (release, ~10 s): run with --include-ignored"]
fn place_right_seed31_hits_no_gauss_seidel_cap() {
    let s = run_kept("place_right_seed31.toml");
    eprintln!(
        "outcome {:?}, e_final {:.3} mm, sweeps max {}",
        s.outcome, s.e_final_mm, s.gs_iterations_max
    );
    assert_eq!(s.gs_not_converged_steps, 0);
    assert!(s.min_clearance_mm > 0.0);
}

/// `scurve_x` of seed 404: the shaft dragged the entry point 42.9 mm through the soft gel, the
/// tip went 14.7 mm from the path (e_mean 6.2 mm) and ended 0.001 mm from the target, and the
/// run counted as reached with exit code 0. A target reached more than
/// `PATH_TOLERANCE_MM` off the path is `left_path` (exit 6) now; should a later controller
/// follow this path, the run is reached, and the test still holds it to the path.
#[test]
#[ignore = "an insertion of 620 steps (release, ~3 s): run with --include-ignored"]
fn scurve_x_seed404_reached_14_mm_off_the_path_is_not_reached() {
    use needle_host::run::Outcome;
    use needle_host::run::metrics::PATH_TOLERANCE_MM;
    let s = run_kept("scurve_x_seed404.toml");
    eprintln!(
        "outcome {:?}, e_final {:.3} mm, path deviation max {:.3} mm, entry shift {:.1} mm",
        s.outcome, s.e_final_mm, s.path_deviation_max_mm, s.entry_shift_max_mm
    );
    assert!(s.path_deviation_max_mm.is_finite());
    if s.path_deviation_max_mm > PATH_TOLERANCE_MM {
        assert_ne!(s.outcome, Outcome::Reached);
        if s.e_final_mm <= 1.0 && s.min_clearance_mm >= 0.0 && s.stopped.is_none() {
            assert_eq!(s.outcome, Outcome::LeftPath);
            assert_eq!(s.outcome.exit_code(), 6);
        }
    }
}

/// `gel_stiff` of seed 8128: a Ø 0.73 mm needle in a 70 kPa gel (steering length 14.1 mm) on a
/// path bending 11.6 mm from its entry line. Shown the planned path, its tip lagged the bend
/// deep in the gel and ended 1.51 mm from the target: missed. Where the needle lags its path's
/// bend (the run's advisory), the target shown to the controller is straightened
/// (`inverse.straighten = "auto"`: the whole way towards the chord from one steering length
/// deep, within 1.5 mm of the path), so the tip turns while it is shallow: it reaches the
/// target, the errors still measured against the planned path.
#[test]
#[ignore = "two insertions of 616 steps (release, ~15 s): run with --include-ignored"]
fn gel_stiff_seed8128_lagging_its_bend_reaches_with_the_target_straightened() {
    use needle_host::run::Outcome;
    use needle_host::straighten::AUTO_FRACTION;
    let auto = run_kept("gel_stiff_seed8128.toml");
    let planned = run_kept_with("gel_stiff_seed8128.toml", &[("inverse.straighten", "0")]);
    for (what, s) in [("auto", &auto), ("planned path", &planned)] {
        eprintln!(
            "{what}: straighten {} from {:.1} mm, outcome {:?}, e_mean {:.3} e_max {:.3} \
             e_final {:.3} mm, clearance {:.3} mm",
            s.straighten,
            s.straighten_from_mm,
            s.outcome,
            s.e_mean_mm,
            s.e_max_mm,
            s.e_final_mm,
            s.min_clearance_mm
        );
    }
    assert!(!auto.advisories.is_empty(), "the needle lags the bend");
    assert_eq!(auto.straighten, AUTO_FRACTION);
    assert_eq!(auto.straighten_from_mm, auto.steering_length_mm);
    assert_eq!(planned.straighten, 0.0);
    assert_eq!(auto.outcome, Outcome::Reached);
    assert!(auto.e_final_mm <= 1.0 && auto.e_max_mm <= 3.0 && auto.e_mean_mm <= 1.0);
    assert!(auto.min_clearance_mm > 0.0);
    assert!(
        planned.e_final_mm > auto.e_final_mm,
        "straightening brought the tip nearer the target"
    );
}

/// `bend_x` of seed 777: a Ø 0.61 mm needle in a 27 kPa gel (steering length 15.0 mm) on a path
/// bending 5.3 mm as s^2.29, most of it deep. Shown the path straightened 40 % towards the
/// chord from the entry point (the default until 2026-12-07, kept for a path with an obstacle
/// near the deep chord), the tip lagged the late bend and ended 1.34 mm from the target:
/// missed. Shown the path down to one steering length and the chord from there (the default
/// now), it reaches it.
#[test]
#[ignore = "two insertions of 617 steps (release, ~15 s): run with --include-ignored"]
fn bend_x_seed777_late_bend_reaches_with_the_chord_from_one_steering_length() {
    use needle_host::run::Outcome;
    let auto = run_kept("bend_x_seed777.toml");
    let entry = run_kept_with(
        "bend_x_seed777.toml",
        &[
            ("inverse.straighten", "0.4"),
            ("inverse.straighten_from", "0"),
        ],
    );
    for (what, s) in [("auto", &auto), ("entry chord 0.4", &entry)] {
        eprintln!(
            "{what}: straighten {} from {:.1} mm, outcome {:?}, e_mean {:.3} e_max {:.3} \
             e_final {:.3} mm",
            s.straighten, s.straighten_from_mm, s.outcome, s.e_mean_mm, s.e_max_mm, s.e_final_mm
        );
    }
    assert!(!auto.advisories.is_empty(), "the needle lags the bend");
    assert_eq!(auto.straighten_from_mm, auto.steering_length_mm);
    assert_eq!(auto.outcome, Outcome::Reached);
    assert!(auto.e_final_mm <= 1.0 && auto.e_max_mm <= 3.0 && auto.e_mean_mm <= 1.0);
    assert!(auto.min_clearance_mm > 0.0);
    assert!(
        entry.e_final_mm > auto.e_final_mm,
        "the chord from one steering length brought the tip nearer the target"
    );
}

/// `tilt_large` of seed 808: a needle tilted 22° from the normal of a 23 kPa gel, pushed along
/// its heading, slid on the surface (μ_s = 0.3: the friction cone's half-angle is 16.7°) and
/// punctured 4.23 mm from its target; the tip then ran 4.1 mm off the path: `left_path`. Once
/// the tip slides off its target before puncture, the heading shown to the controller is held
/// within the friction cone (`inverse.entry_tilt = "auto"`) until it punctures.
#[test]
#[ignore = "two insertions of 670 steps (release, ~10 s): run with --include-ignored"]
fn tilt_large_seed808_sliding_before_puncture_is_held_within_the_friction_cone() {
    use needle_host::run::Outcome;
    let auto = run_kept("tilt_large_seed808.toml");
    let never = run_kept_with("tilt_large_seed808.toml", &[("inverse.entry_tilt", "2.0")]);
    for (what, s) in [("auto", &auto), ("never turned", &never)] {
        eprintln!(
            "{what}: outcome {:?}, at puncture {:?} mm, e_mean {:.3} e_max {:.3} e_final {:.3} mm",
            s.outcome, s.e_puncture_mm, s.e_mean_mm, s.e_max_mm, s.e_final_mm
        );
    }
    for s in [&auto, &never] {
        let slid = s.tip_slid_step.expect("the slide is reported");
        assert!(slid < s.puncture_step.expect("punctured"));
    }
    let at_puncture = |s: &RunSummary| s.e_puncture_mm.expect("punctured");
    assert!(
        at_puncture(&never) > 3.0,
        "the tip slides with its heading kept"
    );
    assert!(
        at_puncture(&auto) < 1.5,
        "held within the cone, the tip stays near its target"
    );
    assert_eq!(auto.outcome, Outcome::Reached);
    assert!(auto.e_final_mm <= 1.0 && auto.e_max_mm <= 3.0 && auto.e_mean_mm <= 1.0);
}
