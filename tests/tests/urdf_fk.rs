//! `needle_host::robot::urdf` + `needle_core::SerialChain` against `urdf_fk.json` (pinocchio 4.1 on
//! the same URDF files: KUKA KR 16-2 with negative axes and a fixed rpy tool frame, PUMA 560 with
//! rpy in every joint origin, the 7-joint LBR iiwa 14 R820), against central finite differences of
//! the chain's own forward kinematics, and the loader's errors.

use nalgebra::{Matrix3, SMatrix, Vector3};
use needle_core::{Kinematics, Pose, SerialChain};
use needle_host::robot::urdf::{UrdfReason, load_chain, load_robot, parse_robot};
use needle_tests::{arr, load_ref, mat, ref_path};

/// Rotation vector (axis × angle) of a rotation matrix close to the identity.
fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    let c = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    let theta = c.acos();
    let k = if theta < 1e-8 {
        0.5
    } else {
        theta / (2.0 * theta.sin())
    };
    Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * k
}

/// Worst errors of one robot.
#[derive(Default, Debug)]
struct Worst {
    pose_mm: f64,
    pose_rot: f64,
    jac_lin_mm: f64,
    jac_ang: f64,
    fd_lin_mm: f64,
    fd_ang: f64,
}

/// Translation bound [mm]: the JSON's numbers are printed with 17 significant digits
/// (shortest round-trip), so its millimetre translations (≤ ~1.3e3) carry ~1e-13 mm of rounding;
/// 1e-9 mm holds with a wide margin.
const POSE_MM: f64 = 1e-9;
const POSE_ROT: f64 = 1e-12;
/// Jacobian bounds: the JSON's rounding again (entries ≤ ~1.3e3 mm/rad, 17 digits).
const JAC_LIN_MM: f64 = 1e-9;
const JAC_ANG: f64 = 1e-12;
/// Central differences, step 1e-5 rad: truncation ~h²/6·|J''| ≈ 2e-8 mm, rounding ~5e-9 mm.
const FD_H: f64 = 1e-5;
const FD_LIN_MM: f64 = 1e-6;
const FD_ANG: f64 = 1e-8;

fn check_robot<const N: usize>(name: &str, base_link: &str) -> Worst {
    let all = load_ref("urdf_fk.json");
    let rob = &all["robots"][name];
    assert_eq!(
        rob["joints"].as_u64(),
        Some(N as u64),
        "{name}: joint count"
    );
    let file = ref_path(rob["urdf"].as_str().expect("urdf"));
    let tip = rob["tip_frame"].as_str().expect("tip_frame");
    let robot = load_robot::<N>(&file, base_link, tip).expect("load");
    let chain: SerialChain<N> = robot.chain;

    // Names and limits.
    let names: Vec<String> = rob["joint_names"]
        .as_array()
        .expect("names")
        .iter()
        .map(|v| v.as_str().expect("name").to_owned())
        .collect();
    assert_eq!(robot.joint_names, names, "{name}: joint names");
    let (lo, hi, vel) = (
        arr(&rob["lower_rad"]),
        arr(&rob["upper_rad"]),
        arr(&rob["velocity_rad_s"]),
    );
    for i in 0..N {
        let l = robot.chain.limits[i];
        assert_eq!(l.lower, lo[i], "{name}: lower {i}");
        assert_eq!(l.upper, hi[i], "{name}: upper {i}");
        assert_eq!(l.max_speed, vel[i], "{name}: velocity {i}");
    }

    let mut w = Worst::default();
    let samples = rob["samples"].as_array().expect("samples");
    assert!(samples.len() >= 31, "{name}: {} samples", samples.len());
    for (k, s) in samples.iter().enumerate() {
        let q: [f64; N] = arr(&s["q"]).try_into().expect("q");
        let t = mat(&s["T"]);
        let jr = mat(&s["J"]);

        let p = chain.tool_pose(&q);
        let h = p.to_homogeneous();
        for r in 0..3 {
            for c in 0..3 {
                w.pose_rot = w.pose_rot.max((h[r][c] - t[r][c]).abs());
            }
            w.pose_mm = w.pose_mm.max((h[r][3] - t[r][3]).abs());
        }
        assert!(
            w.pose_mm <= POSE_MM && w.pose_rot <= POSE_ROT,
            "{name} sample {k}: pose off by {:e} mm / {:e}",
            w.pose_mm,
            w.pose_rot
        );

        let (jac, b): (SMatrix<f64, 6, N>, Pose) = chain.jacobian_tool(&q);
        // The same pose up to rounding (the products are grouped differently).
        assert!(
            (b.translation - p.translation).amax() <= 1e-12
                && (b.rotation - p.rotation).amax() <= 1e-15,
            "{name} sample {k}: jacobian_tool's pose"
        );
        for c in 0..N {
            for r in 0..3 {
                w.jac_lin_mm = w.jac_lin_mm.max((jac[(r, c)] - jr[r][c]).abs());
                w.jac_ang = w.jac_ang.max((jac[(r + 3, c)] - jr[r + 3][c]).abs());
            }
        }
        assert!(
            w.jac_lin_mm <= JAC_LIN_MM && w.jac_ang <= JAC_ANG,
            "{name} sample {k}: Jacobian off by {:e} mm/rad / {:e}",
            w.jac_lin_mm,
            w.jac_ang
        );

        // Central differences: linear rows from the translation, angular rows from
        // log(R(q + h) R(q − h)ᵀ) / 2h (world frame, as the Jacobian's).
        for c in 0..N {
            let (mut qp, mut qm) = (q, q);
            qp[c] += FD_H;
            qm[c] -= FD_H;
            let (pp, pm) = (chain.tool_pose(&qp), chain.tool_pose(&qm));
            let v = (pp.translation - pm.translation) / (2.0 * FD_H);
            let om = log_so3(&(pp.rotation * pm.rotation.transpose())) / (2.0 * FD_H);
            for r in 0..3 {
                w.fd_lin_mm = w.fd_lin_mm.max((v[r] - jac[(r, c)]).abs());
                w.fd_ang = w.fd_ang.max((om[r] - jac[(r + 3, c)]).abs());
            }
        }
        assert!(
            w.fd_lin_mm <= FD_LIN_MM && w.fd_ang <= FD_ANG,
            "{name} sample {k}: finite differences off by {:e} mm/rad / {:e}",
            w.fd_lin_mm,
            w.fd_ang
        );
    }
    println!(
        "{name}: {} samples, worst pose {:.2e} mm / {:.2e} (rotation), Jacobian {:.2e} mm/rad / \
         {:.2e} rad/rad, finite differences {:.2e} mm/rad / {:.2e} rad/rad",
        samples.len(),
        w.pose_mm,
        w.pose_rot,
        w.jac_lin_mm,
        w.jac_ang,
        w.fd_lin_mm,
        w.fd_ang
    );
    w
}

#[test]
fn kr16_2_matches_pinocchio() {
    check_robot::<6>("kr16_2", "base_link");
}

#[test]
fn puma560_matches_pinocchio() {
    check_robot::<6>("puma560", "link1");
}

#[test]
fn lbr_iiwa_14_matches_pinocchio() {
    check_robot::<7>("lbr_iiwa_14_r820", "base_link");
}

#[test]
fn load_chain_is_load_robot_chain() {
    let file = ref_path("urdf/kr16_2.urdf");
    let c = load_chain::<6>(&file, "base_link", "tool0").expect("load");
    let r = load_robot::<6>(&file, "base_link", "tool0").expect("load");
    assert_eq!(c, r.chain);
    // The fixed tool0 frame (xyz 0.158 0 0, rpy 0 1.57079632679 0 on link_6) lands in the tool
    // transform, in mm; the file's π/2 has 12 digits.
    assert_eq!(c.tool.translation, Vector3::new(158.0, 0.0, 0.0));
    assert!((c.tool.rotation * Vector3::z() - Vector3::x()).norm() < 1e-11);
}

fn message<const N: usize>(file: &str, base: &str, tip: &str) -> (String, UrdfReason) {
    let path = ref_path(file);
    let e = load_robot::<N>(&path, base, tip).expect_err("must fail");
    let m = e.to_string();
    assert!(
        m.contains(&path.display().to_string()),
        "message does not name the file: {m}"
    );
    (m, e.reason)
}

#[test]
fn wrong_joint_count_names_file_and_reason() {
    let (m, r) = message::<7>("urdf/kr16_2.urdf", "base_link", "tool0");
    assert!(matches!(
        r,
        UrdfReason::JointCount {
            expected: 7,
            found: 6,
            ..
        }
    ));
    assert!(m.contains("6 movable joints"), "{m}");
    assert!(m.contains("joint_a1") && m.contains("joint_a6"), "{m}");
    assert!(m.contains("the chain has 7"), "{m}");
    let (m, _) = message::<6>("urdf/lbr_iiwa_14_r820.urdf", "base_link", "tool0");
    assert!(
        m.contains("7 movable joints") && m.contains("the chain has 6"),
        "{m}"
    );
}

#[test]
fn unknown_links_name_file_and_reason() {
    let (m, r) = message::<6>("urdf/kr16_2.urdf", "base_link", "flange_typo");
    assert!(matches!(r, UrdfReason::MissingLink { role: "tip", .. }));
    assert!(
        m.contains("the tip link `flange_typo` is not in the file"),
        "{m}"
    );
    let (m, _) = message::<6>("urdf/kr16_2.urdf", "world", "tool0");
    assert!(
        m.contains("the base link `world` is not in the file"),
        "{m}"
    );
}

#[test]
fn no_path_names_file_and_reason() {
    // `base` hangs off base_link: there is no way down from tool0 to it.
    let (m, r) = message::<6>("urdf/kr16_2.urdf", "base", "tool0");
    assert!(matches!(r, UrdfReason::NoPath { .. }));
    assert!(
        m.contains("no chain of joints leads from the base link `base` to the tip link `tool0`"),
        "{m}"
    );
}

fn two_joint(kind: &str, axis: &str) -> String {
    format!(
        r#"<robot name="r">
  <link name="a"/><link name="b"/><link name="c"/>
  <joint name="j1" type="revolute">
    <origin xyz="0 0 0.1" rpy="0 0 0"/><parent link="a"/><child link="b"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="0" velocity="1"/>
  </joint>
  <joint name="j2" type="{kind}">
    <origin xyz="0.2 0 0" rpy="0.1 0.2 0.3"/><parent link="b"/><child link="c"/>
    <axis xyz="{axis}"/><limit lower="-1" upper="1" effort="0" velocity="2"/>
  </joint>
</robot>"#
    )
}

#[test]
fn prismatic_and_zero_axis_are_errors() {
    let e = parse_robot::<2>(&two_joint("prismatic", "1 0 0"), "inline.urdf", "a", "c")
        .expect_err("prismatic");
    let m = e.to_string();
    assert!(m.starts_with("URDF inline.urdf: "), "{m}");
    assert!(m.contains("joint `j2` is prismatic"), "{m}");
    let e = parse_robot::<2>(&two_joint("revolute", "0 0 0"), "inline.urdf", "a", "c")
        .expect_err("axis");
    assert!(matches!(e.reason, UrdfReason::ZeroAxis { .. }));
    assert!(e.to_string().contains("joint `j2` has a zero"), "{e}");
}

#[test]
fn continuous_joint_and_units() {
    let r = parse_robot::<2>(&two_joint("continuous", "0 2 0"), "inline.urdf", "a", "c")
        .expect("continuous is a revolute joint without limits");
    assert_eq!(r.chain.limits[1].lower, f64::NEG_INFINITY);
    assert_eq!(r.chain.limits[1].upper, f64::INFINITY);
    assert_eq!(r.chain.limits[1].max_speed, 2.0);
    // Metres to millimetres, axis normalised, rpy = Rz(yaw) Ry(pitch) Rx(roll).
    assert_eq!(
        r.chain.joints[0].origin.translation,
        Vector3::new(0.0, 0.0, 100.0)
    );
    assert_eq!(
        r.chain.joints[1].origin.translation,
        Vector3::new(200.0, 0.0, 0.0)
    );
    assert_eq!(r.chain.joints[1].axis, Vector3::y());
    let rot = |axis: Vector3<f64>, a: f64| {
        *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), a).matrix()
    };
    let expect = rot(Vector3::z(), 0.3) * rot(Vector3::y(), 0.2) * rot(Vector3::x(), 0.1);
    assert!((r.chain.joints[1].origin.rotation - expect).amax() < 1e-15);
}
