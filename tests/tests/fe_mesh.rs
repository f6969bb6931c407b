//! Meshes: the box generator, Gmsh 4.1 round trips (ASCII and binary), surface extraction and
//! the validation errors.

use nalgebra::Vector3;
use needle_host::mesh::{
    BoxDivisions, GmshError, MeshError, TetMesh, box_divisions_for_target, box_mesh,
    box_mesh_with_divisions, read_gmsh, read_gmsh_bytes, write_gmsh_ascii, write_gmsh_binary,
};

fn gel_box() -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(260.0, -30.0, 0.0),
        Vector3::new(340.0, 30.0, 60.0),
    )
}

#[test]
fn box_mesher_hits_the_target_node_counts_with_near_cubic_cells() {
    let (lo, hi) = gel_box();
    for target in [600, 1100, 1500, 1800, 5000, 20_000] {
        let d = box_divisions_for_target(lo, hi, target);
        let n = d.node_count();
        let rel = (n as f64 - target as f64).abs() / target as f64;
        let cells = [80.0 / d.nx as f64, 60.0 / d.ny as f64, 60.0 / d.nz as f64];
        let aspect = cells.iter().cloned().fold(0.0, f64::max)
            / cells.iter().cloned().fold(f64::INFINITY, f64::min);
        println!(
            "target {target}: {}×{}×{} cells, {n} nodes ({:+.1} %), aspect {aspect:.3}",
            d.nx,
            d.ny,
            d.nz,
            100.0 * (n as f64 / target as f64 - 1.0)
        );
        assert!(rel < 0.12, "target {target}: {n} nodes");
        assert!(aspect < 1.35, "target {target}: cell aspect {aspect}");
    }
}

#[test]
fn box_mesh_is_valid_conforming_and_fills_the_box() {
    let (lo, hi) = gel_box();
    let m = box_mesh(lo, hi, 1500);
    m.validate().unwrap();
    assert!((m.total_volume() - 80.0 * 60.0 * 60.0).abs() < 1e-6);
    assert!((0..m.tet_count()).all(|e| m.tet_volume(e) > 0.0));
    // Conforming: the boundary is exactly the box surface (area check) and closed (Euler).
    let surf = m.surface_triangles();
    let area: f64 = surf
        .iter()
        .map(|t| {
            0.5 * (m.nodes[t[1]] - m.nodes[t[0]])
                .cross(&(m.nodes[t[2]] - m.nodes[t[0]]))
                .norm()
        })
        .sum();
    assert!(
        (area - 2.0 * (80.0 * 60.0 + 80.0 * 60.0 + 60.0 * 60.0)).abs() < 1e-6,
        "surface area {area}"
    );
    // Outward orientation: the divergence theorem gives the volume from the oriented surface.
    let vol: f64 = surf
        .iter()
        .map(|t| {
            m.nodes[t[0]]
                .dot(&(m.nodes[t[1]] - m.nodes[t[0]]).cross(&(m.nodes[t[2]] - m.nodes[t[0]])))
                / 6.0
        })
        .sum();
    assert!(
        (vol - m.total_volume()).abs() < 1e-6 * vol,
        "oriented surface volume {vol}"
    );
    let bb = m.bbox().unwrap();
    assert_eq!((bb.0, bb.1), (lo, hi));
    // Node-to-element adjacency is consistent with the elements.
    let ne = m.node_elements();
    for (e, t) in m.tets.iter().enumerate() {
        for &v in t {
            assert!(ne.of(v).contains(&e));
        }
    }
    let (blo, bhi) = m.element_bbox(0);
    assert!(
        m.tets[0]
            .iter()
            .all(|&v| (0..3).all(|k| m.nodes[v][k] >= blo[k] && m.nodes[v][k] <= bhi[k]))
    );
    assert_eq!(
        m.surface_nodes().len(),
        m.node_count() - {
            let d = box_divisions_for_target(lo, hi, 1500);
            (d.nx - 1) * (d.ny - 1) * (d.nz - 1)
        }
    );
}

fn tmp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("needle-fe-mesh-{}-{name}", std::process::id()))
}

#[test]
fn gmsh_ascii_round_trip_gives_the_same_mesh() {
    let (lo, hi) = gel_box();
    let m = box_mesh_with_divisions(
        lo,
        hi,
        BoxDivisions {
            nx: 4,
            ny: 3,
            nz: 3,
        },
    );
    let path = tmp("ascii.msh");
    write_gmsh_ascii(&m, std::fs::File::create(&path).unwrap()).unwrap();
    let back = read_gmsh(&path).unwrap();
    std::fs::remove_file(&path).ok();
    assert_eq!(back, m);
}

#[test]
fn gmsh_binary_round_trip_gives_the_same_mesh() {
    let (lo, hi) = gel_box();
    let mut m = box_mesh_with_divisions(
        lo,
        hi,
        BoxDivisions {
            nx: 3,
            ny: 4,
            nz: 2,
        },
    );
    m.nodes[0].x += 1.0 / 3.0; // a coordinate with a non-terminating expansion
    let mut bytes = Vec::new();
    write_gmsh_binary(&m, &mut bytes).unwrap();
    assert!(bytes.starts_with(b"$MeshFormat\n4.1 1 8\n"));
    let back = read_gmsh_bytes(&bytes).unwrap();
    assert_eq!(back, m);
}

/// A hand-written Gmsh 4.1 file with sparse node tags, a point, a line and a triangle block
/// (ignored), and a tetrahedron with negative orientation (reordered).
#[test]
fn gmsh_reader_ignores_other_elements_and_handles_sparse_tags() {
    let text = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n2 5 10 50\n0 1 0 1\n50\n9 9 9\n3 1 0 4\n10\n20\n30\n40\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n$Elements\n3 3 1 4\n0 1 15 1\n1 50\n2 1 2 1\n2 10 20 30\n3 1 4 1\n4 10 30 20 40\n$EndElements\n";
    let m = read_gmsh_bytes(text.as_bytes()).unwrap();
    assert_eq!(m.node_count(), 4, "the unused point node is dropped");
    assert_eq!(m.tet_count(), 1);
    assert!(m.tet_volume(0) > 0.0);
    assert_eq!(m.nodes[3], Vector3::new(0.0, 0.0, 1.0));
    assert_eq!(m.surface_triangles().len(), 4);
}

#[test]
fn gmsh_errors_are_reported() {
    assert!(matches!(
        read_gmsh_bytes(b"not a mesh"),
        Err(GmshError::Parse(_))
    ));
    let no_tets = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 3 1 3\n2 1 0 3\n1\n2\n3\n0 0 0\n1 0 0\n0 1 0\n$EndNodes\n$Elements\n1 1 1 1\n2 1 2 1\n1 1 2 3\n$EndElements\n";
    assert!(matches!(
        read_gmsh_bytes(no_tets.as_bytes()),
        Err(GmshError::NoTetrahedra)
    ));
    let bad_tag = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n$Elements\n1 1 1 1\n3 1 4 1\n1 1 2 3 7\n$EndElements\n";
    let err = read_gmsh_bytes(bad_tag.as_bytes()).unwrap_err();
    assert!(
        matches!(
            err,
            GmshError::UnknownNodeTag {
                element_tag: 1,
                node_tag: 7
            }
        ),
        "{err}"
    );
    assert!(matches!(
        read_gmsh(tmp("does-not-exist.msh")),
        Err(GmshError::Io(_))
    ));
}

fn unit_tet() -> (Vec<Vector3<f64>>, Vec<[usize; 4]>) {
    (
        vec![Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()],
        vec![[0, 1, 2, 3]],
    )
}

#[test]
fn bad_meshes_are_rejected_with_the_expected_error() {
    let (n, t) = unit_tet();
    assert!(TetMesh::try_new(n.clone(), t.clone()).is_ok());
    assert_eq!(TetMesh::try_new(n.clone(), vec![]), Err(MeshError::Empty));
    // Inverted.
    let e = TetMesh::try_new(n.clone(), vec![[0, 2, 1, 3]]).unwrap_err();
    assert!(
        matches!(e, MeshError::InvertedElement { element: 0, volume } if volume < 0.0),
        "{e}"
    );
    // Degenerate: flat, and a repeated node.
    let mut flat = n.clone();
    flat[3] = Vector3::new(0.3, 0.3, 1e-9);
    assert!(matches!(
        TetMesh::try_new(flat, t.clone()),
        Err(MeshError::DegenerateElement { element: 0, .. })
    ));
    assert!(matches!(
        TetMesh::try_new(n.clone(), vec![[0, 1, 1, 3]]),
        Err(MeshError::DegenerateElement { element: 0, .. })
    ));
    // Duplicate (same node set, other order).
    let mut n2 = n.clone();
    n2.push(Vector3::new(1.0, 1.0, 1.0));
    let e =
        TetMesh::try_new(n2.clone(), vec![[0, 1, 2, 3], [1, 2, 3, 4], [0, 2, 3, 1]]).unwrap_err();
    assert_eq!(
        e,
        MeshError::DuplicateElement {
            element: 2,
            first: 0
        }
    );
    // Out of range.
    let e = TetMesh::try_new(n.clone(), vec![[0, 1, 2, 9]]).unwrap_err();
    assert_eq!(
        e,
        MeshError::NodeIndexOutOfRange {
            element: 0,
            node: 9,
            node_count: 4
        }
    );
    // Unreferenced node.
    assert_eq!(
        TetMesh::try_new(n2, t.clone()),
        Err(MeshError::UnreferencedNode { node: 4 })
    );
    // Non-finite coordinate.
    let mut nan = n;
    nan[2].y = f64::NAN;
    assert_eq!(
        TetMesh::try_new(nan, t),
        Err(MeshError::NonFiniteNode { node: 2 })
    );
    // Messages name the element.
    assert!(
        MeshError::InvertedElement {
            element: 17,
            volume: -1.0
        }
        .to_string()
        .contains("element 17")
    );
}
