//! A prescribed motion of the gel's support (`[gel.support_motion]`): the fixed nodes follow it
//! (inhomogeneous Dirichlet conditions), the path and obstacles move with the gel, and the
//! motion can be hidden from the controller's model.

use nalgebra::Vector3;
use needle_host::free_motion::{GelModel, GelParams};
use needle_host::mesh::{BoxDivisions, box_mesh_with_divisions};
use needle_host::run::{Outcome, RunOptions, RunResult, run};
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::support_motion::SupportMotion;
use std::path::{Path, PathBuf};

fn scene(base: &str, overrides: &[(&str, &str)]) -> Scene {
    let overrides: Vec<(String, String)> = overrides
        .iter()
        .map(|(f, v)| (f.to_string(), v.to_string()))
        .collect();
    let s = match Scene::builtin(base) {
        Some(s) => s,
        None => Scene::load(Path::new(base)).unwrap(),
    };
    s.with_overrides(&overrides).unwrap()
}

fn run_steps(s: &Scene, steps: usize) -> RunResult {
    let opts = RunOptions {
        steps: Some(steps),
        ..RunOptions::default()
    };
    run(s, &opts, |_| {}).unwrap()
}

const BREATHING_X: &str = "{amplitude = 5.0, period = 4.0, direction = [1.0, 0.0, 0.0]}";

/// A clamped box whose support is moved rigidly by `d` settles, by the corotational free motion
/// alone, into the box moved rigidly by `d`: every node within 1e-9 |d|, no internal force,
/// no stress.
#[test]
fn a_gel_whose_support_moves_rigidly_moves_rigidly() {
    let mesh = box_mesh_with_divisions(
        Vector3::new(260.0, -30.0, 0.0),
        Vector3::new(340.0, 30.0, 60.0),
        BoxDivisions {
            nx: 8,
            ny: 6,
            nz: 6,
        },
    );
    let bottom = mesh.nodes_on_plane(2, 0.0, 1e-9);
    let params = GelParams {
        elasticity: needle_host::fem::Elasticity {
            young_modulus: 0.02,
            poisson_ratio: 0.45,
        },
        ..GelParams::default()
    };
    for d in [
        Vector3::new(5.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, 5.0),
        Vector3::new(-3.0, 4.0, 2.5),
    ] {
        let mut gel = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
        gel.displace_support(&d);
        let mut steps = 0;
        for _ in 0..20 {
            steps += 1;
            let dx = gel.free_motion_unloaded().unwrap().to_vec();
            gel.apply_displacement(&dx).unwrap();
            if dx.iter().fold(0.0f64, |m, v| m.max(v.abs())) < 1e-13 * d.norm() {
                break;
            }
        }
        let off = gel
            .positions()
            .iter()
            .zip(&gel.mesh().nodes)
            .map(|(x, x0)| (x - x0 - d).norm())
            .fold(0.0, f64::max);
        println!("support moved by {d:?}: {steps} Newton steps, farthest node {off:e} mm off");
        assert!(
            off <= 1e-9 * d.norm(),
            "a node is {off:e} mm off the rigid motion"
        );
        let f = gel.compute_internal_forces();
        let fmax = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // Against the force scale of the displacement: E · |d| · element size (≈ 10 mm).
        assert!(
            fmax < 1e-9 * 0.02 * d.norm() * 10.0,
            "internal force {fmax:e} N"
        );
        let positions = gel.positions().to_vec();
        let vm = (0..gel.tetra().len())
            .map(|e| gel.tetra().element_state(e, &positions).von_mises)
            .fold(0.0, f64::max);
        assert!(vm < 1e-12, "von Mises stress {vm:e} MPa");
    }
}

/// The compliance stays consistent with the free motion under a moved support: on a gel whose
/// support moved by 5 mm (and settled), the displacement `K⁻¹ f` the compliance predicts for a
/// small load equals, to first order, the equilibrium the free motion reaches under that load
/// (a finite difference of the nonlinear equilibrium), and equals the still gel's to round-off.
#[test]
fn compliance_under_a_moved_support_predicts_the_equilibrium_by_finite_differences() {
    let mesh = box_mesh_with_divisions(
        Vector3::new(260.0, -30.0, 0.0),
        Vector3::new(340.0, 30.0, 60.0),
        BoxDivisions {
            nx: 6,
            ny: 4,
            nz: 4,
        },
    );
    let bottom = mesh.nodes_on_plane(2, 0.0, 1e-9);
    let top = (0..mesh.nodes.len())
        .max_by(|&a, &b| {
            let score = |i: usize| mesh.nodes[i].z - 1e-3 * (mesh.nodes[i].x - 300.0).abs();
            score(a).total_cmp(&score(b))
        })
        .unwrap();
    let params = GelParams {
        elasticity: needle_host::fem::Elasticity {
            young_modulus: 0.02,
            poisson_ratio: 0.45,
        },
        ..GelParams::default()
    };
    let settle = |gel: &mut GelModel, f: &[f64]| {
        for _ in 0..30 {
            let dx = gel.free_motion(f).unwrap().to_vec();
            gel.apply_displacement(&dx).unwrap();
            if dx.iter().fold(0.0f64, |m, v| m.max(v.abs())) < 1e-14 {
                break;
            }
        }
    };
    let mut predicted = Vec::new();
    for d in [Vector3::zeros(), Vector3::new(5.0, 0.0, 0.0)] {
        let mut gel = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
        gel.displace_support(&d);
        let zero = vec![0.0; gel.dof_count()];
        settle(&mut gel, &zero);
        gel.refactor().unwrap();
        let before = gel.positions().to_vec();
        for eps in [1e-4, 1e-5] {
            let mut f = vec![0.0; gel.dof_count()];
            f[3 * top] = eps; // N along x on a top node
            f[3 * top + 2] = -0.5 * eps;
            let mut u = f.clone();
            gel.solve(&mut u).unwrap();
            let mut loaded = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
            loaded.displace_support(&d);
            settle(&mut loaded, &zero);
            settle(&mut loaded, &f);
            let mut worst: f64 = 0.0;
            let mut scale: f64 = 0.0;
            for (i, (x, x0)) in loaded.positions().iter().zip(&before).enumerate() {
                let ui = Vector3::new(u[3 * i], u[3 * i + 1], u[3 * i + 2]);
                worst = worst.max((x - x0 - ui).norm());
                scale = scale.max(ui.norm());
            }
            println!(
                "support {:?}, load {eps:e} N: |K⁻¹f| {scale:.3e} mm, FD mismatch {worst:.3e} mm",
                d.as_slice()
            );
            // Second order in the load: the mismatch falls ~100× for a 10× smaller load.
            assert!(
                worst < 1e-4 * scale,
                "mismatch {worst:e} against {scale:e} mm"
            );
            if eps == 1e-5 {
                predicted.push(u);
            }
        }
    }
    let diff = predicted[0]
        .iter()
        .zip(&predicted[1])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    let scale = predicted[0].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        diff < 1e-9 * scale,
        "moved and still compliances differ by {diff:e} mm"
    );
}

/// At t = 0 a breathing motion (phase 0) is no motion, and a run under a zero-amplitude motion
/// is the run without motion, bit for bit.
#[test]
fn prescribed_motion_at_t0_is_no_motion() {
    let m = SupportMotion::breathing(5.0, 4.0, [1.0, 0.0, 0.0], 0.0).unwrap();
    assert_eq!(m.displacement(0.0), Vector3::zeros());
    let still = scene("simple", &[("gel.box.nodes", "300")]);
    let mut setup = Setup::build(&scene(
        "simple",
        &[
            ("gel.box.nodes", "300"),
            ("gel.support_motion.breathing", BREATHING_X),
        ],
    ))
    .unwrap();
    let rest = setup.world.gel.positions().to_vec();
    setup.world.move_support(0.0);
    assert_eq!(setup.world.gel.positions(), &rest[..]);

    let zero = scene(
        "simple",
        &[
            ("gel.box.nodes", "300"),
            (
                "gel.support_motion.breathing",
                "{amplitude = 0.0, period = 4.0, direction = [1.0, 0.0, 0.0]}",
            ),
        ],
    );
    let (a, b) = (run_steps(&still, 150), run_steps(&zero, 150));
    assert!(
        a.reports.iter().any(|r| r.inserted),
        "the run should puncture"
    );
    for (x, y) in a.reports.iter().zip(&b.reports) {
        assert_eq!(
            (x.tip, x.target, x.q),
            (y.tip, y.target, y.q),
            "step {}",
            x.step
        );
    }
}

/// Before puncture the target is the rest path's point carried by the support; the motion
/// hidden from the model leaves the controller's joints exactly those of the run without motion
/// (it sees nothing of it), while the world and its target move.
#[test]
fn target_moves_with_the_support_and_the_hidden_motion_leaves_the_joints_unchanged() {
    let still = run_steps(&scene("simple", &[("gel.box.nodes", "300")]), 160);
    let moving = |hidden: &str| {
        run_steps(
            &scene(
                "simple",
                &[
                    ("gel.box.nodes", "300"),
                    ("gel.support_motion.breathing", BREATHING_X),
                    ("gel.support_motion.hidden", hidden),
                ],
            ),
            160,
        )
    };
    let (modelled, hidden) = (moving("false"), moving("true"));
    let m = SupportMotion::breathing(5.0, 4.0, [1.0, 0.0, 0.0], 0.0).unwrap();
    let dt = 0.04;
    let mut air = 0;
    for (s, r) in still.reports.iter().zip(&modelled.reports) {
        if r.inserted || s.inserted {
            break;
        }
        air += 1;
        let d = m.displacement((r.step + 1) as f64 * dt);
        assert!(
            (r.target - s.target - d).norm() < 1e-12,
            "step {}: target moved by {:?}, support by {d:?}",
            r.step,
            r.target - s.target
        );
    }
    assert!(air > 50, "{air} steps in the air");
    assert!(modelled.reports.iter().any(|r| r.inserted));
    // Hidden: the joints are the still run's, bit for bit; the world's target moved.
    assert_eq!(hidden.reports.len(), still.reports.len());
    for (s, h) in still.reports.iter().zip(&hidden.reports) {
        assert_eq!(s.q, h.q, "step {}", s.step);
    }
    // The summaries say which run had a motion, which one, and whether it was hidden.
    assert_eq!(still.summary.support_motion, None);
    let said = |r: &RunResult| r.summary.support_motion.clone().expect("a support motion");
    assert_eq!(said(&modelled), m.summary(false));
    assert_eq!(said(&hidden), m.summary(true));
    let json = serde_json::to_value(&hidden.summary).unwrap();
    let motion = &json["support_motion"];
    assert_eq!(motion["kind"], "breathing");
    assert_eq!(motion["amplitude_mm"], 5.0);
    assert_eq!(motion["period_s"], 4.0);
    assert_eq!(motion["direction"], serde_json::json!([1.0, 0.0, 0.0]));
    assert_eq!(motion["hidden"], true);
    assert_eq!(
        serde_json::to_value(&still.summary).unwrap()["support_motion"],
        serde_json::Value::Null
    );
    let last = hidden.reports.len() - 1;
    let moved = (hidden.reports[last].target - still.reports[last].target).norm();
    println!("hidden: the world's target is {moved:.3} mm from the model's at the last step");
    assert!(moved > 1.0);
}

/// `text` written to `name` in `dir`.
fn temp_csv(dir: &tempfile::TempDir, name: &str, text: &str) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn setup_error(csv: &Path) -> String {
    let s = scene(
        "simple",
        &[
            ("gel.box.nodes", "300"),
            (
                "gel.support_motion.csv",
                &format!("{:?}", csv.display().to_string()),
            ),
        ],
    );
    match Setup::build(&s) {
        Ok(_) => panic!("{} should be refused", csv.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn csv_motion_errors_name_the_file_the_line_and_the_reason() {
    let dir = tempfile::Builder::new()
        .prefix("needle-support-motion-")
        .tempdir()
        .unwrap();
    let bad = temp_csv(&dir, "bad.csv", "t,dx,dy,dz\n0,0,0,0\n1.0,0.5,x,0\n");
    let e = setup_error(&bad);
    assert_eq!(
        e,
        format!(
            "gel.support_motion.csv: {}: line 3: `dy` is not a number: `x`",
            bad.display()
        )
    );
    let short = temp_csv(&dir, "short.csv", "0,0,0,0\n1,2,3\n");
    assert!(setup_error(&short).contains("line 2: expected 4 fields"));
    let back = temp_csv(&dir, "back.csv", "0,0,0,0\n2,0,0,1\n1,0,0,2\n");
    assert!(setup_error(&back).contains("line 3: `t` must increase"));
    let missing = bad.with_file_name("missing.csv");
    assert!(setup_error(&missing).contains("cannot read"));
    // A good table runs, and drives the support: 2 mm along y after 1 s.
    let good = temp_csv(&dir, "good.csv", "t, dx, dy, dz\n0, 0, 0, 0\n1, 0, 2, 0\n");
    let s = scene(
        "simple",
        &[
            ("gel.box.nodes", "300"),
            (
                "gel.support_motion.csv",
                &format!("{:?}", good.display().to_string()),
            ),
        ],
    );
    let r = run_steps(&s, 30);
    let said = r.summary.support_motion.expect("the table in the summary");
    assert_eq!(said.kind, needle_host::support_motion::MotionKind::Table);
    assert_eq!((said.amplitude_mm, said.table_rows), (2.0, Some(2)));
    assert_eq!(
        (said.direction, said.period_s),
        (Some([0.0, 1.0, 0.0]), None)
    );
    assert!(!said.hidden);
    let mut setup = Setup::build(&s).unwrap();
    setup.world.move_support(1.0);
    assert_eq!(setup.world.support_offset, Vector3::new(0.0, 2.0, 0.0));
    assert_eq!(r.reports.len(), 30);
    // The example scene's trace: its first cycle peaks at 2 s, 5 mm along x and 0.6 mm along z.
    let trace = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scenes/tissue/breathing_trace_complex.toml"
    );
    let mut setup = Setup::build(&scene(trace, &[])).unwrap();
    setup.world.move_support(2.0);
    assert!((setup.world.support_offset - Vector3::new(5.0, 0.0, 0.6)).norm() < 1e-12);
    // Both `breathing` and `csv`, or neither: refused by the scene's validation, naming the field.
    let both = Scene::builtin("simple").unwrap().with_overrides(&[
        ("gel.support_motion.breathing".into(), BREATHING_X.into()),
        ("gel.support_motion.csv".into(), "\"m.csv\"".into()),
    ]);
    assert!(both.unwrap_err().to_string().contains("gel.support_motion"));
    let zero_dir = Scene::builtin("simple").unwrap().with_overrides(&[(
        "gel.support_motion.breathing".into(),
        "{amplitude = 5.0, period = 4.0, direction = [0.0, 0.0, 0.0]}".into(),
    )]);
    assert!(
        zero_dir
            .unwrap_err()
            .to_string()
            .contains("gel.support_motion.breathing.direction")
    );
}

/// `scenes/tissue/breathing_complex.toml`: the complex insertion with its support breathing
/// 5 mm every 4 s across the insertion, with the motion modelled (target: e_mean and e_final
/// ≤ 1.0 mm) and hidden from the model. Bounds: the figures measured when this was written
/// (modelled 0.118 / 1.255 / 0.006 mm; hidden 0.614 / 1.707 / 1.207 mm) with a small margin.
/// Since settling ends at the first step that moves the tip away (2026-12-01), the hidden run
/// stops one step after its planned ones, at 0.560 / 1.591 / 0.778 mm: within the reach
/// tolerance at that breathing phase, so its outcome is no longer asserted, its errors are.
#[test]
#[ignore = "two complex insertions, about 40 s in release"]
fn breathing_complex_tracks_the_moving_path_when_the_motion_is_modelled() {
    let file = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scenes/tissue/breathing_complex.toml"
    );
    let modelled = run(&scene(file, &[]), &RunOptions::default(), |_| {}).unwrap();
    let s = &modelled.summary;
    println!(
        "modelled: e_mean {:.3} e_max {:.3} e_final {:.4} mm, {:?}",
        s.e_mean_mm, s.e_max_mm, s.e_final_mm, s.outcome
    );
    assert_eq!(s.outcome, Outcome::Reached);
    assert!(s.e_mean_mm <= 0.15, "e_mean {}", s.e_mean_mm);
    assert!(s.e_max_mm <= 1.4, "e_max {}", s.e_max_mm);
    assert!(s.e_final_mm <= 0.05, "e_final {}", s.e_final_mm);
    assert!(
        s.min_clearance_mm > 1.0,
        "min clearance {}",
        s.min_clearance_mm
    );
    let hidden = run(
        &scene(file, &[("gel.support_motion.hidden", "true")]),
        &RunOptions::default(),
        |_| {},
    )
    .unwrap();
    let h = &hidden.summary;
    println!(
        "hidden: e_mean {:.3} e_max {:.3} e_final {:.4} mm, {:?}",
        h.e_mean_mm, h.e_max_mm, h.e_final_mm, h.outcome
    );
    // The same controller blind to the motion: several times the tracking error, and a hundred
    // times the modelled run's distance to the path's end.
    assert!(h.e_mean_mm >= 0.5 && h.e_max_mm >= 1.5, "{h:?}");
    assert!(h.e_final_mm >= 0.5, "{h:?}");
}

/// The tissue's shift under the needle (`target_shift_max_mm`, `entry_shift_max_mm`) is the
/// gel's own deformation: a support that carries the whole gel 4.5 mm sideways by the last step
/// moves neither figure by more than a tenth of a millimetre (measured against the support, it
/// would be millimetres), and the insertion does move the tissue (both figures above zero),
/// more at the entry, which the needle drags, than at the target 40 mm below.
#[test]
fn tissue_shift_is_measured_against_the_moving_support_not_the_world() {
    let still = run_steps(&scene("simple", &[("gel.box.nodes", "300")]), 160);
    let moving = run_steps(
        &scene(
            "simple",
            &[
                ("gel.box.nodes", "300"),
                ("gel.support_motion.breathing", BREATHING_X),
            ],
        ),
        160,
    );
    let (s, m) = (&still.summary, &moving.summary);
    println!(
        "still: target {:.4} entry {:.4} mm; breathing: target {:.4} entry {:.4} mm",
        s.target_shift_max_mm, s.entry_shift_max_mm, m.target_shift_max_mm, m.entry_shift_max_mm
    );
    assert!(s.puncture_step.is_some() && m.puncture_step.is_some());
    assert!(s.target_shift_max_mm > 0.0 && s.entry_shift_max_mm > s.target_shift_max_mm);
    assert!((m.target_shift_max_mm - s.target_shift_max_mm).abs() < 0.1);
    assert!((m.entry_shift_max_mm - s.entry_shift_max_mm).abs() < 0.1);
    let d = SupportMotion::breathing(5.0, 4.0, [1.0, 0.0, 0.0], 0.0)
        .unwrap()
        .displacement(160.0 * 0.04);
    assert!(d.norm() > 4.0, "the support moved {d:?}");
    // Before the puncture nothing is measured.
    let air = run_steps(&scene("simple", &[("gel.box.nodes", "300")]), 20);
    assert_eq!(air.summary.puncture_step, None);
    assert_eq!(air.summary.target_shift_max_mm, 0.0);
    assert_eq!(air.summary.entry_shift_max_mm, 0.0);
    let json = serde_json::to_value(&still.summary).unwrap();
    assert!(
        json["target_shift_max_mm"]
            .as_f64()
            .is_some_and(|x| x > 0.0)
    );
}
