//! The simulated system and its interaction state: the robot, the gel and needle FE models, the
//! planned path and obstacles embedded in the gel, and what the needle has done so far
//! (punctured, sliding points, joints, target). State only: the step lives in [`crate::step`],
//! its tuning in [`crate::step::StepParams`], its scratch in [`crate::step::Pipeline`].

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::error::SetupError;
use crate::free_motion::{GelModel, NeedleModel};
use crate::proximity::{DeformingSurface, Embedded, SurfaceClearance, TetLocator};
use crate::scene::SampledPath;
use crate::support_motion::SupportMotion;
use nalgebra::{Matrix3, Rotation3, Vector3};
use needle_core::kinematics::{Kinematics, Pose, Robot};

/// A sliding point ψ: a gel material point the shaft must pass through.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlidingPoint {
    /// Identifier, increasing in creation order.
    pub id: usize,
    /// The gel point.
    pub at: Embedded,
}

/// What a [`World`] is built from (by [`crate::setup`], or by hand); `N` joints.
pub struct WorldParts<const N: usize = 6> {
    /// The robot holding the needle.
    pub robot: Robot<N>,
    /// The gel at rest.
    pub gel: GelModel,
    /// The needle at its start pose, base node 0 on `B(q)`.
    pub needle: NeedleModel,
    /// Rest length of the needle [mm].
    pub needle_length: f64,
    /// The planned path (rest configuration).
    pub path: SampledPath,
    /// Obstacles in the rest configuration.
    pub obstacles: Vec<ObstacleShape>,
    /// Start joints [rad].
    pub q: [f64; N],
    /// A prescribed motion of the gel's fixed nodes (none: they stay at rest).
    pub support_motion: Option<SupportMotion>,
}

/// An obstacle in the rest configuration [mm].
#[derive(Clone, Debug, PartialEq)]
pub enum ObstacleShape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vector3<f64>,
        /// Radius.
        radius: f64,
    },
    /// A closed, outward-oriented surface mesh.
    Mesh(crate::obstacle_mesh::SurfaceMesh),
}

/// An obstacle embedded in the gel: it deforms with it.
#[derive(Clone, Debug, PartialEq)]
pub enum Obstacle {
    /// A sphere whose centre moves with the gel (its radius stays).
    Sphere {
        /// The centre.
        centre: Embedded,
        /// Radius [mm].
        radius: f64,
    },
    /// A closed surface each of whose vertices moves with the gel.
    Mesh {
        /// The vertices.
        vertices: Vec<Embedded>,
        /// Triangles (outward).
        triangles: Vec<[usize; 3]>,
        /// The surface's parry mesh, updated as the vertices move.
        surface: DeformingSurface,
    },
}

/// The whole simulated system and its interaction state; the robot has `N` joints (6 by
/// default; [`crate::setup::AnySetup`] picks it from the scene).
pub struct World<const N: usize = 6> {
    /// The robot.
    pub robot: Robot<N>,
    /// The gel.
    pub gel: GelModel,
    /// The needle: nodes `0..n`, base first, 6 dofs each (translation, then a world-frame
    /// rotation increment), dofs of node `i` at `6 i`.
    pub needle: NeedleModel,
    /// Rest length of the needle [mm].
    pub needle_length: f64,
    /// The planned path.
    pub path: SampledPath,
    /// Surface triangles of the gel (outward).
    pub surface: Vec<[usize; 3]>,
    rest_locator: TetLocator,
    /// The entry point (planned before puncture, actual after), embedded in the gel.
    pub entry: Embedded,
    /// The rest surface's outward unit normal at the planned entry point.
    pub entry_normal: Vector3<f64>,
    /// Obstacles embedded in the gel.
    pub obstacles: Vec<Obstacle>,
    /// Whether the tip has punctured the surface.
    pub punctured: bool,
    /// Whether the tip pushed on the surface in the last step (contact force > 0).
    pub in_contact: bool,
    /// Whether the tip has slid on the surface since it touched it (its friction force on the
    /// Coulomb cone's boundary in a step before puncture); cleared at puncture. While set, the
    /// heading shown to the controller is turned into the cone ([`crate::step::StepParams`]'s
    /// `entry_tilt`).
    pub tip_slid: bool,
    /// Sliding points, oldest first.
    pub sliding: Vec<SlidingPoint>,
    pub(crate) next_sliding_id: usize,
    /// Depth at which the last sliding point was created [mm].
    pub(crate) last_sliding_depth: f64,
    /// Smallest rest element size of the gel [mm] (see [`element_size`]).
    pub(crate) min_element_size: f64,
    /// Joints [rad].
    pub q: [f64; N],
    /// Target arc length from the start tip [mm].
    pub c: f64,
    /// Steps done.
    pub steps: usize,
    /// Needle node frame → needle-base frame `B` offset: `R_node = R_B · r_off`.
    pub(crate) r_off: Matrix3<f64>,
    /// The prescribed motion of the gel's fixed nodes (none: they stay at rest).
    pub support_motion: Option<SupportMotion>,
    /// The support's current displacement from rest (zero without motion) [mm].
    pub support_offset: Vector3<f64>,
    /// How far the target shown to the controller is straightened towards the path's chord
    /// along the path (`inverse.straighten` resolved, kept clear of the obstacles; none: the
    /// planned path).
    pub straightening: crate::straighten::Straightening,
}

/// The fixed rotation `r_off` between the needle-base frame `B` (needle along its z axis) and the
/// needle's node frame (needle along `axis`): `R_node = R_B · r_off`, so `r_off · axis = z`.
pub fn node_frame_offset(axis: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::rotation_between(axis, &Vector3::z())
        .map(|r| r.into_inner())
        // axis = −z: a half turn about x.
        .unwrap_or_else(|| Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0))
}

/// Closest point of the polyline `x` to `p`: segment index and fraction in [0, 1].
pub(crate) fn closest_on_polyline(x: &[Vector3<f64>], p: &Vector3<f64>) -> (usize, f64) {
    let mut best = (f64::INFINITY, 0, 0.0);
    for e in 0..x.len() - 1 {
        let d = x[e + 1] - x[e];
        let l2 = d.norm_squared();
        let f = if l2 > 0.0 {
            ((p - x[e]).dot(&d) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let dist = (x[e] + f * d - p).norm_squared();
        if dist < best.0 {
            best = (dist, e, f);
        }
    }
    (best.1, best.2)
}

/// Distance from `p` to the segment `[a, b]`.
fn distance_point_segment(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 {
        ((p - a).dot(&d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + f * d - p).norm()
}

/// Size of a tetrahedron: the edge of the regular tetrahedron of the same volume,
/// `(6√2 V)^(1/3)` [mm] (a cube of side a split into 6 tetrahedra: 2^(1/6) a ≈ 1.12 a).
pub fn element_size(nodes: &[Vector3<f64>], t: &[usize; 4]) -> f64 {
    let v = (nodes[t[1]] - nodes[t[0]])
        .cross(&(nodes[t[2]] - nodes[t[0]]))
        .dot(&(nodes[t[3]] - nodes[t[0]]))
        .abs()
        / 6.0;
    (6.0 * std::f64::consts::SQRT_2 * v).cbrt()
}

impl<const N: usize> World<N> {
    /// Assembles a world from its parts: embeds the path's entry point and the obstacles in the
    /// rest gel, finds its surface and smallest element.
    ///
    /// # Errors
    /// [`SetupError::EntryOffGel`], [`SetupError::ObstacleOutside`].
    pub fn try_new(parts: WorldParts<N>) -> Result<Self, SetupError> {
        let WorldParts {
            robot,
            gel,
            needle,
            needle_length,
            path,
            obstacles,
            q,
            support_motion,
        } = parts;
        let mesh = gel.mesh();
        let (rest, tets) = (&mesh.nodes, &mesh.tets);
        let min_element_size = tets
            .iter()
            .map(|t| element_size(rest, t))
            .fold(f64::INFINITY, f64::min);
        let rest_locator = TetLocator::new(rest, tets);
        let entry = rest_locator
            .locate(rest, tets, &path.entry(), 1.0)
            .ok_or_else(|| SetupError::EntryOffGel(path.entry()))?;
        let obstacles = obstacles
            .iter()
            .enumerate()
            .map(|(index, o)| match o {
                &ObstacleShape::Sphere { center, radius } => rest_locator
                    .locate(rest, tets, &center, 0.0)
                    .map(|centre| Obstacle::Sphere { centre, radius })
                    .ok_or(SetupError::ObstacleOutside { index, center }),
                ObstacleShape::Mesh(m) => {
                    // Every vertex in an element of the rest gel (on its surface counts, as
                    // for the path: barycentric weights above −1e-9).
                    let vertices = m
                        .vertices
                        .iter()
                        .enumerate()
                        .map(|(vertex, p)| {
                            rest_locator
                                .locate(rest, tets, p, 0.0)
                                .filter(|e| e.weights.iter().all(|w| *w >= -1e-9))
                                .ok_or(SetupError::ObstacleVertexOutside {
                                    index,
                                    vertex,
                                    node_tag: m.node_tags.as_ref().map(|t| t[vertex]),
                                    point: *p,
                                })
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    Ok(Obstacle::Mesh {
                        vertices,
                        triangles: m.triangles.clone(),
                        surface: DeformingSurface::new(m.triangles.clone()),
                    })
                }
            })
            .collect::<Result<Vec<_>, _>>()?;
        let surface = mesh.surface_triangles();
        let entry_normal = crate::proximity::SurfaceProjector::new(rest, &surface)
            .project(rest, &surface, &path.entry(), f64::MAX)
            .map_or_else(Vector3::z, |h| h.smooth_normal);
        let r_off = node_frame_offset(&needle.axis());
        Ok(Self {
            robot,
            gel,
            needle,
            needle_length,
            path,
            surface,
            rest_locator,
            entry,
            entry_normal,
            obstacles,
            punctured: false,
            in_contact: false,
            tip_slid: false,
            sliding: Vec::new(),
            next_sliding_id: 0,
            last_sliding_depth: 0.0,
            min_element_size,
            q,
            c: 0.0,
            steps: 0,
            r_off,
            support_motion,
            support_offset: Vector3::zeros(),
            straightening: Default::default(),
        })
    }

    /// Moves the gel's fixed nodes to their prescribed positions at time `t` [s]: rest
    /// position + the support motion's displacement `d(t)` (nothing without a motion). This is
    /// the inhomogeneous Dirichlet condition of the next free motion: the fixed dofs stay
    /// eliminated from the system, so `K⁻¹` (and the compliance `W`) is the same operator as
    /// with a still support; the moved nodes enter through the internal forces `f_int(x)` of the
    /// right-hand side, and the free motion carries the free nodes along.
    pub fn move_support(&mut self, t: f64) {
        let Some(motion) = &self.support_motion else {
            return;
        };
        let d = motion.displacement(t);
        self.support_offset = d;
        self.gel.displace_support(&d);
    }

    /// Needle-base pose `B(q)` in the world.
    pub fn base_pose(&self, q: &[f64; N]) -> Pose {
        self.robot.tool_pose(q)
    }

    /// Current needle tip [mm].
    pub fn tip(&self) -> Vector3<f64> {
        *self.needle.positions().last().unwrap_or(&Vector3::zeros())
    }

    /// The gel's rest node positions [mm] and tetrahedra.
    fn rest_mesh(&self) -> (&[Vector3<f64>], &[[usize; 4]]) {
        let m = self.gel.mesh();
        (&m.nodes, &m.tets)
    }

    /// The position of a gel point in the current configuration [mm].
    pub fn gel_point(&self, e: &Embedded) -> Vector3<f64> {
        e.position(self.gel.positions(), &self.gel.mesh().tets)
    }

    /// The target point for arc length `c`: in the air on the approach segment (fixed to the
    /// gel's support: it moves by the support's displacement), inside the gel embedded at its
    /// rest barycentric coordinates (moves with the gel).
    ///
    /// Until the tip has punctured the surface the target stays the rest-configuration path
    /// point (carried by the support's displacement, if any): the tip pressing on the surface indents the gel, and a target
    /// embedded below it would recede with that indentation — the controller would chase it
    /// sideways instead of pushing through. Once punctured, the target is embedded.
    pub fn target_embedding(&self, c: f64) -> Option<Embedded> {
        if c < self.path.approach || !self.punctured {
            return None;
        }
        let (p, _) = self.path.at(c);
        let (rest, tets) = self.rest_mesh();
        self.rest_locator.locate(rest, tets, &p, 1.0)
    }

    /// The target shown to the controller at arc length `c`: the planned path's point
    /// straightened as [`World::straightening`] says ([`SampledPath::straightened`]), embedded
    /// in the gel as [`World::target_embedding`]. The errors are measured against the planned
    /// target.
    pub fn shown_target_embedding(&self, c: f64) -> Option<Embedded> {
        if c < self.path.approach || !self.punctured {
            return None;
        }
        let p = self.straightening.point(&self.path, c);
        let (rest, tets) = self.rest_mesh();
        self.rest_locator.locate(rest, tets, &p, 1.0)
    }

    /// Whether `p` lies in the rest gel (barycentric weights above −1 %: on the surface counts).
    pub fn in_rest_gel(&self, p: &Vector3<f64>) -> bool {
        let (rest, tets) = self.rest_mesh();
        self.rest_locator
            .locate(rest, tets, p, 0.0)
            .is_some_and(|e| e.weights.iter().all(|w| *w >= -0.01))
    }

    /// Current target point [mm]: embedded in the gel ([`World::target_embedding`]), else the
    /// rest path's point carried by the support's displacement (zero without a support motion).
    pub fn target(&self, c: f64) -> Vector3<f64> {
        match self.target_embedding(c) {
            Some(e) => self.gel_point(&e),
            None => self.path.at(c).0 + self.support_offset,
        }
    }

    /// Current entry point [mm].
    pub fn entry_point(&self) -> Vector3<f64> {
        self.gel_point(&self.entry)
    }

    /// How far the gel point `e` has moved from its rest position, the support's motion taken
    /// out [mm].
    pub fn shift_from_rest(&self, e: &Embedded) -> Vector3<f64> {
        let mesh = self.gel.mesh();
        self.gel_point(e) - e.position(&mesh.nodes, &mesh.tets) - self.support_offset
    }

    /// How far the entry point (the material point the needle punctured; the planned entry
    /// before) has moved from its rest position, the support's motion taken out [mm].
    pub fn entry_shift(&self) -> Vector3<f64> {
        self.shift_from_rest(&self.entry)
    }

    /// Insertion depth: tip distance past the entry point, 0 before puncture [mm].
    pub fn depth(&self) -> f64 {
        if self.punctured {
            (self.tip() - self.entry_point()).norm()
        } else {
            0.0
        }
    }

    /// Largest lateral violation of the sliding points (distance across the shaft) [mm].
    pub fn sliding_residual(&self) -> f64 {
        let nodes = self.needle.positions();
        self.sliding
            .iter()
            .map(|s| {
                let g = self.gel_point(&s.at);
                let (e, f) = closest_on_polyline(nodes, &g);
                let p = nodes[e] * (1.0 - f) + nodes[e + 1] * f;
                // Lateral: across the segment's axis. A point the tip is being withdrawn past
                // (kept until it is a margin beyond the tip) is measured against the shaft's
                // line, not against the tip itself.
                let t = (nodes[e + 1] - nodes[e]).normalize();
                let d = g - p;
                (d - t * d.dot(&t)).norm()
            })
            .fold(0.0, f64::max)
    }

    /// The inserted part of the needle's centre line: each segment `k` (nodes `k`, `k + 1`)
    /// clipped to the needle within `depth` of arc length from the tip, as `(k, f0)`: the part
    /// from fraction `f0` to 1. Empty before puncture.
    pub fn inserted_segments(&self) -> Vec<(usize, f64)> {
        let nodes = self.needle.positions();
        let depth = self.depth();
        if !self.punctured || depth <= 0.0 {
            return Vec::new();
        }
        let mut arc = vec![0.0; nodes.len()];
        for k in (0..nodes.len() - 1).rev() {
            arc[k] = arc[k + 1] + (nodes[k + 1] - nodes[k]).norm();
        }
        (0..nodes.len() - 1)
            .filter(|&k| arc[k + 1] < depth)
            .map(|k| {
                let f0 = if arc[k] > depth {
                    (arc[k] - depth) / (arc[k] - arc[k + 1])
                } else {
                    0.0
                };
                (k, f0)
            })
            .collect()
    }

    /// The current vertices of a mesh obstacle [mm].
    pub fn obstacle_vertices(&self, vertices: &[Embedded]) -> Vec<Vector3<f64>> {
        vertices.iter().map(|e| self.gel_point(e)).collect()
    }

    /// The signed clearance of the inserted needle to a mesh obstacle at its current (deformed)
    /// vertices, with its closest pair ([`crate::proximity::ClosedSurface::clearance`], the
    /// obstacle's `surface` updated to the vertices); `segment` and `fraction` are the needle's
    /// (segment `k` between nodes `k` and `k + 1`). `None` when nothing is inserted.
    pub fn mesh_clearance(
        &self,
        vertices: &[Embedded],
        surface: &DeformingSurface,
    ) -> Option<SurfaceClearance> {
        let inserted = self.inserted_segments();
        if inserted.is_empty() {
            return None;
        }
        let nodes = self.needle.positions();
        let segments: Vec<_> = inserted
            .iter()
            .map(|&(k, f0)| (nodes[k] + f0 * (nodes[k + 1] - nodes[k]), nodes[k + 1]))
            .collect();
        let mut c = surface.clearance(&self.obstacle_vertices(vertices), &segments)?;
        // Back to the needle's segment and fraction.
        let (k, f0) = inserted[c.segment];
        c.segment = k;
        c.fraction = f0 + c.fraction * (1.0 - f0);
        Some(c)
    }

    /// Clearance of the inserted needle to each deformed obstacle surface (negative: hit) [mm].
    ///
    /// The inserted part is the needle within `depth` of arc length from the tip; before
    /// puncture nothing is inserted and every clearance is `+∞`. A sphere: the distance of
    /// its centre to the centre line less its radius; a mesh: [`Self::mesh_clearance`].
    pub fn clearances(&self) -> Vec<f64> {
        let nodes = self.needle.positions();
        let depth = self.depth();
        // Arc length from the tip to each node.
        let mut arc = vec![0.0; nodes.len()];
        for k in (0..nodes.len() - 1).rev() {
            arc[k] = arc[k + 1] + (nodes[k + 1] - nodes[k]).norm();
        }
        self.obstacles
            .iter()
            .map(|o| match o {
                Obstacle::Sphere { centre, radius } => {
                    let c = self.gel_point(centre);
                    let mut best = f64::INFINITY;
                    for k in 0..nodes.len() - 1 {
                        if self.punctured && arc[k + 1] < depth {
                            // Clip the segment to the inserted part.
                            let f = if arc[k] > depth {
                                (arc[k] - depth) / (arc[k] - arc[k + 1])
                            } else {
                                0.0
                            };
                            let a = nodes[k] + f * (nodes[k + 1] - nodes[k]);
                            best = best.min(distance_point_segment(&c, &a, &nodes[k + 1]));
                        }
                    }
                    best - radius
                }
                Obstacle::Mesh {
                    vertices, surface, ..
                } => self
                    .mesh_clearance(vertices, surface)
                    .map_or(f64::INFINITY, |c| c.value),
            })
            .collect()
    }
}
