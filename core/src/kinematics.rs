//! Robot kinematics: a serial chain in standard Denavit–Hartenberg form.
//!
//! Link `i` contributes `T_i = Rz(q_i + θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)`; the flange pose in the
//! world frame is `E(q) = base · T_1 ⋯ T_N` and the needle base (tool point) is `B(q) = E(q) · T_EB`.
//! The geometric Jacobian maps joint rates to the twist of a point of the last link, in the world
//! frame: rows `[vx, vy, vz]` in mm/rad and `[wx, wy, wz]` in rad/rad, column `i` being
//! `[z_{i-1} × (p − o_{i-1}); z_{i-1}]` with `z_{i-1}`, `o_{i-1}` the axis and origin of joint `i`.

use core::f64::consts::{FRAC_PI_2, PI};
use nalgebra::{Matrix3, SMatrix, Vector3};

/// A rigid transform: rotation then translation, `x ↦ R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Rotation matrix (columns are the frame's axes expressed in the parent frame).
    pub rotation: Matrix3<f64>,
    /// Origin of the frame in the parent frame [mm].
    pub translation: Vector3<f64>,
}

crate::zeroed::impl_zeroable!(Pose {
    rotation,
    translation
});

impl Pose {
    /// The identity transform.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// A pure translation [mm].
    pub fn from_translation(t: Vector3<f64>) -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: t,
        }
    }

    /// Composition `self · other` (apply `other` first, in `self`'s frame).
    #[inline]
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            rotation: self.rotation * other.rotation,
            translation: self.rotation * other.translation + self.translation,
        }
    }

    /// Maps a point given in this frame to the parent frame [mm].
    #[inline]
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// The frame's z axis in the parent frame (unit vector).
    #[inline]
    pub fn z_axis(&self) -> Vector3<f64> {
        self.rotation.column(2).into_owned()
    }

    /// The 4×4 homogeneous matrix, row-major (translation in mm).
    pub fn to_homogeneous(&self) -> [[f64; 4]; 4] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            [r[(0, 0)], r[(0, 1)], r[(0, 2)], t[0]],
            [r[(1, 0)], r[(1, 1)], r[(1, 2)], t[1]],
            [r[(2, 0)], r[(2, 1)], r[(2, 2)], t[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }
}

/// One row of a standard DH table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DhJoint {
    /// Joint angle offset θ_i added to q_i [rad].
    pub theta_offset: f64,
    /// Offset along the previous z axis d_i [mm].
    pub d: f64,
    /// Length along the new x axis a_i [mm].
    pub a: f64,
    /// Twist about the new x axis α_i [rad].
    pub alpha: f64,
}

crate::zeroed::impl_zeroable!(DhJoint {
    theta_offset,
    d,
    a,
    alpha
});

impl DhJoint {
    /// The link transform `Rz(q + θ) Tz(d) Tx(a) Rx(α)` for joint value `q` [rad].
    #[inline]
    pub fn transform(&self, q: f64) -> Pose {
        let (st, ct) = libm::sincos(q + self.theta_offset);
        let (sa, ca) = libm::sincos(self.alpha);
        Pose {
            rotation: Matrix3::new(ct, -st * ca, st * sa, st, ct * ca, -ct * sa, 0.0, sa, ca),
            translation: Vector3::new(self.a * ct, self.a * st, self.d),
        }
    }
}

/// Position and speed limits of one joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimit {
    /// Lowest joint value [rad].
    pub lower: f64,
    /// Highest joint value [rad].
    pub upper: f64,
    /// Largest joint speed magnitude [rad/s].
    pub max_speed: f64,
}

crate::zeroed::impl_zeroable!(JointLimit {
    lower,
    upper,
    max_speed
});

impl JointLimit {
    /// Limits given in degrees and degrees per second.
    pub fn from_degrees(lower: f64, upper: f64, max_speed: f64) -> Self {
        let k = PI / 180.0;
        Self {
            lower: lower * k,
            upper: upper * k,
            max_speed: max_speed * k,
        }
    }

    /// Mid-range joint value [rad].
    pub fn mid(&self) -> f64 {
        0.5 * (self.lower + self.upper)
    }
}

/// A serial robot with `N` revolute joints in standard DH form, a base and a tool transform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DhChain<const N: usize> {
    /// DH table, joint 1 first.
    pub joints: [DhJoint; N],
    /// Joint position and speed limits.
    pub limits: [JointLimit; N],
    /// World ← robot base frame (the DH frame 0) [mm].
    pub base: Pose,
    /// Flange ← needle base, `T_EB` [mm]; identity: the needle starts at the flange along its z axis.
    pub tool: Pose,
}

crate::zeroed::impl_zeroable!(DhChain<const N> {
    joints,
    limits,
    base,
    tool
});

/// The Mitsubishi RV-1A of DESIGN.md (6 joints).
pub type Rv1a = DhChain<6>;

impl DhChain<6> {
    /// The Mitsubishi RV-1A: DH table, joint limits and speed limits of DESIGN.md, identity base
    /// and tool. At `q = 0` the flange is at (−90, 0, 782) mm.
    pub fn rv1a() -> Self {
        let j = |theta_offset, d, a, alpha| DhJoint {
            theta_offset,
            d,
            a,
            alpha,
        };
        Self {
            joints: [
                j(0.0, 300.0, 0.0, -FRAC_PI_2),
                j(-FRAC_PI_2, 0.0, 250.0, 0.0),
                j(FRAC_PI_2, 0.0, -90.0, FRAC_PI_2),
                j(0.0, 160.0, 0.0, -FRAC_PI_2),
                j(0.0, 0.0, 0.0, FRAC_PI_2),
                j(0.0, 72.0, 0.0, 0.0),
            ],
            limits: [
                JointLimit::from_degrees(-150.0, 150.0, 180.0),
                JointLimit::from_degrees(-60.0, 120.0, 90.0),
                JointLimit::from_degrees(60.0, 155.0, 135.0),
                JointLimit::from_degrees(-160.0, 160.0, 180.0),
                JointLimit::from_degrees(-90.0, 90.0, 180.0),
                JointLimit::from_degrees(-200.0, 200.0, 210.0),
            ],
            base: Pose::identity(),
            tool: Pose::identity(),
        }
    }
}

impl<const N: usize> DhChain<N> {
    /// World poses of every link frame, `frames[i] = base · T_1 ⋯ T_{i+1}`; returns the flange
    /// pose (`frames[N-1]`, or `base` when `N = 0`).
    pub fn link_frames(&self, q: &[f64; N], frames: &mut [Pose; N]) -> Pose {
        let mut t = self.base;
        for i in 0..N {
            t = t.compose(&self.joints[i].transform(q[i]));
            frames[i] = t;
        }
        t
    }

    /// Flange pose `E(q)` in the world frame.
    ///
    /// # Example
    /// ```
    /// use needle_core::DhChain;
    ///
    /// let rv1a = DhChain::rv1a();
    /// let home = rv1a.flange_pose(&[0.0; 6]);
    /// assert!((home.translation - nalgebra::Vector3::new(-90.0, 0.0, 782.0)).norm() < 1e-9);
    /// // The needle base is the flange until a tool transform is set.
    /// assert_eq!(rv1a.tool_pose(&[0.0; 6]), home);
    /// ```
    pub fn flange_pose(&self, q: &[f64; N]) -> Pose {
        let mut t = self.base;
        for i in 0..N {
            t = t.compose(&self.joints[i].transform(q[i]));
        }
        t
    }

    /// Needle base (tool) pose `B(q) = E(q) · T_EB` in the world frame.
    pub fn tool_pose(&self, q: &[f64; N]) -> Pose {
        self.flange_pose(q).compose(&self.tool)
    }

    /// Geometric Jacobian of the point `p` [mm, world] rigidly attached to the last link, given
    /// the link frames from [`Self::link_frames`].
    fn jacobian_at(&self, frames: &[Pose; N], p: &Vector3<f64>) -> SMatrix<f64, 6, N> {
        let mut jac = SMatrix::<f64, 6, N>::zeros();
        for i in 0..N {
            let prev = if i == 0 { &self.base } else { &frames[i - 1] };
            let z = prev.z_axis();
            let v = z.cross(&(p - prev.translation));
            for r in 0..3 {
                jac[(r, i)] = v[r];
                jac[(r + 3, i)] = z[r];
            }
        }
        jac
    }

    /// Geometric Jacobian (6×N, world frame) of the flange origin: rows vx, vy, vz [mm/rad],
    /// wx, wy, wz [rad/rad].
    pub fn jacobian_flange(&self, q: &[f64; N]) -> SMatrix<f64, 6, N> {
        let mut frames = [Pose::identity(); N];
        let e = self.link_frames(q, &mut frames);
        self.jacobian_at(&frames, &e.translation)
    }

    /// Geometric Jacobian (6×N, world frame) of the tool point (needle base `B`): rows vx, vy, vz
    /// [mm/rad], wx, wy, wz [rad/rad]. Also returns the tool pose.
    ///
    /// # Example
    /// ```
    /// use needle_core::DhChain;
    ///
    /// let chain = DhChain::rv1a();
    /// let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    /// let (jac, _) = chain.jacobian_tool(&q);
    /// // Column 1 is the needle-base velocity per unit rate of joint 2: a central difference.
    /// let h = 1e-5;
    /// let (mut qp, mut qm) = (q, q);
    /// qp[1] += h;
    /// qm[1] -= h;
    /// let v = (chain.tool_pose(&qp).translation - chain.tool_pose(&qm).translation) / (2.0 * h);
    /// for r in 0..3 {
    ///     assert!((v[r] - jac[(r, 1)]).abs() < 1e-4); // mm/rad
    /// }
    /// ```
    pub fn jacobian_tool(&self, q: &[f64; N]) -> (SMatrix<f64, 6, N>, Pose) {
        let mut frames = [Pose::identity(); N];
        let b = self.link_frames(q, &mut frames).compose(&self.tool);
        (self.jacobian_at(&frames, &b.translation), b)
    }

    /// Whether every joint is within its position limits (inclusive) and finite.
    pub fn within_limits(&self, q: &[f64; N]) -> bool {
        q.iter()
            .zip(&self.limits)
            .all(|(&v, l)| v >= l.lower && v <= l.upper)
    }

    /// Clamps `q` into the position limits; returns `true` when any joint was moved.
    pub fn clamp_to_limits(&self, q: &mut [f64; N]) -> bool {
        let mut clamped = false;
        for (v, l) in q.iter_mut().zip(&self.limits) {
            // Not `f64::clamp`: it panics on inverted or NaN bounds, and limits are user data.
            let c = v.max(l.lower).min(l.upper);
            if c != *v {
                clamped = true;
                *v = c;
            }
        }
        clamped
    }

    /// Mid-range joint vector [rad].
    pub fn mid_range(&self) -> [f64; N] {
        let mut q = [0.0; N];
        for (v, l) in q.iter_mut().zip(&self.limits) {
            *v = l.mid();
        }
        q
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn rv1a_home_flange() {
        let e = DhChain::rv1a().flange_pose(&[0.0; 6]);
        assert!((e.translation - Vector3::new(-90.0, 0.0, 782.0)).norm() < 1e-9);
    }
}
