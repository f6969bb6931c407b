//! The objective `T(q) = (e_x, e_y, e_z, w_θ (k θ1 + (1 − k) θ2))` of the paper's §IV-A,
//! evaluated from the observation rows `o = o_free + C λ` of a frame and the needle-base pose.

use super::InverseParams;
use crate::kinematics::Pose;
use crate::math::angle_between;
use crate::payload::{ComplianceFrame, ObsIndex};
use nalgebra::Vector3;

/// Blend factor `k` of the angular objective.
///
/// This follows the paper's *text* (§IV-A), not its eq. 13: in the air (not inserted) only the
/// tip angle θ1 counts (`k = 1`); once inserted, `k` falls linearly from 1 at the entry point to
/// 0 at depth `d`, beyond which only the base angle θ2 counts (`k = 0`). Eq. 13 as printed
/// (`k = 0` outside the gel, `k = l/d`, then 1) contradicts the text and would steer by θ2 in the
/// air, where θ2 is zero by construction.
pub fn blend_factor(inserted: bool, depth: f64, d: f64) -> f64 {
    if !inserted {
        return 1.0;
    }
    if !(d > 0.0) {
        return 0.0;
    }
    (1.0 - depth / d).clamp(0.0, 1.0)
}

/// Breakdown of an objective evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Objective {
    /// `T = (e_x, e_y, e_z, w_θ (k θ1 + (1 − k) θ2))` [mm].
    pub t: [f64; 4],
    /// Tip-direction angle θ1 to the target tangent [rad].
    pub theta1: f64,
    /// Base-direction angle θ2 to the entry point [rad].
    pub theta2: f64,
    /// Blend factor k [-].
    pub k: f64,
    /// Rotation vector taking the target tangent onto the tip direction, `|φ1| = θ1` [rad].
    pub phi1: [f64; 3],
    /// Rotation vector taking the entry direction onto the base direction, `|φ2| = θ2` [rad].
    pub phi2: [f64; 3],
}

impl Objective {
    /// Derivative of the angular component `w_θ (k θ1 + (1 − k) θ2)` along a change of the
    /// rotation vectors, `perturbed` holding the values after a step `h`: the angles are norms
    /// of smooth rotation vectors, so the vectors are differenced and the norm is differentiated
    /// analytically, `dθ = φ̂ · dφ` (0 at θ = 0, where θ is minimal).
    pub(super) fn angle_derivative(&self, perturbed: &Objective, h: f64, weight: f64) -> f64 {
        let dir = |phi: &[f64; 3], theta: f64| {
            if theta > 0.0 {
                Vector3::from(*phi) / theta
            } else {
                Vector3::zeros()
            }
        };
        let d1 = (Vector3::from(perturbed.phi1) - Vector3::from(self.phi1)) / h;
        let d2 = (Vector3::from(perturbed.phi2) - Vector3::from(self.phi2)) / h;
        let g1 = dir(&self.phi1, self.theta1).dot(&d1);
        let g2 = dir(&self.phi2, self.theta2).dot(&d2);
        weight * (self.k * g1 + (1.0 - self.k) * g2)
    }
}

/// Rotation vector taking `from` onto `to` (axis `from × to`, angle in `[0, π]`), with its
/// angle; zero when either vector is zero or they are parallel.
fn rotation_between(from: &Vector3<f64>, to: &Vector3<f64>) -> ([f64; 3], f64) {
    let theta = angle_between(from, to);
    let axis = from.cross(to);
    let n = axis.norm();
    if n > 0.0 && theta > 0.0 {
        ((axis * (theta / n)).into(), theta)
    } else {
        ([0.0; 3], theta)
    }
}

/// The direction the tip should point along: the path's tangent `t̂` at the target, plus, once
/// inserted and with a look-ahead `l` > 0, the tip's error `e` to the target over `l`
/// (`l t̂ + e`, the direction from the tip to the point `l` ahead of the target along the
/// tangent). The tangent alone when that vector vanishes.
pub(super) fn aim_direction(
    inserted: bool,
    l: f64,
    tangent: &Vector3<f64>,
    e: &Vector3<f64>,
) -> Vector3<f64> {
    let n = tangent.norm();
    if !inserted || !(l > 0.0) || !(n > 0.0) {
        return *tangent;
    }
    let aim = tangent * (l / n) + e;
    if aim.norm() > 0.0 { aim } else { *tangent }
}

/// The tip's error `s` further along (docs of [`super::InverseParams::qp_horizon`]):
/// `e + s |t| (t̂ − ĥ)`, with `t̂` and `ĥ` the unit tangent and tip direction. The target
/// tangent `t` is a difference quotient over 1 mm of path, so `|t|` ≈ 1 along the path and
/// falls to 0 over its last millimetre: the horizon closes smoothly at the path's end, where
/// the objective is the error itself. `e` itself when not inserted, `s` = 0, or the tip
/// direction vanishes.
pub(super) fn predicted_error(
    inserted: bool,
    s: f64,
    tangent: &Vector3<f64>,
    tip_dir: &Vector3<f64>,
    e: &Vector3<f64>,
) -> Vector3<f64> {
    let nh = tip_dir.norm();
    if !inserted || !(s > 0.0) || !(nh > 0.0) {
        return *e;
    }
    e + (tangent - tip_dir * (tangent.norm() / nh)) * s
}

/// The objective for constraint forces `lambda` and needle-base pose `b` (from forward
/// kinematics), see the module docs.
pub fn evaluate_objective<const M: usize, const N: usize>(
    frame: &ComplianceFrame<M, N>,
    lambda: &[f64; M],
    b: &Pose,
    params: &InverseParams,
) -> Objective {
    let v = |idx| Vector3::from(frame.observe(idx, lambda));
    let tip = v(ObsIndex::TIP_POSITION);
    let tip_dir = v(ObsIndex::TIP_DIRECTION);
    let target = v(ObsIndex::TARGET_POINT);
    let tangent = v(ObsIndex::TARGET_TANGENT);
    let entry = v(ObsIndex::ENTRY_POINT);
    let e = target - tip;
    // The look-ahead belongs to the QP update; the paper's update keeps the paper's θ1.
    let look_ahead = match params.method {
        super::StepMethod::Qp => params.aim_ahead,
        super::StepMethod::Paper => 0.0,
    };
    let heading = aim_direction(frame.inserted != 0, look_ahead, &tangent, &e);
    let horizon = match params.method {
        super::StepMethod::Qp => params.qp_horizon,
        super::StepMethod::Paper => 0.0,
    };
    let e = predicted_error(frame.inserted != 0, horizon, &tangent, &tip_dir, &e);
    let (phi1, theta1) = rotation_between(&heading, &tip_dir);
    let (phi2, theta2) = rotation_between(&(entry - b.translation), &b.z_axis());
    let k = blend_factor(
        frame.inserted != 0,
        frame.insertion_depth,
        params.blend_depth,
    );
    let ang = params.angle_weight * (k * theta1 + (1.0 - k) * theta2);
    Objective {
        t: [e[0], e[1], e[2], ang],
        theta1,
        theta2,
        k,
        phi1,
        phi2,
    }
}
