//! Robot kinematics: a general serial chain of revolute joints (the URDF form).
//!
//! Joint `i` contributes `T_i(q_i) = O_i · Rot(a_i, q_i)`: a fixed origin transform `O_i` (the
//! joint frame in the previous joint's child frame) followed by a rotation by `q_i` about the unit
//! axis `a_i` given in the joint frame. The tool pose in the world frame is
//! `B(q) = base · T_1 ⋯ T_N · tool`. Standard Denavit–Hartenberg ([`DhChain`]) is one way to write
//! such a chain: [`SerialChain::from_dh`].
//!
//! The geometric Jacobian has [`DhChain`]'s convention: the twist of the tool origin in the world
//! frame, rows `[vx, vy, vz]` in mm/rad and `[wx, wy, wz]` in rad/rad, column `i` being
//! `[w_i × (p − o_i); w_i]` with `w_i`, `o_i` joint `i`'s axis and origin in the world frame.

use crate::kinematics::{DhChain, JointLimit, Kinematics, Pose};
use nalgebra::{Matrix3, Vector3};

/// One revolute joint: its fixed origin transform and its rotation axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SerialJoint {
    /// Previous link frame ← joint frame (at `q = 0`), translation in mm.
    pub origin: Pose,
    /// Unit rotation axis in the joint frame; positive `q` turns right-handed about it.
    pub axis: Vector3<f64>,
}

crate::zeroed::impl_zeroable!(SerialJoint { origin, axis });

impl SerialJoint {
    /// The link transform `O · Rot(axis, q)` for joint value `q` [rad].
    #[inline]
    pub fn transform(&self, q: f64) -> Pose {
        Pose {
            rotation: self.origin.rotation * axis_angle(&self.axis, q),
            translation: self.origin.translation,
        }
    }
}

/// Rotation by `angle` [rad] about the unit vector `k` (Rodrigues).
#[inline]
fn axis_angle(k: &Vector3<f64>, angle: f64) -> Matrix3<f64> {
    let (s, c) = libm::sincos(angle);
    let v = 1.0 - c;
    let (x, y, z) = (k[0], k[1], k[2]);
    Matrix3::new(
        c + x * x * v,
        x * y * v - z * s,
        x * z * v + y * s,
        y * x * v + z * s,
        c + y * y * v,
        y * z * v - x * s,
        z * x * v - y * s,
        z * y * v + x * s,
        c + z * z * v,
    )
}

/// A serial robot with `N` revolute joints given by origin transforms and axes, a base and a tool
/// transform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SerialChain<const N: usize> {
    /// Joints, joint 1 first.
    pub joints: [SerialJoint; N],
    /// World ← robot base link [mm].
    pub base: Pose,
    /// Last joint's child link ← tool frame [mm] (fixed joints after the last movable one).
    pub tool: Pose,
    /// Joint position and speed limits (±∞ for a continuous joint).
    pub limits: [JointLimit; N],
}

crate::zeroed::impl_zeroable!(SerialChain<const N> {
    joints,
    base,
    tool,
    limits
});

impl<const N: usize> SerialChain<N> {
    /// The same kinematics as a DH chain: joint `i` turns about the z axis of DH frame `i − 1`,
    /// and DH link `i`'s fixed part `Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)` becomes the origin of joint
    /// `i + 1` (of the tool for the last link); the limits are the table's.
    pub fn from_dh(dh: &DhChain<N>) -> Self {
        let mut joints = [SerialJoint {
            origin: Pose::identity(),
            axis: Vector3::z(),
        }; N];
        let mut carry = Pose::identity();
        for i in 0..N {
            joints[i].origin = carry;
            // Rz(q + θ) Tz(d) Tx(a) Rx(α) = Rz(q) · [Rz(θ) Tz(d) Tx(a) Rx(α)] = Rz(q) · T(0).
            carry = dh.joints[i].transform(0.0);
        }
        Self {
            joints,
            base: dh.base,
            tool: carry.compose(&dh.tool),
            limits: dh.limits,
        }
    }

    /// Whether every axis is finite and of unit length (to 1e-9).
    pub fn axes_are_unit(&self) -> bool {
        self.joints
            .iter()
            .all(|j| (j.axis.norm_squared() - 1.0).abs() < 1e-9)
    }
}

impl<const N: usize> Kinematics<N> for SerialChain<N> {
    fn base(&self) -> &Pose {
        &self.base
    }
    fn tool(&self) -> &Pose {
        &self.tool
    }
    fn limits(&self) -> &[JointLimit; N] {
        &self.limits
    }
    #[inline]
    fn link(&self, i: usize, q: f64) -> Pose {
        self.joints[i].transform(q)
    }
    /// The joint frame before its rotation is `prev · O_i`; the rotation leaves the axis and the
    /// origin unchanged.
    #[inline]
    fn joint_axis(&self, i: usize, prev: &Pose) -> (Vector3<f64>, Vector3<f64>) {
        let j = &self.joints[i];
        let f = prev.compose(&j.origin);
        (f.rotation * j.axis, f.translation)
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::kinematics::{DhJoint, JointLimit};

    /// Deterministic uniform numbers in [-1, 1) (xorshift64*).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
    }

    fn check_same<const N: usize>(dh: &DhChain<N>, rng: &mut Rng) {
        let s = SerialChain::from_dh(dh);
        assert!(s.axes_are_unit());
        for _ in 0..200 {
            let mut q = [0.0; N];
            for v in q.iter_mut() {
                *v = 3.5 * rng.next();
            }
            let (pd, ps) = (dh.tool_pose(&q), s.tool_pose(&q));
            assert!((pd.translation - ps.translation).amax() < 1e-12 * 1e3);
            assert!((pd.rotation - ps.rotation).amax() < 1e-12);
            let (jd, bd) = dh.jacobian_tool(&q);
            let (js, bs) = s.jacobian_tool(&q);
            assert!((bd.translation - bs.translation).amax() < 1e-9);
            for c in 0..N {
                for r in 0..3 {
                    // mm/rad entries of arms ~1 m: 1e-12 relative.
                    assert!((jd[(r, c)] - js[(r, c)]).abs() < 1e-12 * 1e3, "{r},{c}");
                    assert!((jd[(r + 3, c)] - js[(r + 3, c)]).abs() < 1e-12, "{r},{c}");
                }
            }
        }
    }

    #[test]
    fn from_dh_matches_rv1a() {
        let mut dh = DhChain::rv1a();
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        check_same(&dh, &mut rng);
        // A non-trivial base and tool.
        dh.base = Pose {
            rotation: axis_angle(&Vector3::new(0.6, 0.0, 0.8), 0.7),
            translation: Vector3::new(100.0, -50.0, 20.0),
        };
        dh.tool = Pose {
            rotation: axis_angle(&Vector3::new(0.0, 0.6, -0.8), -1.1),
            translation: Vector3::new(5.0, 10.0, 120.0),
        };
        check_same(&dh, &mut rng);
    }

    #[test]
    fn from_dh_matches_random_seven_joint_chain() {
        let mut rng = Rng(12345);
        let mut joints = [DhJoint {
            theta_offset: 0.0,
            d: 0.0,
            a: 0.0,
            alpha: 0.0,
        }; 7];
        for j in joints.iter_mut() {
            *j = DhJoint {
                theta_offset: 3.0 * rng.next(),
                d: 400.0 * rng.next(),
                a: 400.0 * rng.next(),
                alpha: 3.0 * rng.next(),
            };
        }
        let dh = DhChain {
            joints,
            limits: [JointLimit::from_degrees(-180.0, 180.0, 90.0); 7],
            base: Pose::from_translation(Vector3::new(1.0, 2.0, 3.0)),
            tool: Pose::from_translation(Vector3::new(0.0, 0.0, 50.0)),
        };
        check_same(&dh, &mut rng);
    }

    #[test]
    fn rodrigues_is_a_rotation() {
        let k = Vector3::new(1.0, -2.0, 2.0) / 3.0;
        let r = axis_angle(&k, 0.9);
        assert!((r * r.transpose() - Matrix3::identity()).amax() < 1e-15);
        assert!((r * k - k).amax() < 1e-15);
        assert!((r.determinant() - 1.0).abs() < 1e-14);
    }
}
