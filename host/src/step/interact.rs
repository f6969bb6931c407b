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
use crate::proximity::{Embedded, SurfaceProjector, TetLocator};
use crate::world::{SlidingPoint, World, element_size};

/// The constraint forces of a step, by role.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Forces {
    /// Norms of λ per role: base, contact, sliding [N or N·mm].
    pub norms: [f64; 3],
    /// Normal force of the tip contact [N] (0 without contact).
    pub contact: f64,
    /// Magnitude of the tip contact's friction force [N] (0 without contact or friction).
    pub contact_tangential: f64,
}

/// The norms of `λ` per role and the tip contact's normal and friction forces.
pub fn forces(set: &ConstraintSet, lambda: &[f64]) -> Forces {
    let mut norms = [0.0f64; 3];
    let mut contact = 0.0;
    let mut contact_tangential = 0.0;
    for (g, s) in set.groups.iter().zip(set.starts()) {
        let l = &lambda[s..s + g.rows];
        let n2: f64 = l.iter().map(|v| v * v).sum();
        match g.role {
            GroupRole::Base => norms[0] += n2,
            GroupRole::Contact => {
                norms[1] += n2;
                contact = l[0];
                contact_tangential = l[1..].iter().map(|v| v * v).sum::<f64>().sqrt();
            }
            GroupRole::Sliding(_) => norms[2] += n2,
        }
    }
    Forces {
        norms: norms.map(f64::sqrt),
        contact,
        contact_tangential,
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

/// How close to the Coulomb cone's boundary `|λ_t| = μ λ_n` the tip's friction force counts as
/// sliding (the constraint solve's tolerance leaves a sliding contact's force a little inside).
const SLIDING_FRACTION: f64 = 0.999;

/// How far the tip may lie from its target along the surface, sliding, before its heading is
/// held within the friction cone [mm]: a tilted tip arriving on its path slides along it at
/// touch-down and may go on sliding with its target; only a slide that leaves the target counts.
const SLIP_OFF_TARGET: f64 = 0.2;

/// The tip's distance from its target along the surface at the entry point (the component
/// across the surface's normal taken out) [mm].
fn slip_off_target<const N: usize>(world: &World<N>) -> f64 {
    let e = world.target(world.c) - world.tip();
    let n = world.entry_normal;
    (e - n * n.dot(&e)).norm()
}

/// Whether the tip contact's forces `forces` lie on the boundary of its friction cone `mu`: the
/// tip slides on the surface.
pub fn tip_slides(forces: &Forces, mu: f64) -> bool {
    forces.contact > 0.0 && forces.contact_tangential >= SLIDING_FRACTION * mu * forces.contact
}

/// Puncture and sliding points after a step with the constraint forces `forces` (the tip's
/// contact, before puncture). Returns whether the tip punctured the surface in this step.
///
/// # Errors
/// [`SimError::PunctureOffGel`] when the tip punctures at a point that is not on the gel.
pub fn update<const N: usize>(
    world: &mut World<N>,
    forces: &Forces,
    inter: &Interaction,
) -> Result<bool, SimError> {
    let contact_force = forces.contact;
    world.in_contact = contact_force > 0.0;
    if !world.punctured
        && !world.tip_slid
        && tip_slides(forces, inter.surface_friction)
        && slip_off_target(world) > SLIP_OFF_TARGET
    {
        world.tip_slid = true;
        tracing::debug!(
            step = world.steps,
            "the tip slides on the gel's surface before puncture: its heading is held within \
             the friction cone until it punctures"
        );
    }
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

/// How far from the tip the element found for a puncture may lie [mm] (the tip contact holds
/// the tip on the surface to the solve's tolerance; the tip is then just outside it).
const PUNCTURE_REACH: f64 = 2.0;

/// The tip punctured the surface: the contact gives way to a sliding point at the entry.
///
/// Where one element holds the tip, or none (the tip just outside the surface it pressed:
/// the nearest, [`TetLocator::locate`]), the entry and the first sliding point are the
/// material point at the tip in that element. Where several hold it — a fold of elements
/// pushed over each other under a deep indentation (or a face two elements share) — the first
/// sliding point goes to the element holding the tip most deeply (the largest smallest
/// barycentric weight, lower index on a tie), and the entry, from which the depth and the
/// sliding points' spacing are measured, is the material point nearest the gel's surface
/// at rest ([`in_a_fold`]): the needle punctures the surface's material, not the inside of
/// the gel the fold carried under the tip. Neither choice follows the order of a search,
/// which the round-off of the positions decides.
fn puncture<const N: usize>(world: &mut World<N>) -> Result<(), SimError> {
    let tip = world.tip();
    let (nodes, tets) = (world.gel.positions(), &world.gel.mesh().tets);
    let locator = TetLocator::new(nodes, tets);
    let held = locator.holding(nodes, tets, &tip);
    let at = deepest_holder(&held)
        .or_else(|| locator.locate(nodes, tets, &tip, PUNCTURE_REACH))
        .ok_or(SimError::PunctureOffGel(tip))?;
    let entry = if held.len() >= 2 {
        in_a_fold(&world.gel.mesh().nodes, tets, &world.surface, &held)
    } else {
        None
    };
    world.punctured = true;
    world.tip_slid = false;
    world.entry = entry.unwrap_or(at);
    add_sliding(world, at);
    world.last_sliding_depth = 0.0;
    Ok(())
}

/// Of the material points `held` (one point's coordinates in each element holding it), the one
/// its element holds most deeply: the largest smallest barycentric weight, the lower element
/// index on a tie; whatever the order of `held`.
pub(crate) fn deepest_holder(held: &[Embedded]) -> Option<Embedded> {
    held.iter()
        .max_by(|a, b| {
            a.min_weight()
                .total_cmp(&b.min_weight())
                .then(b.tet.cmp(&a.tet))
        })
        .copied()
}

/// Of the material points `held` (one point's coordinates in each element holding it), the one
/// nearest the surface at rest (`rest` node positions); ties go to the lower element index.
///
/// Where the tip has pushed the surface in far enough to fold the elements under it (a soft
/// gel indented by more than an element before it gives way), the tip lies inside several
/// elements at once, inverted ones among them, and which one a volume search meets first
/// depends on the round-off of the positions. An entry embedded in a folded element maps to a
/// point deep inside the gel once the gel relaxes: `simple_soft` (3 kPa, indented 13.8 mm, 4
/// elements inverted at puncture) measured its depth from 11 mm under the surface for the
/// whole insertion in one run and from the surface in another with the same joints.
pub(crate) fn in_a_fold(
    rest: &[nalgebra::Vector3<f64>],
    tets: &[[usize; 4]],
    surface: &[[usize; 3]],
    held: &[Embedded],
) -> Option<Embedded> {
    let projector = SurfaceProjector::new(rest, surface);
    let depth = |e: &Embedded| {
        let p = e.position(rest, tets);
        projector
            .project(rest, surface, &p, f64::INFINITY)
            .map_or(f64::INFINITY, |h| (h.point - p).norm())
    };
    held.iter()
        .map(|e| (depth(e), e))
        .min_by(|(a, x), (b, y)| a.total_cmp(b).then(x.tet.cmp(&y.tet)))
        .map(|(_, e)| *e)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::box_mesh;
    use nalgebra::Vector3;

    /// `simple_soft` measured its depth from 11 mm under the gel's surface for a whole
    /// insertion: the tip punctured a deep indentation where elements folded over each other,
    /// and the volume search embedded the entry in one of the folded elements. The entry in a
    /// fold is the material point at the tip nearest the surface at rest.
    #[test]
    fn a_puncture_in_a_fold_is_embedded_in_the_surface_material_at_the_tip() {
        let mesh = box_mesh(Vector3::zeros(), Vector3::new(20.0, 20.0, 20.0), 300);
        let surface = mesh.surface_triangles();
        let mut nodes = mesh.nodes.clone();
        // Push the top node nearest the middle 12 mm down, through the elements under it.
        let top = (0..nodes.len())
            .filter(|&i| nodes[i].z > 19.999)
            .min_by(|&a, &b| {
                let d = |i: usize| (nodes[i].xy() - nalgebra::Vector2::new(10.0, 10.0)).norm();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        nodes[top].z -= 12.0;
        let tip = nodes[top] + Vector3::new(0.0, 0.0, 0.01);
        let locator = TetLocator::new(&nodes, &mesh.tets);
        let held = locator.holding(&nodes, &mesh.tets, &tip);
        assert!(
            held.len() >= 2,
            "the indentation folds elements over the tip"
        );
        let at = in_a_fold(&mesh.nodes, &mesh.tets, &surface, &held).expect("an entry");
        // The material point at the tip, in the element that came down with the surface.
        let p = at.position(&nodes, &mesh.tets);
        assert!((p - tip).norm() < 1e-9, "{p:?} against the tip {tip:?}");
        let rest = at.position(&mesh.nodes, &mesh.tets);
        assert!(rest.z > 19.9, "the entry at rest: {rest:?}");
        // The volume search alone may find a folded element whose point lies deep at rest;
        // at least one of the holders does.
        let lowest_at_rest = held
            .iter()
            .map(|e| e.position(&mesh.nodes, &mesh.tets).z)
            .fold(f64::INFINITY, f64::min);
        assert!(
            lowest_at_rest < 15.0,
            "a holder deep at rest: {lowest_at_rest}"
        );
        // The first sliding point's element does not follow the order the search met them in.
        let deepest = deepest_holder(&held).expect("a holder");
        let mut reversed = held.clone();
        reversed.reverse();
        assert_eq!(deepest_holder(&reversed), Some(deepest));
        assert!(held.iter().all(|e| e.min_weight() <= deepest.min_weight()));
        // Away from any fold one element holds a point, and nothing changes there.
        let inside = Vector3::new(7.3, 8.1, 6.2);
        assert_eq!(locator.holding(&nodes, &mesh.tets, &inside).len(), 1);
    }

    /// A contact's friction force on its cone's boundary slides; inside it, or without a
    /// normal force, it does not.
    #[test]
    fn a_friction_force_on_the_cone_boundary_slides() {
        let at = |contact: f64, contact_tangential: f64| Forces {
            norms: [0.0; 3],
            contact,
            contact_tangential,
        };
        assert!(tip_slides(&at(0.1, 0.03), 0.3));
        assert!(tip_slides(&at(0.1, 0.03 * SLIDING_FRACTION), 0.3));
        assert!(!tip_slides(&at(0.1, 0.02), 0.3));
        assert!(!tip_slides(&at(0.0, 0.0), 0.3));
        // Frictionless: any contact slides.
        assert!(tip_slides(&at(0.1, 0.0), 0.0));
    }
}
