//! `needle_core::kinematics` against `rv1a_fk.json` (roboticstoolbox / pinocchio) and against
//! central finite differences of its own forward kinematics.

use needle_core::kinematics::{DhChain, Kinematics, Pose};
use needle_tests::{arr, load_ref, mat};
use serde_json::Value;

fn q6(v: &Value) -> [f64; 6] {
    arr(v).try_into().expect("6 joints")
}

fn check_pose(p: &Pose, t: &[Vec<f64>], what: &str) {
    let h = p.to_homogeneous();
    for r in 0..3 {
        for c in 0..3 {
            let d = (h[r][c] - t[r][c]).abs();
            assert!(
                d <= 1e-12,
                "{what}: R[{r}][{c}] {} vs {} (Δ {d:e})",
                h[r][c],
                t[r][c]
            );
        }
        let d = (h[r][3] - t[r][3]).abs();
        assert!(
            d <= 1e-9,
            "{what}: p[{r}] {} vs {} (Δ {d:e} mm)",
            h[r][3],
            t[r][3]
        );
    }
}

#[test]
fn dh_table_matches_reference() {
    let r = load_ref("rv1a_fk.json");
    let chain = DhChain::rv1a();
    let dh = &r["dh"];
    let (d, a, al, off) = (
        arr(&dh["d"]),
        arr(&dh["a"]),
        arr(&dh["alpha"]),
        arr(&dh["offset"]),
    );
    for (i, j) in chain.joints.iter().enumerate() {
        assert_eq!(
            (j.d, j.a, j.alpha, j.theta_offset),
            (d[i], a[i], al[i], off[i]),
            "joint {i}"
        );
    }
}

#[test]
fn fk_frames_and_jacobian_match_all_51_samples() {
    let r = load_ref("rv1a_fk.json");
    let samples = r["samples"].as_array().expect("samples");
    assert_eq!(samples.len(), 51);
    let chain = DhChain::rv1a();
    for (k, s) in samples.iter().enumerate() {
        let q = q6(&s["q"]);
        let mut frames = [Pose::identity(); 6];
        let e = chain.link_frames(&q, &mut frames);
        check_pose(&e, &mat(&s["T"]), &format!("sample {k} flange"));
        check_pose(
            &chain.flange_pose(&q),
            &mat(&s["T"]),
            &format!("sample {k} flange_pose"),
        );
        // Identity tool: the tool pose is the flange pose.
        check_pose(
            &chain.tool_pose(&q),
            &mat(&s["T"]),
            &format!("sample {k} tool_pose"),
        );
        for (i, f) in s["frames_0i"]
            .as_array()
            .expect("frames")
            .iter()
            .enumerate()
        {
            check_pose(&frames[i], &mat(f), &format!("sample {k} frame {}", i + 1));
        }
        let jref = mat(&s["J"]);
        let j = chain.jacobian_flange(&q);
        let (jt, _) = chain.jacobian_tool(&q);
        for row in 0..6 {
            let tol = if row < 3 { 1e-9 } else { 1e-12 };
            for col in 0..6 {
                let d = (j[(row, col)] - jref[row][col]).abs();
                assert!(d <= tol, "sample {k} J[{row}][{col}] Δ {d:e}");
                assert_eq!(
                    j[(row, col)],
                    jt[(row, col)],
                    "identity tool: same Jacobian"
                );
            }
        }
        let det = j.determinant();
        let dref = s["det_J"].as_f64().expect("det");
        assert!(
            (det - dref).abs() <= 1e-9 * (1.0 + dref.abs()),
            "sample {k} det {det} vs {dref}"
        );
    }
}

/// Rotation vector of `a · bᵀ` for nearby rotations (first order: the skew part).
fn small_rotation(
    a: &nalgebra::Matrix3<f64>,
    b: &nalgebra::Matrix3<f64>,
) -> nalgebra::Vector3<f64> {
    let d = a * b.transpose();
    nalgebra::Vector3::new(
        d[(2, 1)] - d[(1, 2)],
        d[(0, 2)] - d[(2, 0)],
        d[(1, 0)] - d[(0, 1)],
    ) * 0.5
}

fn check_fd(chain: &DhChain<6>, q: &[f64; 6], tool: bool) {
    let h = 1e-6;
    let (j, _) = if tool {
        chain.jacobian_tool(q)
    } else {
        (chain.jacobian_flange(q), Pose::identity())
    };
    let pose = |q: &[f64; 6]| {
        if tool {
            chain.tool_pose(q)
        } else {
            chain.flange_pose(q)
        }
    };
    for i in 0..6 {
        let (mut qp, mut qm) = (*q, *q);
        qp[i] += h;
        qm[i] -= h;
        let (pp, pm) = (pose(&qp), pose(&qm));
        let v = (pp.translation - pm.translation) / (2.0 * h);
        let w = small_rotation(&pp.rotation, &pm.rotation) / (2.0 * h);
        for r in 0..3 {
            assert!(
                (v[r] - j[(r, i)]).abs() <= 1e-5 * (1.0 + v[r].abs()),
                "v {r},{i}: {} vs {}",
                v[r],
                j[(r, i)]
            );
            assert!(
                (w[r] - j[(r + 3, i)]).abs() <= 1e-8,
                "w {r},{i}: {} vs {}",
                w[r],
                j[(r + 3, i)]
            );
        }
    }
}

#[test]
fn jacobian_matches_central_differences() {
    let r = load_ref("rv1a_fk.json");
    let mut chain = DhChain::rv1a();
    for s in r["samples"].as_array().expect("samples") {
        check_fd(&chain, &q6(&s["q"]), false);
    }
    // With a base and a tool transform, the tool-point Jacobian is still the derivative of the
    // tool pose.
    chain.base = Pose {
        rotation: *nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.3).matrix(),
        translation: nalgebra::Vector3::new(10.0, -20.0, 5.0),
    };
    chain.tool = Pose {
        rotation: *nalgebra::Rotation3::from_euler_angles(0.3, 0.1, -0.4).matrix(),
        translation: nalgebra::Vector3::new(5.0, 3.0, 40.0),
    };
    for s in r["samples"].as_array().expect("samples").iter().take(20) {
        check_fd(&chain, &q6(&s["q"]), true);
        check_fd(&chain, &q6(&s["q"]), false);
    }
}

#[test]
fn home_flange_position() {
    let e = DhChain::rv1a().flange_pose(&[0.0; 6]);
    assert!((e.translation - nalgebra::Vector3::new(-90.0, 0.0, 782.0)).norm() < 1e-12);
}
