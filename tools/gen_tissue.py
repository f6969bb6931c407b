#!/usr/bin/env python3
"""Writes the meshes of the tissue-region scenes (scenes/tissue/): Gmsh 4.1 ASCII, mm, one
physical volume group per region, whose tag the scene's `[[gel.regions]]` maps to a material.

Usage:
    python3 tools/gen_tissue.py              # into scenes/tissue/
    python3 tools/gen_tissue.py --out DIR

Needs the `gmsh` package (pinned in tools/requirements.txt). The meshes are committed, so the
scenes run without Gmsh; the same input writes the same files (single thread, fixed seed).

- lesion.msh: the benchmark box [260, 340] x [-30, 30] x [0, 60] with a sphere of radius
  LESION_RADIUS around LESION_CENTRE (on the `simple` path) cut out as its own volume:
  physical tags 1 ("tissue") and 2 ("lesion"); elements of about H_LESION in the lesion and
  H_TISSUE elsewhere.
- skin.msh: the same box split at z = 60 - SKIN_THICKNESS: physical tags 1 ("tissue", below)
  and 2 ("skin", the top layer); elements of about H_SKIN near the top, H_TISSUE elsewhere.
"""

from __future__ import annotations

import argparse
import os

from gen_suite import GMSH_OPTIONS

BOX_MIN = (260.0, -30.0, 0.0)
BOX_SIZE = (80.0, 60.0, 60.0)
LESION_CENTRE = (302.0, 0.0, 35.0)  # the `simple` path's point at s = 0.5
LESION_RADIUS = 8.0
SKIN_THICKNESS = 4.0
H_TISSUE = 6.0
H_LESION = 3.0
H_SKIN = 4.0


def options(gmsh):
    # The suite's settings (the same mesher, seed and format), with the element size from the
    # size fields alone.
    for name, v in GMSH_OPTIONS + (
        ("Mesh.MeshSizeExtendFromBoundary", 0),
        ("Mesh.MeshSizeFromPoints", 0),
        ("Mesh.MeshSizeFromCurvature", 0),
    ):
        gmsh.option.setNumber(name, v)


def box(gmsh):
    return gmsh.model.occ.addBox(*BOX_MIN, *BOX_SIZE)


def size_field(gmsh, inner_volumes, h_in, h_out, distance):
    """Element size h_in inside `inner_volumes`, growing to h_out over `distance` mm."""
    surfaces = [s for v in inner_volumes for _, s in gmsh.model.getBoundary([(3, v)], oriented=False)]
    d = gmsh.model.mesh.field.add("Distance")
    gmsh.model.mesh.field.setNumbers(d, "SurfacesList", surfaces)
    t = gmsh.model.mesh.field.add("Threshold")
    gmsh.model.mesh.field.setNumber(t, "InField", d)
    gmsh.model.mesh.field.setNumber(t, "SizeMin", h_in)
    gmsh.model.mesh.field.setNumber(t, "SizeMax", h_out)
    gmsh.model.mesh.field.setNumber(t, "DistMin", 0.0)
    gmsh.model.mesh.field.setNumber(t, "DistMax", distance)
    c = gmsh.model.mesh.field.add("Constant")
    gmsh.model.mesh.field.setNumber(c, "VIn", h_in)
    gmsh.model.mesh.field.setNumber(c, "VOut", h_out)
    gmsh.model.mesh.field.setNumbers(c, "VolumesList", inner_volumes)
    m = gmsh.model.mesh.field.add("Min")
    gmsh.model.mesh.field.setNumbers(m, "FieldsList", [t, c])
    gmsh.model.mesh.field.setAsBackgroundMesh(m)


def two_regions(gmsh, tool, is_inner, inner_name, h_inner, distance):
    """The box fragmented by the volume `tool`: physical volume 1 ("tissue") the rest of the box,
    2 (`inner_name`) the part where `is_inner(volume)`; elements of h_inner there."""
    out, _ = gmsh.model.occ.fragment([(3, box(gmsh))], [(3, tool)])
    gmsh.model.occ.synchronize()
    vols = [t for _, t in out]
    inner = [v for v in vols if is_inner(v)]
    outer = [v for v in vols if not is_inner(v)]
    assert len(inner) == 1 and len(outer) == 1, (inner, outer)
    gmsh.model.addPhysicalGroup(3, outer, 1, name="tissue")
    gmsh.model.addPhysicalGroup(3, inner, 2, name=inner_name)
    size_field(gmsh, inner, h_inner, H_TISSUE, distance)


def lesion(gmsh):
    sphere = gmsh.model.occ.addSphere(*LESION_CENTRE, LESION_RADIUS)

    def is_lesion(v):  # the volume whose centre of mass is the sphere's centre
        c = gmsh.model.occ.getCenterOfMass(3, v)
        return sum((c[i] - LESION_CENTRE[i]) ** 2 for i in range(3)) < 1e-6

    two_regions(gmsh, sphere, is_lesion, "lesion", H_LESION, 8.0)


def skin(gmsh):
    top = BOX_MIN[2] + BOX_SIZE[2]
    layer = gmsh.model.occ.addBox(BOX_MIN[0], BOX_MIN[1], top - SKIN_THICKNESS, BOX_SIZE[0], BOX_SIZE[1], SKIN_THICKNESS)

    def is_skin(v):
        return gmsh.model.occ.getCenterOfMass(3, v)[2] > top - SKIN_THICKNESS

    two_regions(gmsh, layer, is_skin, "skin", H_SKIN, 6.0)


def write(gmsh, build, path):
    gmsh.clear()
    gmsh.model.add(os.path.basename(path))
    build(gmsh)
    gmsh.model.mesh.generate(3)
    gmsh.write(path)
    tags, _, _ = gmsh.model.mesh.getNodes()
    _, elem_tags, _ = gmsh.model.mesh.getElements(3)
    print(f"{path}: {len(tags)} nodes, {sum(len(t) for t in elem_tags)} tetrahedra")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "scenes", "tissue"))
    args = ap.parse_args()
    import gmsh  # noqa: PLC0415

    os.makedirs(args.out, exist_ok=True)
    gmsh.initialize(["gen_tissue"], readConfigFiles=False)
    try:
        options(gmsh)
        write(gmsh, lesion, os.path.join(args.out, "lesion.msh"))
        write(gmsh, skin, os.path.join(args.out, "skin.msh"))
    finally:
        gmsh.finalize()


if __name__ == "__main__":
    main()
