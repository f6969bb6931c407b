//! From a scene to the core's types: the robot (preset, DH table or URDF) and the inverse
//! controller's tuning.

use super::{PoseSpec, Scene};
use crate::joints::SUPPORTED_JOINTS;
use crate::robot::urdf::UrdfError;
use crate::robot::urdf::{UrdfReason, load_robot};
use nalgebra::{Rotation3, Vector3};
use needle_core::SerialChain;
use needle_core::constraint::GsParams;
use needle_core::inverse::{InverseParams, JacobianMode, StepMethod};
use needle_core::kinematics::{DhChain, DhJoint, JointLimit, Kinematics, Pose, Robot};
use std::path::Path;

/// A URDF loader's error as `(field, reason)`: the link fields for a missing link or chain,
/// `robot.urdf` otherwise.
fn urdf_error(e: UrdfError) -> (String, String) {
    let field = match &e.reason {
        UrdfReason::MissingLink { role: "base", .. } => "robot.base_link",
        UrdfReason::MissingLink { .. } | UrdfReason::NoPath { .. } => "robot.tip_link",
        _ => "robot.urdf",
    };
    (field.to_owned(), e.to_string())
}

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
    /// The robot's joint count: 6 for the preset or a DH table; the movable joints of the chain
    /// from `base_link` to `tip_link` of `robot.urdf`. This host runs 6 and 7 joints
    /// ([`SUPPORTED_JOINTS`]); another count is refused, naming the joints found.
    ///
    /// # Errors
    /// `(field, reason)` when the URDF cannot be read, has no such chain, or a count this host
    /// does not run.
    pub fn joint_count(&self) -> Result<usize, (String, String)> {
        let Some(file) = &self.robot.urdf else {
            return Ok(6);
        };
        let r = &self.robot;
        let link = |v: &Option<String>| v.clone().unwrap_or_default();
        match load_robot::<6>(file, &link(&r.base_link), &link(&r.tip_link)) {
            Ok(_) => Ok(6),
            Err(e) => match &e.reason {
                UrdfReason::JointCount { found, .. } if SUPPORTED_JOINTS.contains(found) => {
                    Ok(*found)
                }
                UrdfReason::JointCount {
                    found,
                    joints,
                    base,
                    tip,
                    ..
                } => Err((
                    "robot.urdf".into(),
                    format!(
                        "URDF {}: {found} movable joints from `{base}` to `{tip}` ({}); this \
                         host runs arms of 6 or 7 joints",
                        file.display(),
                        joints.join(", ")
                    ),
                )),
                _ => Err(urdf_error(e)),
            },
        }
    }

    /// The robot of a 6-joint scene ([`Scene::robot_n`] with `N` = 6).
    ///
    /// # Errors
    /// As [`Scene::robot_n`].
    pub fn robot(&self) -> Result<Robot<6>, (String, String)> {
        self.robot_n::<6>()
    }

    /// The robot with `N` joints: preset, DH table or URDF chain; limits (scene overrides in
    /// degrees), base and tool.
    ///
    /// # Errors
    /// `(field, reason)` when the URDF cannot be turned into an `N`-joint chain (the reason
    /// names the file), when `N` is not 6 for the preset or a DH table, when a per-joint list
    /// (`joint_min_deg`, …) has another length than `N`, or when it leaves a joint without a
    /// speed limit that the scene does not give.
    pub fn robot_n<const N: usize>(&self) -> Result<Robot<N>, (String, String)> {
        let r = &self.robot;
        let mut robot = match &r.urdf {
            Some(file) => Robot::Serial(self.urdf_chain::<N>(file)?),
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
                let field = if r.dh.is_some() {
                    "robot.dh"
                } else {
                    "robot.preset"
                };
                let wrong = || {
                    (
                        field.to_owned(),
                        format!("a robot of 6 joints, asked for as one of {N}"),
                    )
                };
                Robot::Dh(DhChain {
                    joints: <[DhJoint; N]>::try_from(&chain.joints[..]).map_err(|_| wrong())?,
                    limits: <[JointLimit; N]>::try_from(&chain.limits[..]).map_err(|_| wrong())?,
                    base: chain.base,
                    tool: chain.tool,
                })
            }
        };
        for (field, v) in [
            ("robot.joint_min_deg", &r.joint_min_deg),
            ("robot.joint_max_deg", &r.joint_max_deg),
            ("robot.speed_limit_deg_s", &r.speed_limit_deg_s),
            ("robot.start_joints_deg", &r.start_joints_deg),
            ("robot.ik_seed_deg", &r.ik_seed_deg),
        ] {
            if let Some(v) = v
                && v.len() != N
            {
                return Err((
                    field.into(),
                    format!(
                        "needs {N} values, one per joint of this robot (got {})",
                        v.len()
                    ),
                ));
            }
        }
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
                    "joint {} has no velocity limit in {}: give the {N} speed limits [deg/s]",
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
    fn urdf_chain<const N: usize>(&self, file: &Path) -> Result<SerialChain<N>, (String, String)> {
        let r = &self.robot;
        let link = |v: &Option<String>| v.clone().unwrap_or_default();
        let robot =
            load_robot::<N>(file, &link(&r.base_link), &link(&r.tip_link)).map_err(urdf_error)?;
        let mut chain = robot.chain;
        chain.base = r.base.to_pose().compose(&chain.base);
        chain.tool = chain.tool.compose(&r.tool.to_pose());
        Ok(chain)
    }

    /// The needle's steering length in the gel [mm] ([`crate::setup::steering_length`] of the
    /// needle's diameter and modulus and the gel's modulus).
    pub fn steering_length(&self) -> f64 {
        crate::setup::steering_length(
            self.needle.diameter,
            self.needle.young_modulus,
            self.gel.young_modulus,
        )
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
            qp_horizon: v.qp_horizon.horizon(self.steering_length()),
            replan_rejected: v.replan_rejected,
            second_opinion: v.second_opinion,
            qp_angle_damping_max: v.qp_angle_damping_max,
            resume_held: v.resume_held,
            limit_avoidance: v.limit_avoidance,
            settling_margin: v.settling_margin,
            qp_spin_weight: v.qp_spin_weight,
            jacobian: match v.jacobian {
                super::JacobianSpec::Solve => JacobianMode::Solve,
                super::JacobianSpec::Linearized => JacobianMode::Linearized,
                super::JacobianSpec::Hybrid => JacobianMode::Hybrid,
            },
            gs: GsParams {
                tolerance: self.solver.gs_tolerance,
                max_iterations: self.solver.gs_max_iterations,
                relaxation: self.solver.gs_relaxation,
                ..InverseParams::default().gs
            },
            ..InverseParams::default()
        }
    }
}
