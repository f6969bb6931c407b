//! From a scene to the core's types: the robot (preset, DH table or URDF) and the inverse
//! controller's tuning.

use super::{PoseSpec, Scene};
use crate::robot::urdf::{UrdfReason, load_robot};
use nalgebra::{Rotation3, Vector3};
use needle_core::SerialChain;
use needle_core::constraint::GsParams;
use needle_core::inverse::{InverseParams, JacobianMode, StepMethod};
use needle_core::kinematics::{DhChain, DhJoint, JointLimit, Kinematics, Pose, Robot};
use std::path::Path;

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
    /// The robot: preset, DH table or URDF chain; limits (scene overrides in degrees), base
    /// and tool.
    ///
    /// # Errors
    /// `(field, reason)` when the URDF cannot be turned into a 6-joint chain (the reason names
    /// the file), or when it leaves a joint without a speed limit that the scene does not give.
    pub fn robot(&self) -> Result<Robot<6>, (String, String)> {
        let r = &self.robot;
        let mut robot = match &r.urdf {
            Some(file) => Robot::Serial(self.urdf_chain(file)?),
            None => {
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
                chain.base = r.base.to_pose();
                chain.tool = r.tool.to_pose();
                Robot::Dh(chain)
            }
        };
        let k = std::f64::consts::PI / 180.0;
        for (i, l) in robot.limits_mut().iter_mut().enumerate() {
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
        if let Some(i) = robot
            .limits()
            .iter()
            .position(|l| l.max_speed.is_nan() || l.max_speed <= 0.0)
        {
            return Err((
                "robot.speed_limit_deg_s".into(),
                format!(
                    "joint {} has no velocity limit in {}: give the six speed limits [deg/s]",
                    i + 1,
                    r.urdf
                        .as_deref()
                        .unwrap_or(Path::new("the robot"))
                        .display()
                ),
            ));
        }
        Ok(robot)
    }

    /// The chain of `robot.urdf` from `base_link` to `tip_link`, placed at `robot.base`, the
    /// needle base at `robot.tool` in the tip link's frame.
    fn urdf_chain(&self, file: &Path) -> Result<SerialChain<6>, (String, String)> {
        let r = &self.robot;
        let link = |v: &Option<String>| v.clone().unwrap_or_default();
        let robot = load_robot::<6>(file, &link(&r.base_link), &link(&r.tip_link)).map_err(|e| {
            let field = match &e.reason {
                UrdfReason::MissingLink { role: "base", .. } => "robot.base_link",
                UrdfReason::MissingLink { .. } | UrdfReason::NoPath { .. } => "robot.tip_link",
                _ => "robot.urdf",
            };
            let mut reason = e.to_string();
            if let UrdfReason::JointCount { found: 7, .. } = e.reason {
                reason.push_str(
                    ": 7-joint robots run in the core's controller, not yet in this host (6 joints)",
                );
            }
            (field.to_owned(), reason)
        })?;
        let mut chain = robot.chain;
        chain.base = r.base.to_pose().compose(&chain.base);
        chain.tool = chain.tool.compose(&r.tool.to_pose());
        Ok(chain)
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
            qp_heading: v.qp_heading,
            aim_ahead: v.aim_ahead,
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
