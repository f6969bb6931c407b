//! From a scene to the core's types: the robot chain and the inverse controller's tuning.

use super::{PoseSpec, Scene};
use nalgebra::{Rotation3, Vector3};
use needle_core::constraint::GsParams;
use needle_core::inverse::{InverseParams, JacobianMode, StepMethod};
use needle_core::kinematics::{DhChain, DhJoint, JointLimit, Pose};

impl PoseSpec {
    /// The transform `x ↦ Rz(yaw) Ry(pitch) Rx(roll) x + t`.
    pub fn to_pose(&self) -> Pose {
        let [r, p, y] = self.rpy;
        Pose {
            rotation: Rotation3::from_euler_angles(r, p, y).into_inner(),
            translation: Vector3::from(self.translation),
        }
    }
}

impl Scene {
    /// The robot: preset or DH table, limits (scene overrides in degrees), base and tool.
    pub fn robot(&self) -> DhChain<6> {
        let r = &self.robot;
        let mut chain = DhChain::rv1a();
        if let Some(rows) = &r.dh {
            for (j, row) in chain.joints.iter_mut().zip(rows) {
                *j = DhJoint {
                    theta_offset: row.theta,
                    d: row.d,
                    a: row.a,
                    alpha: row.alpha,
                };
            }
        }
        let k = std::f64::consts::PI / 180.0;
        for i in 0..6 {
            let l = &mut chain.limits[i];
            if let Some(v) = &r.joint_min_deg {
                l.lower = v[i] * k;
            }
            if let Some(v) = &r.joint_max_deg {
                l.upper = v[i] * k;
            }
            if let Some(v) = &r.speed_limit_deg_s {
                *l = JointLimit {
                    max_speed: v[i] * k,
                    ..*l
                };
            }
        }
        chain.base = r.base.to_pose();
        chain.tool = r.tool.to_pose();
        chain
    }

    /// The inverse controller's tuning (the core's defaults for what a scene does not set).
    pub fn inverse_params(&self) -> InverseParams {
        let v = &self.inverse;
        InverseParams {
            joint_step: v.delta_q,
            blend_depth: v.blend_distance,
            angle_weight: v.angle_weight,
            damping: v.damping,
            tolerance: v.tolerance,
            max_base_step: v.max_base_step,
            method: match v.method {
                super::MethodSpec::Qp => StepMethod::Qp,
                super::MethodSpec::Paper => StepMethod::Paper,
            },
            clearance_margin: v.clearance_margin,
            qp_angle_weight: v.qp_angle_weight,
            jacobian: match v.jacobian {
                super::JacobianSpec::Solve => JacobianMode::Solve,
                super::JacobianSpec::Linearized => JacobianMode::Linearized,
                super::JacobianSpec::Hybrid => JacobianMode::Hybrid,
            },
            gs: GsParams {
                tolerance: self.solver.gs_tolerance,
                max_iterations: self.solver.gs_max_iterations,
                ..GsParams::default()
            },
            ..InverseParams::default()
        }
    }
}
