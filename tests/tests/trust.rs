//! Regression tests of issue 13 (trust): no success that was not earned, plans refused at
//! set-up, hostile input refused with one line naming the field. Each test is named after the
//! case that broke.

use needle_host::error::SetupError;
use needle_host::mesh::{TetMesh, box_mesh, read_gmsh, read_gmsh_bytes, write_gmsh_ascii};
use needle_host::run::{RunOptions, StopReason, run};
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use std::path::{Path, PathBuf};

fn simple(overrides: &[(&str, &str)]) -> Result<Scene, String> {
    let o: Vec<(String, String)> = overrides
        .iter()
        .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
        .collect();
    Scene::builtin("simple")
        .expect("simple")
        .with_overrides(&o)
        .map_err(|e| e.to_string())
}

/// The message of a scene refused by validation (it must name `field`, on one line).
fn refused(overrides: &[(&str, &str)], field: &str) -> String {
    let e = simple(overrides).expect_err("the scene must be refused");
    assert!(e.contains(field), "`{e}` does not name {field}");
    assert!(!e.contains('\n'), "not one line: {e}");
    e
}

/// The message of a scene refused at set-up (one line).
fn setup_refused(scene: &Scene) -> String {
    let e = match Setup::build(scene) {
        Ok(_) => panic!("the set-up must be refused"),
        Err(e) => needle_host::error::chain(&e),
    };
    assert!(!e.contains('\n'), "not one line: {e}");
    e
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A fresh folder of this test, removed when dropped, and `name` in it.
fn tmp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = (tempfile::Builder::new().prefix("needle-trust-").tempdir()).expect("tmp dir");
    let path = dir.path().join(name);
    (dir, path)
}

// ---- 1. Divergence stops the run -------------------------------------------------------------

#[test]
fn poisson_0_4999999_blowing_up_at_puncture_is_stopped_as_diverged() {
    let scene = simple(&[("gel.poisson_ratio", "0.4999999")]).expect("valid");
    let r = run(
        &scene,
        &RunOptions {
            steps: Some(160),
            ..RunOptions::default()
        },
        |_| {},
    )
    .expect("run");
    let s = &r.summary;
    assert!(!s.completed, "a blown-up run reported completed");
    let why = s.stop_reason.as_ref().expect("a stop reason");
    assert!(why.is_divergence(), "{why:?}");
    assert!(
        s.stopped.as_deref().is_some_and(|m| m.contains("diverged")),
        "{:?}",
        s.stopped
    );
    // Stopped at the blow-up (puncture is at step ~101), not 10 m later.
    assert!(s.steps < 120, "stopped only after {} steps", s.steps);
    assert!(r.reports.iter().all(|x| x.tip.norm() < 1e3));
}

#[test]
fn ordinary_run_is_not_stopped_by_the_divergence_checks() {
    let scene = simple(&[("gel.box.nodes", "300")]).expect("valid");
    let r = run(
        &scene,
        &RunOptions {
            steps: Some(150),
            ..RunOptions::default()
        },
        |_| {},
    )
    .expect("run");
    assert!(r.summary.completed, "{:?}", r.summary.stopped);
    assert!(r.summary.stop_reason.is_none());
    assert!(r.summary.puncture_step.is_some());
}

#[test]
fn stop_reason_serialises_with_its_kind() {
    let why = StopReason::TipLeftGel {
        distance_mm: 1457.0,
        limit_mm: 120.0,
    };
    let j = serde_json::to_value(&why).expect("json");
    assert_eq!(j["kind"], "tip_left_gel");
    assert!(why.is_divergence());
    assert!(
        !StopReason::NoCommand { waited_s: 2.0 }.is_divergence(),
        "a missing command is not a divergence"
    );
}

// ---- 2. Unusable numbers and plans refused at set-up -----------------------------------------

#[test]
fn needle_of_e_1e_minus_6_that_never_punctures_is_refused() {
    refused(&[("needle.young_modulus", "1e-6")], "needle.young_modulus");
}

#[test]
fn needle_of_e_1e300_is_refused() {
    refused(&[("needle.young_modulus", "1e300")], "needle.young_modulus");
}

#[test]
fn entry_shift_bound_of_0_mm_is_refused() {
    refused(
        &[("inverse.max_entry_shift", "0")],
        "inverse.max_entry_shift",
    );
    simple(&[("inverse.max_entry_shift", "15")]).expect("a positive bound is accepted");
}

#[test]
fn time_step_1e_minus_300_is_refused() {
    refused(&[("solver.time_step", "1e-300")], "solver.time_step");
}

#[test]
fn path_samples_1e8_is_refused() {
    refused(&[("path.samples", "100000000")], "path.samples");
}

#[test]
fn formula_of_200000_terms_is_refused() {
    let long = format!("\"60 - 50*s{}\"", " + 0*s".repeat(200_000));
    let e = refused(&[("path.formula.z", &long)], "path.formula.z");
    assert!(
        e.len() < 400,
        "the message repeats the formula: {} chars",
        e.len()
    );
}

#[test]
fn insertion_steps_1e17_is_refused() {
    refused(
        &[("insertion.steps", "100000000000000000")],
        "insertion.steps",
    );
}

#[test]
fn path_below_the_fixed_bottom_is_refused() {
    let scene = simple(&[("path.formula.z", "\"60 - 80*s\"")]).expect("valid numbers");
    let e = setup_refused(&scene);
    assert!(e.contains("path") && e.contains("fixed bottom"), "{e}");
}

#[test]
fn path_outside_the_gel_is_refused() {
    let scene = simple(&[("path.formula.x", "\"300 + 50*s^2\"")]).expect("valid numbers");
    let e = setup_refused(&scene);
    assert!(e.contains("outside the gel"), "{e}");
}

#[test]
fn obstacle_placed_on_the_path_is_refused() {
    let scene = simple(&[(
        "obstacles",
        "[{ name = \"on\", center = [300.0, 0.0, 40.0], radius = 3.0 }]",
    )])
    .expect("valid numbers");
    let e = setup_refused(&scene);
    assert!(
        e.contains("obstacles[0]") && e.contains("on the path"),
        "{e}"
    );
}

#[test]
fn needle_of_5_mm_inserted_41_mm_is_refused() {
    let scene = simple(&[("needle.length", "5.0")]).expect("valid numbers");
    let e = setup_refused(&scene);
    assert!(e.contains("needle.length"), "{e}");
}

#[test]
fn entry_point_off_the_gel_is_one_line_in_mm() {
    let scene = simple(&[("path.formula.z", "\"70 - 50*s\"")]).expect("valid numbers");
    let e = setup_refused(&scene);
    assert!(e.contains("(300.00, 0.00, 70.00) mm"), "{e}");
}

#[test]
fn every_scene_of_the_repository_is_still_accepted() {
    let mut files = Vec::new();
    let dirs = [
        "scenes",
        "scenes/suite",
        "scenes/hard",
        "scenes/obstacles",
        "scenes/robots",
        "scenes/tissue",
    ];
    for dir in dirs {
        for e in std::fs::read_dir(repo().join(dir)).expect("scenes") {
            let p = e.expect("entry").path();
            if p.extension().is_some_and(|x| x == "toml") {
                files.push(p);
            }
        }
    }
    assert!(files.len() > 20);
    // Each with its robot's joint count (a 7-joint arm in `scenes/robots`).
    struct Built;
    impl needle_host::setup::WithSetup for Built {
        type Output = ();
        fn with<const N: usize>(self, _: Setup<N>) {}
    }
    for f in files {
        let scene = Scene::load(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        if let Err(e) = needle_host::setup::with_setup(&scene, Built) {
            panic!("{}: {}", f.display(), needle_host::error::chain(&e));
        }
    }
}

// ---- 2. Meshes ---------------------------------------------------------------------------------

fn small_box() -> TetMesh {
    box_mesh(
        nalgebra::Vector3::new(0.0, 0.0, 0.0),
        nalgebra::Vector3::new(10.0, 10.0, 10.0),
        64,
    )
}

fn gmsh_text(mesh: &TetMesh) -> String {
    let mut b = Vec::new();
    write_gmsh_ascii(mesh, &mut b).expect("write");
    String::from_utf8(b).expect("utf8")
}

#[test]
fn tangled_mesh_with_a_node_moved_through_its_neighbours_is_refused() {
    let mut mesh = small_box();
    mesh.validate().expect("the box is valid");
    // An interior node pushed 25 mm through its neighbours (then re-oriented as the Gmsh reader
    // does): every element positive, the mesh folded.
    let centre = nalgebra::Vector3::new(5.0, 5.0, 5.0);
    let i = (0..mesh.nodes.len())
        .min_by(|&a, &b| {
            (mesh.nodes[a] - centre)
                .norm()
                .total_cmp(&(mesh.nodes[b] - centre).norm())
        })
        .expect("a node");
    mesh.nodes[i].x += 25.0;
    let text = gmsh_text(&mesh);
    let e = read_gmsh_bytes(text.as_bytes()).expect_err("a tangled mesh must be refused");
    let msg = e.to_string();
    assert!(msg.contains("element") && msg.contains("tangled"), "{msg}");
}

#[test]
fn gmsh_header_with_a_false_node_count_is_refused() {
    let mesh = small_box();
    let text = gmsh_text(&mesh);
    let n = mesh.nodes.len();
    // `$Nodes` is followed by `blocks count min max`.
    let at = text.find("$Nodes\n").expect("$Nodes") + "$Nodes\n".len();
    let line_end = at + text[at..].find('\n').expect("line");
    let fields: Vec<&str> = text[at..line_end].split_whitespace().collect();
    assert_eq!(fields[1], n.to_string());
    let forged = format!(
        "{}{} {} {} {}{}",
        &text[..at],
        fields[0],
        n + 5,
        fields[2],
        fields[3],
        &text[line_end..]
    );
    let e = read_gmsh_bytes(forged.as_bytes()).expect_err("a lying header must be refused");
    assert!(e.to_string().contains("$Nodes"), "{e}");
}

#[test]
fn gel_mesh_dev_zero_is_refused_without_reading_it() {
    let e = read_gmsh("/dev/zero").expect_err("/dev/zero is no mesh");
    assert!(e.to_string().contains("not a regular file"), "{e}");
    let e = read_gmsh(repo().join("scenes")).expect_err("a folder is no mesh");
    assert!(e.to_string().contains("directory"), "{e}");
}

#[test]
fn gmsh_parse_error_is_one_line_without_a_hex_dump() {
    let e = read_gmsh_bytes(
        b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 3\n\x01\x02\x03garbage",
    )
    .expect_err("garbage");
    let msg = e.to_string();
    assert!(!msg.contains('\n') && msg.len() < 300, "{msg}");
}

#[test]
fn mesh_in_metres_gets_a_hint() {
    let mut mesh = small_box();
    for p in &mut mesh.nodes {
        *p *= 0.01; // 10 mm written as metres… read as 0.1 mm
    }
    let (_dir, path) = tmp("metres.msh");
    std::fs::write(&path, gmsh_text(&mesh)).expect("write");
    let mut scene = Scene::builtin("simple").expect("simple");
    scene.gel.box_mesh = None;
    scene.gel.mesh = Some(path);
    let e = setup_refused(&scene);
    assert!(e.contains("metres"), "{e}");
    assert!(matches!(Setup::build(&scene), Err(SetupError::Plan { .. })));
}

#[test]
fn scene_file_dev_zero_is_refused_without_reading_it() {
    let e = Scene::load(Path::new("/dev/zero")).expect_err("/dev/zero is no scene");
    assert!(e.to_string().contains("not a regular file"), "{e}");
}

/// The suite's copies of the tissue and obstacle example scenes (`scenes/suite/tissue_lesion`,
/// `obstacle_surfaces`, `breathing`) say the same as their originals but for the name and the
/// relative paths of their files: a change to one that misses the other fails here.
#[test]
fn the_suites_copies_of_example_scenes_match_their_originals() {
    for (copy, original, rel) in [
        ("tissue_lesion", "tissue/lesion", "../tissue/"),
        ("obstacle_surfaces", "obstacles/mesh_msh", "../obstacles/"),
        ("breathing", "tissue/breathing_complex", "../tissue/"),
    ] {
        let read = |p: &str| {
            std::fs::read_to_string(repo().join(format!("scenes/{p}.toml"))).expect("scene file")
        };
        let (c, o) = (read(&format!("suite/{copy}")), read(original));
        let header: Vec<&str> = c.lines().take(3).collect();
        assert!(
            header.iter().all(|l| l.starts_with('#')) && header[0].contains(original),
            "{copy}: a three-line header naming scenes/{original}.toml"
        );
        let name = |t: &str| {
            t.lines()
                .find_map(|l| l.strip_prefix("name = "))
                .map(str::to_owned)
        };
        assert_eq!(name(&c).as_deref(), Some(format!("\"{copy}\"").as_str()));
        let mut first = true;
        let body: Vec<String> = c
            .lines()
            .skip(3)
            .map(|l| {
                if first && l.starts_with("name = ") {
                    first = false;
                    format!("name = {}", name(&o).expect("a name"))
                } else {
                    l.replacen(&format!("\"{rel}"), "\"", 1)
                }
            })
            .collect();
        let want: Vec<&str> = o.lines().collect();
        assert_eq!(
            body, want,
            "scenes/suite/{copy}.toml against scenes/{original}.toml"
        );
    }
}

/// A thin needle in a stiff gel on a bending path is accepted, but its plan says at set-up that
/// the tip may lag the bend (issue 12: under 18 mm of steering length most such runs miss);
/// the benchmark's needle, and a straight entry with the thin needle, say nothing.
#[test]
fn short_steering_length_on_a_bending_path_is_an_advisory_at_set_up() {
    let thin = Scene::load(&repo().join("scenes/suite/needle_thin.toml")).expect("needle_thin");
    let plan = Setup::build(&thin).expect("accepted").plan;
    assert_eq!(plan.advisories.len(), 1, "{:?}", plan.advisories);
    let a = &plan.advisories[0];
    assert!(a.contains("13.0 mm") && a.contains("bends 11.5 mm"), "{a}");
    assert!(!a.contains('\n'), "not one line: {a}");
    for name in ["complex", "simple"] {
        let scene = Scene::builtin(name).expect("builtin");
        let plan = Setup::build(&scene).expect("accepted").plan;
        assert!(plan.advisories.is_empty(), "{name}: {:?}", plan.advisories);
    }
    // The same thin needle in the same gel on a straight vertical path: no advisory.
    let mut straight = thin.clone();
    let o = [(
        "path.formula".to_owned(),
        "{ x = \"303.0464\", y = \"1.5189\", z = \"60 - 50*s\" }".to_owned(),
    )];
    straight = straight.with_overrides(&o).expect("straight path");
    straight.obstacles.clear();
    let plan = Setup::build(&straight).expect("accepted").plan;
    assert!(plan.advisories.is_empty(), "{:?}", plan.advisories);
}
