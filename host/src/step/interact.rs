//! Stage 6, the interaction bookkeeping after the corrective motion (paper §III-C):
//!
//! - **puncture**: when the tip's normal contact force reaches `p_f`, the surface gives way —
//!   once: the contact group is replaced by a sliding point at the entry, and does not come
//!   back while the needle is inside;
//! - **sliding points**: a new one each time the tip has advanced `max(d_n, h)` past the last
//!   (`h` the element size), released when the needle is withdrawn past them; the surface is
//!   whole again once every sliding point is released.

use super::Interaction;
use crate::compliance::PointColumns;
use crate::constraints::{ConstraintSet, GroupRole, Model};
use crate::error::SimError;
use crate::proximity::{Embedded, TetLocator};
use crate::world::{SlidingPoint, World, element_size};

/// The constraint forces of a step, by role.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Forces {
    /// Norms of λ per role: base, contact, sliding [N or N·mm].
    pub norms: [f64; 3],
    /// Normal force of the tip contact [N] (0 without contact).
    pub contact: f64,
}

/// The norms of `λ` per role and the tip's normal contact force.
pub fn forces(set: &ConstraintSet, lambda: &[f64]) -> Forces {
    let mut norms = [0.0f64; 3];
    let mut contact = 0.0;
    for (g, s) in set.groups.iter().zip(set.starts()) {
        let l = &lambda[s..s + g.rows];
        let n2: f64 = l.iter().map(|v| v * v).sum();
        match g.role {
            GroupRole::Base => norms[0] += n2,
            GroupRole::Contact => {
                norms[1] += n2;
                contact = l[0];
            }
            GroupRole::Sliding(_) => norms[2] += n2,
        }
    }
    Forces {
        norms: norms.map(f64::sqrt),
        contact,
    }
}

/// Keeps the gel columns of the sliding points for the next step (valid while the gel's factor
/// is reused).
pub fn keep_columns(set: &mut ConstraintSet, columns: &mut Vec<(usize, PointColumns)>) {
    for g in &set.groups {
        if let GroupRole::Sliding(id) = g.role
            && let Some(a) = g.attachments.iter().find(|a| a.model == Model::Gel)
            && let Some(cols) = set.gel.points[a.point].cols.take()
        {
            columns.push((id, cols));
        }
    }
}

/// Puncture and sliding points after a step whose tip contact force was `contact_force` [N].
/// Returns whether the tip punctured the surface in this step.
///
/// # Errors
/// [`SimError::PunctureOffGel`] when the tip punctures at a point that is not on the gel.
pub fn update<const N: usize>(
    world: &mut World<N>,
    contact_force: f64,
    inter: &Interaction,
) -> Result<bool, SimError> {
    world.in_contact = contact_force > 0.0;
    let mut punctured_now = false;
    if !world.punctured && contact_force >= inter.puncture_force {
        puncture(world)?;
        punctured_now = true;
    }
    if world.punctured {
        update_sliding_points(world, inter);
    }
    Ok(punctured_now)
}

/// The tip punctured the surface: the contact gives way to a sliding point at the entry.
fn puncture<const N: usize>(world: &mut World<N>) -> Result<(), SimError> {
    let tip = world.tip();
    let (nodes, tets) = (world.gel.positions(), &world.gel.mesh().tets);
    let at = TetLocator::new(nodes, tets)
        .locate(nodes, tets, &tip, 2.0)
        .ok_or(SimError::PunctureOffGel(tip))?;
    world.punctured = true;
    world.entry = at;
    add_sliding(world, at);
    world.last_sliding_depth = 0.0;
    Ok(())
}

fn add_sliding<const N: usize>(world: &mut World<N>, at: Embedded) {
    world.sliding.push(SlidingPoint {
        id: world.next_sliding_id,
        at,
    });
    world.next_sliding_id += 1;
}

/// New sliding point every `max(d_n, h)` of advance; release the ones the tip has been
/// withdrawn past.
fn update_sliding_points<const N: usize>(world: &mut World<N>, inter: &Interaction) {
    let nodes = world.needle.positions();
    let n = nodes.len();
    let tip = nodes[n - 1];
    let tdir = (nodes[n - 1] - nodes[n - 2]).normalize();
    // Released once the tip is withdrawn past the point by more than a margin (half the
    // spacing, at most 1 mm): without it, the point created at the tip itself would flicker
    // in and out with the tip's sub-millimetre back-and-forth.
    let margin = (0.5 * inter.constraint_spacing).min(1.0);
    let (gel_nodes, tets) = (world.gel.positions(), &world.gel.mesh().tets);
    world.sliding.retain(|s| {
        let g = s.at.position(gel_nodes, tets);
        (g - tip).dot(&tdir) <= margin
    });
    if world.sliding.is_empty() {
        // Fully withdrawn: the surface is whole again for contact purposes.
        world.punctured = false;
        world.last_sliding_depth = 0.0;
        return;
    }
    let depth = world.depth();
    if depth < world.last_sliding_depth {
        world.last_sliding_depth = depth;
    }
    let gate = inter.constraint_spacing.max(world.min_element_size);
    if depth - world.last_sliding_depth >= gate
        && let Some(at) = TetLocator::new(gel_nodes, tets).locate(gel_nodes, tets, &tip, 1.0)
    {
        // Sliding points no closer than the element size: the gel is linear in an element,
        // so two points closer than an element are nearly the same constraint. With a stiff
        // needle their rows are almost parallel: Gauss-Seidel stalls (d_n = 1 mm on a
        // 1500-node box: every step at the sweep cap), and the pair clamps the shaft like a
        // lever — large opposite lateral forces whose μ_n-bounds lock it, so the shaft
        // drags the gel instead of sliding (the tip stuck at 4–6 mm depth, 40–75 N of
        // sliding force). The spacing actually used is `max(d_n, h)`, `h` the rest size of
        // the tetrahedron the tip is in (see `element_size`).
        let h = element_size(&world.gel.mesh().nodes, &tets[at.tet]);
        if depth - world.last_sliding_depth >= h {
            add_sliding(world, at);
            world.last_sliding_depth = depth;
        }
    }
}
