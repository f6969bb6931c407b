//! Stage 5, the corrective motion (SOFA's `computeMotionCorrectionFromLambda`):
//!
//! ```text
//! x = x_free + K⁻¹ Hᵀ λ,      K⁻¹ Hᵀ λ = Σ_h Σ_{b∈h} s_b U_b D_bᵀ λ_h
//! ```
//!
//! with the Cartesian columns `U_b = K⁻¹ P_bᵀ` of each attachment `b` (the compliance stage
//! computed them), its directions `D_b` and side `s_b` (+1 needle, −1 gel). No solve, except
//! with `solver.gel_solve = "refine"`: the gel's whole step, free plus corrective motion, made
//! with the factor in use, is then refined to the step's own matrix by CG
//! ([`crate::free_motion::FeModel::refine_step`]).

use crate::constraints::{ConstraintSet, GroupRole, Model};
use crate::error::{Body, NonFiniteAt, SimError};
use crate::world::World;
use nalgebra::Vector3;

/// The row forces `λ` of each attachment of group `h` (its own rows, up to three).
fn attachment_lambda(lambda: &[f64], start: usize, row_offset: usize, rows: usize) -> Vector3<f64> {
    let mut l = Vector3::zeros();
    for r in 0..rows {
        l[r] = lambda[start + row_offset + r];
    }
    l
}

/// Adds the corrective motion `K⁻¹ Hᵀ λ` of each model to `needle_dx` and `gel_dx`.
pub fn add_correction(
    set: &ConstraintSet,
    lambda: &[f64],
    needle_dx: &mut [f64],
    gel_dx: &mut [f64],
) {
    for (h, start) in set.groups.iter().zip(set.starts()) {
        for b in &h.attachments {
            let l = attachment_lambda(lambda, start, b.row_offset, b.rows);
            let f = b.sign * b.d.transpose() * l;
            let (store, out) = match b.model {
                Model::Needle => (&set.needle, &mut *needle_dx),
                Model::Gel => (&set.gel, &mut *gel_dx),
            };
            store.cols(b.point).add_response(&f, out);
        }
    }
}

/// Moves both bodies to `x_free + K⁻¹ Hᵀ λ`: adds the correction to the free motions
/// `needle_dx`, `gel_dx` and applies them. With `far_pending` (the gel's free motion and
/// columns solved on its near dofs only), the gel's far dofs are then solved once for the
/// free and the corrective motion together
/// ([`crate::free_motion::FeModel::complete_far`]).
///
/// # Errors
/// [`SimError::NonFinite`] when a position is not finite afterwards; the far rows' solve's.
pub fn apply<const N: usize>(
    world: &mut World<N>,
    set: &ConstraintSet,
    lambda: &[f64],
    needle_dx: &mut [f64],
    gel_dx: &mut [f64],
    far_pending: bool,
) -> Result<(), SimError> {
    add_correction(set, lambda, needle_dx, gel_dx);
    if far_pending && gel_dx.iter().all(|v| v.is_finite()) {
        world
            .gel
            .complete_far(gel_dx)
            .map_err(SimError::in_free_motion(Body::Gel))?;
    }
    // Refined-step mode: the gel's step to its own matrix (a no-op otherwise; a non-finite
    // step is left to the check below).
    if gel_dx.iter().all(|v| v.is_finite()) {
        world
            .gel
            .refine_step(gel_dx)
            .map_err(SimError::in_free_motion(Body::Gel))?;
    }
    // Finite (the command was checked) and of the models' own lengths: cannot fail.
    let _ = world.needle.apply_displacement(needle_dx);
    let _ = world.gel.apply_displacement(gel_dx);
    let finite = world
        .needle
        .positions()
        .iter()
        .chain(world.gel.positions())
        .all(|p| p.iter().all(|v| v.is_finite()));
    if finite {
        Ok(())
    } else {
        Err(SimError::NonFinite(NonFiniteAt::Correction))
    }
}

/// The force each row group applies to the needle, world frame [N] (the gel receives the
/// opposite of every contact and sliding force); for the base group, its translational rows.
pub fn needle_forces(set: &ConstraintSet, lambda: &[f64]) -> Vec<(GroupRole, Vector3<f64>)> {
    set.groups
        .iter()
        .zip(set.starts())
        .map(|(g, start)| {
            let a = &g.attachments[0];
            let l = attachment_lambda(lambda, start, a.row_offset, a.rows.min(3));
            (g.role, a.sign * a.d.transpose() * l)
        })
        .collect()
}

/// The force one row group applies to the needle, and where.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConstraintForce {
    /// What the group models.
    pub role: GroupRole,
    /// The group's point on the needle, world frame [mm].
    pub at: Vector3<f64>,
    /// The force on the needle (the gel receives its opposite), world frame [N]; for the base,
    /// its translational rows.
    pub force: Vector3<f64>,
}

/// Every group's [`ConstraintForce`] at needle positions `x`, and the nodal forces `Pᵀ f` the
/// constraints apply to the needle's nodes (translational dofs; the base's moment left out) [N].
pub fn constraint_forces(
    set: &ConstraintSet,
    lambda: &[f64],
    x: &[Vector3<f64>],
) -> (Vec<ConstraintForce>, Vec<Vector3<f64>>) {
    let mut nodal = vec![Vector3::zeros(); x.len()];
    let mut groups = Vec::with_capacity(set.groups.len());
    for (g, start) in set.groups.iter().zip(set.starts()) {
        let mut first = None;
        for b in g.attachments.iter().filter(|b| b.model == Model::Needle) {
            let l = attachment_lambda(lambda, start, b.row_offset, b.rows.min(3));
            let f = b.sign * b.d.transpose() * l;
            let map = &set.needle.points[b.point].map;
            let mut at = Vector3::zeros();
            let mut translational = false;
            for &(block, w) in &map.blocks[..map.len] {
                let node = block / 6;
                if block % 6 == 0 && node < x.len() {
                    nodal[node] += w * f;
                    at += w * x[node];
                    translational = true;
                }
            }
            if translational && first.is_none() {
                first = Some((at, f));
            }
        }
        if let Some((at, force)) = first {
            groups.push(ConstraintForce {
                role: g.role,
                at,
                force,
            });
        }
    }
    (groups, nodal)
}
