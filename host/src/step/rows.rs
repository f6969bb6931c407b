//! Stage 2, proximity (CD): the row groups of a step from the current and free-motion positions —
//! the needle base χ, the sliding points ψ (oldest first: a stable row order for the core's
//! warm start), the tip on the gel surface φ before puncture — with their violations `δ_free`
//! (`δ > 0`: violated, see `docs/architecture.md`).

use super::{FreePositions, Interaction};
use crate::compliance::{PointColumns, PointMap};
use crate::constraints::{
    Attachment, ConstraintGroup, ConstraintSet, GroupRole, Model, group, orthonormal_pair,
};
use crate::proximity::{CachedProjector, Embedded, box_distance};
use crate::world::{SlidingPoint, World, closest_on_polyline};
use nalgebra::Matrix3;
use needle_core::payload::GroupKind;

/// Tip-to-surface distance under which the contact rows are built [mm].
const CONTACT_DISTANCE: f64 = 5.0;

/// Rebuilds `set` for `world`: χ, then ψ (taking the cached gel columns of each sliding point
/// out of `columns`, which is then emptied), then φ.
pub fn build<const N: usize>(
    set: &mut ConstraintSet,
    world: &World<N>,
    free: &FreePositions,
    inter: &Interaction,
    columns: &mut Vec<(usize, PointColumns)>,
    surface: &mut CachedProjector,
) {
    set.needle.points.clear();
    set.gel.points.clear();
    set.groups.clear();
    base_rows(set);
    for s in &world.sliding {
        let cached = columns
            .iter()
            .position(|(id, _)| *id == s.id)
            .map(|k| columns.swap_remove(k).1);
        sliding_rows(set, world, free, inter, s, cached);
    }
    columns.clear();
    if !world.punctured {
        contact_rows(set, world, free, inter, surface);
    }
}

/// The gel map of an embedded point: its tetrahedron's free nodes with their weights.
pub fn gel_map<const N: usize>(world: &World<N>, e: &Embedded) -> PointMap {
    let t = world.gel.mesh().tets[e.tet];
    PointMap::weighted((0..4).map(|k| (world.gel.node_dof(t[k]), e.weights[k])))
}

/// χ: the needle base, 6 bilateral rows on node 0 (the core computes δ from q).
fn base_rows(set: &mut ConstraintSet) {
    let eye = Matrix3::identity();
    let bt = set.needle.push(PointMap::single(0));
    let br = set.needle.push(PointMap::single(3));
    let side = |point, row_offset| Attachment {
        model: Model::Needle,
        point,
        row_offset,
        rows: 3,
        d: eye,
        sign: 1.0,
    };
    set.groups.push(ConstraintGroup {
        kind: group(GroupKind::Bilateral, 0.0, 0.0),
        role: GroupRole::Base,
        rows: 6,
        attachments: vec![side(bt, 0), side(br, 3)],
        delta: [0.0; 6],
    });
}

/// ψ: the shaft through a sliding point — two lateral rows across the shaft at its closest
/// point, and an axial friction row when the shaft has friction or resistance.
fn sliding_rows<const N: usize>(
    set: &mut ConstraintSet,
    world: &World<N>,
    free: &FreePositions,
    inter: &Interaction,
    s: &SlidingPoint,
    cached: Option<PointColumns>,
) {
    let nodes = world.needle.positions();
    let g = world.gel_point(&s.at);
    let g_free = free.gel_point(world, &s.at);
    let (e, f) = closest_on_polyline(nodes, &g);
    let n = nodes[e] * (1.0 - f) + nodes[e + 1] * f;
    let n_free = free.needle[e] * (1.0 - f) + free.needle[e + 1] * f;
    let tdir = (nodes[e + 1] - nodes[e]).normalize();
    let (l1, l2) = orthonormal_pair(&tdir);
    let d = Matrix3::from_rows(&[l1.transpose(), l2.transpose(), tdir.transpose()]);
    let np = set.needle.push(PointMap::weighted([
        (Some(6 * e), 1.0 - f),
        (Some(6 * (e + 1)), f),
    ]));
    let gp = set.gel.push(gel_map(world, &s.at));
    set.gel.points[gp].cols = cached;
    let friction = inter.shaft_friction > 0.0 || inter.shaft_resistance > 0.0;
    let rows = if friction { 3 } else { 2 };
    let rel = (n_free - n) - (g_free - g);
    let mut delta = [0.0; 6];
    delta[0] = -l1.dot(&(n_free - g_free));
    delta[1] = -l2.dot(&(n_free - g_free));
    delta[2] = -tdir.dot(&rel);
    let kind = if friction {
        group(
            GroupKind::Sliding,
            inter.shaft_friction,
            inter.shaft_resistance,
        )
    } else {
        group(GroupKind::Bilateral, 0.0, 0.0)
    };
    set.groups.push(ConstraintGroup::pair(
        kind,
        GroupRole::Sliding(s.id),
        rows,
        (np, gp),
        d,
        delta,
    ));
}

/// φ: the tip on the gel surface (before puncture) — a unilateral normal row, two Coulomb
/// friction rows — when the tip is within [`CONTACT_DISTANCE`] of the surface.
fn contact_rows<const N: usize>(
    set: &mut ConstraintSet,
    world: &World<N>,
    free: &FreePositions,
    inter: &Interaction,
    surface: &mut CachedProjector,
) {
    let gel_nodes = world.gel.positions();
    let n_last = world.needle.node_count() - 1;
    let tip = world.needle.positions()[n_last];
    // On the way to the gel, the tip farther than CONTACT_DISTANCE from the box of the gel's
    // nodes is farther than that from every surface triangle: no rows, and no BVH built over
    // the whole surface for a query that cannot hit (most of the approach's steps).
    if !world.in_contact && box_distance(gel_nodes, &tip) > CONTACT_DISTANCE {
        return;
    }
    // Built again only when the gel moved: at rest, before the tip touches it, one BVH.
    let projector = surface.get(gel_nodes, &world.surface);
    // A tip that pushed on the surface last step keeps its contact rows however deep the
    // dimple under it (a point load on a coarse mesh can indent by more than
    // CONTACT_DISTANCE): a contact is never lost by looking too close.
    let reach = if world.in_contact {
        f64::MAX
    } else {
        CONTACT_DISTANCE
    };
    let Some(hit) = projector
        .project(gel_nodes, &world.surface, &tip, reach)
        .filter(|h| h.signed_distance < CONTACT_DISTANCE)
    else {
        return;
    };
    let tri = world.surface[hit.triangle];
    let s_free: nalgebra::Vector3<f64> = (0..3).map(|k| hit.weights[k] * free.gel[tri[k]]).sum();
    let tip_free = free.needle[n_last];
    // The smooth normal: continuous as the closest point crosses edges and vertices of the
    // faceted, indented surface (the face normal flips between steep faces around the pushed
    // node and makes the tip chatter sideways).
    let nrm = hit.smooth_normal;
    let (t1, t2) = orthonormal_pair(&nrm);
    let d = Matrix3::from_rows(&[nrm.transpose(), t1.transpose(), t2.transpose()]);
    let friction = inter.surface_friction > 0.0;
    let rows = if friction { 3 } else { 1 };
    let rel = (tip_free - tip) - (s_free - hit.point);
    let mut delta = [0.0; 6];
    delta[0] = -nrm.dot(&(tip_free - s_free));
    delta[1] = -t1.dot(&rel);
    delta[2] = -t2.dot(&rel);
    let np = set.needle.push(PointMap::single(6 * n_last));
    let gp = set.gel.push(PointMap::weighted(
        (0..3).map(|k| (world.gel.node_dof(tri[k]), hit.weights[k])),
    ));
    let kind = if friction {
        group(GroupKind::Contact, inter.surface_friction, 0.0)
    } else {
        group(GroupKind::Unilateral, 0.0, 0.0)
    };
    set.groups.push(ConstraintGroup::pair(
        kind,
        GroupRole::Contact,
        rows,
        (np, gp),
        d,
        delta,
    ));
}
