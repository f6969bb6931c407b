//! Stage 3, the observations of the frame and its header: what the core's objective looks at —
//! tip, tip direction, target point and tangent, entry point — each `o = o_free + C λ` (laid out
//! by `needle_core::payload::ObsIndex`), and the needle base after free motion, the joints, the
//! insertion depth and the sequence.

use super::{FreePositions, ROWS, StepParams};
use crate::compliance::PointMap;
use crate::constraints::{ClearanceKind, ClearanceObservation, Model, Observation};
use crate::step::rows::gel_map;
use crate::world::{Obstacle, World};
use nalgebra::{Matrix3, Rotation3, Vector3};
use needle_core::inverse::base_violation;
use needle_core::payload::{ComplianceFrame, NCLEAR, ValidationError};

/// Arc length between the target and the second point that defines the target tangent [mm].
const TANGENT_STEP: f64 = 1.0;

/// The five observations of the frame (tip, tip direction, target, target tangent, entry) for
/// the target at arc length `c`. Once the tip has slid on the surface before puncture
/// ([`World::tip_slid`]), the target's tangent is turned towards the gel's inward normal at the
/// entry point until at most `entry_tilt` [rad] from it ([`within_cone`]).
pub fn observations<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    c: f64,
    entry_tilt: f64,
) -> [Observation; 5] {
    let nodes = world.needle.positions();
    let n_last = nodes.len() - 1;
    let eye = Matrix3::identity();
    let tip = Observation {
        model: Model::Needle,
        map: PointMap::single(6 * n_last),
        a: eye,
        free: free.needle[n_last],
    };
    // Tip direction from the last segment: linear in the two nodes (the core normalises).
    let len = (nodes[n_last] - nodes[n_last - 1])
        .norm()
        .max(f64::MIN_POSITIVE);
    let dir = Observation {
        model: Model::Needle,
        map: PointMap::weighted([
            (Some(6 * n_last), 1.0 / len),
            (Some(6 * (n_last - 1)), -1.0 / len),
        ]),
        a: eye,
        free: (free.needle[n_last] - free.needle[n_last - 1]) / len,
    };
    let (target, mut tangent) = target_observations(world, free, c);
    if world.tip_slid
        && !world.punctured
        && let Some(r) = within_cone(&tangent.free, &-world.entry_normal, entry_tilt)
    {
        tangent.a = r * tangent.a;
        tangent.free = r * tangent.free;
    }
    [tip, dir, target, tangent, entry_observation(world, free)]
}

/// The rotation that turns the heading `t` towards the unit axis `n` (the surface's inward
/// normal) until it is `max_tilt` [rad] from it, in the plane of the two; none when `t` is
/// within `max_tilt` of `n` already (or zero, or along `−n`). A needle pushed at more than the
/// friction cone's half-angle from the normal slides on the surface instead of indenting it.
pub fn within_cone(t: &Vector3<f64>, n: &Vector3<f64>, max_tilt: f64) -> Option<Matrix3<f64>> {
    let u = t.try_normalize(f64::MIN_POSITIVE)?;
    let tilt = u.dot(n).clamp(-1.0, 1.0).acos();
    if tilt <= max_tilt {
        return None;
    }
    let side = (u - n * u.dot(n)).try_normalize(1e-12)?;
    let max = max_tilt.max(0.0);
    let to = n * max.cos() + side * max.sin();
    Rotation3::rotation_between(&u, &to).map(Rotation3::into_inner)
}

/// The entry point, observed after the free motion.
fn entry_observation<const N: usize>(world: &World<N>, free: &FreePositions) -> Observation {
    gel_observation(
        gel_map(world, &world.entry),
        free.gel_point(world, &world.entry),
    )
}

/// The spacing of the extra clearance rows behind the needle point nearest to an obstacle
/// (towards the base, along the needle) [mm]. A row holds its needle point fixed in the needle;
/// when the needle advances along itself, another point comes where the nearest one was, and
/// the row of the nearest point alone then over-predicts the clearance (by 0.21 mm for an
/// advance of 4.3 mm past an obstacle, `docs/benchmark.md`). The distance to a sphere or a
/// convex surface is convex, so each row's linear model under-predicts its point's clearance,
/// and rows every 1.5 mm over the step's largest advance bound the needle's clearance over it.
const BEHIND_SPACING_MM: f64 = 1.5;

/// The fewest rows behind each nearest point (1.5, 3.0 and 4.5 mm: the default trust region
/// of 5 mm, and the benchmark scenes' 3 mm).
const BEHIND_MIN_ROWS: usize = 3;

/// How many rows behind each nearest point cover an advance of `max_base_step` [mm] per step:
/// the multiples of [`BEHIND_SPACING_MM`] within it, at least [`BEHIND_MIN_ROWS`], at most
/// what the frame holds besides one nearest point (`NCLEAR − 1`, also without a trust region).
pub fn rows_behind(max_base_step: f64) -> usize {
    let most = NCLEAR - 1;
    if !max_base_step.is_finite() {
        return most;
    }
    let within = (max_base_step / BEHIND_SPACING_MM + 1e-9).floor().max(0.0) as usize;
    within.clamp(BEHIND_MIN_ROWS, most)
}

/// The obstacles the controller sees: for each obstacle, the point of the inserted needle
/// nearest to it at the start of the step (the needle within `depth` of the tip, as
/// [`World::clearances`] measures) and the obstacle's point (a sphere's centre; a mesh's
/// closest surface point, through its triangle's vertices), observed after the free motion;
/// the `NCLEAR` nearest obstacles when there are more. Then, as the capacity allows, the rows
/// of the inserted needle points every [`BEHIND_SPACING_MM`] behind each nearest point over the
/// step's largest advance `max_base_step` ([`rows_behind`]), lowest clearance first. With a
/// bound on the entry point's shift (`max_entry_shift`) its row comes first
/// ([`entry_shift_row`]), and with a yield strain (`yield_strain`) the rows of the most bent
/// nodes next ([`bending_rows`], also before the puncture). No obstacle row before puncture
/// (nothing is inserted).
pub fn clearance_observations<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    params: &StepParams,
) -> Vec<ClearanceObservation> {
    let bend = bending_rows(world, free, params.yield_strain);
    let depth = world.depth();
    if !world.punctured || depth <= 0.0 {
        return bend;
    }
    let drag = entry_shift_row(world, free, params.max_entry_shift);
    let reserved = bend.len() + usize::from(drag.is_some());
    let obstacles = obstacle_rows(world, free, params.max_base_step, depth, reserved);
    drag.into_iter().chain(bend).chain(obstacles).collect()
}

/// The clearance a bending row gives a straight needle [mm]: the row's value falls linearly
/// from it to 0 at the yield strain, so the QP's `clearance_margin` (0.2 mm by default) keeps
/// the strain a tenth under the yield strain.
pub const BEND_ROW_SCALE_MM: f64 = 2.0;

/// The share of the yield strain from which a node gets a bending row [-]. A choice, not a
/// proof: the frame holds 8 clearance rows in all, and a node bent less is taken not to pass
/// the yield strain within one step.
const BEND_ROW_FROM: f64 = 0.5;

/// The most bending rows of a frame (the nodes bent most, each the most of its neighbours).
pub const BEND_ROWS: usize = 2;

/// The bound `ε ≤ ε_y` on the needle's bending strain (`yield_strain`, `+∞`: none) as
/// clearance rows, at most [`BEND_ROWS`]: at each node bent more than [`BEND_ROW_FROM`] of
/// `ε_y` and no less than its neighbours (most bent first), the clearance
/// `S (1 − ε/ε_y)` ([`BEND_ROW_SCALE_MM`] = `S`), linearised through the second difference
/// `d = x₋ − 2x + x₊` of the node's neighbourhood (the clamp's: nodes 0, 1, 2): the strain
/// `ε ≈ r |d⊥| / ℓ²` (`r` the outer radius, `ℓ²` the product of the two element lengths,
/// `d⊥` across the needle) grows along `d⊥`, so the row is `S r / (ε_y ℓ²)` times `d`,
/// its clearance growing along `−d⊥ / |d⊥|`.
pub fn bending_rows<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    yield_strain: f64,
) -> Vec<ClearanceObservation> {
    if !yield_strain.is_finite() || yield_strain <= 0.0 {
        return Vec::new();
    }
    bending_rows_of(
        world.needle.positions(),
        &free.needle,
        &world.needle.bending_strains(),
        world.needle.beams().outer_radius(),
        yield_strain,
    )
}

/// [`bending_rows`] of a needle whose nodes are at `nodes` at the start of the step and at
/// `free` after its free motion, bent by `strains` at them, of outer radius `radius` [mm].
fn bending_rows_of(
    nodes: &[Vector3<f64>],
    free: &[Vector3<f64>],
    strains: &[f64],
    radius: f64,
    yield_strain: f64,
) -> Vec<ClearanceObservation> {
    let n = strains.len().min(nodes.len()).min(free.len());
    if n < 3 {
        return Vec::new();
    }
    let mut bent: Vec<(f64, usize)> = (0..n)
        .filter(|&k| {
            let s = strains[k];
            s >= BEND_ROW_FROM * yield_strain
                && (k == 0 || strains[k - 1] <= s)
                && (k + 1 == n || strains[k + 1] <= s)
        })
        .map(|k| (strains[k], k))
        .collect();
    bent.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut centres: Vec<usize> = Vec::new();
    let mut rows = Vec::new();
    for (strain, k) in bent {
        let c = k.clamp(1, n - 2);
        if rows.len() == BEND_ROWS || centres.contains(&c) {
            continue;
        }
        let (a, b) = (nodes[c] - nodes[c - 1], nodes[c + 1] - nodes[c]);
        let d = b - a;
        let along = (a + b).try_normalize(f64::MIN_POSITIVE);
        let across = along.map(|t| d - t * t.dot(&d));
        let Some(normal) = across.and_then(|v| v.try_normalize(1e-12)) else {
            continue;
        };
        let l2 = a.norm() * b.norm();
        let g = BEND_ROW_SCALE_MM * radius / (yield_strain * l2);
        if !g.is_finite() {
            continue;
        }
        centres.push(c);
        rows.push(ClearanceObservation {
            needle: Observation {
                model: Model::Needle,
                map: PointMap::weighted([
                    (Some(6 * (c - 1)), g),
                    (Some(6 * c), -2.0 * g),
                    (Some(6 * (c + 1)), g),
                ]),
                a: Matrix3::identity(),
                free: (free[c - 1] - 2.0 * free[c] + free[c + 1]) * g,
            },
            obstacle: Vec::new(),
            clearance: BEND_ROW_SCALE_MM * (1.0 - strain / yield_strain),
            normal: -normal,
            current: d * g,
            kind: ClearanceKind::Bending(k),
        });
    }
    rows
}

/// The bound `|s| ≤ S` on the entry point's shift `s` from rest (`S` = `max_entry_shift`,
/// [`World::entry_shift`]) as a clearance row, linearised along the shift now: clearance
/// `S − |s|`, growing along `−ŝ` with the entry point's motion (none for `S = +∞` or no shift
/// yet).
fn entry_shift_row<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    max_entry_shift: f64,
) -> Option<ClearanceObservation> {
    let s = world.entry_shift();
    let len = s.norm();
    (max_entry_shift.is_finite() && len > 0.0).then(|| ClearanceObservation {
        needle: entry_observation(world, free),
        obstacle: Vec::new(),
        clearance: max_entry_shift - len,
        normal: -s / len,
        current: world.entry_point(),
        kind: ClearanceKind::EntryShift,
    })
}

/// The obstacles' rows of [`clearance_observations`], `reserved` slots fewer.
fn obstacle_rows<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    max_base_step: f64,
    depth: f64,
    reserved: usize,
) -> Vec<ClearanceObservation> {
    let capacity = NCLEAR.saturating_sub(reserved);
    if world.obstacles.is_empty() || capacity == 0 {
        return Vec::new();
    }
    let nodes = world.needle.positions();
    let n = nodes.len();
    // Arc length from the tip to each node.
    let mut arc = vec![0.0; n];
    for k in (0..n - 1).rev() {
        arc[k] = arc[k + 1] + (nodes[k + 1] - nodes[k]).norm();
    }
    let needle_at = |k: usize, f: f64| Observation {
        model: Model::Needle,
        map: PointMap::weighted([(Some(6 * k), 1.0 - f), (Some(6 * (k + 1)), f)]),
        a: Matrix3::identity(),
        free: free.needle[k] * (1.0 - f) + free.needle[k + 1] * f,
    };
    // The inserted needle point at arc length `alpha` from the tip: (segment, fraction).
    let point_at = |alpha: f64| {
        if alpha > depth {
            return None;
        }
        let j = (0..n - 1).find(|&j| arc[j + 1] <= alpha && alpha <= arc[j])?;
        let len = arc[j] - arc[j + 1];
        let g = if len > 0.0 {
            (arc[j] - alpha) / len
        } else {
            0.0
        };
        Some((j, g, nodes[j] * (1.0 - g) + nodes[j + 1] * g))
    };
    let behind = |k: usize, f: f64| {
        let nearest = arc[k] * (1.0 - f) + arc[k + 1] * f;
        (1..=rows_behind(max_base_step))
            .filter_map(move |i| point_at(nearest + i as f64 * BEHIND_SPACING_MM))
    };
    let mut extra: Vec<(f64, ClearanceObservation)> = Vec::new();
    let mut seen: Vec<(f64, ClearanceObservation)> = world
        .obstacles
        .iter()
        .enumerate()
        .filter_map(|(index, o)| match o {
            Obstacle::Sphere {
                centre: e,
                radius: r,
            } => {
                let c = world.gel_point(e);
                let mut best = (f64::INFINITY, n - 2, 1.0);
                for k in (0..n - 1).filter(|&k| arc[k + 1] < depth) {
                    // The segment clipped to the inserted part, as a fraction range of [k, k + 1].
                    let f0 = if arc[k] > depth {
                        (arc[k] - depth) / (arc[k] - arc[k + 1])
                    } else {
                        0.0
                    };
                    let (a, b) = (nodes[k], nodes[k + 1]);
                    let ab = b - a;
                    let l2 = ab.norm_squared();
                    let f = if l2 > 0.0 {
                        ((c - a).dot(&ab) / l2).clamp(f0, 1.0)
                    } else {
                        1.0
                    };
                    let d = (a + f * ab - c).norm();
                    if d < best.0 {
                        best = (d, k, f);
                    }
                }
                let (d, k, f) = best;
                let current = nodes[k] * (1.0 - f) + nodes[k + 1] * f - c;
                let dist = current.norm();
                let normal = if dist > 0.0 {
                    current / dist
                } else {
                    Vector3::zeros()
                };
                let centre = gel_observation(gel_map(world, e), free.gel_point(world, e));
                for (j, g, p) in behind(k, f) {
                    let current = p - c;
                    let dist = current.norm();
                    if dist > 0.0 {
                        extra.push((
                            dist - r,
                            ClearanceObservation {
                                needle: needle_at(j, g),
                                obstacle: vec![centre],
                                clearance: dist - r,
                                normal: current / dist,
                                current,
                                kind: ClearanceKind::Obstacle(index),
                            },
                        ));
                    }
                }
                Some((
                    d - r,
                    ClearanceObservation {
                        needle: needle_at(k, f),
                        obstacle: vec![centre],
                        clearance: dist - r,
                        normal,
                        current,
                        kind: ClearanceKind::Obstacle(index),
                    },
                ))
            }
            Obstacle::Mesh {
                vertices,
                triangles,
                surface,
            } => {
                let c = world.mesh_clearance(vertices, surface)?;
                let surface_point = |c: &crate::proximity::SurfaceClearance| {
                    let tri = triangles[c.triangle];
                    (0..3)
                        .map(|i| {
                            let e = &vertices[tri[i]];
                            let w = c.weights[i];
                            Observation {
                                model: Model::Gel,
                                map: gel_map(world, e),
                                a: Matrix3::identity() * w,
                                free: free.gel_point(world, e) * w,
                            }
                        })
                        .collect()
                };
                let obstacle = surface_point(&c);
                let at = world.obstacle_vertices(vertices);
                for (j, g, p) in behind(c.segment, c.fraction) {
                    if let Some(b) = surface.clearance(&at, &[(p, p)]) {
                        extra.push((
                            b.value,
                            ClearanceObservation {
                                needle: needle_at(j, g),
                                obstacle: surface_point(&b),
                                clearance: b.value,
                                normal: b.normal,
                                current: b.point - b.surface_point,
                                kind: ClearanceKind::Obstacle(index),
                            },
                        ));
                    }
                }
                Some((
                    c.value,
                    ClearanceObservation {
                        needle: needle_at(c.segment, c.fraction),
                        obstacle,
                        clearance: c.value,
                        normal: c.normal,
                        current: c.point - c.surface_point,
                        kind: ClearanceKind::Obstacle(index),
                    },
                ))
            }
        })
        .collect();
    seen.sort_by(|a, b| a.0.total_cmp(&b.0));
    seen.truncate(capacity);
    extra.sort_by(|a, b| a.0.total_cmp(&b.0));
    extra.truncate(capacity - seen.len());
    seen.extend(extra);
    seen.into_iter().map(|(_, c)| c).collect()
}

/// An observed gel point or direction.
fn gel_observation(map: PointMap, free: Vector3<f64>) -> Observation {
    Observation {
        model: Model::Gel,
        map,
        a: Matrix3::identity(),
        free,
    }
}

/// The target point and tangent shown to the controller ([`World::shown_target_embedding`]):
/// embedded in the gel (the tangent as the difference of the points [`TANGENT_STEP`] of path
/// apart over [`crate::straighten::Straightening::span`]: a unit vector at rest where the shown
/// path is straightened) once both
/// are inside it, else the rest path's, carried by the support's
/// displacement (fixed in the world without a support motion).
fn target_observations<const N: usize>(
    world: &World<N>,
    free: &FreePositions,
    c: f64,
) -> (Observation, Observation) {
    let fixed = PointMap::weighted([]);
    match (
        world.shown_target_embedding(c),
        world.shown_target_embedding(c + TANGENT_STEP),
    ) {
        (Some(a), Some(b)) => {
            let (ma, mb) = (gel_map(world, &a), gel_map(world, &b));
            let inv = 1.0 / world.straightening.span(&world.path, c, TANGENT_STEP);
            let map = PointMap::weighted(
                ma.used()
                    .iter()
                    .map(|&(d, w)| (Some(d), w * -inv))
                    .chain(mb.used().iter().map(|&(d, w)| (Some(d), w * inv))),
            );
            let (pa, pb) = (free.gel_point(world, &a), free.gel_point(world, &b));
            (
                gel_observation(ma, pa),
                gel_observation(map, (pb - pa) * inv),
            )
        }
        (a, _) => {
            let (p, t) = world.path.at(c);
            let p = p + world.support_offset;
            let target = match a {
                Some(a) => gel_observation(gel_map(world, &a), free.gel_point(world, &a)),
                None => gel_observation(fixed, p),
            };
            (target, gel_observation(fixed, t))
        }
    }
}

/// Rotation exp([θ]×).
fn exp_so3(theta: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*theta).into_inner()
}

/// Header fields of the frame: the needle base after free motion (from `needle_dx`, the free
/// motion), its violation of `B(q)`, the joints, the control period `dt` [s], the insertion
/// state and the sequence; then validates the whole frame.
///
/// # Errors
/// The frame's [`ValidationError`].
pub fn fill_header<const N: usize>(
    f: &mut ComplianceFrame<ROWS, N>,
    world: &World<N>,
    needle_dx: &[f64],
    free: &FreePositions,
    dt: f64,
) -> Result<(), ValidationError> {
    let p0 = free.needle[0];
    let r0 =
        exp_so3(&Vector3::new(needle_dx[3], needle_dx[4], needle_dx[5])) * world.needle.rotation(0);
    // The frame carries the needle base as a B-frame orientation: R_B = R_node · r_offᵀ.
    let rb = r0 * world.r_off.transpose();
    f.p_free = [p0.x, p0.y, p0.z];
    for i in 0..3 {
        for j in 0..3 {
            f.r_free[i][j] = rb[(i, j)];
        }
    }
    let base = world.base_pose(&world.q);
    let d = base_violation(&base, &f.p_free, &f.r_free);
    f.delta_free[..6].copy_from_slice(&d);
    f.q = world.q;
    f.dt = dt;
    f.inserted = u32::from(world.punctured);
    f.insertion_depth = world.depth();
    f.sequence = world.steps as u64;
    f.version = needle_core::payload::VERSION;
    f.validate()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Nodes every `h` mm along a circular arc of curvature `k` [1/mm] from the origin along x,
    /// bending towards +z.
    fn arc(k: f64, h: f64, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| {
                let s = i as f64 * h;
                Vector3::new((k * s).sin() / k, 0.0, (1.0 - (k * s).cos()) / k)
            })
            .collect()
    }

    /// A bending row's linear model, `clearance + n·(free − current)` as the frame takes it
    /// (`ConstraintSet::fill_clearances`), against its value `S (1 − ε/ε_y)` after the needle
    /// bends more: from an arc at 90 % of the yield strain to arcs 5 % more and less bent,
    /// and by finite differences of 10⁻⁶ of the curvature (within 1 %: the second difference
    /// over the element lengths at the start follows the curvature to `O((κ h)²)`).
    #[test]
    fn a_bending_row_predicts_the_strain_of_a_needle_bent_further() {
        let (r, h, yield_strain) = (0.34, 3.0, 0.01);
        let k1 = 0.9 * yield_strain / r;
        let nodes = arc(k1, h, 12);
        let strains = vec![r * k1; nodes.len()];
        let model = |k2: f64| {
            let free = arc(k2, h, 12);
            let rows = bending_rows_of(&nodes, &free, &strains, r, yield_strain);
            assert_eq!(rows.len(), BEND_ROWS);
            rows.iter()
                .map(|row| row.clearance + row.normal.dot(&(row.needle.free - row.current)))
                .collect::<Vec<_>>()
        };
        let exact = |k: f64| BEND_ROW_SCALE_MM * (1.0 - r * k / yield_strain);
        for k2 in [k1, 1.05 * k1, 0.95 * k1] {
            for predicted in model(k2) {
                assert!(
                    (predicted - exact(k2)).abs() < 1e-3,
                    "curvature {k2}: predicted {predicted} mm against {} mm",
                    exact(k2)
                );
            }
        }
        let dk = 1e-6 * k1;
        for (up, down) in model(k1 + dk).iter().zip(model(k1 - dk)) {
            let slope = (up - down) / (2.0 * dk);
            let expected = -BEND_ROW_SCALE_MM * r / yield_strain;
            assert!(
                (slope / expected - 1.0).abs() < 1e-2,
                "d clearance / d curvature {slope} against {expected}"
            );
        }
    }

    /// Rows go to the nodes bent most, each the most of its neighbours and past half the
    /// yield strain, the clamp's on nodes 0, 1, 2; none when no node is bent that far.
    #[test]
    fn bending_rows_go_to_the_most_bent_nodes() {
        let (r, yield_strain) = (0.34, 0.01);
        let nodes = arc(0.01, 3.0, 9);
        let share = [0.3, 0.8, 0.6, 0.2, 0.55, 0.7, 0.65, 0.1, 0.0];
        let strains: Vec<f64> = share.iter().map(|s| s * yield_strain).collect();
        let rows = bending_rows_of(&nodes, &nodes, &strains, r, yield_strain);
        let centre = |row: &ClearanceObservation| row.needle.map.blocks[1].0 / 6;
        assert_eq!(rows.iter().map(centre).collect::<Vec<_>>(), [1, 5]);
        assert!((rows[0].clearance - 0.2 * BEND_ROW_SCALE_MM).abs() < 1e-12);
        // The clamp's node alone bent: its row on nodes 0, 1, 2.
        let mut clamp = vec![0.0; 9];
        clamp[0] = 0.9 * yield_strain;
        let rows = bending_rows_of(&nodes, &nodes, &clamp, r, yield_strain);
        assert_eq!(rows.iter().map(centre).collect::<Vec<_>>(), [1]);
        let low: Vec<f64> = strains.iter().map(|s| 0.6 * s).collect();
        assert!(bending_rows_of(&nodes, &nodes, &low, r, yield_strain).is_empty());
    }

    /// A heading tilted past the bound is turned in the plane of the heading and the normal to
    /// exactly the bound, its length kept; one within the bound, or along the normal, is left.
    #[test]
    fn a_heading_outside_the_cone_is_turned_onto_its_boundary() {
        let n = Vector3::new(0.0, 0.0, -1.0);
        let max = 0.9 * 0.3_f64.atan();
        let tilt = 18.5_f64.to_radians();
        let t = Vector3::new(0.0, tilt.sin(), -tilt.cos()) * 2.0;
        let r = within_cone(&t, &n, max).unwrap();
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-12);
        let u = r * t;
        assert!((u.norm() - 2.0).abs() < 1e-12);
        assert!((u.normalize().dot(&n).acos() - max).abs() < 1e-12);
        assert!(
            u.x.abs() < 1e-12 && u.y > 0.0,
            "in the plane, on the same side: {u:?}"
        );
        // Within the bound, along the normal, zero: no turn.
        let inside = Vector3::new(0.0, (0.5 * max).sin(), -(0.5 * max).cos());
        assert!(within_cone(&inside, &n, max).is_none());
        assert!(within_cone(&n, &n, max).is_none());
        assert!(within_cone(&Vector3::zeros(), &n, max).is_none());
        // A bound of π/2 or more never turns a heading into the gel.
        assert!(within_cone(&t, &n, std::f64::consts::FRAC_PI_2).is_none());
    }
}
