//! Tetrahedral meshes of the gel: the box generator, Gmsh import/export, validation, surface
//! extraction and the small topology helpers the later stages (point location, proximity) use.
//!
//! A mesh is plain data: node positions (world frame, mm) and 4-node elements, 0-based,
//! positively oriented (`det[x1 − x0, x2 − x0, x3 − x0] > 0`).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

mod generate;
mod gmsh;
mod gmsh2;
mod validate;
mod vtk;

pub use generate::{BoxDivisions, box_divisions_for_target, box_mesh, box_mesh_with_divisions};
pub use gmsh::{
    GmshError, GmshSurface, PhysicalGroup, read_gmsh, read_gmsh_bytes, read_gmsh_surface,
    read_gmsh_surface_bytes, write_gmsh_ascii, write_gmsh_binary,
};
pub use validate::{MeshError, degenerate_ratio_threshold};
pub use vtk::{VtkError, read_legacy_vtk_bytes, read_vtk, read_vtu_bytes};

/// Why a mesh file could not be read (by its format).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshFileError {
    /// A Gmsh `.msh` file.
    #[error(transparent)]
    Gmsh(#[from] GmshError),
    /// A VTK `.vtu` or legacy `.vtk` file.
    #[error(transparent)]
    Vtk(#[from] VtkError),
}

/// Reads a tetrahedral mesh by the file's extension: `.vtu` and `.vtk` through [`read_vtk`],
/// anything else as Gmsh ([`read_gmsh`]).
///
/// # Errors
/// [`MeshFileError`] naming the element or cell at fault and the reason.
pub fn read_mesh(path: impl AsRef<std::path::Path>) -> Result<TetMesh, MeshFileError> {
    let path = path.as_ref();
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("vtu") || e.eq_ignore_ascii_case("vtk") => {
            Ok(read_vtk(path)?)
        }
        _ => Ok(read_gmsh(path)?),
    }
}

use nalgebra::Vector3;

/// Local node triples of the four faces of a positively oriented tetrahedron, each ordered so
/// that its normal `(b − a) × (c − a)` points out of the element; face `i` is opposite node `i`.
pub const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// A linear tetrahedral mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct TetMesh {
    /// Node positions in the world frame [mm].
    pub nodes: Vec<Vector3<f64>>,
    /// Elements as four 0-based node indices, positively oriented.
    pub tets: Vec<[usize; 4]>,
    /// Region tag of each element (same length as `tets`): the Gmsh physical volume tag or the
    /// `.vtu` / `.vtk` cell value `region`; 0 where the file gives none (and for generated boxes).
    /// A scene maps tags to materials (`[[gel.regions]]`).
    pub regions: Vec<i32>,
}

/// Node-to-element adjacency in compressed form: the elements around node `i` are
/// `elements[offsets[i]..offsets[i + 1]]`, in increasing order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeElements {
    /// Start of each node's list in `elements`; length `node count + 1`.
    pub offsets: Vec<usize>,
    /// Element indices, grouped by node.
    pub elements: Vec<usize>,
}

impl NodeElements {
    /// The elements that use node `node`.
    pub fn of(&self, node: usize) -> &[usize] {
        &self.elements[self.offsets[node]..self.offsets[node + 1]]
    }
}

/// Signed volume of the tetrahedron `(a, b, c, d)` [mm³]; positive when positively oriented.
pub fn signed_volume(
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
    d: &Vector3<f64>,
) -> f64 {
    (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0
}

impl TetMesh {
    /// Builds a mesh and validates it (see [`TetMesh::validate`]).
    ///
    /// # Errors
    /// The first [`MeshError`] found, naming the element or node at fault.
    pub fn try_new(nodes: Vec<Vector3<f64>>, tets: Vec<[usize; 4]>) -> Result<Self, MeshError> {
        let regions = vec![0; tets.len()];
        Self::try_new_with_regions(nodes, tets, regions)
    }

    /// Builds a mesh whose element `e` lies in region `regions[e]`, and validates it.
    ///
    /// # Errors
    /// The first [`MeshError`] found (among them [`MeshError::RegionCount`]).
    pub fn try_new_with_regions(
        nodes: Vec<Vector3<f64>>,
        tets: Vec<[usize; 4]>,
        regions: Vec<i32>,
    ) -> Result<Self, MeshError> {
        let mesh = Self {
            nodes,
            tets,
            regions,
        };
        mesh.validate()?;
        Ok(mesh)
    }

    /// The distinct region tags of the elements, sorted.
    pub fn region_tags(&self) -> Vec<i32> {
        let mut tags = self.regions.clone();
        tags.sort_unstable();
        tags.dedup();
        tags
    }

    /// The nodes' bounding box `(min, max)` [mm] (infinite, inverted, for a mesh without nodes).
    pub fn bounds(&self) -> (Vector3<f64>, Vector3<f64>) {
        self.nodes.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        )
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Number of tetrahedra.
    pub fn tet_count(&self) -> usize {
        self.tets.len()
    }

    /// Signed volume of element `e` [mm³].
    pub fn tet_volume(&self, e: usize) -> f64 {
        let [a, b, c, d] = self.tets[e];
        signed_volume(
            &self.nodes[a],
            &self.nodes[b],
            &self.nodes[c],
            &self.nodes[d],
        )
    }

    /// Sum of the element volumes [mm³].
    pub fn total_volume(&self) -> f64 {
        (0..self.tets.len()).map(|e| self.tet_volume(e)).sum()
    }

    /// Axis-aligned bounding box of element `e`: `(min, max)` corners [mm].
    pub fn element_bbox(&self, e: usize) -> (Vector3<f64>, Vector3<f64>) {
        let t = self.tets[e];
        let mut lo = self.nodes[t[0]];
        let mut hi = lo;
        for &n in &t[1..] {
            lo = lo.inf(&self.nodes[n]);
            hi = hi.sup(&self.nodes[n]);
        }
        (lo, hi)
    }

    /// Axis-aligned bounding box of all nodes: `(min, max)` [mm]; `None` for an empty mesh.
    pub fn bbox(&self) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let first = *self.nodes.first()?;
        Some(
            self.nodes
                .iter()
                .fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))),
        )
    }

    /// Node-to-element adjacency (for point location and load distribution).
    pub fn node_elements(&self) -> NodeElements {
        let n = self.nodes.len();
        let mut offsets = vec![0usize; n + 1];
        for t in &self.tets {
            for &v in t {
                offsets[v + 1] += 1;
            }
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut elements = vec![0usize; offsets[n]];
        for (e, t) in self.tets.iter().enumerate() {
            for &v in t {
                elements[fill[v]] = e;
                fill[v] += 1;
            }
        }
        NodeElements { offsets, elements }
    }

    /// Boundary faces (faces used by exactly one element), oriented with outward normals
    /// (counter-clockwise seen from outside), sorted for determinism.
    pub fn surface_triangles(&self) -> Vec<[usize; 3]> {
        use std::collections::HashMap;
        let mut faces: HashMap<[usize; 3], (u32, [usize; 3])> =
            HashMap::with_capacity(self.tets.len() * 2);
        for t in &self.tets {
            for f in TET_FACES {
                let tri = [t[f[0]], t[f[1]], t[f[2]]];
                let mut key = tri;
                key.sort_unstable();
                faces
                    .entry(key)
                    .and_modify(|e| e.0 += 1)
                    .or_insert((1, tri));
            }
        }
        let mut out: Vec<[usize; 3]> = faces
            .into_values()
            .filter(|(c, _)| *c == 1)
            .map(|(_, tri)| rotate_min_first(tri))
            .collect();
        out.sort_unstable();
        out
    }

    /// Nodes lying on the boundary surface, sorted.
    pub fn surface_nodes(&self) -> Vec<usize> {
        let mut on = vec![false; self.nodes.len()];
        for tri in self.surface_triangles() {
            for v in tri {
                on[v] = true;
            }
        }
        (0..on.len()).filter(|&i| on[i]).collect()
    }

    /// Nodes whose coordinate `axis` (0 = x, 1 = y, 2 = z) is within `tol` of `value` [mm]
    /// (e.g. the bottom face `z = 0` to clamp).
    pub fn nodes_on_plane(&self, axis: usize, value: f64, tol: f64) -> Vec<usize> {
        (0..self.nodes.len())
            .filter(|&i| (self.nodes[i][axis] - value).abs() <= tol)
            .collect()
    }
}

/// A mesh from a file's nodes and tetrahedra (indices into `nodes`, in file order): nodes that
/// no tetrahedron uses dropped and the rest renumbered in file order, elements of negative
/// orientation reordered, then validated. Element indices in the error are the tetrahedra's
/// order in `tets`.
pub(crate) fn compact_oriented(
    nodes: Vec<Vector3<f64>>,
    tets: Vec<[usize; 4]>,
    regions: Vec<i32>,
) -> Result<TetMesh, MeshError> {
    let mut new_index = vec![usize::MAX; nodes.len()];
    for (element, t) in tets.iter().enumerate() {
        for &v in t {
            let Some(slot) = new_index.get_mut(v) else {
                return Err(MeshError::NodeIndexOutOfRange {
                    element,
                    node: v,
                    node_count: nodes.len(),
                });
            };
            *slot = 0;
        }
    }
    let mut out_nodes = Vec::new();
    for (i, p) in nodes.into_iter().enumerate() {
        if new_index[i] == 0 {
            new_index[i] = out_nodes.len();
            out_nodes.push(p);
        }
    }
    let tets = tets
        .into_iter()
        .map(|t| {
            let mut t = t.map(|v| new_index[v]);
            let [a, b, c, d] = t.map(|v| &out_nodes[v]);
            if signed_volume(a, b, c, d) < 0.0 {
                t.swap(2, 3);
            }
            t
        })
        .collect();
    TetMesh::try_new_with_regions(out_nodes, tets, regions)
}

/// Cyclic rotation of a triangle so that its smallest index comes first (orientation kept).
fn rotate_min_first(t: [usize; 3]) -> [usize; 3] {
    if t[0] <= t[1] && t[0] <= t[2] {
        t
    } else if t[1] <= t[2] {
        [t[1], t[2], t[0]]
    } else {
        [t[2], t[0], t[1]]
    }
}
