//! The gel model against `elastic_box_{coarse,fine}.json` (scikit-fem P1 linear elasticity,
//! SI units; converted here to mm, N, MPa): stiffness, linear static solutions of all four load
//! cases, and the corotational model in the small-load limit.

use nalgebra::Vector3;
use needle_host::fem::Elasticity;
use needle_host::fem::tetra::Kinematics;
use needle_host::free_motion::{GelModel, GelParams};
use needle_host::mesh::TetMesh;
use needle_tests::{load_ref, max_rel_err as rel_err};
use serde_json::Value;

const CASES: [&str; 4] = [
    "traction_compress",
    "traction_shear",
    "point_load",
    "prescribed_top",
];

fn vec3s(v: &Value, scale: f64) -> Vec<Vector3<f64>> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|p| {
            let a = p.as_array().expect("triple");
            Vector3::new(
                a[0].as_f64().unwrap(),
                a[1].as_f64().unwrap(),
                a[2].as_f64().unwrap(),
            ) * scale
        })
        .collect()
}

fn indices(v: &Value) -> Vec<usize> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|i| i.as_u64().unwrap() as usize)
        .collect()
}

fn mesh_of(r: &Value) -> TetMesh {
    let nodes = vec3s(&r["points"], 1000.0);
    let tets = r["tets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            let a = indices(t);
            [a[0], a[1], a[2], a[3]]
        })
        .collect();
    TetMesh::try_new(nodes, tets).expect("reference mesh is valid")
}

fn params(r: &Value, kinematics: Kinematics) -> GelParams {
    GelParams {
        elasticity: Elasticity {
            young_modulus: r["material"]["E_Pa"].as_f64().unwrap() * 1e-6,
            poisson_ratio: r["material"]["nu"].as_f64().unwrap(),
        },
        kinematics,
        ..GelParams::default()
    }
}

fn flat(v: &[Vector3<f64>]) -> Vec<f64> {
    v.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

/// Solves one case with `load_scale` times the load / prescribed displacement, iterating the
/// free-motion Newton step `iters` times; returns the displacement [mm] divided by the scale.
fn solve_case(
    r: &Value,
    case: &str,
    kinematics: Kinematics,
    load_scale: f64,
    iters: usize,
) -> (Vec<f64>, GelModel) {
    let c = &r["cases"][case];
    let fixed = indices(&c["fixed_nodes"]);
    let mut model = GelModel::try_new(mesh_of(r), &fixed, &params(r, kinematics)).unwrap();
    let u_fixed = vec3s(&c["u_fixed"], 1000.0 * load_scale);
    for (k, &n) in fixed.iter().enumerate() {
        model.positions_mut()[n] += u_fixed[k];
    }
    let f = flat(&vec3s(&c["f"], load_scale));
    for _ in 0..iters {
        let dx = model.free_motion(&f).unwrap().to_vec();
        model.apply_displacement(&dx).unwrap();
    }
    let rest = model.mesh().nodes.clone();
    let u: Vec<f64> = model
        .positions()
        .iter()
        .zip(&rest)
        .flat_map(|(x, x0)| {
            let d = (x - x0) / load_scale;
            [d.x, d.y, d.z]
        })
        .collect();
    (u, model)
}

fn check_linear(name: &str) {
    let r = load_ref(name);
    for case in CASES {
        let (u, mut model) = solve_case(&r, case, Kinematics::Linear, 1.0, 1);
        let u_ref = flat(&vec3s(&r["cases"][case]["u"], 1000.0));
        let err = rel_err(&u, &u_ref);
        assert!(
            err <= 1e-8,
            "{name} {case}: linear displacement relative error {err:e}"
        );
        // Strain energy ½ u·K u = ½ u·f_int [N·mm = mJ] vs the reference [J].
        let f_int = model.compute_internal_forces().to_vec();
        let energy: f64 = 0.5 * u.iter().zip(&f_int).map(|(a, b)| a * b).sum::<f64>();
        let e_ref = r["cases"][case]["strain_energy_J"].as_f64().unwrap() * 1000.0;
        assert!(
            (energy - e_ref).abs() <= 1e-8 * e_ref,
            "{name} {case}: energy {energy} vs {e_ref}"
        );
        // Internal forces equal the applied loads on free dofs.
        let f_ref = flat(&vec3s(&r["cases"][case]["f"], 1.0));
        let fmax = f_int.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for g in 0..f_int.len() {
            if !model.is_fixed_dof(g) {
                assert!(
                    (f_int[g] - f_ref[g]).abs() <= 1e-9 * fmax,
                    "{name} {case}: f_int[{g}]"
                );
            }
        }
        println!("{name} {case}: rel. error {err:.2e}, energy {energy:.6e} mJ (ref {e_ref:.6e})");
    }
}

/// The assembled sparse matrix reproduces the reference: `K_ff u_ref = f_ref` on free dofs.
fn check_matrix(name: &str) {
    let r = load_ref(name);
    let case = "traction_shear";
    let c = &r["cases"][case];
    let fixed = indices(&c["fixed_nodes"]);
    let mut model =
        GelModel::try_new(mesh_of(&r), &fixed, &params(&r, Kinematics::Corotational)).unwrap();
    model.refactor().unwrap();
    let u_ref = flat(&vec3s(&c["u"], 1000.0));
    let f_ref = flat(&vec3s(&c["f"], 1.0));
    let n = model.free_dof_count();
    let mut uf = vec![0.0; n];
    let mut ff = vec![0.0; n];
    for g in 0..model.dof_count() {
        if let Some(k) = model.reduced_index(g) {
            uf[k] = u_ref[g];
            ff[k] = f_ref[g];
        }
    }
    let mut ku = vec![0.0; n];
    model.matrix().mul_vec(&uf, &mut ku).unwrap();
    let fmax = ff.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = ku
        .iter()
        .zip(&ff)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / fmax;
    assert!(err < 1e-9, "{name}: |K u_ref − f_ref| / |f| = {err:e}");
    let energy = 0.5 * uf.iter().zip(&ku).map(|(a, b)| a * b).sum::<f64>();
    let e_ref = c["strain_energy_J"].as_f64().unwrap() * 1000.0;
    assert!((energy - e_ref).abs() < 1e-9 * e_ref);
}

fn check_corotational_small_load(name: &str) {
    let r = load_ref(name);
    for case in CASES {
        let scale = 1e-5;
        let (u, _) = solve_case(&r, case, Kinematics::Corotational, scale, 2);
        let u_ref = flat(&vec3s(&r["cases"][case]["u"], 1000.0));
        let err = rel_err(&u, &u_ref);
        assert!(
            err <= 1e-4,
            "{name} {case}: corotational small-load relative error {err:e}"
        );
        println!("{name} {case}: corotational (load × {scale:e}) rel. error {err:.2e}");
    }
}

#[test]
fn linear_solutions_match_coarse_reference() {
    check_linear("elastic_box_coarse.json");
}

#[test]
fn linear_solutions_match_fine_reference() {
    check_linear("elastic_box_fine.json");
}

#[test]
fn assembled_matrix_matches_coarse_reference() {
    check_matrix("elastic_box_coarse.json");
}

#[test]
fn assembled_matrix_matches_fine_reference() {
    check_matrix("elastic_box_fine.json");
}

#[test]
fn corotational_small_load_limit_coarse() {
    check_corotational_small_load("elastic_box_coarse.json");
}

#[test]
fn corotational_small_load_limit_fine() {
    check_corotational_small_load("elastic_box_fine.json");
}

#[test]
fn reference_mesh_volume() {
    let r = load_ref("elastic_box_coarse.json");
    let m = mesh_of(&r);
    let v_ref = r["total_volume_m3"].as_f64().unwrap() * 1e9;
    assert!((m.total_volume() - v_ref).abs() < 1e-9 * v_ref);
}
