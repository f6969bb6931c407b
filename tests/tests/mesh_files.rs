//! Mesh files as other tools write them (`tests/data/mesh/`, written by Gmsh 4.15 through
//! `tools/gen_mesh_fixtures.py`): Gmsh 2.2 and 4.1, ASCII and binary, with physical volume
//! groups as regions; and the errors for what the readers refuse, each naming the element.

use needle_host::mesh::{GmshError, TetMesh, read_gmsh, read_gmsh_bytes};
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/mesh")
        .join(name);
    assert!(p.is_file(), "fixture {} is missing", p.display());
    p
}

const GMSH_FILES: [&str; 4] = [
    "two_regions_v22_ascii.msh",
    "two_regions_v22_binary.msh",
    "two_regions_v41_ascii.msh",
    "two_regions_v41_binary.msh",
];

/// The two-region box: 92 nodes, 251 tetrahedra (Gmsh's count), volume 1000 mm³, region 1
/// below z = 5 and region 2 above it.
fn check_two_regions(name: &str, m: &TetMesh) {
    assert_eq!((m.node_count(), m.tet_count()), (92, 251), "{name}");
    assert!(
        (m.total_volume() - 1000.0).abs() < 1e-9,
        "{name}: volume {}",
        m.total_volume()
    );
    assert_eq!(m.region_tags(), vec![1, 2], "{name}");
    for (e, t) in m.tets.iter().enumerate() {
        let zc = t.iter().map(|&v| m.nodes[v].z).sum::<f64>() / 4.0;
        let expected = if zc < 5.0 { 1 } else { 2 };
        assert_eq!(m.regions[e], expected, "{name}: element {e} at z = {zc}");
    }
}

#[test]
fn gmsh_22_and_41_ascii_and_binary_read_the_same_two_region_mesh() {
    let first = read_gmsh(fixture(GMSH_FILES[0])).expect("read");
    for name in GMSH_FILES {
        let m = read_gmsh(fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        check_two_regions(name, &m);
        assert_eq!(
            m.tets, first.tets,
            "{name}: same elements in the same order"
        );
        assert_eq!(m.regions, first.regions, "{name}");
        for (a, b) in m.nodes.iter().zip(&first.nodes) {
            assert!((a - b).norm() <= 1e-12, "{name}: node {a} against {b}");
        }
    }
}

#[test]
fn our_gmsh_writer_keeps_the_regions() {
    let m = read_gmsh(fixture(GMSH_FILES[2])).expect("read");
    for binary in [false, true] {
        let mut bytes = Vec::new();
        if binary {
            needle_host::mesh::write_gmsh_binary(&m, &mut bytes).expect("write");
        } else {
            needle_host::mesh::write_gmsh_ascii(&m, &mut bytes).expect("write");
        }
        let back = read_gmsh_bytes(&bytes).expect("read back");
        assert_eq!(back, m, "binary {binary}");
    }
}

#[test]
fn a_hexahedral_mesh_is_refused_naming_the_element() {
    let e = read_gmsh(fixture("hexahedra_v41_ascii.msh")).expect_err("hexahedra");
    assert!(matches!(e, GmshError::NotTetrahedral { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("hexahedron") && msg.contains("element"),
        "{msg}"
    );
}

/// A Gmsh 2.2 ASCII text with the given element lines (nodes of a unit tetrahedron and one more).
fn v22(elements: &[&str]) -> String {
    format!(
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n$EndNodes\n$Elements\n{}\n{}\n$EndElements\n",
        elements.len(),
        elements.join("\n")
    )
}

#[test]
fn gmsh_22_errors_name_the_element_and_the_reason() {
    // Two tetrahedra, one reversed (reoriented), tags 7 and 9, physical tags 3 and 4.
    let ok = read_gmsh_bytes(v22(&["7 4 2 3 1 1 2 3 4", "9 4 2 4 1 2 3 4 5"]).as_bytes())
        .expect("valid");
    assert_eq!(ok.regions, vec![3, 4]);
    assert!(
        ok.tets
            .iter()
            .enumerate()
            .all(|(e, _)| ok.tet_volume(e) > 0.0)
    );
    let cases: [(&[&str], &str); 5] = [
        (
            &["7 4 2 3 1 1 2 3 9"],
            "element 7 references unknown node tag 9",
        ),
        (&["7 4 2 3 1 1 2 3 2"], "gmsh element 7 is invalid"),
        (&["7 5 2 3 1 1 2 3 4 5 1 2 3"], "element 7 is a hexahedron"),
        (&["7 4 2 3 1 1 2 3"], "the tags and nodes of element 7"),
        (&["7 99 2 3 1 1 2 3 4"], "element 7 has unknown type 99"),
    ];
    for (lines, expected) in cases {
        let e = read_gmsh_bytes(v22(lines).as_bytes()).expect_err(expected);
        assert!(e.to_string().contains(expected), "{lines:?}: {e}");
    }
    // Triangles and lines are skipped; with no tetrahedron the file is refused.
    let e = read_gmsh_bytes(v22(&["1 2 2 3 1 1 2 3"]).as_bytes()).expect_err("no tets");
    assert!(matches!(e, GmshError::NoTetrahedra), "{e:?}");
}

/// VTK files of the same mesh, written by VTK 9.7.2 and meshio 5.3.5
/// (`tools/gen_vtk_fixtures.py`), with the top face's triangles (skipped) and the cell array
/// `region`.
const VTK_FILES: [&str; 14] = [
    "vtk_ascii.vtu",
    "vtk_binary.vtu",
    "vtk_binary_zlib.vtu",
    "vtk_appended_raw_zlib.vtu",
    "vtk_appended_base64.vtu",
    "vtk_appended_raw_uint64.vtu",
    "meshio_ascii.vtu",
    "meshio_zlib.vtu",
    "vtk_legacy_ascii.vtk",
    "vtk_legacy_binary.vtk",
    "vtk_legacy42_ascii.vtk",
    "vtk_legacy42_binary.vtk",
    "meshio_ascii.vtk",
    "meshio_binary.vtk",
];

#[test]
fn vtu_and_legacy_vtk_of_every_layout_read_the_gmsh_mesh_and_its_regions() {
    let gmsh = read_gmsh(fixture(GMSH_FILES[2])).expect("read");
    for name in VTK_FILES {
        let m =
            needle_host::mesh::read_mesh(fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        check_two_regions(name, &m);
        assert_eq!(m.tets, gmsh.tets, "{name}: same elements");
        assert_eq!(m.regions, gmsh.regions, "{name}");
        // VTK's legacy and meshio's XML ASCII writers keep 11 or 12 significant digits.
        let tol = if name.contains("ascii") { 1e-8 } else { 1e-12 };
        for (a, b) in m.nodes.iter().zip(&gmsh.nodes) {
            assert!((a - b).norm() <= tol, "{name}: node {a} against {b}");
        }
    }
}

#[test]
fn vtk_errors_name_the_cell_and_the_reason() {
    let e = needle_host::mesh::read_mesh(fixture("vtk_hexahedron.vtu")).expect_err("hexahedron");
    assert!(e.to_string().contains("vtk cell 0: a hexahedron"), "{e}");
    let e = needle_host::mesh::read_mesh(fixture("vtk_appended_raw_lz4.vtu")).expect_err("lz4");
    assert!(e.to_string().contains("vtkLZ4DataCompressor"), "{e}");
    let legacy = |cells: &str, types: &str| {
        format!(
            "# vtk DataFile Version 4.2\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\n{cells}\n{types}\n"
        )
    };
    let ok = needle_host::mesh::read_legacy_vtk_bytes(
        legacy("CELLS 2 10\n4 0 1 2 3\n4 1 2 4 3", "CELL_TYPES 2\n10 10").as_bytes(),
    )
    .expect("valid");
    assert_eq!(ok.tet_count(), 2);
    for (cells, types, expected) in [
        (
            "CELLS 2 10\n4 0 1 2 3\n4 1 2 4 9",
            "CELL_TYPES 2\n10 10",
            "vtk cell 1: point index 9 out of range (5 points)",
        ),
        (
            "CELLS 2 10\n4 0 1 2 3\n4 0 1 2 3",
            "CELL_TYPES 2\n10 10",
            "vtk cell 1: element 1 duplicates element 0",
        ),
        (
            "CELLS 2 10\n4 0 1 2 3\n4 0 1 2 1",
            "CELL_TYPES 2\n10 10",
            "vtk cell 1: element 1 is degenerate",
        ),
        (
            "CELLS 1 9\n8 0 1 2 3 4 0 1 2",
            "CELL_TYPES 1\n12",
            "vtk cell 0: a hexahedron",
        ),
        (
            "CELLS 1 5\n4 0 1 2 3",
            "CELL_TYPES 2\n10 10",
            "2 CELL_TYPES for 1 CELLS",
        ),
    ] {
        let e = needle_host::mesh::read_legacy_vtk_bytes(legacy(cells, types).as_bytes())
            .expect_err(expected);
        assert!(e.to_string().contains(expected), "{cells}: {e}");
    }
}

/// A gel frame as `needle run --vtk-every` writes it (our zlib-compressed `.vtu` writer, with
/// the `region` cell array) reads back as the same mesh: a run's output can be a scene's mesh.
#[test]
fn a_vtu_written_by_the_frame_writer_reads_back_with_its_regions() {
    use needle_host::output::vtu::{Array, CellKind, Grid, Values};
    let m = read_gmsh(fixture(GMSH_FILES[2])).expect("read");
    let grid = Grid {
        points: m.nodes.clone(),
        cells: m
            .tets
            .iter()
            .map(|t| (CellKind::Tetra, t.to_vec()))
            .collect(),
        cell_data: vec![Array::new("region", Values::I32(m.regions.clone()))],
        ..Grid::default()
    };
    let text = grid.to_vtu().expect("a valid grid");
    let back = needle_host::mesh::read_vtu_bytes(text.as_bytes()).expect("reads back");
    assert_eq!(back, m);
}
