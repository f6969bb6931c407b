#!/usr/bin/env python3
"""Writes the surface meshes of the mesh-obstacle scenes (scenes/obstacles/), in mm, about the
origin (each scene places its mesh by `scale` and `translation`):

- box.stl: a cube of side 6 mm, ASCII STL, 12 triangles, counter-clockwise seen from outside;
- sphere.obj: the unit sphere as an icosahedron subdivided twice (320 triangles, every vertex at
  radius 1), Wavefront OBJ.

Usage:
    python3 tools/gen_obstacle_meshes.py            # into scenes/obstacles/
    python3 tools/gen_obstacle_meshes.py --out DIR

Plain Python, no package needed; the same input writes the same files. The files are committed,
so the scenes run without this script.
"""

from __future__ import annotations

import argparse
import math
import os

BOX_HALF = 3.0
SPHERE_SUBDIVISIONS = 2


def box():
    h = BOX_HALF
    v = [((h if i & 1 else -h), (h if i & 2 else -h), (h if i & 4 else -h)) for i in range(8)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    t = [tri for q in quads for tri in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return v, t


def icosphere(n):
    g = (1.0 + math.sqrt(5.0)) / 2.0
    raw = [(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g),
           (0, -1, -g), (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)]

    def unit(p):
        r = math.sqrt(sum(c * c for c in p))
        return tuple(c / r for c in p)

    v = [unit(p) for p in raw]
    t = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(n):
        mid = {}

        def midpoint(i, j):
            key = (min(i, j), max(i, j))
            if key not in mid:
                v.append(unit(tuple((a + b) / 2.0 for a, b in zip(v[i], v[j]))))
                mid[key] = len(v) - 1
            return mid[key]

        nxt = []
        for a, b, c in t:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            nxt += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        t = nxt
    return v, t


def normal(a, b, c):
    u = [b[k] - a[k] for k in range(3)]
    w = [c[k] - a[k] for k in range(3)]
    n = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
    r = math.sqrt(sum(x * x for x in n))
    return tuple(x / r for x in n)


def fmt(x):
    return repr(float(x)) if x != 0 else "0.0"


def write_stl(path, name, v, t):
    with open(path, "w", newline="\n") as f:
        f.write(f"solid {name}\n")
        for tri in t:
            a, b, c = (v[i] for i in tri)
            f.write("  facet normal {} {} {}\n    outer loop\n".format(*map(fmt, normal(a, b, c))))
            for p in (a, b, c):
                f.write("      vertex {} {} {}\n".format(*map(fmt, p)))
            f.write("    endloop\n  endfacet\n")
        f.write(f"endsolid {name}\n")


def write_obj(path, comment, v, t):
    with open(path, "w", newline="\n") as f:
        f.write(f"# {comment}\n")
        for p in v:
            f.write("v {} {} {}\n".format(*(f"{c:.17g}" for c in p)))
        for a, b, c in t:
            f.write(f"f {a + 1} {b + 1} {c + 1}\n")


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(here, "..", "scenes", "obstacles"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    write_stl(os.path.join(args.out, "box.stl"), "box", *box())
    write_obj(os.path.join(args.out, "sphere.obj"),
              f"unit icosphere, {SPHERE_SUBDIVISIONS} subdivisions (tools/gen_obstacle_meshes.py)",
              *icosphere(SPHERE_SUBDIVISIONS))


if __name__ == "__main__":
    main()
