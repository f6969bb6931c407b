//! Proximity (the paper's collision detection stage, CD): the one module that talks to parry.
//!
//! Two queries, each built only when a scene needs it:
//! - [`TetLocator`]: which tetrahedron of a (possibly deformed) mesh holds a point, and its
//!   barycentric coordinates — to embed the path and the obstacles in the rest mesh once, and to
//!   drop a sliding point where the tip has cut;
//! - [`SurfaceProjector`]: the closest point of the deformed gel surface to the needle tip, with
//!   the triangle, its barycentric coordinates and the outward normal — the tip contact φ before puncture.
//!
//! parry 0.31 speaks glam (`glamx`); conversion to nalgebra happens here and nowhere else.

use nalgebra::Vector3;
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::math::Vector as GVec;
use parry3d_f64::partitioning::{Bvh, BvhBuildStrategy};
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::Triangle;

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
            let worst = w.iter().copied().fold(f64::INFINITY, f64::min);
            if best.as_ref().is_none_or(|(b, _)| worst > *b) {
                best = Some((worst, Embedded { tet, weights: w }));
            }
            if worst >= 0.0 {
                break;
            }
        }
        best.map(|(_, e)| e)
    }
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
}
