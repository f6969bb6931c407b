#!/usr/bin/env python3
"""Writes the Gmsh surface meshes of the mesh-obstacle scene scenes/obstacles/mesh_msh.toml and
of its tests: two closed surfaces meshed by Gmsh in one file, each its own physical surface
group, in mm in the gel's rest frame (the `simple` scene's gel and path):

- physical surface 1, "nodule": a sphere of radius 3 mm about (300, 0, 20) (where `simple`'s
  spherical obstacle is);
- physical surface 2, "vessel": a closed cylinder of radius 1.5 mm along y, from y = -10 to
  y = 10, its axis at x = 297, z = 40 (the `simple` path passes x = 301.28 at z = 40).

Every node is rounded to a multiple of 2^-10 mm (under a micrometre): such a coordinate is a
32-bit float, which a binary STL stores, and has at most 13 significant digits, which Gmsh's
ASCII writer (16 digits) keeps, so every file holds exactly the same surface. Each surface
entity is oriented outwards.

Files written:

- OUT/nodule_vessel.msh: Gmsh 4.1 ASCII (the scene's file), into scenes/obstacles/;
- TESTS/nodule_vessel_v41_ascii.msh, _v41_binary.msh, _v22_ascii.msh, _v22_binary.msh: the
  same mesh in each format Gmsh writes, into tests/data/mesh/;
- TESTS/nodule.stl, TESTS/vessel.stl: each group as a binary STL, its triangles in the order
  and with the vertex order of the .msh file's elements.

Usage:
    python3 tools/gen_obstacle_msh.py
    python3 tools/gen_obstacle_msh.py --out DIR --tests DIR

Needs the `gmsh` package (pinned in tools/requirements.txt). The files are committed, so the
scene and the tests run without Gmsh; the same input writes the same files (single thread,
fixed seed).
"""

from __future__ import annotations

import argparse
import math
import os
import struct

from gen_suite import GMSH_OPTIONS

NODULE_CENTRE = (300.0, 0.0, 20.0)
NODULE_RADIUS = 3.0
VESSEL_AXIS_X, VESSEL_AXIS_Z = 297.0, 40.0
VESSEL_RADIUS = 1.5
VESSEL_Y = (-10.0, 10.0)
H = 0.8  # element size [mm]


GRID = 1024.0  # nodes on multiples of 1/GRID mm


def snap(x):
    return round(x * GRID) / GRID


def build(gmsh):
    gmsh.model.add("nodule_vessel")
    occ = gmsh.model.occ
    nodule = occ.addSphere(*NODULE_CENTRE, NODULE_RADIUS)
    vessel = occ.addCylinder(VESSEL_AXIS_X, VESSEL_Y[0], VESSEL_AXIS_Z,
                             0.0, VESSEL_Y[1] - VESSEL_Y[0], 0.0, VESSEL_RADIUS)
    occ.synchronize()
    groups = {}
    for tag, name, vol in ((1, "nodule", nodule), (2, "vessel", vessel)):
        faces = [t for (_, t) in gmsh.model.getBoundary([(3, vol)], oriented=False)]
        gmsh.model.addPhysicalGroup(2, faces, tag)
        gmsh.model.setPhysicalName(2, tag, name)
        groups[tag] = (name, faces)
    gmsh.option.setNumber("Mesh.MeshSizeMin", H)
    gmsh.option.setNumber("Mesh.MeshSizeMax", H)
    gmsh.model.mesh.generate(2)
    # Round every node to the grid.
    tags, coords, _ = gmsh.model.mesh.getNodes()
    for i, t in enumerate(tags):
        gmsh.model.mesh.setNode(int(t), [snap(c) for c in coords[3 * i:3 * i + 3]], [])
    # Orient each surface entity outwards (both shapes are convex: every triangle's normal
    # points away from the shape's centre, or its axis).
    centre = {1: lambda p: NODULE_CENTRE, 2: lambda p: (VESSEL_AXIS_X, p[1], VESSEL_AXIS_Z)}
    for tag, (_, faces) in groups.items():
        for face in faces:
            ntag, ncoord, _ = gmsh.model.mesh.getNodes(2, face, includeBoundary=True)
            pos = {int(t): ncoord[3 * i:3 * i + 3] for i, t in enumerate(ntag)}
            _, enodes = gmsh.model.mesh.getElementsByType(2, face)
            s = 0.0
            for k in range(0, len(enodes), 3):
                a, b, c = (pos[int(n)] for n in enodes[k:k + 3])
                u = [b[i] - a[i] for i in range(3)]
                w = [c[i] - a[i] for i in range(3)]
                n = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
                m = [(a[i] + b[i] + c[i]) / 3 for i in range(3)]
                o = centre[tag](m)
                s += sum(n[i] * (m[i] - o[i]) for i in range(3))
            if s < 0:
                gmsh.model.mesh.reverse([(2, face)])
    return groups


def write_stl(gmsh, path, name, faces):
    tris = []
    for face in faces:
        ntag, ncoord, _ = gmsh.model.mesh.getNodes(2, face, includeBoundary=True)
        pos = {int(t): ncoord[3 * i:3 * i + 3] for i, t in enumerate(ntag)}
        _, enodes = gmsh.model.mesh.getElementsByType(2, face)
        for k in range(0, len(enodes), 3):
            tris.append([pos[int(n)] for n in enodes[k:k + 3]])
    with open(path, "wb") as f:
        f.write(f"binary STL {name} (tools/gen_obstacle_msh.py)".encode().ljust(80, b" "))
        f.write(struct.pack("<I", len(tris)))
        for a, b, c in tris:
            u = [b[i] - a[i] for i in range(3)]
            w = [c[i] - a[i] for i in range(3)]
            n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]]
            r = math.sqrt(sum(x * x for x in n)) or 1.0
            f.write(struct.pack("<3f", *(x / r for x in n)))
            for p in (a, b, c):
                f.write(struct.pack("<3f", *p))
            f.write(struct.pack("<H", 0))


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(here, "..", "scenes", "obstacles"))
    ap.add_argument("--tests", default=os.path.join(here, "..", "tests", "data", "mesh"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    os.makedirs(args.tests, exist_ok=True)
    import gmsh

    gmsh.initialize(["-noenv"])
    try:
        for name, v in GMSH_OPTIONS:
            gmsh.option.setNumber(name, v)
        groups = build(gmsh)
        for version, binary, path in (
            (4.1, 0, os.path.join(args.out, "nodule_vessel.msh")),
            (4.1, 0, os.path.join(args.tests, "nodule_vessel_v41_ascii.msh")),
            (4.1, 1, os.path.join(args.tests, "nodule_vessel_v41_binary.msh")),
            (2.2, 0, os.path.join(args.tests, "nodule_vessel_v22_ascii.msh")),
            (2.2, 1, os.path.join(args.tests, "nodule_vessel_v22_binary.msh")),
        ):
            gmsh.option.setNumber("Mesh.MshFileVersion", version)
            gmsh.option.setNumber("Mesh.Binary", binary)
            gmsh.write(path)
        for name, faces in groups.values():
            write_stl(gmsh, os.path.join(args.tests, f"{name}.stl"), name, faces)
    finally:
        gmsh.finalize()


if __name__ == "__main__":
    main()
