#!/usr/bin/env python3
"""Writes the small mesh files the mesh-reader tests read (tests/data/mesh/), each written by the
tool that owns its format, so that the readers are checked against files they did not write.

Usage:
    python3 tools/gen_mesh_fixtures.py [--out DIR]

Needs `gmsh` (tools/requirements.txt). The mesh: the box [0, 10] x [0, 10] x [0, 10] mm split
at z = 5 into two volumes, physical volume groups 1 ("bottom") and 2 ("top"), a physical
surface group 3 on the top face (triangles the readers must skip), element size 4 mm.
Written as Gmsh 2.2 and 4.1, ASCII and binary: two_regions_v22_ascii.msh,
two_regions_v22_binary.msh, two_regions_v41_ascii.msh, two_regions_v41_binary.msh; and the
same box meshed with 8-node hexahedra (`hexahedra_v41_ascii.msh`), which must be refused.
"""

from __future__ import annotations

import argparse
import os


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "tests", "data", "mesh"))
    args = ap.parse_args()
    import gmsh  # noqa: PLC0415

    os.makedirs(args.out, exist_ok=True)
    gmsh.initialize(["gen_mesh_fixtures"], readConfigFiles=False)
    try:
        for name, v in (
            ("General.Terminal", 0),
            ("General.NumThreads", 1),
            ("Mesh.RandomSeed", 1),
            ("Mesh.MeshSizeMin", 4.0),
            ("Mesh.MeshSizeMax", 4.0),
            ("Mesh.SaveAll", 0),
        ):
            gmsh.option.setNumber(name, v)
        gmsh.model.add("two_regions")
        a = gmsh.model.occ.addBox(0, 0, 0, 10, 10, 5)
        b = gmsh.model.occ.addBox(0, 0, 5, 10, 10, 5)
        gmsh.model.occ.fragment([(3, a)], [(3, b)])
        gmsh.model.occ.synchronize()
        low = [t for _, t in gmsh.model.getEntities(3) if gmsh.model.occ.getCenterOfMass(3, t)[2] < 5]
        high = [t for _, t in gmsh.model.getEntities(3) if gmsh.model.occ.getCenterOfMass(3, t)[2] > 5]
        gmsh.model.addPhysicalGroup(3, low, 1, name="bottom")
        gmsh.model.addPhysicalGroup(3, high, 2, name="top")
        top = [t for _, t in gmsh.model.getEntities(2) if abs(gmsh.model.occ.getCenterOfMass(2, t)[2] - 10) < 1e-9]
        gmsh.model.addPhysicalGroup(2, top, 3, name="top_face")
        gmsh.model.mesh.generate(3)
        for version, tag in ((2.2, "v22"), (4.1, "v41")):
            for binary, kind in ((0, "ascii"), (1, "binary")):
                gmsh.option.setNumber("Mesh.MshFileVersion", version)
                gmsh.option.setNumber("Mesh.Binary", binary)
                path = os.path.join(args.out, f"two_regions_{tag}_{kind}.msh")
                gmsh.write(path)
                print(path)
        nodes, _, _ = gmsh.model.mesh.getNodes()
        types, elems, _ = gmsh.model.mesh.getElements(3)
        print(f"{len(nodes)} nodes, {sum(len(e) for e in elems)} tetrahedra")

        gmsh.clear()
        gmsh.model.add("hexahedra")
        gmsh.model.occ.addBox(0, 0, 0, 10, 10, 10)
        gmsh.model.occ.synchronize()
        for c in gmsh.model.getEntities(1):
            gmsh.model.mesh.setTransfiniteCurve(c[1], 3)
        for s in gmsh.model.getEntities(2):
            gmsh.model.mesh.setTransfiniteSurface(s[1])
            gmsh.model.mesh.setRecombine(2, s[1])
        gmsh.model.mesh.setTransfiniteVolume(1)
        gmsh.model.addPhysicalGroup(3, [1], 1, name="gel")
        gmsh.option.setNumber("Mesh.Recombine3DAll", 1)
        gmsh.model.mesh.generate(3)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        path = os.path.join(args.out, "hexahedra_v41_ascii.msh")
        gmsh.write(path)
        print(path)
    finally:
        gmsh.finalize()


if __name__ == "__main__":
    main()
