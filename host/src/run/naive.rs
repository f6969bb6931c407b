//! The naive baseline (paper §V-A): the joints a *rigid* needle in a *rigid* gel would need to
//! follow the rest path — tip on the target, needle along the path tangent, by IK — computed up
//! front and replayed open-loop ([`crate::open_loop::OpenLoop`]) in the deformable simulation.

use crate::step::Insertion;
use crate::world::World;
use needle_core::ik::{IkError, IkParams, solve_ik};

/// Why the naive trajectory ends before its last step.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NaiveStop {
    /// The rigid IK stopped away from the pose.
    #[error("rigid IK out of reach ({distance:.3} mm away)")]
    OutOfReach {
        /// The step.
        step: usize,
        /// Where the IK stopped [mm].
        distance: f64,
    },
    /// The rigid IK failed.
    #[error("rigid IK failed")]
    Failed {
        /// The step.
        step: usize,
        /// Why.
        #[source]
        source: IkError,
    },
}

impl NaiveStop {
    /// The step the IK could not reach.
    pub fn step(&self) -> usize {
        match self {
            Self::OutOfReach { step, .. } | Self::Failed { step, .. } => *step,
        }
    }
}

/// The naive baseline's joints from `world`'s start: for each of `steps` steps, IK of a rigid
/// straight needle with its tip on the rest path at the step's target and its axis along the
/// rest path's tangent. Stops at the first pose the IK cannot reach, and says why.
pub fn naive_trajectory<const N: usize>(
    world: &World<N>,
    insertion: &Insertion,
    steps: usize,
) -> (Vec<[f64; N]>, Option<NaiveStop>) {
    let path = &world.path;
    let mut q = world.q;
    // Grown step by step (`steps` may be far more than the path needs).
    let mut out = Vec::new();

    let ik = IkParams {
        max_iterations: 2000,
        ..IkParams::default()
    };
    for step in 0..steps {
        let c = insertion.target_arc(path.total_length(), step);
        let (tip, t) = path.at(c);
        let base = tip - world.needle_length * t;
        match solve_ik(
            &world.robot,
            [base.x, base.y, base.z],
            [t.x, t.y, t.z],
            &q,
            &ik,
        ) {
            // A rigid model needs no better than 10 µm / 1 mrad; the wrist is near singular along
            // these paths, where the damped IK creeps towards tighter tolerances.
            Ok(r) if r.position_error <= 1e-2 && r.angle_error <= 1e-3 => {
                q = r.q;
                out.push(q);
            }
            Ok(r) => {
                let distance = r.position_error;
                return (out, Some(NaiveStop::OutOfReach { step, distance }));
            }
            Err(source) => return (out, Some(NaiveStop::Failed { step, source })),
        }
    }
    (out, None)
}
