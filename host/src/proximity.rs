//! Proximity (the paper's collision detection stage, CD): the one module that talks to parry.
//!
//! Two queries, each built only when a scene needs it:
//! - [`TetLocator`]: which tetrahedron of a (possibly deformed) mesh holds a point, and its
//!   barycentric coordinates — to embed the path and the obstacles in the rest mesh once, and to
//!   drop a sliding point where the tip has cut;
//! - [`SurfaceProjector`]: the closest point of the deformed gel surface to the needle tip, with
//!   the triangle, its barycentric coordinates and the outward normal — the tip contact φ before puncture;
//! - [`ClosedSurface`]: the signed clearance of a polyline (the inserted needle's centre line) to
//!   a closed triangulated surface (an obstacle given as a mesh), with its closest pair.
//!
//! parry 0.31 speaks glam (`glamx`); conversion to nalgebra happens here and nowhere else.

use nalgebra::Vector3;
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::math::{Pose, Vector as GVec};
use parry3d_f64::partitioning::{Bvh, BvhBuildStrategy};
use parry3d_f64::query::{ClosestPoints, PointQuery, PointQueryWithLocation, closest_points};
use parry3d_f64::shape::{Segment, TriMesh, TriMeshFlags, Triangle};

#[inline]
fn to_g(v: &Vector3<f64>) -> GVec {
    GVec::new(v.x, v.y, v.z)
}

#[inline]
fn from_g(v: GVec) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

/// Barycentric coordinates of `p` in the tetrahedron `x` (they sum to 1; all ≥ 0 inside).
/// `None` for a degenerate tetrahedron.
pub fn barycentric_tet(x: &[Vector3<f64>; 4], p: &Vector3<f64>) -> Option<[f64; 4]> {
    let m = nalgebra::Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let inv = m.try_inverse()?;
    let l = inv * (p - x[0]);
    let b = [1.0 - l.x - l.y - l.z, l.x, l.y, l.z];
    b.iter().all(|v| v.is_finite()).then_some(b)
}

/// Barycentric coordinates of `p` (assumed on or near the triangle's plane) in triangle `x`.
pub fn barycentric_triangle(x: &[Vector3<f64>; 3], p: &Vector3<f64>) -> [f64; 3] {
    let e0 = x[1] - x[0];
    let e1 = x[2] - x[0];
    let d = p - x[0];
    let (d00, d01, d11) = (e0.dot(&e0), e0.dot(&e1), e1.dot(&e1));
    let (d20, d21) = (d.dot(&e0), d.dot(&e1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() <= f64::MIN_POSITIVE {
        return [1.0, 0.0, 0.0];
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    [1.0 - v - w, v, w]
}

/// A point embedded in a tetrahedral mesh: it moves with the mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Embedded {
    /// Tetrahedron index.
    pub tet: usize,
    /// Barycentric weights of the tetrahedron's four nodes.
    pub weights: [f64; 4],
}

impl Embedded {
    /// The point's position for the given node positions [mm].
    pub fn position(&self, nodes: &[Vector3<f64>], tets: &[[usize; 4]]) -> Vector3<f64> {
        let t = tets[self.tet];
        (0..4).map(|k| self.weights[k] * nodes[t[k]]).sum()
    }

    /// The smallest barycentric weight: ≥ 0 inside the element, the deeper inside the larger.
    pub fn min_weight(&self) -> f64 {
        self.weights.iter().copied().fold(f64::INFINITY, f64::min)
    }
}

/// Point location in a tetrahedral mesh through a BVH of element boxes.
pub struct TetLocator {
    bvh: Bvh,
}

fn tet_aabb(nodes: &[Vector3<f64>], t: &[usize; 4]) -> Aabb {
    let mut mins = nodes[t[0]];
    let mut maxs = nodes[t[0]];
    for &i in &t[1..] {
        mins = mins.inf(&nodes[i]);
        maxs = maxs.sup(&nodes[i]);
    }
    Aabb::new(to_g(&mins), to_g(&maxs))
}

impl TetLocator {
    /// Builds the BVH over the elements at the given node positions.
    pub fn new(nodes: &[Vector3<f64>], tets: &[[usize; 4]]) -> Self {
        let leaves: Vec<Aabb> = tets.iter().map(|t| tet_aabb(nodes, t)).collect();
        Self {
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves),
        }
    }

    /// The element holding `p`, with barycentric coordinates, or — when `p` lies outside the
    /// mesh (or in a gap of an inverted region) — the element whose coordinates are least
    /// negative among those whose box is within `reach` of `p` [mm]. `None` if nothing is near.
    pub fn locate(
        &self,
        nodes: &[Vector3<f64>],
        tets: &[[usize; 4]],
        p: &Vector3<f64>,
        reach: f64,
    ) -> Option<Embedded> {
        let r = Vector3::repeat(reach.max(0.0));
        let query = Aabb::new(to_g(&(p - r)), to_g(&(p + r)));
        let mut best: Option<(f64, Embedded)> = None;
        for leaf in self.bvh.intersect_aabb(&query) {
            let tet = leaf as usize;
            let t = tets[tet];
            let x = [nodes[t[0]], nodes[t[1]], nodes[t[2]], nodes[t[3]]];
            let Some(w) = barycentric_tet(&x, p) else {
                continue;
            };
            let e = Embedded { tet, weights: w };
            let worst = e.min_weight();
            if best.as_ref().is_none_or(|(b, _)| worst > *b) {
                best = Some((worst, e));
            }
            if worst >= 0.0 {
                break;
            }
        }
        best.map(|(_, e)| e)
    }

    /// Every element holding `p` (every barycentric weight ≥ 0), with its coordinates, in the
    /// search's order: one inside a mesh whose elements do not overlap, none outside it or in
    /// a gap, several where elements fold over each other (an inverted region) or on a face
    /// they share.
    pub fn holding(
        &self,
        nodes: &[Vector3<f64>],
        tets: &[[usize; 4]],
        p: &Vector3<f64>,
    ) -> Vec<Embedded> {
        let query = Aabb::new(to_g(p), to_g(p));
        (self.bvh.intersect_aabb(&query))
            .filter_map(|leaf| {
                let tet = leaf as usize;
                let t = tets[tet];
                let x = [nodes[t[0]], nodes[t[1]], nodes[t[2]], nodes[t[3]]];
                let e = Embedded {
                    tet,
                    weights: barycentric_tet(&x, p)?,
                };
                (e.min_weight() >= 0.0).then_some(e)
            })
            .collect()
    }
}

/// Distance [mm] from `p` to the axis-aligned box of `nodes` (0 inside it; infinite without
/// nodes). No triangle or element over these nodes is nearer to `p`: a query whose reach is
/// shorter can be answered "nothing" without building a BVH.
pub fn box_distance(nodes: &[Vector3<f64>], p: &Vector3<f64>) -> f64 {
    let Some(first) = nodes.first() else {
        return f64::INFINITY;
    };
    let (lo, hi) = nodes[1..]
        .iter()
        .fold((*first, *first), |(lo, hi), n| (lo.inf(n), hi.sup(n)));
    let outside = (lo - p).sup(&Vector3::zeros()) + (p - hi).sup(&Vector3::zeros());
    outside.norm()
}

/// The closest point of a triangulated surface to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceHit {
    /// Triangle index in the surface list.
    pub triangle: usize,
    /// Barycentric weights of the closest point in that triangle.
    pub weights: [f64; 3],
    /// The closest point [mm].
    pub point: Vector3<f64>,
    /// The triangle's unit outward normal.
    pub normal: Vector3<f64>,
    /// The smooth unit outward normal at the closest point: the area-weighted vertex normals of
    /// the triangle interpolated with `weights` (continuous across edges and vertices, unlike
    /// `normal`; at the bottom of a dimple pushed by a point it stays along the undeformed
    /// normal instead of jumping between the steep faces around the pushed node).
    pub smooth_normal: Vector3<f64>,
    /// Signed distance along the normal (negative: the query point is below the surface) [mm].
    pub signed_distance: f64,
}

/// Closest-point queries on a (deforming) triangulated surface.
pub struct SurfaceProjector {
    bvh: Bvh,
    vertex_normals: Vec<Vector3<f64>>,
}

impl SurfaceProjector {
    /// Builds the BVH over the triangles at the given node positions.
    pub fn new(nodes: &[Vector3<f64>], triangles: &[[usize; 3]]) -> Self {
        let leaves: Vec<Aabb> = triangles
            .iter()
            .map(|t| {
                let mins = nodes[t[0]].inf(&nodes[t[1]]).inf(&nodes[t[2]]);
                let maxs = nodes[t[0]].sup(&nodes[t[1]]).sup(&nodes[t[2]]);
                Aabb::new(to_g(&mins), to_g(&maxs))
            })
            .collect();
        let mut vertex_normals = vec![Vector3::zeros(); nodes.len()];
        for t in triangles {
            // Cross product = twice the area times the normal: an area-weighted sum.
            let n = (nodes[t[1]] - nodes[t[0]]).cross(&(nodes[t[2]] - nodes[t[0]]));
            for &i in t {
                vertex_normals[i] += n;
            }
        }
        for n in &mut vertex_normals {
            *n = n
                .try_normalize(f64::MIN_POSITIVE)
                .unwrap_or_else(Vector3::zeros);
        }
        Self {
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves),
            vertex_normals,
        }
    }

    /// The closest surface point to `p` within `max_distance` [mm].
    pub fn project(
        &self,
        nodes: &[Vector3<f64>],
        triangles: &[[usize; 3]],
        p: &Vector3<f64>,
        max_distance: f64,
    ) -> Option<SurfaceHit> {
        let gp = to_g(p);
        let (leaf, (_, proj)) = self.bvh.project_point(gp, max_distance, |i, _| {
            let t = triangles[i as usize];
            let tri = Triangle::new(to_g(&nodes[t[0]]), to_g(&nodes[t[1]]), to_g(&nodes[t[2]]));
            Some(tri.project_local_point(gp, false))
        })?;
        let triangle = leaf as usize;
        let t = triangles[triangle];
        let x = [nodes[t[0]], nodes[t[1]], nodes[t[2]]];
        let point = from_g(proj.point);
        let normal = (x[1] - x[0])
            .cross(&(x[2] - x[0]))
            .try_normalize(f64::MIN_POSITIVE)?;
        let weights = barycentric_triangle(&x, &point);
        let smooth_normal = (0..3)
            .map(|k| weights[k] * self.vertex_normals[t[k]])
            .sum::<Vector3<f64>>()
            .try_normalize(f64::MIN_POSITIVE)
            .unwrap_or(normal);
        Some(SurfaceHit {
            triangle,
            weights,
            point,
            normal,
            smooth_normal,
            signed_distance: (p - point).dot(&normal),
        })
    }
}

/// A [`SurfaceProjector`] kept with the node positions it was built at, for one surface: built
/// again only when a position changed (bit for bit). Before the needle touches it the gel is at
/// rest and its positions do not change from step to step (see `FeModel::free_motion_unloaded`),
/// so the tip's approach, within [`box_distance`] reach of the gel, queries one projector
/// instead of building a BVH over the whole surface every step.
#[derive(Default)]
pub struct CachedProjector {
    at: Vec<Vector3<f64>>,
    projector: Option<SurfaceProjector>,
    builds: usize,
}

impl CachedProjector {
    /// The projector of `triangles` at `nodes` (always the same `triangles` for one cache).
    pub fn get(&mut self, nodes: &[Vector3<f64>], triangles: &[[usize; 3]]) -> &SurfaceProjector {
        if self.projector.is_none() || !crate::free_motion::same_bits(&self.at, nodes) {
            self.at.clear();
            self.at.extend_from_slice(nodes);
            self.builds += 1;
            self.projector = Some(SurfaceProjector::new(nodes, triangles));
        }
        self.projector
            .get_or_insert_with(|| SurfaceProjector::new(nodes, triangles))
    }

    /// How many projectors it has built.
    pub fn builds(&self) -> usize {
        self.builds
    }
}

impl std::fmt::Debug for CachedProjector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CachedProjector")
            .field("nodes", &self.at.len())
            .field("built", &self.projector.is_some())
            .field("builds", &self.builds)
            .finish()
    }
}

/// The closest pair of a polyline and a closed surface, and their signed distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceClearance {
    /// Signed distance [mm]: the smallest distance of the polyline to the surface when it lies
    /// wholly outside, else minus the depth of its deepest point inside.
    pub value: f64,
    /// Segment `[x_k, x_{k+1}]` of the polyline holding the closest point.
    pub segment: usize,
    /// Its fraction along the segment, in [0, 1].
    pub fraction: f64,
    /// Triangle of the surface holding the closest surface point.
    pub triangle: usize,
    /// Barycentric weights of that point in the triangle.
    pub weights: [f64; 3],
    /// The polyline's point [mm].
    pub point: Vector3<f64>,
    /// The surface's point [mm].
    pub surface_point: Vector3<f64>,
    /// Unit vector along which `value` grows when the polyline's point moves away from the
    /// surface's: `value = normalᵀ (point − surface_point)`.
    pub normal: Vector3<f64>,
}

/// A closed, outward-oriented triangulated surface at given vertex positions (an obstacle);
/// inside and outside are told by the angle-weighted pseudo-normals.
pub struct ClosedSurface {
    mesh: TriMesh,
}

/// A closed surface whose vertices move (a mesh obstacle, each vertex embedded in the gel): the
/// parry mesh is kept with the vertices it was built at, and rebuilt only when they have moved
/// since the last query; at unchanged vertices (the step's observers after its last stage: the
/// summary, `steps.csv`, the ParaView frames; and the next step's clearance rows, which are
/// taken at the gel's positions the last step ended with) it is reused.
///
/// It is rebuilt, not refitted: parry 0.31.1's `TriMesh::set_vertices` (the BVH built for the
/// first vertices, its boxes refitted; the pseudo-normals recomputed) answers the same queries
/// but breaks ties between equidistant triangles in another order, which moved one clearance
/// of `scenes/obstacles/mesh_box.toml` (a needle segment parallel to a face of two triangles)
/// by 5.6e-14 mm at step 565; a rebuilt mesh gives every run bit for bit as before.
pub struct DeformingSurface {
    triangles: Vec<[usize; 3]>,
    /// The vertices of the last query and the surface at them.
    state: std::sync::Mutex<Option<Box<SurfaceAt>>>,
}

/// A surface and the vertices it was built at.
type SurfaceAt = (Vec<Vector3<f64>>, ClosedSurface);

impl DeformingSurface {
    /// A surface of these triangles (outward), its vertices given at each query.
    pub fn new(triangles: Vec<[usize; 3]>) -> Self {
        Self {
            triangles,
            state: std::sync::Mutex::new(None),
        }
    }

    /// The triangles.
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// [`ClosedSurface::clearance`] of `segments` to the surface at `vertices` (the same count
    /// and order at every call); `None` without segments or for a surface parry refuses.
    pub fn clearance(
        &self,
        vertices: &[Vector3<f64>],
        segments: &[(Vector3<f64>, Vector3<f64>)],
    ) -> Option<SurfaceClearance> {
        let mut state = self
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match state.as_deref_mut() {
            Some((at, surface)) if at.len() == vertices.len() => {
                if at.as_slice() != vertices {
                    *surface = ClosedSurface::new(vertices, &self.triangles)?;
                    at.copy_from_slice(vertices);
                }
            }
            _ => {
                *state = Some(Box::new((
                    vertices.to_vec(),
                    ClosedSurface::new(vertices, &self.triangles)?,
                )));
            }
        }
        state.as_ref()?.1.clearance(segments)
    }
}

impl Clone for DeformingSurface {
    fn clone(&self) -> Self {
        Self::new(self.triangles.clone())
    }
}

impl PartialEq for DeformingSurface {
    /// The same triangles (the cached parry mesh is not compared).
    fn eq(&self, other: &Self) -> bool {
        self.triangles == other.triangles
    }
}

impl std::fmt::Debug for DeformingSurface {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeformingSurface")
            .field("triangles", &self.triangles.len())
            .finish_non_exhaustive()
    }
}

/// Samples per segment of the search for the deepest point of a polyline inside a surface.
const DEPTH_SAMPLES: usize = 32;

impl ClosedSurface {
    /// The surface at `vertices`; `None` for a surface parry refuses (no triangle).
    pub fn new(vertices: &[Vector3<f64>], triangles: &[[usize; 3]]) -> Option<Self> {
        let v = vertices.iter().map(to_g).collect();
        let t = triangles
            .iter()
            .map(|t| t.map(|i| u32::try_from(i).unwrap_or(u32::MAX)))
            .collect();
        TriMesh::with_flags(v, t, TriMeshFlags::ORIENTED)
            .ok()
            .map(|mesh| Self { mesh })
    }

    /// Signed distance of `p` to the surface (negative inside), the closest triangle and the
    /// closest point's barycentric weights in it.
    pub fn signed_distance(&self, p: &Vector3<f64>) -> (f64, usize, [f64; 3], Vector3<f64>) {
        let (proj, (tri, loc)) = self
            .mesh
            .project_local_point_and_get_location(to_g(p), false);
        let s = from_g(proj.point);
        let d = (p - s).norm();
        let w = loc.barycentric_coordinates().unwrap_or([1.0, 0.0, 0.0]);
        (if proj.is_inside { -d } else { d }, tri as usize, w, s)
    }

    /// Whether `p` lies inside the surface.
    pub fn contains(&self, p: &Vector3<f64>) -> bool {
        self.signed_distance(p).0 < 0.0
    }

    /// The signed clearance of the polyline made of `segments` (each `(a, b)`) to the surface:
    /// for a segment wholly outside, parry's closest points of the segment and the triangle
    /// mesh (exact); for a segment that crosses the surface or lies inside, its deepest point,
    /// found by sampling the segment and refining the best sample by golden-section search.
    /// `None` without segments.
    pub fn clearance(&self, segments: &[(Vector3<f64>, Vector3<f64>)]) -> Option<SurfaceClearance> {
        let mut best: Option<SurfaceClearance> = None;
        for (k, (a, b)) in segments.iter().enumerate() {
            let c = self.segment_clearance(k, a, b);
            if best.as_ref().is_none_or(|x| c.value < x.value) {
                best = Some(c);
            }
        }
        best
    }

    fn pair(
        &self,
        k: usize,
        a: &Vector3<f64>,
        b: &Vector3<f64>,
        p: Vector3<f64>,
    ) -> SurfaceClearance {
        let ab = b - a;
        let l2 = ab.norm_squared();
        let fraction = if l2 > 0.0 {
            ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (value, triangle, weights, s) = self.signed_distance(&p);
        let t = self.mesh.triangle(triangle as u32);
        let face = from_g(t.normal().unwrap_or(GVec::Z));
        // value = nᵀ (p − s): outside n points from s to p, inside from p to s.
        let normal = (p - s)
            .try_normalize(1e-12)
            .map_or(face, |u| if value < 0.0 { -u } else { u });
        SurfaceClearance {
            value,
            segment: k,
            fraction,
            triangle,
            weights,
            point: p,
            surface_point: s,
            normal,
        }
    }

    fn segment_clearance(&self, k: usize, a: &Vector3<f64>, b: &Vector3<f64>) -> SurfaceClearance {
        let seg = Segment::new(to_g(a), to_g(b));
        let id = Pose::IDENTITY;
        if let Ok(ClosestPoints::WithinMargin(p, _)) =
            closest_points(&id, &seg, &id, &self.mesh, f64::MAX)
        {
            // Not touching the surface: wholly outside or wholly inside.
            let c = self.pair(k, a, b, from_g(p));
            if c.value > 0.0 {
                return c;
            }
        }
        // Crossing or inside: the deepest point, by samples refined by golden section.
        let at = |f: f64| a + (b - a) * f;
        let phi = |f: f64| self.signed_distance(&at(f)).0;
        let (mut fbest, mut vbest) = (0.0, phi(0.0));
        for i in 1..=DEPTH_SAMPLES {
            let f = i as f64 / DEPTH_SAMPLES as f64;
            let v = phi(f);
            if v < vbest {
                (fbest, vbest) = (f, v);
            }
        }
        let h = 1.0 / DEPTH_SAMPLES as f64;
        let (mut lo, mut hi) = ((fbest - h).max(0.0), (fbest + h).min(1.0));
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
        let (mut v1, mut v2) = (phi(x1), phi(x2));
        for _ in 0..40 {
            if v1 < v2 {
                (hi, x2, v2) = (x2, x1, v1);
                x1 = hi - g * (hi - lo);
                v1 = phi(x1);
            } else {
                (lo, x1, v1) = (x1, x2, v2);
                x2 = lo + g * (hi - lo);
                v2 = phi(x2);
            }
        }
        let (f, v) = if v1 < v2 { (x1, v1) } else { (x2, v2) };
        let f = if v < vbest { f } else { fbest };
        self.pair(k, a, b, at(f))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> (Vec<Vector3<f64>>, Vec<[usize; 4]>) {
        (
            vec![
                Vector3::zeros(),
                Vector3::x(),
                Vector3::y(),
                Vector3::z(),
                Vector3::new(1.0, 1.0, 1.0),
            ],
            vec![[0, 1, 2, 3], [1, 2, 3, 4]],
        )
    }

    #[test]
    fn barycentric_coordinates_reproduce_the_point() {
        let (n, t) = unit_tet();
        let loc = TetLocator::new(&n, &t);
        for p in [Vector3::new(0.1, 0.2, 0.3), Vector3::new(0.6, 0.6, 0.5)] {
            let e = loc.locate(&n, &t, &p, 0.0).expect("inside");
            assert!(e.weights.iter().all(|w| *w >= -1e-12), "{e:?}");
            assert!((e.position(&n, &t) - p).norm() < 1e-12);
        }
        // Outside, but within reach: the nearest element, coordinates extrapolate exactly.
        let p = Vector3::new(-0.05, 0.1, 0.1);
        let e = loc.locate(&n, &t, &p, 0.2).expect("near");
        assert_eq!(e.tet, 0);
        assert!((e.position(&n, &t) - p).norm() < 1e-12);
        assert!(
            loc.locate(&n, &t, &Vector3::new(5.0, 5.0, 5.0), 0.1)
                .is_none()
        );
    }

    #[test]
    fn surface_projection_finds_the_closest_face_and_signed_distance() {
        // The square z = 0 of two triangles, normal +z.
        let n = vec![
            Vector3::zeros(),
            Vector3::x(),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::y(),
        ];
        let tris = vec![[0, 1, 2], [0, 2, 3]];
        let s = SurfaceProjector::new(&n, &tris);
        let hit = s
            .project(&n, &tris, &Vector3::new(0.25, 0.75, 0.4), 10.0)
            .expect("hit");
        assert_eq!(hit.triangle, 1);
        assert!((hit.point - Vector3::new(0.25, 0.75, 0.0)).norm() < 1e-12);
        assert!((hit.signed_distance - 0.4).abs() < 1e-12);
        assert!((hit.normal - Vector3::z()).norm() < 1e-12);
        assert!((hit.smooth_normal - Vector3::z()).norm() < 1e-12);
        let w = hit.weights;
        let back = w[0] * n[0] + w[1] * n[2] + w[2] * n[3];
        assert!((back - hit.point).norm() < 1e-12);
        let below = s
            .project(&n, &tris, &Vector3::new(0.75, 0.25, -0.1), 10.0)
            .expect("hit");
        assert!((below.signed_distance + 0.1).abs() < 1e-12);
        assert!(
            s.project(&n, &tris, &Vector3::new(0.5, 0.5, 30.0), 1.0)
                .is_none()
        );
    }

    #[test]
    fn cached_projector_is_built_again_only_when_a_node_moves() {
        let mut n = vec![
            Vector3::zeros(),
            Vector3::x(),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::y(),
        ];
        let tris = vec![[0, 1, 2], [0, 2, 3]];
        let p = Vector3::new(0.7, 0.6, 0.3);
        let mut cache = CachedProjector::default();
        let first = cache.get(&n, &tris).project(&n, &tris, &p, 10.0);
        let again = cache.get(&n, &tris).project(&n, &tris, &p, 10.0);
        assert_eq!(cache.builds(), 1, "the same positions: no new build");
        assert_eq!(first, again);
        // A node moved by one unit in the last place: built again.
        n[2].z = f64::from_bits(n[2].z.to_bits() + 1);
        let _ = cache.get(&n, &tris);
        assert_eq!(cache.builds(), 2);
        // Moved further: built again, and the answer is a fresh projector's.
        n[2].z = 0.2;
        let moved = cache.get(&n, &tris).project(&n, &tris, &p, 10.0);
        assert_eq!(cache.builds(), 3);
        assert_eq!(
            moved,
            SurfaceProjector::new(&n, &tris).project(&n, &tris, &p, 10.0)
        );
        assert_ne!(moved, first);
    }

    #[test]
    fn box_distance_bounds_every_surface_query() {
        let (n, _) = unit_tet();
        let tris = vec![[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 2, 3]];
        assert_eq!(
            box_distance(&n, &Vector3::new(0.5, 0.2, 0.9)),
            0.0,
            "inside"
        );
        let d = box_distance(&n, &Vector3::new(4.0, -2.0, 0.5));
        assert!((d - (9.0f64 + 4.0).sqrt()).abs() < 1e-12, "{d}");
        assert_eq!(box_distance(&[], &Vector3::zeros()), f64::INFINITY);
        // Never more than the distance to the nearest triangle: a projection within a reach
        // shorter than the box distance finds nothing.
        let s = SurfaceProjector::new(&n, &tris);
        for p in [
            Vector3::new(3.0, 0.5, 0.5),
            Vector3::new(-1.0, -1.0, 2.5),
            Vector3::new(0.5, 0.5, -0.3),
        ] {
            let d = box_distance(&n, &p);
            let hit = s.project(&n, &tris, &p, 10.0).expect("hit");
            assert!(d <= (hit.point - p).norm() + 1e-12, "{p:?}: {d}");
            assert!(s.project(&n, &tris, &p, 0.99 * d).is_none(), "{p:?}");
        }
    }

    #[test]
    fn smooth_normal_is_continuous_at_the_bottom_of_a_dimple() {
        // A square fan of four triangles around a centre node pushed down by 1: the face normals
        // tilt by 45°, the interpolated vertex normal at the centre is the undeformed +z (the
        // query point just below the pushed node, as a tip pressing on it).
        let n = vec![
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(-1.0, 0.0, 0.0),
            Vector3::new(0.0, -1.0, 0.0),
        ];
        let tris = vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]];
        let s = SurfaceProjector::new(&n, &tris);
        let hit = s
            .project(&n, &tris, &Vector3::new(1e-9, 2e-9, -1.2), 10.0)
            .expect("hit");
        assert!(hit.normal.z < 0.75, "a steep face: {:?}", hit.normal);
        assert!(
            (hit.smooth_normal - Vector3::z()).norm() < 1e-6,
            "{:?}",
            hit.smooth_normal
        );
        // Between vertices the smooth normal is the interpolation, still unit and outward.
        let mid = s
            .project(&n, &tris, &Vector3::new(0.4, 0.4, 0.5), 10.0)
            .expect("hit");
        assert!((mid.smooth_normal.norm() - 1.0).abs() < 1e-12 && mid.smooth_normal.z > 0.7);
    }

    use crate::obstacle_mesh::{box_surface, icosphere};

    /// A small deterministic generator in [−1, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    fn distance_point_segment(c: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
        let d = b - a;
        let f = ((c - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
        (a + f * d - c).norm()
    }

    #[test]
    fn a_triangulated_sphere_gives_the_analytic_sphere_clearance_within_its_tessellation_error() {
        let (centre, r) = (Vector3::new(3.0, -1.0, 2.0), 2.5);
        let m = icosphere(3);
        let v: Vec<_> = m.vertices.iter().map(|u| centre + u * r).collect();
        // The inscribed polyhedron lies between the sphere and the faces' nearest planes.
        let sag = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| v[i]);
                let n = (b - a).cross(&(c - a)).normalize();
                r - (a - centre).dot(&n)
            })
            .fold(0.0, f64::max);
        assert!(sag > 0.0 && sag < 0.02, "sagitta {sag}");
        let s = ClosedSurface::new(&v, &m.triangles).expect("surface");
        let mut seed = 7;
        let (mut outside, mut inside) = (0, 0);
        for _ in 0..200 {
            let a = centre + Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * 4.0;
            let b = a + Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * 3.0;
            let analytic = distance_point_segment(&centre, &a, &b) - r;
            let c = s.clearance(&[(a, b)]).expect("one segment");
            // The polyhedron is inside the sphere: its clearance is larger, by at most the
            // sagitta (and the sampled depth inside is exact to the same bound).
            assert!(
                c.value >= analytic - 1e-6 && c.value <= analytic + sag + 1e-6,
                "{a:?} {b:?}: mesh {} analytic {analytic} (sagitta {sag})",
                c.value
            );
            // The pair is consistent: value = nᵀ (p − s), |n| = 1, p on the segment, s on the
            // surface's triangle with the given weights.
            assert!((c.value - c.normal.dot(&(c.point - c.surface_point))).abs() < 1e-9);
            assert!((c.normal.norm() - 1.0).abs() < 1e-12);
            assert!((a + (b - a) * c.fraction - c.point).norm() < 1e-9);
            let t = m.triangles[c.triangle];
            let sp: Vector3<f64> = (0..3).map(|i| c.weights[i] * v[t[i]]).sum();
            assert!((sp - c.surface_point).norm() < 1e-9);
            if analytic > 0.05 {
                outside += 1;
            } else if analytic < -0.05 {
                inside += 1;
                assert!(c.value < 0.0);
            }
        }
        assert!(
            outside > 50 && inside > 20,
            "{outside} outside, {inside} inside"
        );
    }

    #[test]
    fn a_box_gives_its_exact_signed_clearance_outside_across_and_inside() {
        let b = box_surface(
            &Vector3::new(-1.0, -2.0, -3.0),
            &Vector3::new(1.0, 2.0, 3.0),
        );
        let s = ClosedSurface::new(&b.vertices, &b.triangles).expect("surface");
        let clear = |a: [f64; 3], b: [f64; 3]| {
            s.clearance(&[(Vector3::from(a), Vector3::from(b))])
                .expect("segment")
        };
        // Outside, facing the x face: 0.5 mm away, normal +x.
        let c = clear([1.5, -5.0, 0.0], [1.5, 5.0, 0.0]);
        assert!((c.value - 0.5).abs() < 1e-12, "{c:?}");
        assert!((c.normal - Vector3::x()).norm() < 1e-12);
        // Outside, nearest to an edge: √(0.5² + 0.5²).
        let c = clear([1.5, 2.5, -10.0], [1.5, 2.5, 10.0]);
        assert!((c.value - 0.5f64.hypot(0.5)).abs() < 1e-12, "{c:?}");
        // Through the box along z on its axis: the deepest point is 1 mm from the x faces.
        let c = clear([0.0, 0.0, -10.0], [0.0, 0.0, 10.0]);
        assert!((c.value + 1.0).abs() < 1e-9, "{c:?}");
        // Wholly inside, off-centre: 0.3 mm from the +x face at its deepest end... along y the
        // segment ends 0.5 mm from the +y face, its x stays 0.7 (0.3 from +x).
        let c = clear([0.7, 0.0, 0.0], [0.7, 1.5, 0.0]);
        assert!((c.value + 0.3).abs() < 1e-9, "{c:?}");
        assert!((c.normal - Vector3::x()).norm() < 1e-6, "{c:?}");
        // Entering through a face: depth of the inner end, 0.4 below the +z face... the end
        // (0, 0, 2.6) is 0.4 from +z, 1 from ±x.
        let c = clear([0.0, 0.0, 5.0], [0.0, 0.0, 2.6]);
        assert!((c.value + 0.4).abs() < 1e-9, "{c:?}");
        // Inside test.
        assert!(s.contains(&Vector3::new(0.9, 1.9, 2.9)));
        assert!(!s.contains(&Vector3::new(1.1, 0.0, 0.0)));
        // Several segments: the smallest.
        let c = s
            .clearance(&[
                (Vector3::new(3.0, 0.0, 0.0), Vector3::new(3.0, 1.0, 0.0)),
                (Vector3::new(1.25, 0.0, 0.0), Vector3::new(1.25, 1.0, 0.0)),
            ])
            .expect("segments");
        assert_eq!(c.segment, 1);
        assert!((c.value - 0.25).abs() < 1e-12);
    }

    /// The clearance's first-order change under a motion of the polyline's nodes and the
    /// surface's vertices is `nᵀ (Δp − Δs)`, with `p` the polyline's point at its fixed fraction
    /// and `s` the surface point at its fixed barycentric weights (the sensitivity the host's
    /// clearance rows use), against central finite differences: of the signed distance of the
    /// point `p` at its fixed fraction (outside and inside), and of the whole clearance
    /// (outside, where the closest pair is unique and the two agree; inside, the deepest point
    /// is in general equidistant from two faces and the clearance has a kink there, so the rows
    /// hold the needle point fixed, as for a sphere).
    #[test]
    fn the_clearance_sensitivity_matches_finite_differences() {
        let m = icosphere(2);
        let centre = Vector3::new(0.0, 0.0, 0.0);
        let mut seed = 11;
        let mut checked = [0, 0];
        for trial in 0..60 {
            // An irregular surface: the sphere's vertices moved radially.
            let v: Vec<_> = m
                .vertices
                .iter()
                .map(|u| centre + u * (2.0 + 0.3 * lcg(&mut seed)))
                .collect();
            // A polyline of two segments, outside or through the surface.
            let off = if trial % 2 == 0 { 3.0 } else { 1.0 };
            let x: Vec<Vector3<f64>> = (0..3)
                .map(|i| {
                    Vector3::new(
                        off + 0.3 * lcg(&mut seed),
                        -3.0 + 3.0 * i as f64 + 0.3 * lcg(&mut seed),
                        0.5 * lcg(&mut seed),
                    )
                })
                .collect();
            // A random direction of motion of every node and vertex.
            let dx: Vec<Vector3<f64>> = (0..3)
                .map(|_| Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)))
                .collect();
            let dv: Vec<Vector3<f64>> = (0..v.len())
                .map(|_| Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)))
                .collect();
            let moved = |h: f64| {
                let xs: Vec<_> = x.iter().zip(&dx).map(|(a, d)| a + d * h).collect();
                let vs: Vec<_> = v.iter().zip(&dv).map(|(a, d)| a + d * h).collect();
                (xs, ClosedSurface::new(&vs, &m.triangles).expect("surface"))
            };
            let clearance = |h: f64| {
                let (xs, s) = moved(h);
                s.clearance(&[(xs[0], xs[1]), (xs[1], xs[2])])
                    .expect("segments")
            };
            let c = clearance(0.0);
            let k = c.segment;
            // The signed distance of the needle point at its fixed fraction.
            let at_point = |h: f64| {
                let (xs, s) = moved(h);
                let p = xs[k] * (1.0 - c.fraction) + xs[k + 1] * c.fraction;
                s.signed_distance(&p)
            };
            let dp = dx[k] * (1.0 - c.fraction) + dx[k + 1] * c.fraction;
            let t = m.triangles[c.triangle];
            let ds: Vector3<f64> = (0..3).map(|i| dv[t[i]] * c.weights[i]).sum();
            let predicted = c.normal.dot(&(dp - ds));
            let h = 1e-5;
            let (plus, minus) = (at_point(h), at_point(-h));
            let inside = c.value < 0.0;
            if plus.1 == c.triangle && minus.1 == c.triangle {
                let fd = (plus.0 - minus.0) / (2.0 * h);
                assert!(
                    (fd - predicted).abs() < 1e-5 * (1.0 + predicted.abs()),
                    "trial {trial} (inside {inside}): finite difference {fd}, predicted {predicted}"
                );
            } else {
                // The closest triangle switches at p (inside, the deepest point is in general
                // equidistant from two faces): the prediction is the derivative along one side.
                let forward = (plus.0 - c.value) / h;
                let backward = (c.value - minus.0) / h;
                let err = (forward - predicted)
                    .abs()
                    .min((backward - predicted).abs());
                assert!(
                    err < 1e-4 * (1.0 + predicted.abs()),
                    "trial {trial} (inside {inside}): one-sided differences {forward}, {backward}, predicted {predicted}"
                );
            }
            if !inside {
                let (cp, cm) = (clearance(h), clearance(-h));
                let fd = (cp.value - cm.value) / (2.0 * h);
                assert!(
                    (fd - predicted).abs() < 1e-5 * (1.0 + predicted.abs()),
                    "trial {trial}: finite difference of the clearance {fd}, predicted {predicted}"
                );
            }
            checked[usize::from(inside)] += 1;
        }
        assert!(checked[0] > 15 && checked[1] > 15, "checked {checked:?}");
    }
}
