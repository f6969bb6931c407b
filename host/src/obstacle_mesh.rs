//! Obstacles given as closed surface meshes: reading STL (binary or ASCII), Wavefront OBJ and
//! Gmsh `.msh` files (the triangles of one physical surface group, through the gel mesh's Gmsh
//! reader, [`crate::mesh::read_gmsh_surface`]), placing them (`scale`, then `translation`), and checking that the surface is closed
//! and consistently oriented, so that inside and outside are well defined. Outward orientation
//! is taken from the enclosed volume: a surface whose triangles all face inwards is flipped.

// Units are written in brackets ([mm]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use nalgebra::Vector3;
use std::collections::HashMap;
use std::path::Path;

/// Largest obstacle mesh file read [bytes].
pub const MAX_OBSTACLE_MESH_BYTES: u64 = 64 << 20;

/// Most triangles of one obstacle mesh.
pub const MAX_OBSTACLE_TRIANGLES: usize = 200_000;

/// A closed, outward-oriented triangulated surface [mm].
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMesh {
    /// Vertices (duplicates merged).
    pub vertices: Vec<Vector3<f64>>,
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: Vec<[usize; 3]>,
    /// The Gmsh node tag of each vertex (read from a `.msh` file), for messages.
    pub node_tags: Option<Vec<u64>>,
}

/// How a surface's triangles and vertices are named in messages: by their index (`triangle 3`,
/// `vertex 7`), or by their tags in a Gmsh file (`gmsh element 12`, `gmsh node 9`).
pub struct Names<'a> {
    /// The name of triangle `k` (in the input's order).
    pub triangle: &'a dyn Fn(usize) -> String,
    /// The name of vertex `i` (in the input's order).
    pub vertex: &'a dyn Fn(usize) -> String,
}

impl Names<'_> {
    /// `triangle k`, `vertex i`.
    pub const INDICES: Names<'static> = Names {
        triangle: &|k| format!("triangle {k}"),
        vertex: &|i| format!("vertex {i}"),
    };
}

impl SurfaceMesh {
    /// Volume enclosed by the surface (positive when it is oriented outwards) [mm³].
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i]);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    /// Builds a surface from vertices and triangles: merges vertices of identical coordinates,
    /// drops nothing, checks that every edge is shared by exactly two triangles traversing it
    /// in opposite directions (closed and consistently oriented), that no triangle is
    /// degenerate, and orients it outwards.
    ///
    /// # Errors
    /// The reason, in words.
    pub fn closed(vertices: Vec<Vector3<f64>>, triangles: Vec<[usize; 3]>) -> Result<Self, String> {
        Self::closed_named(vertices, triangles, &Names::INDICES)
    }

    /// [`Self::closed`], the triangles and vertices named in messages by `names`.
    ///
    /// # Errors
    /// The reason, in words.
    pub fn closed_named(
        vertices: Vec<Vector3<f64>>,
        triangles: Vec<[usize; 3]>,
        names: &Names<'_>,
    ) -> Result<Self, String> {
        Self::closed_merged(vertices, triangles, names).map(|(m, _)| m)
    }

    /// [`Self::closed_named`], and for each vertex of the surface the input vertex it was
    /// merged from first.
    fn closed_merged(
        vertices: Vec<Vector3<f64>>,
        triangles: Vec<[usize; 3]>,
        names: &Names<'_>,
    ) -> Result<(Self, Vec<usize>), String> {
        if triangles.is_empty() {
            return Err("the file holds no triangle".into());
        }
        if triangles.len() > MAX_OBSTACLE_TRIANGLES {
            return Err(format!(
                "{} triangles, more than the limit of {MAX_OBSTACLE_TRIANGLES}",
                triangles.len()
            ));
        }
        if let Some(v) = vertices.iter().find(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(format!("a vertex is not finite: {v:?}"));
        }
        // Merge vertices with identical coordinates.
        let mut index: HashMap<[u64; 3], usize> = HashMap::new();
        let mut merged = Vec::new();
        // The first input vertex of each merged vertex (its name in messages).
        let mut first = Vec::new();
        let mut map = Vec::with_capacity(vertices.len());
        for (i, v) in vertices.iter().enumerate() {
            // +0.0 and −0.0 are the same point.
            let key = [v.x, v.y, v.z].map(|c| (c + 0.0).to_bits());
            let k = *index.entry(key).or_insert_with(|| {
                merged.push(*v);
                first.push(i);
                merged.len() - 1
            });
            map.push(k);
        }
        let tri = |k: usize| (names.triangle)(k);
        let vtx = |m: usize| (names.vertex)(first[m]);
        let mut tris = Vec::with_capacity(triangles.len());
        for (k, t) in triangles.iter().enumerate() {
            if let Some(i) = t.iter().find(|&&i| i >= vertices.len()) {
                return Err(format!(
                    "{} names vertex {i}, but there are {} vertices",
                    tri(k),
                    vertices.len()
                ));
            }
            let t = t.map(|i| map[i]);
            let [a, b, c] = t.map(|i| merged[i]);
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || (b - a).cross(&(c - a)).norm() == 0.0
            {
                return Err(format!("{} is degenerate (zero area)", tri(k)));
            }
            tris.push(t);
        }
        // Each directed edge once, and its reverse once.
        let mut directed: HashMap<(usize, usize), usize> = HashMap::new();
        for (k, t) in tris.iter().enumerate() {
            for e in 0..3 {
                let (i, j) = (t[e], t[(e + 1) % 3]);
                if let Some(other) = directed.insert((i, j), k) {
                    return Err(format!(
                        "not a closed, consistently oriented surface: {} and {} traverse the \
                         edge from {} to {} in the same direction (or it has more than two \
                         triangles)",
                        tri(other),
                        tri(k),
                        vtx(i),
                        vtx(j)
                    ));
                }
            }
        }
        // In triangle order, so that the hole named is always the same.
        for (k, t) in tris.iter().enumerate() {
            for e in 0..3 {
                let (i, j) = (t[e], t[(e + 1) % 3]);
                if !directed.contains_key(&(j, i)) {
                    return Err(format!(
                        "not a closed surface: the edge between {} and {} borders only one \
                         triangle, {} (a hole)",
                        vtx(i),
                        vtx(j),
                        tri(k)
                    ));
                }
            }
        }
        let mut mesh = Self {
            vertices: merged,
            triangles: tris,
            node_tags: None,
        };
        let v = mesh.volume();
        if v == 0.0 || !v.is_finite() {
            return Err("the surface encloses no volume".into());
        }
        if v < 0.0 {
            for t in &mut mesh.triangles {
                t.swap(1, 2);
            }
        }
        Ok((mesh, first))
    }

    /// The surface scaled by `scale` about the file's origin, then moved by `translation`.
    pub fn placed(mut self, scale: f64, translation: &Vector3<f64>) -> Self {
        for v in &mut self.vertices {
            *v = *v * scale + translation;
        }
        self
    }
}

/// The unit sphere as an icosahedron whose faces are split `subdivisions` times into four,
/// the new vertices pushed onto the sphere (20·4ⁿ triangles, every vertex at radius 1): a
/// triangulated sphere for tests and example scenes.
pub fn icosphere(subdivisions: usize) -> SurfaceMesh {
    let (vertices, triangles) = crate::output::vtu::unit_sphere(subdivisions);
    SurfaceMesh {
        vertices,
        triangles,
        node_tags: None,
    }
}

/// An axis-aligned box from `min` to `max` as 12 outward triangles.
pub fn box_surface(min: &Vector3<f64>, max: &Vector3<f64>) -> SurfaceMesh {
    let vertices = (0..8)
        .map(|i| {
            Vector3::new(
                if i & 1 == 0 { min.x } else { max.x },
                if i & 2 == 0 { min.y } else { max.y },
                if i & 4 == 0 { min.z } else { max.z },
            )
        })
        .collect();
    // Faces as quads counter-clockwise seen from outside, split along a diagonal.
    let quads = [
        [0, 2, 3, 1], // z = min
        [4, 5, 7, 6], // z = max
        [0, 1, 5, 4], // y = min
        [2, 6, 7, 3], // y = max
        [0, 4, 6, 2], // x = min
        [1, 3, 7, 5], // x = max
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    SurfaceMesh {
        vertices,
        triangles,
        node_tags: None,
    }
}

/// Reads a closed surface mesh: STL (binary or ASCII) by the extension `.stl`, Wavefront OBJ
/// by `.obj` (every object of the file, its faces triangulated as fans), Gmsh by `.msh`
/// (format 2.2 or 4.1, ASCII or binary: the triangles of the physical surface group `group`,
/// or every surface element of a file whose surface elements lie in at most one physical
/// group; see [`crate::mesh::read_gmsh_surface`]). `group` is refused for the other formats.
/// Errors of a Gmsh file name its elements and nodes by their tags in the file.
///
/// # Errors
/// The reason, in words (the caller names the file and field).
pub fn read_surface_mesh(
    path: &Path,
    group: Option<&crate::mesh::PhysicalGroup>,
) -> Result<SurfaceMesh, SurfaceMeshError> {
    read(path, group).map_err(|(reason, in_group)| SurfaceMeshError { reason, in_group })
}

/// Why a surface mesh file cannot be used.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SurfaceMeshError {
    /// The reason, in words.
    pub reason: String,
    /// Whether the physical group chosen is at fault (not in the file, or given for a file
    /// without groups), rather than the file.
    pub in_group: bool,
}

impl std::fmt::Display for SurfaceMeshError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.reason)
    }
}

fn read(
    path: &Path,
    group: Option<&crate::mesh::PhysicalGroup>,
) -> Result<SurfaceMesh, (String, bool)> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("stl" | "obj" | "msh")) {
        return Err((
            "unknown mesh format: the file name must end in `.stl`, `.obj` or `.msh`".to_owned(),
            false,
        ));
    }
    if ext.as_deref() == Some("msh") {
        let s = crate::mesh::read_gmsh_surface(path, group).map_err(|e| match e {
            crate::mesh::GmshError::Io(e) => (format!("cannot read: {e}"), false),
            e @ crate::mesh::GmshError::UnknownGroup { .. } => (e.to_string(), true),
            e => (e.to_string(), false),
        })?;
        let names = Names {
            triangle: &|k| format!("gmsh element {}", s.element_tags[k]),
            vertex: &|i| format!("gmsh node {}", s.node_tags[i]),
        };
        let (mut mesh, first) =
            SurfaceMesh::closed_merged(s.nodes.clone(), s.triangles.clone(), &names)
                .map_err(|e| (e, false))?;
        mesh.node_tags = Some(first.iter().map(|&i| s.node_tags[i]).collect());
        return Ok(mesh);
    }
    if let Some(g) = group {
        return Err((
            format!("a {g} is chosen, but only a Gmsh `.msh` file has physical groups"),
            true,
        ));
    }
    let bytes = crate::bounded_read::read_bounded(path, MAX_OBSTACLE_MESH_BYTES)
        .map_err(|e| (format!("cannot read: {e}"), false))?;
    let (vertices, triangles) = match ext.as_deref() {
        Some("stl") => {
            let mesh = stl_io::read_stl(&mut std::io::Cursor::new(&bytes))
                .map_err(|e| (format!("not a valid STL file: {e}"), false))?;
            (
                mesh.vertices
                    .iter()
                    .map(|v| Vector3::new(v.0[0].into(), v.0[1].into(), v.0[2].into()))
                    .collect(),
                mesh.faces.iter().map(|f| f.vertices).collect(),
            )
        }
        Some("obj") => {
            let options = tobj::LoadOptions {
                triangulate: true,
                single_index: false,
                ..Default::default()
            };
            let (models, _) = tobj::load_obj_buf(
                &mut std::io::BufReader::new(std::io::Cursor::new(&bytes)),
                &options,
                // Materials are not used: no file besides the mesh is read.
                |_| Err(tobj::LoadError::OpenFileFailed),
            )
            .map_err(|e| (format!("not a valid OBJ file: {e}"), false))?;
            let mut vertices = Vec::new();
            let mut triangles = Vec::new();
            for m in &models {
                let base = vertices.len();
                let p = &m.mesh.positions;
                vertices.extend(
                    p.chunks_exact(3)
                        .map(|c| Vector3::new(c[0].into(), c[1].into(), c[2].into())),
                );
                triangles.extend(m.mesh.indices.chunks_exact(3).map(|t| {
                    [
                        base + t[0] as usize,
                        base + t[1] as usize,
                        base + t[2] as usize,
                    ]
                }));
            }
            (vertices, triangles)
        }
        _ => unreachable!("the extension was checked"),
    };
    SurfaceMesh::closed(vertices, triangles).map_err(|e| (e, false))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
        (
            vec![Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
    }

    #[test]
    fn a_closed_surface_is_accepted_and_oriented_outwards() {
        let (v, t) = tetra();
        let m = SurfaceMesh::closed(v.clone(), t.clone()).unwrap();
        assert!((m.volume() - 1.0 / 6.0).abs() < 1e-15);
        // Inward-facing: flipped.
        let inward: Vec<_> = t.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let m = SurfaceMesh::closed(v, inward).unwrap();
        assert!((m.volume() - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn holes_inconsistent_orientation_and_degenerate_triangles_are_refused() {
        let (v, mut t) = tetra();
        let e = SurfaceMesh::closed(v.clone(), t[..3].to_vec()).unwrap_err();
        assert!(e.contains("hole"), "{e}");
        t[3] = [1, 3, 2];
        let e = SurfaceMesh::closed(v.clone(), t).unwrap_err();
        assert!(e.contains("same direction"), "{e}");
        let e = SurfaceMesh::closed(v.clone(), vec![[0, 1, 1]]).unwrap_err();
        assert!(e.contains("degenerate"), "{e}");
        let e = SurfaceMesh::closed(v, vec![[0, 1, 7]]).unwrap_err();
        assert!(e.contains("names vertex 7"), "{e}");
    }

    #[test]
    fn the_generated_sphere_and_box_are_closed_and_outward() {
        for n in 0..4 {
            let m = icosphere(n);
            assert_eq!(m.triangles.len(), 20 << (2 * n));
            assert!(m.vertices.iter().all(|v| (v.norm() - 1.0).abs() < 1e-15));
            let c = SurfaceMesh::closed(m.vertices.clone(), m.triangles.clone()).unwrap();
            // Outward already (not flipped), and the volume tends to 4π/3 from below.
            assert_eq!(c.triangles, m.triangles);
            assert!(m.volume() > 0.0 && m.volume() < 4.0 * std::f64::consts::PI / 3.0);
        }
        let b = box_surface(
            &Vector3::new(-1.0, -2.0, -3.0),
            &Vector3::new(1.0, 2.0, 3.0),
        );
        let c = SurfaceMesh::closed(b.vertices.clone(), b.triangles.clone()).unwrap();
        assert_eq!(c.triangles, b.triangles);
        assert!((b.volume() - 48.0).abs() < 1e-12);
    }

    #[test]
    fn stl_ascii_binary_and_obj_read_the_same_surface() {
        let (v, t) = tetra();
        let dir = std::env::temp_dir().join(format!("needle-obstacle-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // Binary STL (written by stl_io), unindexed: the reader merges the shared vertices.
        let tris: Vec<stl_io::Triangle> = t
            .iter()
            .map(|t| stl_io::Triangle {
                normal: stl_io::Normal::new([0.0; 3]),
                vertices: t
                    .map(|i| stl_io::Vertex::new([v[i].x as f32, v[i].y as f32, v[i].z as f32])),
            })
            .collect();
        let bin = dir.join("t.stl");
        stl_io::write_stl(&mut std::fs::File::create(&bin).unwrap(), tris.iter()).unwrap();
        // ASCII STL, by hand.
        let mut ascii = String::from("solid t\n");
        for t in &t {
            ascii.push_str(" facet normal 0 0 0\n  outer loop\n");
            for &i in t {
                ascii.push_str(&format!("   vertex {} {} {}\n", v[i].x, v[i].y, v[i].z));
            }
            ascii.push_str("  endloop\n endfacet\n");
        }
        ascii.push_str("endsolid t\n");
        let asc = dir.join("a.STL");
        std::fs::write(&asc, ascii).unwrap();
        // OBJ (1-based indices), one face a quad-free triangle each.
        let mut obj = String::new();
        for p in &v {
            obj.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
        for t in &t {
            obj.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
        }
        let objf = dir.join("t.obj");
        std::fs::write(&objf, obj).unwrap();
        for f in [&bin, &asc, &objf] {
            let m = read_surface_mesh(f, None).unwrap();
            assert_eq!((m.vertices.len(), m.triangles.len()), (4, 4), "{f:?}");
            assert!((m.volume() - 1.0 / 6.0).abs() < 1e-7, "{f:?}");
        }
        let placed = read_surface_mesh(&objf, None)
            .unwrap()
            .placed(2.0, &Vector3::new(1.0, 0.0, 0.0));
        assert!((placed.volume() - 8.0 / 6.0).abs() < 1e-12);
        assert!(placed.vertices.contains(&Vector3::new(3.0, 0.0, 0.0)));
        // Unknown extension, missing file, garbage.
        let e = read_surface_mesh(&dir.join("t.ply"), None)
            .unwrap_err()
            .reason;
        assert!(e.contains("unknown mesh format"), "{e}");
        let e = read_surface_mesh(&dir.join("missing.stl"), None)
            .unwrap_err()
            .reason;
        assert!(e.contains("cannot read"), "{e}");
        let bad = dir.join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
        assert!(read_surface_mesh(&bad, None).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
