//! A URDF file to a [`SerialChain`]: the kinematics only (visual and collision meshes, inertias
//! and dynamics are ignored).
//!
//! The joints on the path from a base link to a tip link make the chain; fixed joints are folded
//! into the origin of the next movable joint (or into the tool transform after the last one).
//! Lengths are converted from metres to millimetres; `rpy` is URDF's fixed-axis roll-pitch-yaw,
//! `R = Rz(yaw) · Ry(pitch) · Rx(roll)`. The base link is the chain's world frame (identity base).
//! Revolute and continuous joints are accepted; any other movable type is an error.

// Units are written in brackets ([mm], [rad]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use nalgebra::{Matrix3, Vector3};
use needle_core::{JointLimit, Pose, SerialChain, SerialJoint};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Metres (URDF) to millimetres (the core).
const MM_PER_M: f64 = 1000.0;

/// Why a URDF could not be turned into a chain: the file and the reason.
#[derive(Debug, thiserror::Error)]
#[error("URDF {}: {reason}", path.display())]
pub struct UrdfError {
    /// The file (or the label given to [`parse_robot`]).
    pub path: PathBuf,
    /// What is wrong with it.
    pub reason: UrdfReason,
}

/// What is wrong with a URDF.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum UrdfReason {
    /// The file cannot be read or is not URDF XML.
    #[error("cannot be read or parsed: {0}")]
    Parse(String),
    /// The base or the tip link is not in the file.
    #[error("the {role} link `{link}` is not in the file")]
    MissingLink {
        /// `"base"` or `"tip"`.
        role: &'static str,
        /// The link asked for.
        link: String,
    },
    /// No chain of joints leads from the base link to the tip link.
    #[error("no chain of joints leads from the base link `{base}` to the tip link `{tip}`")]
    NoPath {
        /// Base link.
        base: String,
        /// Tip link.
        tip: String,
    },
    /// The number of movable joints between base and tip is not the chain's.
    #[error(
        "{found} movable joints from `{base}` to `{tip}` ({}), but the chain has {expected}",
        joints.join(", ")
    )]
    JointCount {
        /// Joints the chain was built for.
        expected: usize,
        /// Movable joints found.
        found: usize,
        /// Their names, base first.
        joints: Vec<String>,
        /// Base link.
        base: String,
        /// Tip link.
        tip: String,
    },
    /// A joint on the path is neither revolute, continuous nor fixed.
    #[error("joint `{joint}` is {kind}: only revolute, continuous and fixed joints are supported")]
    UnsupportedJoint {
        /// Joint name.
        joint: String,
        /// Its type (`prismatic`, `floating`, `planar`, …).
        kind: String,
    },
    /// A movable joint's axis is zero (or not finite).
    #[error("joint `{joint}` has a zero or non-finite axis {axis:?}")]
    ZeroAxis {
        /// Joint name.
        joint: String,
        /// The axis as written.
        axis: [f64; 3],
    },
    /// A joint origin is not finite.
    #[error("joint `{joint}` has a non-finite origin")]
    NonFiniteOrigin {
        /// Joint name.
        joint: String,
    },
}

/// A chain read from a URDF with its joints' names and limits.
#[derive(Clone, Debug)]
pub struct UrdfRobot<const N: usize> {
    /// The kinematics, base link = world frame, tool = the tip link's frame [mm]; its limits
    /// per movable joint, base first: `lower`, `upper` [rad] and `max_speed` = the URDF
    /// `velocity` [rad/s] (0 where the file gives none). Continuous joints get ±∞ positions.
    pub chain: SerialChain<N>,
    /// The movable joints' names, base first.
    pub joint_names: Vec<String>,
}

/// The chain from `base_link` to `tip_link` of a URDF file; see [`load_robot`] for the limits.
pub fn load_chain<const N: usize>(
    path: impl AsRef<Path>,
    base_link: &str,
    tip_link: &str,
) -> Result<SerialChain<N>, UrdfError> {
    load_robot(path, base_link, tip_link).map(|r| r.chain)
}

/// The chain from `base_link` to `tip_link` of a URDF file, with joint names and limits.
pub fn load_robot<const N: usize>(
    path: impl AsRef<Path>,
    base_link: &str,
    tip_link: &str,
) -> Result<UrdfRobot<N>, UrdfError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| UrdfError {
        path: path.to_path_buf(),
        reason: UrdfReason::Parse(e.to_string()),
    })?;
    parse_robot(&text, path, base_link, tip_link)
}

/// [`load_robot`] on URDF text; `label` names it in errors.
pub fn parse_robot<const N: usize>(
    text: &str,
    label: impl AsRef<Path>,
    base_link: &str,
    tip_link: &str,
) -> Result<UrdfRobot<N>, UrdfError> {
    let err = |reason| UrdfError {
        path: label.as_ref().to_path_buf(),
        reason,
    };
    let robot =
        urdf_rs::read_from_string(text).map_err(|e| err(UrdfReason::Parse(e.to_string())))?;
    build(&robot, base_link, tip_link).map_err(err)
}

/// Rotation of URDF `rpy`: `Rz(yaw) · Ry(pitch) · Rx(roll)`.
pub fn rpy_matrix(rpy: [f64; 3]) -> Matrix3<f64> {
    let (sr, cr) = rpy[0].sin_cos();
    let (sp, cp) = rpy[1].sin_cos();
    let (sy, cy) = rpy[2].sin_cos();
    Matrix3::new(
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )
}

/// A URDF origin as a pose in mm.
fn origin_pose(o: &urdf_rs::Pose) -> Pose {
    Pose {
        rotation: rpy_matrix(o.rpy.0),
        translation: Vector3::from(o.xyz.0) * MM_PER_M,
    }
}

fn build<const N: usize>(
    robot: &urdf_rs::Robot,
    base: &str,
    tip: &str,
) -> Result<UrdfRobot<N>, UrdfReason> {
    for (role, link) in [("base", base), ("tip", tip)] {
        if !robot.links.iter().any(|l| l.name == link) {
            return Err(UrdfReason::MissingLink {
                role,
                link: link.to_owned(),
            });
        }
    }
    // In a tree every link but the root has one parent joint: walk up from the tip.
    let parent_joint: HashMap<&str, &urdf_rs::Joint> = robot
        .joints
        .iter()
        .map(|j| (j.child.link.as_str(), j))
        .collect();
    let no_path = || UrdfReason::NoPath {
        base: base.to_owned(),
        tip: tip.to_owned(),
    };
    let mut path = Vec::new();
    let mut link = tip;
    while link != base {
        let j = parent_joint.get(link).ok_or_else(no_path)?;
        if path.len() > robot.joints.len() {
            return Err(no_path()); // a loop
        }
        path.push(*j);
        link = j.parent.link.as_str();
    }
    path.reverse();

    let movable: Vec<&urdf_rs::Joint> = path
        .iter()
        .copied()
        .filter(|j| j.joint_type != urdf_rs::JointType::Fixed)
        .collect();
    for j in &movable {
        use urdf_rs::JointType as T;
        if !matches!(j.joint_type, T::Revolute | T::Continuous) {
            return Err(UrdfReason::UnsupportedJoint {
                joint: j.name.clone(),
                kind: format!("{:?}", j.joint_type).to_lowercase(),
            });
        }
    }
    if movable.len() != N {
        return Err(UrdfReason::JointCount {
            expected: N,
            found: movable.len(),
            joints: movable.iter().map(|j| j.name.clone()).collect(),
            base: base.to_owned(),
            tip: tip.to_owned(),
        });
    }

    let mut joints = [SerialJoint {
        origin: Pose::identity(),
        axis: Vector3::z(),
    }; N];
    let mut limits = [JointLimit {
        lower: 0.0,
        upper: 0.0,
        max_speed: 0.0,
    }; N];
    let mut names = Vec::with_capacity(N);
    let mut pending = Pose::identity();
    let mut k = 0;
    for j in &path {
        let o = origin_pose(&j.origin);
        if !(o.rotation.iter().all(|v| v.is_finite())
            && o.translation.iter().all(|v| v.is_finite()))
        {
            return Err(UrdfReason::NonFiniteOrigin {
                joint: j.name.clone(),
            });
        }
        pending = pending.compose(&o);
        if j.joint_type == urdf_rs::JointType::Fixed {
            continue;
        }
        let a = Vector3::from(j.axis.xyz.0);
        let norm = a.norm();
        if !(norm > 1e-12 && norm.is_finite()) {
            return Err(UrdfReason::ZeroAxis {
                joint: j.name.clone(),
                axis: j.axis.xyz.0,
            });
        }
        joints[k] = SerialJoint {
            origin: pending,
            axis: a / norm,
        };
        limits[k] = if j.joint_type == urdf_rs::JointType::Continuous {
            JointLimit {
                lower: f64::NEG_INFINITY,
                upper: f64::INFINITY,
                max_speed: j.limit.velocity,
            }
        } else {
            JointLimit {
                lower: j.limit.lower,
                upper: j.limit.upper,
                max_speed: j.limit.velocity,
            }
        };
        names.push(j.name.clone());
        pending = Pose::identity();
        k += 1;
    }
    Ok(UrdfRobot {
        chain: SerialChain {
            joints,
            base: Pose::identity(),
            tool: pending,
            limits,
        },
        joint_names: names,
    })
}
