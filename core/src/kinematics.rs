//! Robot kinematics: a serial chain in standard Denavit–Hartenberg form.
//!
//! Link `i` contributes `T_i = Rz(q_i + θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)`; the flange pose in the
//! world frame is `E(q) = base · T_1 ⋯ T_N` and the needle base (tool point) is `B(q) = E(q) · T_EB`.
//! The geometric Jacobian maps joint rates to the twist of a point of the last link, in the world
//! frame: rows `[vx, vy, vz]` in mm/rad and `[wx, wy, wz]` in rad/rad, column `i` being
//! `[z_{i-1} × (p − o_{i-1}); z_{i-1}]` with `z_{i-1}`, `o_{i-1}` the axis and origin of joint `i`.

use crate::serial_chain::SerialChain;
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

    /// Mid-range joint value [rad]; 0 for a joint without finite limits (continuous).
    pub fn mid(&self) -> f64 {
        let m = 0.5 * (self.lower + self.upper);
        if m.is_finite() { m } else { 0.0 }
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

/// The kinematics of a serial chain of `N` revolute joints, however it is written (a DH table,
/// joint origins and axes): the link transforms and joint axes, the base and tool transforms and
/// the joint limits. Forward kinematics, the Jacobian and the limit helpers are written once, on
/// these.
pub trait Kinematics<const N: usize> {
    /// World ← robot base [mm].
    fn base(&self) -> &Pose;
    /// Last link ← tool (needle base) [mm].
    fn tool(&self) -> &Pose;
    /// Joint position and speed limits.
    fn limits(&self) -> &[JointLimit; N];
    /// Link transform of joint `i` (previous link frame ← link `i`'s frame) at joint value `q`.
    fn link(&self, i: usize, q: f64) -> Pose;
    /// Unit axis and a point of joint `i` in the world frame, given the world pose `prev` of the
    /// link frame before it (the base for joint 0).
    fn joint_axis(&self, i: usize, prev: &Pose) -> (Vector3<f64>, Vector3<f64>);

    /// World poses of every link frame, `frames[i] = base · T_1 ⋯ T_{i+1}`; returns the flange
    /// pose (`frames[N-1]`, or `base` when `N = 0`).
    fn link_frames(&self, q: &[f64; N], frames: &mut [Pose; N]) -> Pose {
        let mut t = *self.base();
        for i in 0..N {
            t = t.compose(&self.link(i, q[i]));
            frames[i] = t;
        }
        t
    }

    /// Flange pose `E(q)` in the world frame.
    ///
    /// # Example
    /// ```
    /// use needle_core::{DhChain, Kinematics};
    ///
    /// let rv1a = DhChain::rv1a();
    /// let home = rv1a.flange_pose(&[0.0; 6]);
    /// assert!((home.translation - nalgebra::Vector3::new(-90.0, 0.0, 782.0)).norm() < 1e-9);
    /// // The needle base is the flange until a tool transform is set.
    /// assert_eq!(rv1a.tool_pose(&[0.0; 6]), home);
    /// ```
    fn flange_pose(&self, q: &[f64; N]) -> Pose {
        let mut t = *self.base();
        for i in 0..N {
            t = t.compose(&self.link(i, q[i]));
        }
        t
    }

    /// Needle base (tool) pose `B(q) = E(q) · T_EB` in the world frame.
    fn tool_pose(&self, q: &[f64; N]) -> Pose {
        self.flange_pose(q).compose(self.tool())
    }

    /// Geometric Jacobian of the point `p` [mm, world] rigidly attached to the last link, given
    /// the link frames from [`Self::link_frames`].
    fn jacobian_at(&self, frames: &[Pose; N], p: &Vector3<f64>) -> SMatrix<f64, 6, N> {
        let mut jac = SMatrix::<f64, 6, N>::zeros();
        for i in 0..N {
            let prev = if i == 0 { self.base() } else { &frames[i - 1] };
            let (w, o) = self.joint_axis(i, prev);
            let v = w.cross(&(p - o));
            for r in 0..3 {
                jac[(r, i)] = v[r];
                jac[(r + 3, i)] = w[r];
            }
        }
        jac
    }

    /// Geometric Jacobian (6×N, world frame) of the flange origin: rows vx, vy, vz [mm/rad],
    /// wx, wy, wz [rad/rad].
    fn jacobian_flange(&self, q: &[f64; N]) -> SMatrix<f64, 6, N> {
        let mut frames = [Pose::identity(); N];
        let e = self.link_frames(q, &mut frames);
        self.jacobian_at(&frames, &e.translation)
    }

    /// Geometric Jacobian (6×N, world frame) of the tool point (needle base `B`): rows vx, vy, vz
    /// [mm/rad], wx, wy, wz [rad/rad]. Also returns the tool pose.
    ///
    /// # Example
    /// ```
    /// use needle_core::{DhChain, Kinematics};
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
    fn jacobian_tool(&self, q: &[f64; N]) -> (SMatrix<f64, 6, N>, Pose) {
        let mut frames = [Pose::identity(); N];
        let b = self.link_frames(q, &mut frames).compose(self.tool());
        (self.jacobian_at(&frames, &b.translation), b)
    }

    /// Whether every joint is within its position limits (inclusive) and finite.
    fn within_limits(&self, q: &[f64; N]) -> bool {
        q.iter()
            .zip(self.limits())
            .all(|(&v, l)| v >= l.lower && v <= l.upper)
    }

    /// Clamps `q` into the position limits; returns `true` when any joint was moved.
    fn clamp_to_limits(&self, q: &mut [f64; N]) -> bool {
        let mut clamped = false;
        for (v, l) in q.iter_mut().zip(self.limits()) {
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
    fn mid_range(&self) -> [f64; N] {
        let mut q = [0.0; N];
        for (v, l) in q.iter_mut().zip(self.limits()) {
            *v = l.mid();
        }
        q
    }

    /// The smallest distance of a joint to one of its position limits, and that joint [rad]
    /// (negative outside the limits; `+∞` when no joint has a finite limit).
    fn limit_margin(&self, q: &[f64; N]) -> (f64, usize) {
        let mut best = (f64::INFINITY, 0);
        for (i, (v, l)) in q.iter().zip(self.limits()).enumerate() {
            let m = (v - l.lower).min(l.upper - v);
            if m < best.0 {
                best = (m, i);
            }
        }
        best
    }
}

impl<const N: usize> Kinematics<N> for DhChain<N> {
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
    /// Joint `i` turns about the z axis of DH frame `i − 1`.
    #[inline]
    fn joint_axis(&self, _i: usize, prev: &Pose) -> (Vector3<f64>, Vector3<f64>) {
        (prev.z_axis(), prev.translation)
    }
}

/// The robot a controller steers: a DH table (the RV-1A preset, a `[robot]` table) or a general
/// serial chain (a URDF). Each keeps its own arithmetic, so a DH robot's results do not depend on
/// the general form existing.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, u8)]
pub enum Robot<const N: usize> {
    /// Standard Denavit–Hartenberg.
    Dh(DhChain<N>) = 0,
    /// Joint origins and axes (URDF).
    Serial(SerialChain<N>) = 1,
}

// SAFETY: `repr(C, u8)`: a `u8` tag then the variant's fields. All-zero bytes are tag 0, the
// `Dh` variant, over an all-zero `DhChain`, which is `Zeroable`.
unsafe impl<const N: usize> crate::zeroed::Zeroable for Robot<N> {}
const _: () = {
    #[allow(dead_code)]
    fn variant_zero_is_zeroable<const N: usize>(c: &DhChain<N>) {
        crate::zeroed::require_zeroable(c);
    }
};

impl<const N: usize> From<DhChain<N>> for Robot<N> {
    fn from(c: DhChain<N>) -> Self {
        Self::Dh(c)
    }
}

impl<const N: usize> From<SerialChain<N>> for Robot<N> {
    fn from(c: SerialChain<N>) -> Self {
        Self::Serial(c)
    }
}

/// Calls `$f` on the chain inside a [`Robot`].
macro_rules! dispatch {
    ($self:ident, $c:ident => $e:expr) => {
        match $self {
            Robot::Dh($c) => $e,
            Robot::Serial($c) => $e,
        }
    };
}

impl<const N: usize> Kinematics<N> for Robot<N> {
    fn base(&self) -> &Pose {
        dispatch!(self, c => c.base())
    }
    fn tool(&self) -> &Pose {
        dispatch!(self, c => c.tool())
    }
    fn limits(&self) -> &[JointLimit; N] {
        dispatch!(self, c => c.limits())
    }
    fn link(&self, i: usize, q: f64) -> Pose {
        dispatch!(self, c => c.link(i, q))
    }
    fn joint_axis(&self, i: usize, prev: &Pose) -> (Vector3<f64>, Vector3<f64>) {
        dispatch!(self, c => c.joint_axis(i, prev))
    }
    // The loops once per call, not a match per joint.
    fn tool_pose(&self, q: &[f64; N]) -> Pose {
        dispatch!(self, c => c.tool_pose(q))
    }
    fn jacobian_tool(&self, q: &[f64; N]) -> (SMatrix<f64, 6, N>, Pose) {
        dispatch!(self, c => c.jacobian_tool(q))
    }
}

impl<const N: usize> Robot<N> {
    /// Joint limits, mutable (e.g. a scene's overrides).
    pub fn limits_mut(&mut self) -> &mut [JointLimit; N] {
        dispatch!(self, c => &mut c.limits)
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
