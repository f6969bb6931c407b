#!/usr/bin/env python3
"""Writes the VTK mesh files the mesh-reader tests read (tests/data/mesh/), each written by VTK
itself or by meshio, from the Gmsh fixture two_regions_v41_ascii.msh (92 nodes, 251 tetrahedra,
physical volumes 1 and 2, triangles of the top face).

Usage (with the pinned readers of tests/vtk/requirements.txt: vtk, meshio, numpy):
    python3 tools/gen_vtk_fixtures.py [--out DIR]

Each file holds the tetrahedra and the top face's triangles (the readers must skip them), and
the cell array `region` (Int32: the physical tag; 0 on the triangles).
- VTK 9 XML (vtkXMLUnstructuredGridWriter): vtk_ascii.vtu, vtk_binary.vtu (inline base64),
  vtk_binary_zlib.vtu, vtk_appended_raw_zlib.vtu, vtk_appended_base64.vtu,
  vtk_appended_raw_uint64.vtu (64-bit block headers), vtk_appended_raw_lz4.vtu (lz4: refused).
- VTK legacy (vtkUnstructuredGridWriter): vtk_legacy_ascii.vtk, vtk_legacy_binary.vtk (format
  5.1: offsets and connectivity), vtk_legacy42_ascii.vtk, vtk_legacy42_binary.vtk (format 4.2).
- meshio: meshio_ascii.vtu, meshio_zlib.vtu, meshio_ascii.vtk, meshio_binary.vtk.
- vtk_hexahedron.vtu: one hexahedron (refused, naming the cell).
"""

from __future__ import annotations

import argparse
import os


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(here, "..", "tests", "data", "mesh"))
    args = ap.parse_args()
    import meshio  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415
    import vtk  # noqa: PLC0415
    from vtk.util.numpy_support import numpy_to_vtk  # noqa: PLC0415

    src = meshio.read(os.path.join(args.out, "two_regions_v41_ascii.msh"))
    tets = np.concatenate([c.data for c in src.cells if c.type == "tetra"])
    tet_tags = np.concatenate(
        [t for c, t in zip(src.cells, src.cell_data["gmsh:physical"]) if c.type == "tetra"]
    ).astype(np.int32)
    tris = np.concatenate([c.data for c in src.cells if c.type == "triangle"])
    points = np.asarray(src.points, dtype=np.float64)
    region = np.concatenate([tet_tags, np.zeros(len(tris), dtype=np.int32)])

    def out(name):
        return os.path.join(args.out, name)

    # meshio.
    mesh = meshio.Mesh(points, [("tetra", tets), ("triangle", tris)], cell_data={"region": [tet_tags, np.zeros(len(tris), dtype=np.int32)]})
    meshio.write(out("meshio_ascii.vtu"), mesh, binary=False)
    meshio.write(out("meshio_zlib.vtu"), mesh, binary=True, compression="zlib")
    meshio.write(out("meshio_ascii.vtk"), mesh, binary=False)
    meshio.write(out("meshio_binary.vtk"), mesh, binary=True)

    # VTK.
    grid = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(points, deep=True))
    grid.SetPoints(pts)
    grid.Allocate(len(tets) + len(tris))
    for t in tets:
        grid.InsertNextCell(vtk.VTK_TETRA, 4, [int(v) for v in t])
    for t in tris:
        grid.InsertNextCell(vtk.VTK_TRIANGLE, 3, [int(v) for v in t])
    arr = numpy_to_vtk(region, deep=True, array_type=vtk.VTK_INT)
    arr.SetName("region")
    grid.GetCellData().AddArray(arr)

    def xml(name, mode, compressor=None, header64=False, encode=True, g=grid):
        w = vtk.vtkXMLUnstructuredGridWriter()
        w.SetFileName(out(name))
        w.SetInputData(g)
        {"ascii": w.SetDataModeToAscii, "binary": w.SetDataModeToBinary, "appended": w.SetDataModeToAppended}[mode]()
        if compressor is None:
            w.SetCompressorTypeToNone()
        elif compressor == "zlib":
            w.SetCompressorTypeToZLib()
        else:
            w.SetCompressorTypeToLZ4()
        if header64:
            w.SetHeaderTypeToUInt64()
        else:
            w.SetHeaderTypeToUInt32()
        w.SetEncodeAppendedData(encode)
        assert w.Write() == 1, name

    xml("vtk_ascii.vtu", "ascii")
    xml("vtk_binary.vtu", "binary")
    xml("vtk_binary_zlib.vtu", "binary", "zlib")
    xml("vtk_appended_raw_zlib.vtu", "appended", "zlib", encode=False)
    xml("vtk_appended_base64.vtu", "appended", encode=True)
    xml("vtk_appended_raw_uint64.vtu", "appended", "zlib", header64=True, encode=False)
    xml("vtk_appended_raw_lz4.vtu", "appended", "lz4", encode=False)

    for name, version, binary in (
        ("vtk_legacy_ascii.vtk", None, False),
        ("vtk_legacy_binary.vtk", None, True),
        ("vtk_legacy42_ascii.vtk", 42, False),
        ("vtk_legacy42_binary.vtk", 42, True),
    ):
        w = vtk.vtkUnstructuredGridWriter()
        w.SetFileName(out(name))
        w.SetInputData(grid)
        if version is not None:
            w.SetFileVersion(version)
        if binary:
            w.SetFileTypeToBinary()
        else:
            w.SetFileTypeToASCII()
        assert w.Write() == 1, name

    hexa = vtk.vtkUnstructuredGrid()
    hp = vtk.vtkPoints()
    for p in ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)):
        hp.InsertNextPoint(*p)
    hexa.SetPoints(hp)
    hexa.InsertNextCell(vtk.VTK_HEXAHEDRON, 8, list(range(8)))
    xml("vtk_hexahedron.vtu", "ascii", g=hexa)
    print(f"{len(points)} points, {len(tets)} tetrahedra, {len(tris)} triangles; VTK {vtk.vtkVersion.GetVTKVersion()}, meshio {meshio.__version__}")


if __name__ == "__main__":
    main()
