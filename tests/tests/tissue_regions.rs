//! Tissue regions: a two-material gel read from Gmsh physical volumes, against
//! `bilayer_box.{json,msh}` (scikit-fem P1 linear elasticity with per-element E, SI units;
//! converted here to mm, N, MPa), and the scene's `[[gel.regions]]`.

use nalgebra::Vector3;
use needle_host::fem::Elasticity;
use needle_host::fem::tetra::Kinematics;
use needle_host::free_motion::{GelModel, GelParams, RegionMaterial};
use needle_host::mesh::{TetMesh, read_gmsh};
use needle_host::scene::{RegionSpec, Scene};
use needle_tests::{load_ref, max_rel_err as rel_err, ref_path};
use serde_json::Value;
use std::collections::HashMap;

const CASES: [&str; 2] = ["traction_compress", "traction_shear"];

fn triple(v: &Value) -> Vector3<f64> {
    let a = v.as_array().expect("triple");
    Vector3::new(
        a[0].as_f64().expect("x"),
        a[1].as_f64().expect("y"),
        a[2].as_f64().expect("z"),
    )
}

fn rows(v: &Value) -> Vec<Vector3<f64>> {
    v.as_array().expect("array").iter().map(triple).collect()
}

/// A position [mm] as an exact key (the .msh writes the JSON's points × 1000).
fn key(p: &Vector3<f64>) -> [i64; 3] {
    [p.x, p.y, p.z].map(|c| (c * 1e6).round() as i64)
}

/// The .msh mesh and, for each of its nodes, the JSON point it is.
fn mesh_and_node_map(r: &Value) -> (TetMesh, Vec<usize>) {
    let mesh = read_gmsh(ref_path("bilayer_box.msh")).expect("bilayer_box.msh reads");
    let json_points = rows(&r["points"]);
    let by_key: HashMap<[i64; 3], usize> = json_points
        .iter()
        .enumerate()
        .map(|(i, p)| (key(&(p * 1000.0)), i))
        .collect();
    assert_eq!(by_key.len(), json_points.len(), "distinct JSON points");
    let map = mesh
        .nodes
        .iter()
        .map(|p| {
            *by_key
                .get(&key(p))
                .expect("every .msh node is a JSON point")
        })
        .collect();
    (mesh, map)
}

fn region_e(r: &Value, tag: &str) -> f64 {
    r["regions"][tag]["young_modulus_Pa"]
        .as_f64()
        .expect("region E")
        * 1e-6
}

/// Solves `case` with the model built from `params`: one Newton step for linear kinematics,
/// `iters` steps at `scale` times the load for the corotational one. Returns the displacement
/// [mm] divided by the scale (in the .msh's node order) and its reference.
fn solve(
    r: &Value,
    case: &str,
    params: &GelParams,
    scale: f64,
    iters: usize,
) -> (Vec<f64>, Vec<f64>, f64, f64) {
    let (mesh, map) = mesh_and_node_map(r);
    let fixed: Vec<usize> = (0..mesh.nodes.len())
        .filter(|&i| mesh.nodes[i].z == 0.0)
        .collect();
    let bottom = r["bottom_nodes"].as_array().expect("bottom nodes").len();
    assert_eq!(fixed.len(), bottom, "clamped nodes");
    let c = &r["cases"][case];
    let f_json = rows(&c["f"]);
    let u_json = rows(&c["u"]);
    let f: Vec<f64> = map
        .iter()
        .flat_map(|&j| (f_json[j] * scale).as_slice().to_vec())
        .collect();
    let u_ref: Vec<f64> = map
        .iter()
        .flat_map(|&j| (u_json[j] * 1000.0).as_slice().to_vec())
        .collect();
    let mut model = GelModel::try_new(mesh, &fixed, params).expect("model");
    for _ in 0..iters {
        let dx = model.free_motion(&f).expect("solve").to_vec();
        model.apply_displacement(&dx).expect("apply");
    }
    let rest = model.mesh().nodes.clone();
    let u: Vec<f64> = (model.positions().iter().zip(&rest))
        .flat_map(|(x, x0)| ((x - x0) / scale).as_slice().to_vec())
        .collect();
    // Strain energy ½ u·f [N·mm = mJ] (linear case) against the reference [J].
    let energy = 0.5 * u.iter().zip(&f).map(|(a, b)| a * b).sum::<f64>() / scale;
    let e_ref = c["strain_energy_J"].as_f64().expect("energy") * 1000.0;
    (u, u_ref, energy, e_ref)
}

fn params(r: &Value, default: Elasticity, listed: &[&str], kinematics: Kinematics) -> GelParams {
    let nu = r["nu"].as_f64().expect("nu");
    GelParams {
        elasticity: default,
        regions: listed
            .iter()
            .map(|tag| RegionMaterial {
                tag: tag.parse().expect("tag"),
                elasticity: Elasticity {
                    young_modulus: region_e(r, tag),
                    poisson_ratio: nu,
                },
                density: 1e-9,
            })
            .collect(),
        kinematics,
        ..GelParams::default()
    }
}

#[test]
fn bilayer_msh_regions_are_the_physical_volumes_of_the_reference() {
    let r = load_ref("bilayer_box.json");
    let (mesh, map) = mesh_and_node_map(&r);
    assert_eq!(mesh.region_tags(), vec![1, 2]);
    let json_tets: HashMap<[usize; 4], i64> = (r["tets"].as_array().expect("tets").iter())
        .zip(r["tet_region"].as_array().expect("tet_region"))
        .map(|(t, g)| {
            let mut t: [usize; 4] = std::array::from_fn(|k| t[k].as_u64().expect("node") as usize);
            t.sort_unstable();
            (t, g.as_i64().expect("region"))
        })
        .collect();
    assert_eq!(json_tets.len(), mesh.tet_count());
    for (e, t) in mesh.tets.iter().enumerate() {
        let mut nodes = t.map(|v| map[v]);
        nodes.sort_unstable();
        let expected = json_tets.get(&nodes).expect("every .msh tet is a JSON tet");
        assert_eq!(i64::from(mesh.regions[e]), *expected, "element {e}");
    }
}

/// Both regions listed (the gel's default is a third material no element may take), and only
/// the stiff one listed with the soft one as the gel's default: the same displacements, to
/// 1e-8 of the largest, in both load cases.
#[test]
fn two_material_gel_matches_scikit_fem_in_both_load_cases() {
    let r = load_ref("bilayer_box.json");
    let nu = r["nu"].as_f64().expect("nu");
    let decoy = Elasticity {
        young_modulus: 1.0,
        poisson_ratio: 0.3,
    };
    let soft = Elasticity {
        young_modulus: region_e(&r, "1"),
        poisson_ratio: nu,
    };
    for case in CASES {
        for (label, p) in [
            (
                "both listed",
                params(&r, decoy, &["1", "2"], Kinematics::Linear),
            ),
            ("stiff listed", params(&r, soft, &["2"], Kinematics::Linear)),
        ] {
            let (u, u_ref, energy, e_ref) = solve(&r, case, &p, 1.0, 1);
            let err = rel_err(&u, &u_ref);
            println!(
                "{case}, {label}: relative displacement error {err:.2e}, energy {energy:.6e} mJ (ref {e_ref:.6e})"
            );
            assert!(err <= 1e-8, "{case}, {label}: relative error {err:e}");
            assert!(
                (energy - e_ref).abs() <= 1e-8 * e_ref,
                "{case}, {label}: energy {energy} vs {e_ref}"
            );
        }
        // One material everywhere is far off: the regions matter.
        let (u, u_ref, _, _) = solve(&r, case, &params(&r, soft, &[], Kinematics::Linear), 1.0, 1);
        assert!(
            rel_err(&u, &u_ref) > 0.1,
            "{case}: one material should not match"
        );
    }
}

/// The corotational model with regions tends to the same solution as the load goes to zero.
#[test]
fn corotational_two_material_gel_matches_in_the_small_load_limit() {
    let r = load_ref("bilayer_box.json");
    let decoy = Elasticity {
        young_modulus: 1.0,
        poisson_ratio: 0.3,
    };
    for case in CASES {
        let p = params(&r, decoy, &["1", "2"], Kinematics::Corotational);
        let (u, u_ref, _, _) = solve(&r, case, &p, 1e-4, 4);
        let err = rel_err(&u, &u_ref);
        println!("{case}, corotational at 1e-4 of the load: relative error {err:.2e}");
        assert!(err <= 1e-5, "{case}: relative error {err:e}");
    }
}

fn scene_on_bilayer(regions: Vec<RegionSpec>) -> Scene {
    let mut scene = Scene::builtin("simple").expect("simple");
    scene.gel.box_mesh = None;
    scene.gel.mesh = Some(ref_path("bilayer_box.msh"));
    scene.gel.regions = regions;
    scene
}

fn region(tag: i32, e: f64) -> RegionSpec {
    RegionSpec {
        tag,
        name: "lesion".into(),
        young_modulus: e,
        poisson_ratio: None,
        density: None,
    }
}

#[test]
fn a_listed_region_absent_from_the_mesh_is_refused_naming_file_field_and_tags() {
    let scene = scene_on_bilayer(vec![region(2, 0.02), region(7, 0.05)]);
    let e = needle_host::setup::gel_mesh(&scene).expect_err("region 7 is not in the mesh");
    let msg = needle_host::error::chain(&e);
    for part in [
        "gel.regions[1].tag",
        "region 7",
        "lesion",
        "bilayer_box.msh",
        "[1, 2]",
    ] {
        assert!(msg.contains(part), "`{part}` missing from: {msg}");
    }
    let ok = scene_on_bilayer(vec![region(2, 0.02)]);
    let mesh = needle_host::setup::gel_mesh(&ok).expect("region 2 is in the mesh");
    assert_eq!(mesh.region_tags(), vec![1, 2]);
    let p = needle_host::setup::gel_params(&ok, 1500);
    assert_eq!(p.regions.len(), 1);
    assert_eq!(p.regions[0].elasticity.poisson_ratio, ok.gel.poisson_ratio);
}

#[test]
fn region_fields_are_checked_by_the_scene() {
    for (toml, field) in [
        (
            "[[gel.regions]]\ntag = 1\nyoung_modulus = -1.0\n",
            "gel.regions[0].young_modulus",
        ),
        (
            "[[gel.regions]]\ntag = 1\nyoung_modulus = 0.01\npoisson_ratio = 0.5\n",
            "gel.regions[0].poisson_ratio",
        ),
        (
            "[[gel.regions]]\ntag = 1\nyoung_modulus = 0.01\n[[gel.regions]]\ntag = 1\nyoung_modulus = 0.02\n",
            "gel.regions[1].tag",
        ),
        ("[[gel.regions]]\ntag = 1\n", "gel.regions"),
    ] {
        let text = format!(
            "name = \"r\"\n[path]\npoints = [[300.0, 0.0, 60.0], [300.0, 0.0, 10.0]]\n{toml}"
        );
        let e = Scene::from_toml_str(&text, "regions.toml").expect_err(toml);
        assert!(
            e.field.starts_with(field),
            "{toml}: field {} ({e})",
            e.field
        );
    }
}

fn tissue_scene(name: &str) -> Scene {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes/tissue")
        .join(format!("{name}.toml"));
    Scene::load(&path).expect("tissue scene")
}

/// The committed tissue scenes set up with both regions of their mesh (no Gmsh needed).
#[test]
fn tissue_scenes_set_up_with_two_regions() {
    for name in ["lesion", "skin"] {
        let scene = tissue_scene(name);
        let setup = needle_host::setup::Setup::build(&scene).expect("set up");
        let mesh = setup.world.gel.mesh();
        assert_eq!(mesh.region_tags(), vec![1, 2], "{name}");
        let stiff = mesh.regions.iter().filter(|r| **r == 2).count();
        assert!(
            stiff > 100 && stiff < mesh.tet_count() / 2,
            "{name}: {stiff} elements in region 2"
        );
    }
}

/// Both tissue scenes inserted to their end: the target reached, the obstacle clear, within the
/// `simple` benchmark's bounds (e_mean ≤ 0.5 mm, e_max ≤ 1.8 mm), since they follow its path.
#[test]
#[ignore = "two full insertions (release, ~10 s CPU each): run with --include-ignored"]
fn lesion_and_skin_scenes_reach_their_target() {
    use needle_host::run::{Outcome, RunOptions, run};
    for name in ["lesion", "skin"] {
        let r = run(&tissue_scene(name), &RunOptions::default(), |_| {}).expect("the run starts");
        let s = &r.summary;
        eprintln!(
            "{name}: e_mean {:.3} mm, e_max {:.3} mm, e_final {:.3} mm, min clearance {:.3} mm, {:?}",
            s.e_mean_mm, s.e_max_mm, s.e_final_mm, s.min_clearance_mm, s.outcome
        );
        assert_eq!(s.outcome, Outcome::Reached, "{name}");
        assert!(s.e_mean_mm <= 0.5 && s.e_max_mm <= 1.8, "{name}");
        assert!(s.min_clearance_mm > 0.0, "{name}");
    }
}
