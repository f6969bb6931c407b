use super::*;
use crate::free_motion::LAG_ROTATION_LIMIT;
use nalgebra::Vector3;

fn err_of(text: &str) -> SceneError {
    match Scene::from_toml_str(text, "bad.toml") {
        Ok(_) => panic!("scene was accepted:\n{text}"),
        Err(e) => e,
    }
}

/// `scene` with its fields overridden (`needle run --set FIELD=VALUE`).
fn overridden(scene: &Scene, overrides: &[(&str, &str)]) -> Result<Scene, SceneError> {
    let o: Vec<(String, String)> = (overrides.iter())
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    scene.with_overrides(&o)
}

const MINIMAL: &str = r#"
name = "minimal"
[path]
points = [[300.0, 0.0, 60.0], [300.0, 0.0, 10.0]]
"#;

#[test]
fn builtin_scenes_parse_and_encode_the_benchmark() {
    for name in Scene::BUILTIN {
        let s = Scene::builtin(name).unwrap_or_else(|| panic!("builtin {name} failed"));
        assert_eq!(s.name, name);
        let p = s.sampled_path().expect("path");
        assert!((p.entry() - Vector3::new(300.0, 0.0, 60.0)).norm() < 1e-12);
        assert!((p.points.last().unwrap().z - 10.0).abs() < 1e-12);
        assert_eq!(s.gel.box_mesh.unwrap().nodes, 1500);
        assert_eq!(s.interaction.constraint_spacing, 10.0);
    }
    let simple = Scene::builtin("simple").unwrap();
    let p = simple.sampled_path().unwrap();
    assert!((p.start_tip() - Vector3::new(300.0, 0.0, 70.0)).norm() < 1e-12);
    assert!((p.points.last().unwrap().x - 308.0).abs() < 1e-12);
    assert_eq!(simple.obstacles.len(), 1);

    // Complex: entry tangent tilted atan(3·2π/50) = 20.65° from vertical (BENCHMARK.md: 20.7°).
    let complex = Scene::builtin("complex").unwrap();
    let p = complex.sampled_path().unwrap();
    let tilt = p
        .entry_tangent()
        .dot(&Vector3::new(0.0, 0.0, -1.0))
        .acos()
        .to_degrees();
    assert!((tilt - 20.65).abs() < 0.05, "tilt {tilt}");
    assert_eq!(complex.obstacles.len(), 3);
    // The obstacles sit beside the path at s = 0.25, 0.5, 0.75.
    let (mid, _) = p.at(p.approach + p.length() * 0.5);
    assert!(
        (mid - Vector3::new(300.0, 1.25, 35.0)).norm() < 0.5,
        "{mid}"
    );
}

#[test]
fn shipped_files_equal_the_embedded_scenes() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    for name in Scene::BUILTIN {
        let file = Scene::load(&dir.join(format!("{name}.toml"))).expect("load");
        assert_eq!(Some(file), Scene::builtin(name));
    }
}

#[test]
fn minimal_scene_takes_documented_defaults() {
    let s = Scene::from_toml_str(MINIMAL, "min.toml").expect("minimal");
    assert_eq!(s.gel.young_modulus, 0.02);
    assert_eq!(s.needle.beams, 40);
    assert_eq!(s.interaction.puncture_force, 0.2);
    assert_eq!(s.inverse.delta_q, 0.01);
    assert_eq!(s.path.approach, 10.0);
    assert_eq!(s.robot.preset, "rv1a");
}

#[test]
fn path_is_parametrised_by_arc_length_through_the_approach() {
    let s = Scene::from_toml_str(MINIMAL, "min.toml").unwrap();
    let p = s.sampled_path().unwrap();
    assert_eq!(p.total_length(), 60.0);
    let (a, t) = p.at(0.0);
    assert!((a - Vector3::new(300.0, 0.0, 70.0)).norm() < 1e-12);
    assert!((t - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    let (b, _) = p.at(35.0);
    assert!((b - Vector3::new(300.0, 0.0, 35.0)).norm() < 1e-12);
    let (c, _) = p.at(1e9);
    assert!((c - Vector3::new(300.0, 0.0, 10.0)).norm() < 1e-12);
}

#[test]
fn malformed_scenes_name_file_field_and_reason() {
    let cases: &[(&str, &str, &str)] = &[
        ("[gel]\nyoung_modulus = -1.0\n", "gel.young_modulus", "> 0"),
        (
            "[gel]\npoisson_ratio = 0.5\n",
            "gel.poisson_ratio",
            "(-1, 0.5)",
        ),
        (
            "[gel]\nyoung_modulus = \"soft\"\n",
            "gel.young_modulus",
            "invalid type",
        ),
        (
            "[gel]\nyoungs_modulus = 1.0\n",
            "gel.youngs_modulus",
            "unknown field",
        ),
        ("[needle]\nbeams = 0\n", "needle.beams", "between"),
        (
            "[interaction]\nconstraint_spacing = 0.0\n",
            "interaction.constraint_spacing",
            "> 0",
        ),
        (
            "[robot]\npreset = \"ur5\"\n",
            "robot.preset",
            "unknown robot",
        ),
        (
            "[robot]\njoint_min_deg = [0, 0, 0]\n",
            "robot.joint_min_deg",
            "6 values",
        ),
        ("[inverse]\ndelta_q = 2.0\n", "inverse.delta_q", "0.5"),
        (
            "[[obstacles]]\ncenter = [0, 0, 0]\nradius = -2\n",
            "obstacles[0].radius",
            "> 0",
        ),
        (
            "[gel.fixed]\nbelow_z = nan\n",
            "gel.fixed.below_z",
            "finite",
        ),
    ];
    for (extra, field, reason) in cases {
        let e = err_of(&format!("{MINIMAL}\n{extra}"));
        assert_eq!(e.file, "bad.toml");
        assert_eq!(&e.field, field, "{extra}: {e}");
        assert!(
            e.reason.contains(reason),
            "{extra}: reason `{}` lacks `{reason}`",
            e.reason
        );
        let shown = e.to_string();
        assert!(shown.starts_with("bad.toml: field `"), "{shown}");
    }
}

#[test]
fn malformed_paths_are_rejected_with_their_field() {
    let bad_formula =
        "name = \"x\"\n[path]\nformula = { x = \"300 + q\", y = \"0\", z = \"60 - 50*s\" }\n";
    assert_eq!(err_of(bad_formula).field, "path.formula.x");
    let unparsable =
        "name = \"x\"\n[path]\nformula = { x = \"300 +* (\", y = \"0\", z = \"60 - 50*s\" }\n";
    assert_eq!(err_of(unparsable).field, "path.formula.x");
    let infinite =
        "name = \"x\"\n[path]\nformula = { x = \"300\", y = \"1/s\", z = \"60 - 50*s\" }\n";
    assert_eq!(err_of(infinite).field, "path.formula.y");
    let both = "name = \"x\"\n[path]\npoints = [[0,0,0],[0,0,1]]\nformula = { x = \"0\", y = \"0\", z = \"s\" }\n";
    assert_eq!(err_of(both).field, "path");
    let repeated = "name = \"x\"\n[path]\npoints = [[0,0,0],[0,0,0]]\n";
    assert_eq!(err_of(repeated).field, "path.points[1]");
    let missing = "name = \"x\"\n";
    let e = err_of(missing);
    assert!(e.reason.contains("missing field `path`"), "{e}");
}

#[test]
fn syntax_errors_name_the_file() {
    let e = err_of("name = \"x\"\n[path\n");
    assert_eq!(e.file, "bad.toml");
    assert!(e.field.is_empty());
    assert!(e.reason.contains("line 2"), "{e}");
}

#[test]
fn missing_file_is_an_error_not_a_panic() {
    let e = Scene::load(std::path::Path::new("/nonexistent/scene.toml")).unwrap_err();
    assert!(e.reason.contains("cannot read"), "{e}");
}

/// Every function `docs/scene-format.md` lists for formulas evaluates.
#[test]
fn formula_functions_documented_in_scene_format_work() {
    let text = "name = \"f\"\n[path]\nsamples = 3\nformula = { x = \"sqrt(abs(-4)) + sin(0) + cos(0) + tan(0) + exp(0) + log(1) + 2^2\", y = \"PI*s\", z = \"60 - 50*s\" }\n";
    let s = Scene::from_toml_str(text, "f.toml").expect("functions");
    let p = s.sampled_path().unwrap();
    assert!((p.points[0].x - 8.0).abs() < 1e-12, "{}", p.points[0].x);
    assert!((p.points[2].y - std::f64::consts::PI).abs() < 1e-12);
}

#[test]
fn overrides_set_dotted_fields_and_are_validated() {
    let s = Scene::builtin("simple").unwrap();
    let o = s
        .with_overrides(&[
            ("inverse.delta_q".into(), "0.001".into()),
            ("inverse.jacobian".into(), "\"solve\"".into()),
        ])
        .expect("overrides");
    assert_eq!(o.inverse.delta_q, 0.001);
    assert_eq!(o.inverse.jacobian, JacobianSpec::Solve);
    assert_eq!(o.gel, s.gel);
    let e = s
        .with_overrides(&[("gel.young_modulus".into(), "-1".into())])
        .unwrap_err();
    assert_eq!(e.field, "gel.young_modulus");
    let e = s
        .with_overrides(&[("gel.youngs_modulus".into(), "1".into())])
        .unwrap_err();
    assert_eq!(e.field, "gel.youngs_modulus");
    let e = s
        .with_overrides(&[("inverse.delta_q".into(), "0.0.1".into())])
        .unwrap_err();
    assert!(e.reason.contains("not a TOML value"), "{e}");
}

#[test]
fn factorisation_defaults_follow_the_mode() {
    let s = Scene::builtin("complex").unwrap();
    assert!(s.solver.background_factorization);
    assert_eq!(s.solver.refactor_every, None);
    assert_eq!(s.solver.refactor_every(), 2);
    let set = |o: &[(&str, &str)]| {
        let o: Vec<(String, String)> = o
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect();
        s.with_overrides(&o)
    };
    let sync = set(&[("solver.background_factorization", "false")]).unwrap();
    assert_eq!(sync.solver.refactor_every(), 1, "the paper's: every step");
    let three = set(&[("solver.refactor_every", "3")]).unwrap();
    assert_eq!(three.solver.refactor_every(), 3);
    let e = set(&[("solver.refactor_every", "0")]).unwrap_err();
    assert_eq!(e.field, "solver.refactor_every");
    assert_eq!(s.solver.refresh_rotation, 0.05, "the adaptive refresh");
    assert_eq!(
        s.solver.refresh_ceiling, None,
        "no ceiling: refreshed by rotation alone"
    );
    let ceiling = set(&[("solver.refresh_ceiling", "16")]).unwrap();
    assert_eq!(ceiling.solver.refresh_ceiling, Some(16));
    let adaptive = set(&[("solver.refresh_rotation", "0.02")]).unwrap();
    assert_eq!(adaptive.solver.refresh_rotation, 0.02);
    let fixed = set(&[("solver.refresh_rotation", "0")]).unwrap();
    assert_eq!(fixed.solver.refresh_rotation, 0.0, "the fixed pipeline");
    for bad in ["-0.01", "0.3", "nan"] {
        let e = set(&[("solver.refresh_rotation", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.refresh_rotation", "{bad}");
    }
    let e = set(&[("solver.refresh_ceiling", "0")]).unwrap_err();
    assert_eq!(e.field, "solver.refresh_ceiling");
    assert_eq!(s.solver.near_radius, NearRadiusSpec::Auto, "the default");
    let box_volume = 80.0 * 60.0 * 60.0;
    assert_eq!(
        s.solver
            .near_radius
            .radius(NEAR_AUTO_MIN_NODES - 1, box_volume),
        None
    );
    let at = |nodes| s.solver.near_radius.radius(nodes, box_volume).unwrap();
    assert!((at(5040) - 9.8).abs() < 0.05, "{}", at(5040));
    assert!((at(19_800) - 7.7).abs() < 0.05, "{}", at(19_800));
    assert!(
        (at(1485) - 12.7).abs() < 0.05,
        "the benchmark gels: {}",
        at(1485)
    );
    let near = set(&[("solver.near_radius", "8.5")]).unwrap();
    assert_eq!(near.solver.near_radius, NearRadiusSpec::Radius(8.5));
    assert_eq!(
        near.solver.near_radius.radius(10, 1.0),
        Some(8.5),
        "whatever the gel"
    );
    let off = set(&[("solver.near_radius", "\"off\"")]).unwrap();
    assert_eq!(off.solver.near_radius.radius(100_000, box_volume), None);
    let auto = set(&[("solver.near_radius", "\"auto\"")]).unwrap();
    assert_eq!(auto.solver.near_radius, NearRadiusSpec::Auto);
    for bad in ["0", "-1", "nan", "inf"] {
        let e = set(&[("solver.near_radius", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.near_radius", "{bad}");
        assert!(e.to_string().contains("positive distance"), "{e}");
    }
    // Absent: `refresh_rotation` below FAR_REFRESH_AUTO_MIN_NODES nodes, the limit from it.
    let small = FAR_REFRESH_AUTO_MIN_NODES - 1;
    assert_eq!(
        s.solver.far_refresh_rotation(small),
        s.solver.refresh_rotation
    );
    assert_eq!(
        s.solver.far_refresh_rotation(FAR_REFRESH_AUTO_MIN_NODES),
        LAG_ROTATION_LIMIT
    );
    let far = set(&[("solver.far_refresh_rotation", "0.08")]).unwrap();
    for nodes in [small, FAR_REFRESH_AUTO_MIN_NODES] {
        assert_eq!(
            far.solver.far_refresh_rotation(nodes),
            0.08,
            "as set, at {nodes} nodes"
        );
    }
    let limit = LAG_ROTATION_LIMIT.to_string();
    let at_limit = set(&[("solver.far_refresh_rotation", limit.as_str())]).unwrap();
    assert_eq!(
        at_limit.solver.far_refresh_rotation(small),
        LAG_ROTATION_LIMIT
    );
    // A loop with a deadline keeps the background refreshes at any size.
    let deadline = set(&[("solver.asynchronous_factor", "true")]).unwrap();
    assert_eq!(
        deadline.solver.far_refresh_rotation(19_800),
        deadline.solver.refresh_rotation
    );
    // The gel's parameters follow the size.
    let far_rotation = |nodes| {
        crate::setup::gel_params(&s, nodes)
            .refresh
            .map(|r| r.far_rotation)
    };
    assert_eq!(far_rotation(1500), Some(s.solver.refresh_rotation));
    assert_eq!(far_rotation(19_800), Some(LAG_ROTATION_LIMIT));
    for bad in ["0", "-0.1", "0.3", "nan"] {
        let e = set(&[("solver.far_refresh_rotation", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.far_refresh_rotation", "{bad}");
    }
    assert_eq!(
        s.solver.far_elements,
        FarElementsSpec::Corotational,
        "the default"
    );
    for (text, kind) in [
        ("\"corotational\"", FarElementsSpec::Corotational),
        ("\"linear\"", FarElementsSpec::Linear),
    ] {
        assert_eq!(
            set(&[("solver.far_elements", text)])
                .unwrap()
                .solver
                .far_elements,
            kind
        );
    }
    let e = set(&[("solver.far_elements", "\"rigid\"")]).unwrap_err();
    assert_eq!(e.field, "solver.far_elements");
    assert_eq!(s.solver.entry_radius, NearRadiusSpec::Auto, "the default");
    let entry = set(&[("solver.entry_radius", "12")]).unwrap();
    assert_eq!(entry.solver.entry_radius, NearRadiusSpec::Radius(12.0));
    let off = set(&[("solver.entry_radius", "\"off\"")]).unwrap();
    assert_eq!(off.solver.entry_radius, NearRadiusSpec::Off);
    for bad in ["0", "-1", "nan"] {
        let e = set(&[("solver.entry_radius", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.entry_radius", "{bad}");
    }
    assert_eq!(s.solver.far_residual_tolerance, 1e-3, "the default");
    let exact = set(&[("solver.far_residual_tolerance", "0")]).unwrap();
    assert_eq!(exact.solver.far_residual_tolerance, 0.0);
    let gel = crate::setup::gel_params(
        &set(&[("solver.far_residual_tolerance", "0.01")]).unwrap(),
        1500,
    );
    assert_eq!(gel.far_residual_tolerance, 0.01, "reaches the gel model");
    for bad in ["-1e-3", "0.2", "nan", "inf"] {
        let e = set(&[("solver.far_residual_tolerance", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.far_residual_tolerance", "{bad}");
        assert!(e.to_string().contains("every solve exact"), "{e}");
    }
    assert!(s.solver.defer_far, "the default");
    let whole = set(&[("solver.defer_far", "false")]).unwrap();
    assert!(!whole.solver.defer_far);
    assert!(
        !crate::setup::gel_params(&whole, 1500).defer_far,
        "reaches the gel model"
    );
    assert!(crate::setup::gel_params(&s, 1500).defer_far);
    for bad in ["1", "\"yes\""] {
        let e = set(&[("solver.defer_far", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.defer_far", "{bad}");
    }
    assert!(
        !s.solver.asynchronous_factor,
        "the default: runs repeat bit for bit"
    );
    assert!(!crate::setup::gel_params(&s, 1500).asynchronous_factor);
    let asynchronous = set(&[("solver.asynchronous_factor", "true")]).unwrap();
    assert!(
        crate::setup::gel_params(&asynchronous, 1500).asynchronous_factor,
        "reaches the gel model"
    );
    for bad in ["1", "\"never\""] {
        let e = set(&[("solver.asynchronous_factor", bad)]).unwrap_err();
        assert_eq!(e.field, "solver.asynchronous_factor", "{bad}");
    }
    for bad in ["\"sometimes\"", "true"] {
        let e = set(&[("solver.near_radius", bad)]).unwrap_err();
        assert!(e.to_string().contains("solver.near_radius"), "{bad}: {e}");
        assert!(e.to_string().contains("\"auto\" or \"off\""), "{bad}: {e}");
    }
    assert_eq!(
        s.solver.factor_precision,
        FactorPrecisionSpec::Single,
        "the checked f32 gel factor"
    );
    let double = set(&[("solver.factor_precision", "\"double\"")]).unwrap();
    assert_eq!(double.solver.factor_precision, FactorPrecisionSpec::Double);
    let e = set(&[("solver.factor_precision", "\"half\"")]).unwrap_err();
    assert!(e.to_string().contains("factor_precision"), "{e}");
}

#[test]
fn start_joints_and_insertion_mode_are_checked_and_used() {
    let e = err_of(&format!(
        "{MINIMAL}\n[robot]\nstart_joints_deg = [0.0, 60.0, 120.0, 0.0, 95.0, 0.0]\n"
    ));
    let msg = e.to_string();
    assert!(
        msg.contains("robot.start_joints_deg[4]") && msg.contains("outside the joint limits"),
        "{msg}"
    );
    let e = err_of(&format!(
        "{MINIMAL}\n[robot]\nstart_joints_deg = [0.0, 60.0]\n"
    ));
    assert!(e.to_string().contains("needs 6 values"), "{e}");
    let e = err_of(&format!("{MINIMAL}\n[insertion]\nmode = \"sideways\"\n"));
    assert!(e.to_string().contains("insertion.mode"), "{e}");
    for lead in ["0.05", "nan", "-1.0"] {
        let e = err_of(&format!("{MINIMAL}\n[insertion]\nmax_lead = {lead}\n"));
        assert!(
            e.to_string().contains("insertion.max_lead") && e.to_string().contains("at least"),
            "{lead}: {e}"
        );
    }
    let lead = Scene::from_toml_str(
        &format!("{MINIMAL}\n[insertion]\nmax_lead = 0.5\n"),
        "ok.toml",
    )
    .expect("valid");
    assert_eq!(crate::setup::step_params(&lead).insertion.max_lead, 0.5);

    let s = Scene::from_toml_str(
        &format!("{MINIMAL}\n[insertion]\nmode = \"back-and-forth\"\nadvance_per_step = 1.0\n"),
        "ok.toml",
    )
    .expect("valid");
    // The scene's schedule is the step's: one formula (`step::Insertion`).
    let insertion = crate::setup::step_params(&s).insertion;
    let total = 10.0;
    assert_eq!(insertion.default_steps(total), 20);
    let c: Vec<f64> = (0..22).map(|k| insertion.target_arc(total, k)).collect();
    assert_eq!(c[8], 9.0);
    assert_eq!(c[9], 10.0);
    assert_eq!(c[10], 9.0);
    assert_eq!(c[19], 0.0);
    assert_eq!(c[20], 1.0);
    let insert = Scene::from_toml_str(MINIMAL, "ok.toml").expect("valid");
    let insertion = crate::setup::step_params(&insert).insertion;
    assert_eq!(insertion.target_arc(total, 500), total);
    assert!(
        !insertion.follows_tip(),
        "the default keeps to the schedule"
    );
}

#[test]
fn the_update_method_clearance_margin_and_qp_angle_weight_reach_the_core_and_are_checked() {
    use needle_core::inverse::StepMethod;
    let s = Scene::builtin("complex").unwrap();
    assert_eq!(s.inverse_params().method, StepMethod::Qp, "the default");
    assert_eq!(s.inverse_params().clearance_margin, 0.2);
    assert_eq!(s.inverse_params().qp_angle_weight, 10.0);
    assert!(s.inverse_params().qp_heading, "the default");
    assert!(!s.inverse_params().replan_rejected, "the default");
    assert!(s.inverse_params().resume_held, "the default");
    assert!(s.inverse_params().settling_margin, "the default");
    assert!(!s.inverse_params().second_opinion, "the default");
    assert_eq!(s.inverse_params().qp_angle_damping_max, 5.0, "the default");
    assert_eq!(s.inverse_params().qp_spin_weight, 0.0, "the default");
    assert_eq!(
        s.inverse.entry_tilt,
        crate::step::EntryTilt::Auto,
        "the default"
    );
    let mu = s.interaction.surface_friction;
    let auto = crate::setup::step_params(&s).entry_tilt;
    assert!((auto - crate::step::ENTRY_TILT_FRACTION * mu.atan()).abs() < 1e-15);
    let tilt = s
        .with_overrides(&[("inverse.entry_tilt".into(), "0.25".into())])
        .expect("an angle");
    assert_eq!(crate::setup::step_params(&tilt).entry_tilt, 0.25);
    for bad in ["-0.1", "nan", "\"steep\""] {
        let e = s
            .with_overrides(&[("inverse.entry_tilt".into(), bad.into())])
            .unwrap_err();
        assert!(e.to_string().contains("inverse.entry_tilt"), "{bad}: {e}");
    }
    let o = s
        .with_overrides(&[
            ("inverse.replan_rejected".into(), "true".into()),
            ("inverse.second_opinion".into(), "true".into()),
            ("inverse.qp_angle_damping_max".into(), "21".into()),
            ("inverse.resume_held".into(), "false".into()),
            ("inverse.settling_margin".into(), "false".into()),
            ("inverse.method".into(), "\"paper\"".into()),
            ("inverse.clearance_margin".into(), "0.5".into()),
            ("inverse.qp_angle_weight".into(), "3".into()),
            ("inverse.qp_heading".into(), "false".into()),
            ("inverse.qp_spin_weight".into(), "100".into()),
        ])
        .expect("overrides");
    assert_eq!(o.inverse_params().qp_spin_weight, 100.0);
    assert!(!o.inverse_params().qp_heading);
    assert!(o.inverse_params().replan_rejected);
    assert!(o.inverse_params().second_opinion);
    assert_eq!(o.inverse_params().qp_angle_damping_max, 21.0);
    assert!(!o.inverse_params().resume_held);
    assert!(!o.inverse_params().settling_margin);
    assert_eq!(o.inverse_params().method, StepMethod::Paper);
    assert_eq!(o.inverse_params().clearance_margin, 0.5);
    assert_eq!(o.inverse_params().qp_angle_weight, 3.0);
    let e = s
        .with_overrides(&[("inverse.qp_angle_weight".into(), "-1".into())])
        .unwrap_err();
    assert_eq!(e.field, "inverse.qp_angle_weight");
    let e = s
        .with_overrides(&[("inverse.clearance_margin".into(), "-0.1".into())])
        .unwrap_err();
    assert_eq!(e.field, "inverse.clearance_margin");
    let e = s
        .with_overrides(&[("inverse.qp_angle_damping_max".into(), "-5".into())])
        .unwrap_err();
    assert_eq!(e.field, "inverse.qp_angle_damping_max");
    for bad in ["-1", "nan", "\"high\""] {
        let e = s
            .with_overrides(&[("inverse.qp_spin_weight".into(), bad.into())])
            .unwrap_err();
        assert!(
            e.to_string().contains("inverse.qp_spin_weight"),
            "{bad}: {e}"
        );
    }
    let e = s
        .with_overrides(&[("inverse.method".into(), "\"newton\"".into())])
        .unwrap_err();
    assert!(e.to_string().contains("inverse.method"), "{e}");
}

/// `solver.gs_relaxation` defaults to the core's own default (so the host runs the solves the
/// core's benches time), reaches the core's Gauss-Seidel, and is refused outside [0.1, 1.9]
/// (the range the sweep clamps to) with its field named.
#[test]
fn gs_relaxation_defaults_to_the_cores_and_reaches_its_solves() {
    let s = Scene::builtin("complex").unwrap();
    let core = needle_core::InverseParams::default().gs;
    assert_eq!(s.solver.gs_relaxation, core.relaxation);
    let expected = needle_core::constraint::GsParams {
        tolerance: s.solver.gs_tolerance,
        max_iterations: s.solver.gs_max_iterations,
        ..core
    };
    assert_eq!(s.inverse_params().gs, expected);
    let o = s
        .with_overrides(&[("solver.gs_relaxation".into(), "1.2".into())])
        .expect("in range");
    assert_eq!(o.inverse_params().gs.relaxation, 1.2);
    for bad in ["0.05", "1.95", "2", "nan"] {
        let e = s
            .with_overrides(&[("solver.gs_relaxation".into(), bad.into())])
            .unwrap_err();
        assert_eq!(e.field, "solver.gs_relaxation", "{bad}");
    }
}

/// `inverse.qp_horizon`: `"auto"` by default, resolved from the needle's steering length (the
/// benchmark's needle in its gel: none; a thin needle in a stiff gel: the whole 3 mm); a number
/// is taken as given; a negative one or another word is refused naming the field.
#[test]
fn qp_horizon_is_auto_by_default_and_follows_the_steering_length() {
    let complex = Scene::builtin("complex").unwrap();
    assert_eq!(complex.inverse.qp_horizon, HorizonSpec::Auto, "the default");
    assert!((complex.steering_length() - 26.5).abs() < 0.05);
    assert_eq!(
        complex.inverse_params().qp_horizon,
        0.0,
        "long ℓ: the error now"
    );
    let set = |o: &[(&str, &str)]| overridden(&complex, o);
    // Ø 0.52 mm steel in 25 kPa (the public `needle_thin`): ℓ = 13.0 mm.
    let thin = set(&[("needle.diameter", "0.52"), ("gel.young_modulus", "0.025")]).unwrap();
    assert!(
        (thin.steering_length() - 13.0).abs() < 0.05,
        "{}",
        thin.steering_length()
    );
    assert_eq!(thin.inverse_params().qp_horizon, HORIZON_AUTO_MM);
    // Between the two ends, linear.
    let mid = HorizonSpec::Auto.horizon(0.5 * (HORIZON_AUTO_FULL_BELOW + HORIZON_AUTO_NONE_ABOVE));
    assert!((mid - 0.5 * HORIZON_AUTO_MM).abs() < 1e-12, "{mid}");
    assert_eq!(HorizonSpec::Auto.horizon(f64::NAN), 0.0);
    let fixed = set(&[("inverse.qp_horizon", "2.5")]).unwrap();
    assert_eq!(fixed.inverse.qp_horizon, HorizonSpec::Mm(2.5));
    assert_eq!(
        fixed.inverse_params().qp_horizon,
        2.5,
        "whatever the needle"
    );
    let auto = set(&[("inverse.qp_horizon", "\"auto\"")]).unwrap();
    assert_eq!(auto.inverse.qp_horizon, HorizonSpec::Auto);
    let e = set(&[("inverse.qp_horizon", "-1")]).unwrap_err();
    assert_eq!(e.field, "inverse.qp_horizon");
    let e = set(&[("inverse.qp_horizon", "\"far\"")]).unwrap_err();
    assert!(e.to_string().contains("\"auto\""), "{e}");
    assert!(e.to_string().contains("qp_horizon"), "{e}");
}

/// `SampledPath::straightened`: the planned path at 0, the chord from the path's point
/// `from` past the entry point to the end at 1, in between at a fraction; the approach, the
/// path up to `from` and the end unchanged.
#[test]
fn straightened_path_runs_from_the_path_to_its_chord() {
    // The simple benchmark's path: x = 300 + 8 s², bending towards +x.
    let bent = Scene::builtin("simple").unwrap();
    let p = bent.sampled_path().unwrap();
    let end = p.at(p.total_length()).0;
    for from in [0.0, 20.0] {
        let start = p.at(p.approach + from).0;
        for beta in [0.0, 0.4, 1.0] {
            // The approach in the air, the path down to `from` and the end are the path's own.
            for l in [
                0.0,
                5.0,
                p.approach,
                p.approach + from,
                p.total_length(),
                1e9,
            ] {
                assert!(
                    (p.straightened(l, beta, from) - p.at(l).0).norm() < 1e-12,
                    "{l} {beta} {from}"
                );
            }
        }
        for k in 1..10 {
            let u = f64::from(k) / 10.0;
            let l = p.approach + from + (p.length() - from) * u;
            let (at, chord) = (p.at(l).0, start + (end - start) * u);
            assert_eq!(p.straightened(l, 0.0, from), at);
            assert!((p.straightened(l, 1.0, from) - chord).norm() < 1e-9, "{l}");
            let mid = p.straightened(l, 0.4, from);
            assert!((mid - (at + 0.4 * (chord - at))).norm() < 1e-9, "{l}");
            // The path bends towards +x; its chords lie beyond it, so the shown point does too.
            assert!(
                chord.x > at.x && mid.x > at.x && mid.x < chord.x,
                "{l}: {at} {mid} {chord}"
            );
        }
    }
    // Shallower than `from` the path itself; from beyond the path's end, the path everywhere.
    let l = p.approach + 10.0;
    assert_eq!(p.straightened(l, 1.0, 20.0), p.at(l).0);
    assert_eq!(p.straightened(l + 30.0, 1.0, 1e3), p.at(l + 30.0).0);
}

/// `needle.yield_strain`: absent by default (not checked); a fraction in [10⁻⁶, 1] is taken
/// as given; anything else is refused naming the field (what a run does with it:
/// `run::summary::tests::a_needle_bent_past_its_yield_strain_is_flagged`). Given, the `"qp"`
/// update keeps the needle under it unless `inverse.bound_strain = false`; the paper's update
/// has no rows to keep it with.
#[test]
fn needle_yield_strain_is_optional_and_refused_outside_its_range() {
    use crate::setup::{step_params, strain_bounded};
    let simple = Scene::builtin("simple").unwrap();
    assert_eq!(simple.needle.yield_strain, None, "not checked by default");
    assert!(simple.inverse.bound_strain, "on by default");
    assert!(!strain_bounded(&simple), "nothing to bound it by");
    assert_eq!(step_params(&simple).yield_strain, f64::INFINITY);
    let set = |o: &[(&str, &str)]| overridden(&simple, o);
    let given = set(&[("needle.yield_strain", "0.008")]).unwrap();
    assert_eq!(given.needle.yield_strain, Some(0.008));
    assert!(strain_bounded(&given));
    assert_eq!(step_params(&given).yield_strain, 0.008);
    for off in [
        [
            ("needle.yield_strain", "0.008"),
            ("inverse.bound_strain", "false"),
        ],
        [
            ("needle.yield_strain", "0.008"),
            ("inverse.method", "\"paper\""),
        ],
    ] {
        let s = set(&off).unwrap();
        assert!(!strain_bounded(&s), "{off:?}");
        assert_eq!(step_params(&s).yield_strain, f64::INFINITY, "{off:?}");
    }
    let e = set(&[("inverse.bound_strain", "1")]).unwrap_err();
    assert_eq!(e.field, "inverse.bound_strain");
    for bad in ["0.0", "-0.01", "1.5", "nan", "\"steel\""] {
        let e = set(&[("needle.yield_strain", bad)]).unwrap_err();
        assert_eq!(e.field, "needle.yield_strain", "{bad}");
    }
}

/// `inverse.straighten` and `inverse.straighten_from`: `"auto"` by default; a fraction in
/// [0, 1] and a length ≥ 0 are taken as given; `inverse.straighten_max_offset` is
/// [`crate::straighten::MAX_OFFSET_MM`] by default and taken in (0, the path's tolerance];
/// `inverse.target_standoff` is 0 by default and taken ≥ 0;
/// anything else is refused naming the field (what `"auto"` resolves to: `straighten::tests`).
#[test]
fn straighten_is_auto_by_default_and_refused_outside_its_range() {
    let complex = Scene::builtin("complex").unwrap();
    assert_eq!(complex.inverse.straighten, StraightenSpec::Auto);
    assert_eq!(complex.inverse.straighten_from, StraightenFromSpec::Auto);
    assert_eq!(
        complex.inverse.straighten_max_offset,
        crate::straighten::MAX_OFFSET_MM
    );
    assert!(crate::plan_check::lags_its_bend(13.0, 11.5));
    assert!(!crate::plan_check::lags_its_bend(26.5, 11.5), "long ℓ");
    assert!(
        !crate::plan_check::lags_its_bend(13.0, 0.5),
        "a straight path"
    );
    let set = |o: &[(&str, &str)]| overridden(&complex, o);
    let fixed = set(&[
        ("inverse.straighten", "0.25"),
        ("inverse.straighten_from", "7.5"),
        ("inverse.straighten_max_offset", "3.0"),
        ("inverse.target_standoff", "1.0"),
    ])
    .unwrap();
    assert_eq!(fixed.inverse.straighten_max_offset, 3.0);
    assert_eq!(fixed.inverse.target_standoff, 1.0);
    assert_eq!(complex.inverse.target_standoff, 0.0, "none by default");
    assert_eq!(fixed.inverse.straighten, StraightenSpec::Fraction(0.25));
    assert_eq!(fixed.inverse.straighten_from, StraightenFromSpec::Mm(7.5));
    assert_eq!(fixed.inverse.straighten_from.from(26.5), 7.5);
    assert_eq!(StraightenFromSpec::Auto.from(26.5), 26.5);
    let auto = set(&[
        ("inverse.straighten", "\"auto\""),
        ("inverse.straighten_from", "\"auto\""),
    ])
    .unwrap();
    assert_eq!(auto.inverse.straighten, StraightenSpec::Auto);
    assert_eq!(auto.inverse.straighten_from, StraightenFromSpec::Auto);
    for (field, bad) in [
        ("inverse.straighten", "-0.1"),
        ("inverse.straighten", "1.5"),
        ("inverse.straighten", "nan"),
        ("inverse.straighten_from", "-1.0"),
        ("inverse.straighten_from", "nan"),
        ("inverse.straighten_max_offset", "0.0"),
        ("inverse.straighten_max_offset", "3.01"),
        ("inverse.straighten_max_offset", "nan"),
        ("inverse.target_standoff", "-0.1"),
        ("inverse.target_standoff", "nan"),
    ] {
        let e = set(&[(field, bad)]).unwrap_err();
        assert_eq!(e.field, field, "{bad}");
    }
    for field in ["inverse.straighten", "inverse.straighten_from"] {
        let e = set(&[(field, "\"more\"")]).unwrap_err();
        assert!(e.to_string().contains("\"auto\""), "{e}");
        assert!(e.to_string().contains("straighten"), "{e}");
    }
}
