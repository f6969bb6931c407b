#!/usr/bin/env python3
"""Writes scenes/hard/slivers.msh: an unstructured tetrahedral mesh of the benchmark gel box
[260, 340] x [-30, 30] x [0, 60] mm with sliver tetrahedra, in Gmsh 4.1 ASCII format.

The mesh is the Delaunay tetrahedralisation (scipy.spatial.Delaunay, i.e. Qhull) of
seeded random points: a jittered grid on the six faces (so that the surface is the box) and
uniform random points inside. A Delaunay tetrahedralisation of random points without any
quality refinement is known to contain slivers: four nearly coplanar points on a
near-empty sphere; this one has hundreds with an aspect ratio (longest edge / shortest altitude,
1.22 for a regular tetrahedron) above 20.

Usage: python3 tools/sliver_mesh.py [out.msh]   (needs numpy and scipy: pip install scipy)
The committed file was made by this script as is (seed 7); the tests read the committed file.
"""
import sys

import numpy as np
from scipy.spatial import Delaunay

LO = np.array([260.0, -30.0, 0.0])
HI = np.array([340.0, 30.0, 60.0])
SPACING = 6.0  # target point spacing on the faces [mm]
INTERIOR = 650  # random interior points
SEED = 7


def face_points(rng):
    """A grid on each face with in-plane jitter (edges and corners shared exactly)."""
    n = np.maximum(np.round((HI - LO) / SPACING).astype(int), 1)
    axes = [np.linspace(LO[i], HI[i], n[i] + 1) for i in range(3)]
    pts = set()
    for fixed in range(3):
        a, b = [i for i in range(3) if i != fixed]
        for side in (LO[fixed], HI[fixed]):
            for ia, u in enumerate(axes[a]):
                for ib, v in enumerate(axes[b]):
                    p = [0.0, 0.0, 0.0]
                    p[fixed] = side
                    # Jitter inside the face only, never on its border lines.
                    inner_a = 0 < ia < len(axes[a]) - 1
                    inner_b = 0 < ib < len(axes[b]) - 1
                    p[a] = u + (rng.uniform(-0.3, 0.3) * SPACING if inner_a else 0.0)
                    p[b] = v + (rng.uniform(-0.3, 0.3) * SPACING if inner_b else 0.0)
                    pts.add(tuple(round(c, 9) for c in p))
    return np.array(sorted(pts))


def aspect(x):
    edges = [x[j] - x[i] for i in range(4) for j in range(i + 1, 4)]
    lmax = max(np.linalg.norm(e) for e in edges)
    vol = abs(np.dot(np.cross(x[1] - x[0], x[2] - x[0]), x[3] - x[0])) / 6.0
    faces = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
    amax = max(np.linalg.norm(np.cross(x[b] - x[a], x[c] - x[a])) / 2 for a, b, c in faces)
    hmin = 3.0 * vol / amax
    return lmax / hmin if hmin > 0 else np.inf


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "scenes/hard/slivers.msh"
    rng = np.random.default_rng(SEED)
    surface = face_points(rng)
    margin = 0.5
    inner = rng.uniform(LO + margin, HI - margin, size=(INTERIOR, 3))
    pts = np.vstack([surface, inner])
    tri = Delaunay(pts)
    tets = []
    for t in tri.simplices:
        x = pts[t]
        v = np.dot(np.cross(x[1] - x[0], x[2] - x[0]), x[3] - x[0]) / 6.0
        # Coplanar points on a face can give flat tetrahedra of zero volume: drop them (the
        # threshold is far below any real element, ~36 mm³).
        if abs(v) < 1e-6:
            continue
        if v < 0:
            t = [t[0], t[2], t[1], t[3]]
        tets.append(list(t))
    used = sorted({i for t in tets for i in t})
    index = {old: new for new, old in enumerate(used)}
    nodes = pts[used]
    tets = [[index[i] for i in t] for t in tets]
    ratios = np.array([aspect(nodes[t]) for t in tets])
    with open(out, "w") as f:
        f.write("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n")
        n = len(nodes)
        f.write(f"$Nodes\n1 {n} 1 {n}\n3 1 0 {n}\n")
        f.writelines(f"{i}\n" for i in range(1, n + 1))
        f.writelines(f"{p[0]:.17e} {p[1]:.17e} {p[2]:.17e}\n" for p in nodes)
        m = len(tets)
        f.write(f"$EndNodes\n$Elements\n1 {m} 1 {m}\n3 1 4 {m}\n")
        f.writelines(f"{e + 1} {t[0] + 1} {t[1] + 1} {t[2] + 1} {t[3] + 1}\n" for e, t in enumerate(tets))
        f.write("$EndElements\n")
    print(
        f"{out}: {n} nodes, {m} tetrahedra; aspect ratio (longest edge / shortest altitude) "
        f"max {ratios.max():.1f}, {np.sum(ratios > 20)} elements above 20, {np.sum(ratios > 100)} above 100"
    )


if __name__ == "__main__":
    main()
