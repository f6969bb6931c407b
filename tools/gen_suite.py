#!/usr/bin/env python3
"""Writes the generated scenes of the public suite (shared BENCHMARK.md, "Beyond the two scenes").

Usage:
    python3 tools/gen_suite.py                      # seed 1, into scenes/suite/
    python3 tools/gen_suite.py --seed 2026 --out DIR
    python3 tools/gen_suite.py --list               # the slots and their kinds, nothing written

Python 3.11 standard library, plus the `gmsh` package (pinned in tools/requirements.txt:
`pip install -r tools/requirements.txt`) for the scenes on an unstructured Gmsh mesh; it is only
imported when such a scene is written.

Every slot below is one scene of a fixed *kind* (an S-curve in y, a helix of up to one turn, a
straight entry tilted 15-30 deg, a 3-5 kPa gel, ...). Its parameters are drawn from a random
generator seeded with the string "<seed>/<slot>", so a slot's scene depends on the seed and its
own name only, and the same seed writes byte-identical files. A drawn scene is checked
(`check_scene`) and drawn again if it is physically impossible or meaningless; each rejection is
counted and printed with its reason. The checks:

- the path stays inside the gel, at least WALL_MARGIN from its side walls and at least
  BOTTOM_MARGIN above its fixed bottom; it enters through the top face; its entry is tilted at
  most 30 deg from vertical;
- each obstacle lies wholly inside the gel and leaves a gap of at least the needle radius +
  MIN_GAP_OVER_RADIUS (so the needle can pass) and at most MAX_GAP (1.5 mm) between the rest path
  (the needle's centre line) and its surface; obstacles do not touch each other;
- the needle does not buckle before it punctures the surface (Euler load of the whole needle,
  pinned-pinned, at least BUCKLING_SAFETY x the puncture force), and is long enough that its base
  (the flange) stays at least FLANGE_CLEARANCE above the gel's top face at the end of the path;
- the robot (RV-1A, base at the origin) reaches the start pose from mid-range with the same damped
  least-squares IK as the project (needle-core `solve_ik`), every joint at least
  START_LIMIT_MARGIN inside its limits, and from there reaches the poses of the needle pivoting
  about the entry point along the whole path (the needle's axis from the entry point to the path
  point, the rest of its length outside: the inverse controller's angular objective once
  inserted), every joint at least PATH_LIMIT_MARGIN inside its limits. When the project's start
  fails this, the IK from other seeds (the wrist turned) is tried, and the passing start farthest
  from the limits is written into the scene as `robot.start_joints_deg`.

The puncture force is scaled from the benchmark's 0.2 N (Ø 1 mm needle, 20 kPa gel) with the
needle diameter and the square root of the gel's Young modulus (a stiffer gel and a thicker needle
need more force to puncture); the other interaction and controller values are the benchmark's.
The gel mesh is the box mesher's 1500 nodes, or a Gmsh mesh of about as many nodes.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import sys
from dataclasses import dataclass, field

DEFAULT_SEED = 1

# Checks (mm, deg, -).
WALL_MARGIN = 8.0
BOTTOM_MARGIN = 9.5  # the benchmark paths end 10 mm above the bottom
MAX_ENTRY_TILT_DEG = 30.0
MIN_GAP_OVER_RADIUS = 0.2
MAX_GAP = 1.5
OBSTACLE_WALL_MARGIN = 2.0
OBSTACLE_SEPARATION = 2.0
BUCKLING_SAFETY = 2.0
FLANGE_CLEARANCE = 25.0
START_LIMIT_MARGIN_DEG = 5.0
PATH_LIMIT_MARGIN_DEG = 2.0
MAX_TRIES = 400

# Benchmark values (shared BENCHMARK.md).
BENCH_CENTER = (300.0, 0.0)
BENCH_SIZE = (80.0, 60.0, 60.0)
BENCH_PUNCTURE = 0.2  # N, Ø 1 mm needle in a 20 kPa gel
NEEDLE_E = 200000.0
APPROACH = 10.0
SAMPLES = 201
NODES = 1500

# RV-1A: standard DH rows (theta offset, d, a, alpha) and joint limits [deg] (DESIGN.md).
DH = [
    (0.0, 300.0, 0.0, -math.pi / 2),
    (-math.pi / 2, 0.0, 250.0, 0.0),
    (math.pi / 2, 0.0, -90.0, math.pi / 2),
    (0.0, 160.0, 0.0, -math.pi / 2),
    (0.0, 0.0, 0.0, math.pi / 2),
    (0.0, 72.0, 0.0, 0.0),
]
LIMITS_DEG = [(-150, 150), (-60, 120), (60, 155), (-160, 160), (-90, 90), (-200, 200)]
LIMITS = [(math.radians(a), math.radians(b)) for a, b in LIMITS_DEG]


class Reject(Exception):
    """A drawn scene that is impossible or meaningless; the message says why."""


# ---------------------------------------------------------------------------------------------
# Small vector helpers (3-tuples).



# Gmsh settings of every generated mesh: quiet, one thread, a fixed seed (the same mesh on every
# machine), MSH 4.1 ASCII with the physical groups only. `tools/gen_tissue.py` uses them too.
GMSH_OPTIONS = (
    ("General.Terminal", 0),
    ("General.Verbosity", 0),
    ("General.NumThreads", 1),
    ("Mesh.Algorithm", 6),  # Frontal-Delaunay surfaces
    ("Mesh.Algorithm3D", 1),  # Delaunay volume
    ("Mesh.RandomSeed", 1),
    ("Mesh.Optimize", 1),
    ("Mesh.MshFileVersion", 4.1),
    ("Mesh.Binary", 0),
    ("Mesh.SaveAll", 0),
)

def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def mul(a, k):
    return (a[0] * k, a[1] * k, a[2] * k)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a):
    return math.sqrt(dot(a, a))


def unit(a):
    n = norm(a)
    return (a[0] / n, a[1] / n, a[2] / n)


def point_segment_distance(p, a, b):
    ab = sub(b, a)
    t = dot(sub(p, a), ab) / dot(ab, ab)
    t = min(1.0, max(0.0, t))
    return norm(sub(p, add(a, mul(ab, t))))


def polyline_distance(p, pts):
    return min(point_segment_distance(p, pts[i], pts[i + 1]) for i in range(len(pts) - 1))


# ---------------------------------------------------------------------------------------------
# Robot: forward kinematics and the project's damped least-squares IK (core/src/ik.rs).


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def dh_transform(q, row):
    th, d, a, al = row
    ct, st = math.cos(q + th), math.sin(q + th)
    ca, sa = math.cos(al), math.sin(al)
    return [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]


def frames(q):
    t = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    out = []
    for qi, row in zip(q, DH):
        t = mat_mul(t, dh_transform(qi, row))
        out.append(t)
    return out


def tool_pose(q):
    """Needle base position and axis (flange z) for joints q."""
    f = frames(q)[-1]
    return (f[0][3], f[1][3], f[2][3]), (f[0][2], f[1][2], f[2][2])


def jacobian(q):
    fs = frames(q)
    p = (fs[-1][0][3], fs[-1][1][3], fs[-1][2][3])
    cols = []
    for i in range(6):
        if i == 0:
            z, o = (0.0, 0.0, 1.0), (0.0, 0.0, 0.0)
        else:
            f = fs[i - 1]
            z, o = (f[0][2], f[1][2], f[2][2]), (f[0][3], f[1][3], f[2][3])
        v = cross(z, sub(p, o))
        cols.append(v + z)
    jac = [[cols[j][r] for j in range(6)] for r in range(6)]
    return jac, p, (fs[-1][0][2], fs[-1][1][2], fs[-1][2][2])


def solve_linear(m, b):
    """Gaussian elimination with partial pivoting (small dense systems)."""
    n = len(b)
    a = [row[:] + [b[i]] for i, row in enumerate(m)]
    for c in range(n):
        piv = max(range(c, n), key=lambda r: abs(a[r][c]))
        a[c], a[piv] = a[piv], a[c]
        if abs(a[c][c]) < 1e-300:
            return None
        for r in range(c + 1, n):
            f = a[r][c] / a[c][c]
            for k in range(c, n + 1):
                a[r][k] -= f * a[c][k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (a[r][n] - sum(a[r][k] * x[k] for k in range(r + 1, n))) / a[r][r]
    return x


def clamp(q):
    return [min(max(v, lo), hi) for v, (lo, hi) in zip(q, LIMITS)]


def solve_ik(position, axis, seed, max_iterations=200):
    """core/src/ik.rs `solve_ik` with its default parameters: returns (q, position error, angle)."""
    damping, wa, seed_gain, max_step = 1.0, 100.0, 0.1, 0.2
    a = unit(axis)
    q = clamp(list(seed))
    it = 0
    while True:
        jac, p, z = jacobian(q)
        ep = sub(position, p)
        cr = cross(z, a)
        perr = norm(ep)
        ang = math.atan2(norm(cr), dot(z, a))
        if (perr <= 1e-6 and ang <= 1e-8) or it >= max_iterations:
            return q, perr, ang
        it += 1
        s = norm(cr)
        if s > 1e-300:
            ea = mul(cr, ang / s)
        elif dot(z, a) < 0:
            t = (1.0, 0.0, 0.0) if abs(z[0]) < 0.9 else (0.0, 1.0, 0.0)
            ea = mul(unit(cross(z, t)), math.pi)
        else:
            ea = (0.0, 0.0, 0.0)
        proj = [[(1.0 if i == j else 0.0) - z[i] * z[j] for j in range(3)] for i in range(3)]
        jt = [row[:] for row in jac[:3]]
        for i in range(3):
            jt.append([wa * sum(proj[i][k] * jac[3 + k][j] for k in range(3)) for j in range(6)])
        pe = [sum(proj[i][k] * ea[k] for k in range(3)) * wa for i in range(3)]
        e = list(ep) + pe
        m = [[sum(jt[i][k] * jt[j][k] for k in range(6)) + (damping * damping if i == j else 0.0) for j in range(6)] for i in range(6)]
        y = solve_linear(m, e)
        if y is None:
            return q, perr, ang
        dq = [sum(jt[r][j] * y[r] for r in range(6)) for j in range(6)]
        far = perr > 0.1 or ang > 1e-3
        pull = [seed_gain * (seed[j] - q[j]) if far else 0.0 for j in range(6)]
        jp = solve_linear(m, [sum(jt[i][k] * pull[k] for k in range(6)) for i in range(6)])
        if jp is None:
            return q, perr, ang
        jpull = [sum(jt[r][j] * jp[r] for r in range(6)) for j in range(6)]
        dq = [dq[j] + pull[j] - jpull[j] for j in range(6)]
        big = max(abs(v) for v in dq)
        if big > max_step:
            dq = [v * max_step / big for v in dq]
        if not all(math.isfinite(v) for v in dq):
            return q, perr, ang
        q = clamp([q[j] + dq[j] for j in range(6)])


def limit_margin_deg(q):
    """Smallest distance of a joint from its limits [deg], and which joint."""
    m = [(min(v - lo, hi - v), i) for i, (v, (lo, hi)) in enumerate(zip(q, LIMITS))]
    d, i = min(m)
    return math.degrees(d), i


# ---------------------------------------------------------------------------------------------
# Paths: formulas of s in the project's syntax, evaluated here exactly as written.


def num(v):
    """A constant as written in a formula: 4 decimals, no trailing zeros."""
    t = f"{v:.4f}".rstrip("0").rstrip(".")
    return "0" if t in ("-0", "") else t


def lin(const, terms):
    """`const + c1*e1 - c2*e2 ...` with every coefficient written positive."""
    const += sum(float(num(c)) for c, e in terms if e == "1")
    out = num(const)
    for c, e in terms:
        if e == "1":
            continue
        c = float(num(c))
        if c == 0.0:
            continue
        out += f" {'-' if c < 0 else '+'} {num(abs(c))}*{e}"
    return out


def eval_formula(text, s):
    return eval(text.replace("^", "**"), {"__builtins__": {}}, {"s": s, "PI": math.pi, "sin": math.sin, "cos": math.cos, "sqrt": math.sqrt})


def sample_path(fx, fy, fz):
    pts = []
    for i in range(SAMPLES):
        s = i / (SAMPLES - 1)
        pts.append((eval_formula(fx, s), eval_formula(fy, s), eval_formula(fz, s)))
    return pts


def entry_tangent(pts):
    # host/src/scene/path.rs: second-order one-sided difference.
    return unit(sub(sub(mul(pts[1], 4.0), mul(pts[0], 3.0)), pts[2]))


def arc_length(pts):
    return sum(norm(sub(pts[i + 1], pts[i])) for i in range(len(pts) - 1))


def point_at(pts, l):
    """Point and tangent at arc length l along the polyline (clamped)."""
    acc = 0.0
    for i in range(len(pts) - 1):
        seg = norm(sub(pts[i + 1], pts[i]))
        if acc + seg >= l or i == len(pts) - 2:
            f = min(1.0, max(0.0, (l - acc) / seg))
            t = unit(sub(pts[i + 1], pts[i]))
            return add(pts[i], mul(sub(pts[i + 1], pts[i]), f)), t
        acc += seg
    raise AssertionError


# ---------------------------------------------------------------------------------------------
# Scene description.


@dataclass
class Gel:
    shape: str  # "box" or "cylinder"
    center: tuple  # (x, y) of the footprint's centre [mm]
    bottom: float  # z of the fixed bottom face [mm]
    size: tuple  # box: (wx, wy, h); cylinder: (diameter, diameter, h) [mm]
    young_kpa: float
    poisson: float
    mesh: str = "box"  # "box" (the project's box mesher) or "gmsh"

    @property
    def top(self):
        return self.bottom + self.size[2]

    def box_min(self):
        return (self.center[0] - self.size[0] / 2, self.center[1] - self.size[1] / 2, self.bottom)

    def box_max(self):
        return (self.center[0] + self.size[0] / 2, self.center[1] + self.size[1] / 2, self.top)

    def wall_distance(self, p):
        """Distance from p to the nearest side wall (negative outside)."""
        if self.shape == "cylinder":
            r = math.hypot(p[0] - self.center[0], p[1] - self.center[1])
            return self.size[0] / 2 - r
        lo, hi = self.box_min(), self.box_max()
        return min(p[0] - lo[0], hi[0] - p[0], p[1] - lo[1], hi[1] - p[1])


@dataclass
class Obstacle:
    name: str
    center: tuple
    radius: float
    gap: float = 0.0  # rest path centre line to surface [mm]


@dataclass
class Scene:
    slot: str
    kind: str
    scenario: str
    seed: int
    gel: Gel
    needle_d: float
    needle_l: float
    formula: tuple  # (x, y, z) strings
    shape: str  # one-line description of the path
    obstacles: list = field(default_factory=list)
    # Filled by the checks:
    pts: list = field(default_factory=list)
    info: dict = field(default_factory=dict)

    @property
    def puncture(self):
        return BENCH_PUNCTURE * self.needle_d * math.sqrt(self.gel.young_kpa / 20.0)

    @property
    def beams(self):
        return max(20, round(self.needle_l / 3.0))


# ---------------------------------------------------------------------------------------------
# Drawing.


def log_uniform(rng, lo, hi):
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


def direction(rng, plane):
    """A unit lateral direction: along ±x, ±y, or oblique (30-60 deg from x in any quadrant)."""
    if plane == "x":
        return (rng.choice((-1.0, 1.0)), 0.0)
    if plane == "y":
        return (0.0, rng.choice((-1.0, 1.0)))
    a = math.radians(rng.uniform(30.0, 60.0) + 90.0 * rng.randrange(4))
    return (math.cos(a), math.sin(a))


def lateral_formula(rng, kind, depth):
    """The path of a kind relative to its entry point, drawn from `rng`, for a vertical `depth`.

    Returns (x terms, y terms, z terms, one-line description); each term is (coefficient,
    expression of s), the expression "1" being a constant. x = entry x + sum of the x terms, and
    likewise for y; z = top + sum of the z terms.
    """
    shape, plane = kind.split("_")[0], kind.split("_")[-1]
    zterms = [(-depth, "s")]
    if shape == "bend":
        d = direction(rng, plane)
        b = rng.uniform(5.0, 12.0)
        p = round(rng.uniform(1.5, 2.5), 2)
        e = f"s^{num(p)}"
        xs = [(b * d[0], e)]
        ys = [(b * d[1], e)]
        text = f"bends {b:.1f} mm as s^{num(p)} towards ({d[0]:.2f}, {d[1]:.2f})"
    elif shape == "scurve":
        d = direction(rng, plane)
        a = rng.uniform(2.0, 5.0)
        k = rng.uniform(0.8, 1.2)
        e = f"sin({num(2 * k)}*PI*s)"
        xs = [(a * d[0], e)]
        ys = [(a * d[1], e)]
        text = f"S-curve ±{a:.1f} mm, {k:.2f} periods, along ({d[0]:.2f}, {d[1]:.2f})"
        if plane == "xy":
            # Plus a drift across the S (like the `complex` benchmark's 5 s² in y).
            b = rng.uniform(2.0, 8.0) * rng.choice((-1.0, 1.0))
            xs.append((-b * d[1], "s^2"))
            ys.append((b * d[0], "s^2"))
            text += f", drifting {b:+.1f} mm across"
    elif shape == "helix":
        r = rng.uniform(2.0, 5.0)
        turns = rng.uniform(0.25, 0.6) if plane == "half" else rng.uniform(0.6, 1.0)
        phi = rng.uniform(0.0, 2.0 * math.pi)
        hand = rng.choice((-1.0, 1.0))
        w = f"{num(2 * turns * hand)}*PI*s + {num(phi)}"
        # Centre chosen so that s = 0 is the entry point.
        xs = [(r, f"cos({w})"), (-r * math.cos(float(num(phi))), "1")]
        ys = [(r, f"sin({w})"), (-r * math.sin(float(num(phi))), "1")]
        text = f"helix r {r:.1f} mm, {turns:.2f} turn {'left' if hand > 0 else 'right'}-handed"
    elif shape == "arc":
        # Circular arc in a vertical plane, vertical at the entry, 10 mm sideways at the end.
        d = direction(rng, plane)
        offset = 10.0
        radius = (depth * depth + offset * offset) / (2.0 * offset)
        theta = math.asin(depth / radius)
        e = f"(1 - cos({num(theta)}*s))"
        xs = [(radius * d[0], e)]
        ys = [(radius * d[1], e)]
        zterms = [(-radius, f"sin({num(theta)}*s)")]
        text = f"circular arc r {radius:.1f} mm, 10 mm sideways along ({d[0]:.2f}, {d[1]:.2f})"
    elif shape == "tilt":
        lo, hi = (0.0, 15.0) if plane == "small" else (15.0, 30.0)
        tilt = rng.uniform(lo, hi)
        az = rng.uniform(0.0, 2.0 * math.pi)
        t = depth * math.tan(math.radians(tilt))
        xs = [(t * math.cos(az), "s")]
        ys = [(t * math.sin(az), "s")]
        text = f"straight, tilted {tilt:.1f} deg towards azimuth {math.degrees(az):.0f} deg"
    else:
        raise ValueError(kind)
    return xs, ys, zterms, text


def footprint(xs, ys):
    """Centre of the lateral bounding box of the offsets (s sampled)."""
    u = [sum(c * eval_formula(e, i / 100) for c, e in xs) for i in range(101)]
    v = [sum(c * eval_formula(e, i / 100) for c, e in ys) for i in range(101)]
    return (min(u) + max(u)) / 2, (min(v) + max(v)) / 2


# The slots: name -> (kind of path, what varies besides the path, gel kind).
# `path` is the path kind; "any" draws one of the curved path kinds.
CURVED_KINDS = ["bend_x", "bend_y", "bend_xy", "scurve_x", "scurve_y", "scurve_xy", "helix_half", "helix_full", "arc_x", "arc_y", "arc_xy"]

SLOTS = [
    # name, path kind, scenario, one-line kind description
    ("bend_x", "bend_x", "path", "path bent in x (s^1.5-s^2.5, 5-12 mm)"),
    ("bend_y", "bend_y", "path", "path bent in y (s^1.5-s^2.5, 5-12 mm)"),
    ("bend_xy", "bend_xy", "path", "path bent obliquely in x and y"),
    ("scurve_x", "scurve_x", "path", "S-curve in x (±2-5 mm)"),
    ("scurve_y", "scurve_y", "path", "S-curve in y (±2-5 mm)"),
    ("scurve_xy", "scurve_xy", "path", "oblique S-curve drifting across (like `complex`)"),
    ("helix_half", "helix_half", "path", "helix of 0.25-0.6 turn"),
    ("helix_full", "helix_full", "path", "helix of 0.6-1 turn"),
    ("arc_x", "arc_x", "path", "circular arc, 10 mm offset in x"),
    ("arc_y", "arc_y", "path", "circular arc, 10 mm offset in y"),
    ("arc_xy", "arc_xy", "path", "circular arc, 10 mm offset obliquely"),
    ("tilt_small", "tilt_small", "path", "straight entry tilted 0-15 deg"),
    ("tilt_large", "tilt_large", "path", "straight entry tilted 15-30 deg"),
    ("place_right", "any", "place_right", "gel to the robot's right (azimuth -60..-20 deg), any height, sized otherwise"),
    ("place_ahead", "any", "place_ahead", "gel ahead of the robot (azimuth ±15 deg), nearer or farther, any height, sized otherwise"),
    ("place_left", "any", "place_left", "gel to the robot's left (azimuth 20..60 deg), any height, sized otherwise"),
    ("gmsh_box", "any", "gmsh_box", "unstructured Gmsh mesh of the benchmark box"),
    ("gmsh_cylinder", "any", "gmsh_cylinder", "unstructured Gmsh mesh of a cylindrical gel"),
    ("gel_soft", "any", "soft", "very soft gel, 3-5 kPa"),
    ("gel_stiff", "any", "stiff", "stiff gel, 70-100 kPa"),
    ("gel_incompressible", "any", "incompressible", "nearly incompressible gel, ν 0.48-0.49"),
    ("needle_thin", "any", "thin", "thin needle, Ø 0.5-0.6 mm"),
    ("needle_thick_long", "any", "thick", "thick long needle, Ø 1.35-1.5 mm, 170-200 mm"),
    ("obstacles_tight", "any", "tight", "three obstacles 0.2-0.5 mm outside the needle's surface"),
]


def draw(rng, slot, path_kind, scenario, seed):
    """One candidate scene of a slot (unchecked)."""
    # Defaults: the benchmark's gel box and place, a random material and needle.
    cx, cy = BENCH_CENTER
    bottom = 0.0
    size = BENCH_SIZE
    shape = "box"
    mesh = "box"
    young = log_uniform(rng, 5.0, 60.0)
    poisson = rng.uniform(0.3, 0.49)
    d = rng.uniform(0.6, 1.4)
    length = rng.uniform(100.0, 200.0)
    n_obst = rng.choice((0, 1, 1, 2, 2))
    gap_hi = MAX_GAP
    if path_kind == "any":
        # A curved path: once inserted, a straight needle along a straight path does not load the
        # gel (no tip force after puncture), so the slot's gel, mesh or needle would not matter.
        path_kind = rng.choice(CURVED_KINDS)
    if scenario.startswith("place"):
        lo_az = {"place_right": -60.0, "place_ahead": -15.0, "place_left": 20.0}[scenario]
        az = math.radians(rng.uniform(lo_az, lo_az + 40.0 if lo_az != -15.0 else 15.0))
        rad = rng.uniform(220.0, 380.0)
        cx, cy = rad * math.cos(az), rad * math.sin(az)
        bottom = rng.uniform(-60.0, 60.0)
        size = (rng.uniform(60.0, 100.0), rng.uniform(50.0, 80.0), rng.uniform(50.0, 70.0))
    elif scenario == "gmsh_box":
        mesh = "gmsh"
    elif scenario == "gmsh_cylinder":
        mesh = "gmsh"
        shape = "cylinder"
        dia = rng.uniform(60.0, 90.0)
        size = (dia, dia, 60.0)
    elif scenario == "soft":
        young = rng.uniform(3.0, 5.0)
    elif scenario == "stiff":
        young = rng.uniform(70.0, 100.0)
    elif scenario == "incompressible":
        poisson = rng.uniform(0.48, 0.49)
    elif scenario == "thin":
        d = rng.uniform(0.5, 0.6)
    elif scenario == "thick":
        d = rng.uniform(1.35, 1.5)
        length = rng.uniform(170.0, 200.0)
    elif scenario == "tight":
        n_obst = 3
    gel = Gel(shape, (round(cx, 1), round(cy, 1)), round(bottom, 1), tuple(round(v, 1) for v in size), round(young, 1), round(poisson, 3), mesh)
    d = round(d, 2)
    length = round(length, 1)
    if scenario == "tight":
        gap_hi = d / 2 + 0.5

    depth = gel.size[2] - 10.0
    xs, ys, zterms, text = lateral_formula(rng, path_kind, depth)
    # Centre the path's footprint on the gel, then jitter it within ±5 mm.
    fu, fv = footprint(xs, ys)
    ex = gel.center[0] - fu + rng.uniform(-5.0, 5.0)
    ey = gel.center[1] - fv + rng.uniform(-5.0, 5.0)
    fx = lin(ex, xs)
    fy = lin(ey, ys)
    fz = lin(gel.top, zterms)
    sc = Scene(slot, path_kind, scenario, seed, gel, d, length, (fx, fy, fz), text)
    sc.pts = sample_path(fx, fy, fz)
    r_needle = d / 2
    for k in range(n_obst):
        sc.obstacles.append(draw_obstacle(rng, sc, k, r_needle + MIN_GAP_OVER_RADIUS, gap_hi))
    return sc


def draw_obstacle(rng, sc, k, gap_lo, gap_hi):
    """A sphere beside the path: its surface `gap` from the rest path, measured as the closest
    approach of the whole polyline (a curved path may come closer elsewhere than at the foot)."""
    pts = sc.pts
    total = arc_length(pts)
    l = rng.uniform(0.15, 0.95) * total
    p, t = point_at(pts, l)
    # A random direction perpendicular to the tangent.
    helper = (1.0, 0.0, 0.0) if abs(t[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = unit(cross(t, helper))
    e2 = cross(t, e1)
    a = rng.uniform(0.0, 2.0 * math.pi)
    n = add(mul(e1, math.cos(a)), mul(e2, math.sin(a)))
    radius = round(rng.uniform(1.5, 3.5), 2)
    gap = rng.uniform(gap_lo, gap_hi)
    # Push outwards until the closest approach of the polyline is the drawn gap.
    off = radius + gap
    for _ in range(60):
        c = tuple(round(v, 3) for v in add(p, mul(n, off)))
        real = polyline_distance(c, pts) - radius
        if abs(real - gap) < 1e-3:
            break
        off += gap - real
    c = tuple(round(v, 3) for v in add(p, mul(n, off)))
    return Obstacle(f"o{k + 1}", c, radius, polyline_distance(c, pts) - radius)


# ---------------------------------------------------------------------------------------------
# Checks.


def check_scene(sc):
    g = sc.gel
    pts = sc.pts
    # Path inside the gel.
    if abs(pts[0][2] - g.top) > 1e-9:
        raise Reject("path does not start on the top face")
    for p in pts[1:]:
        if p[2] > g.top + 1e-9:
            raise Reject("path leaves the gel through the top")
        if p[2] < g.bottom + BOTTOM_MARGIN:
            raise Reject(f"path comes within {BOTTOM_MARGIN} mm of the fixed bottom")
    wall = min(g.wall_distance(p) for p in pts)
    if wall < WALL_MARGIN:
        raise Reject(f"path within {WALL_MARGIN} mm of a side wall")
    t0 = entry_tangent(pts)
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, -t0[2]))))
    if tilt > MAX_ENTRY_TILT_DEG:
        raise Reject(f"entry tilted more than {MAX_ENTRY_TILT_DEG} deg")
    length = arc_length(pts)
    # Obstacles.
    r_needle = sc.needle_d / 2
    for i, o in enumerate(sc.obstacles):
        lo, hi = o.center, o.radius + OBSTACLE_WALL_MARGIN
        if g.wall_distance(lo) < hi or lo[2] - g.bottom < hi or g.top - lo[2] < hi:
            raise Reject("obstacle not wholly inside the gel")
        if not (r_needle + MIN_GAP_OVER_RADIUS - 1e-3 <= o.gap <= MAX_GAP + 1e-3):
            raise Reject("obstacle gap outside [needle radius + 0.2, 1.5] mm")
        for q in sc.obstacles[:i]:
            if norm(sub(o.center, q.center)) < o.radius + q.radius + OBSTACLE_SEPARATION:
                raise Reject("obstacles touch each other")
    # Needle: no buckling before puncture (pinned-pinned Euler load of the whole needle).
    inertia = math.pi * sc.needle_d**4 / 64.0
    p_cr = math.pi**2 * NEEDLE_E * inertia / sc.needle_l**2
    if p_cr < BUCKLING_SAFETY * sc.puncture:
        raise Reject("needle would buckle before puncturing the gel")
    # Flange above the gel at the end: rigid needle along the end tangent, and straight along
    # the entry tangent.
    end, t_end = pts[-1], unit(sub(pts[-1], pts[-2]))
    base_end = sub(end, mul(t_end, sc.needle_l))
    flange = min(base_end[2] - g.top, (sc.needle_l - length) * -t0[2])
    if flange < FLANGE_CLEARANCE:
        raise Reject("needle too short: the flange would come within 25 mm of the gel")
    # Robot: the start pose, then the needle pivoting about the entry point along the path.
    q_start, worst, start_note = robot_start(sc, t0, length)
    sc.info = {
        "length": length,
        "tilt": tilt,
        "wall": wall,
        "flange": flange,
        "q_start": q_start,
        "start_note": start_note,
        "limit_margin": worst,
        "p_cr": p_cr,
    }


def pivot_path_margin(sc, q, length):
    """Follows the path with the needle pivoting about the entry point (its axis from the entry
    point to the tip, the inserted length along the path outside; the inverse controller's angular
    objective beyond the blend distance) from joints q: the smallest joint-limit margin [deg], or
    a Reject."""
    pts = sc.pts
    entry = pts[0]
    t0 = entry_tangent(pts)
    worst = limit_margin_deg(q)[0]
    l = 0.0
    while l < length:
        l = min(l + 2.0, length)
        tip, _ = point_at(pts, l)
        chord = sub(tip, entry)
        axis = unit(chord) if norm(chord) > 5.0 else t0
        base = sub(entry, mul(axis, sc.needle_l - l))
        q, perr, ang = solve_ik(base, axis, q, max_iterations=2000)
        if not (perr <= 1e-2 and ang <= 1e-3):
            raise Reject("needle pose along the path out of the robot's reach")
        margin, joint = limit_margin_deg(q)
        if margin < PATH_LIMIT_MARGIN_DEG:
            raise Reject(f"needle pose along the path within {PATH_LIMIT_MARGIN_DEG} deg of a joint limit (J{joint + 1})")
        worst = min(worst, margin)
    return worst


def start_seeds():
    """IK seeds for the start pose: mid-range (what `needle run` uses), then the wrist turned."""
    mid = [(lo + hi) / 2 for lo, hi in LIMITS]
    yield mid
    for j4 in (-90.0, 90.0, -150.0, 150.0, 0.0):
        for j5 in (-45.0, 45.0):
            q = list(mid)
            q[3], q[4] = math.radians(j4), math.radians(j5)
            yield q


def robot_start(sc, t0, length):
    """The start joints: the project's IK from mid-range when that start is at least
    START_LIMIT_MARGIN inside the limits and the path can be followed from it; else, of the IK
    solutions from the other seeds whose start and path pass, the one that stays farthest from
    the joint limits (written into the scene as start_joints_deg).
    Returns (joints [deg] or None for the project's own IK, the path's joint margin, a note)."""
    tip0 = sub(sc.pts[0], mul(t0, APPROACH))
    base0 = sub(tip0, mul(t0, sc.needle_l))
    first = None
    best = None
    for k, seed in enumerate(start_seeds()):
        q, perr, ang = solve_ik(base0, t0, seed)
        if not (perr <= 1e-3 and ang <= 1e-4):
            why = "start pose out of the robot's reach"
        else:
            margin, joint = limit_margin_deg(q)
            if margin < START_LIMIT_MARGIN_DEG:
                why = f"start pose within {START_LIMIT_MARGIN_DEG} deg of a joint limit (J{joint + 1})"
            else:
                try:
                    worst = pivot_path_margin(sc, q, length)
                except Reject as e:
                    why = str(e)
                else:
                    if k == 0:
                        return None, worst, "the project's IK from mid-range"
                    if best is None or worst > best[0]:
                        best = (worst, q, seed)
                    continue
        if first is None:
            first = why
    if best is None:
        raise Reject(first)
    worst, q, seed = best
    note = (
        f"the project's IK from mid-range: {first}; IK from J4 = {math.degrees(seed[3]):.0f}, "
        f"J5 = {math.degrees(seed[4]):.0f} deg instead (the passing start farthest from the limits)"
    )
    return [math.degrees(v) for v in q], worst, note


# ---------------------------------------------------------------------------------------------
# Gmsh meshes.


def gmsh_mesh(sc, path):
    """An unstructured Gmsh tetrahedral mesh of the gel, about NODES nodes, written as MSH 4.1
    ASCII. Single-threaded Delaunay with a fixed random seed: the same input gives the same file."""
    import gmsh  # noqa: PLC0415 (only needed here)

    g = sc.gel
    lo = g.box_min()

    def build(h):
        gmsh.clear()
        gmsh.model.add("gel")
        if g.shape == "cylinder":
            gmsh.model.occ.addCylinder(g.center[0], g.center[1], g.bottom, 0.0, 0.0, g.size[2], g.size[0] / 2)
        else:
            gmsh.model.occ.addBox(lo[0], lo[1], lo[2], g.size[0], g.size[1], g.size[2])
        gmsh.model.occ.synchronize()
        vols = [t for _, t in gmsh.model.getEntities(3)]
        gmsh.model.addPhysicalGroup(3, vols, name="gel")
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(3)
        tags, _, _ = gmsh.model.mesh.getNodes()
        return len(tags)

    gmsh.initialize(["gen_suite"], readConfigFiles=False)
    try:
        for name, v in GMSH_OPTIONS:
            gmsh.option.setNumber(name, v)
        # Bisection on the element size for NODES ± 3 %.
        vol = (math.pi / 4 if g.shape == "cylinder" else 1.0) * g.size[0] * g.size[1] * g.size[2]
        h_lo, h_hi = 0.5 * (vol / NODES) ** (1 / 3), 3.0 * (vol / NODES) ** (1 / 3)
        h = (h_lo + h_hi) / 2
        for _ in range(30):
            h = round((h_lo + h_hi) / 2, 4)
            n = build(h)
            if abs(n - NODES) <= 0.03 * NODES:
                break
            if n > NODES:
                h_lo = h
            else:
                h_hi = h
        else:
            raise Reject("no Gmsh element size gives about 1500 nodes")
        gmsh.write(path)
        _, elem_tags, _ = gmsh.model.mesh.getElements(3)
        return n, sum(len(t) for t in elem_tags), h
    finally:
        gmsh.finalize()


# ---------------------------------------------------------------------------------------------
# Writing.


def fmt(x, digits=3):
    t = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    if "." not in t and "e" not in t:
        t += ".0"
    return "0.0" if t == "-0.0" else t


def fvec(v, digits=3):
    return "[" + ", ".join(fmt(x, digits) for x in v) + "]"


def scene_toml(sc, mesh_info):
    g = sc.gel
    i = sc.info
    desc = f"{SLOT_DESC[sc.slot]}: {sc.shape}"
    lines = [
        f"# Generated by tools/gen_suite.py --seed {sc.seed} (slot `{sc.slot}`): do not edit, re-run the generator.",
        f"# Kind: {SLOT_DESC[sc.slot]}; path kind `{sc.kind}`.",
        f"# Path: {sc.shape}; {i['length']:.1f} mm long in the gel, entry tilted {i['tilt']:.1f} deg.",
        f"# Gel: {g.shape} centred at ({g.center[0]:.1f}, {g.center[1]:.1f}), bottom z = {g.bottom:.1f}, "
        f"{g.size[0]:.1f} x {g.size[1]:.1f} x {g.size[2]:.1f} mm, {g.young_kpa:.1f} kPa, nu {g.poisson:.3f}.",
        f"# Needle: Ø {sc.needle_d:.2f} x {sc.needle_l:.1f} mm; Euler load {i['p_cr']:.2f} N against puncture {sc.puncture:.3f} N "
        f"(0.2 N x Ø/1 mm x sqrt(E/20 kPa)); flange {i['flange']:.0f} mm above the gel at the end.",
        f"# Checks: path ≥ {i['wall']:.1f} mm from the side walls; start joints: {i['start_note']}; "
        f"needle pivoting about the entry point along the path ≥ {i['limit_margin']:.1f} deg inside the joint limits.",
        "# Units: mm, N, MPa, s, rad. Every field is described in docs/scene-format.md.",
        f'name = "{sc.slot}"',
        f'description = "{desc} (tools/gen_suite.py, seed {sc.seed})"',
        "",
        "[robot]",
        'preset = "rv1a"          # Mitsubishi RV-1A, DH table of DESIGN.md',
        "dt = 0.04                # control period [s]",
        *(
            [f"start_joints_deg = {fvec(i['q_start'], 9)}  # see the header"]
            if i["q_start"] is not None
            else []
        ),
        "",
        "[robot.tool]             # needle base at the flange, along flange z",
        "translation = [0.0, 0.0, 0.0]",
        "rpy = [0.0, 0.0, 0.0]",
        "",
        "[gel]",
    ]
    if g.mesh == "gmsh":
        n, m, h = mesh_info
        lines.append(f'mesh = "{sc.slot}.msh"  # Gmsh {g.shape}: {n} nodes, {m} tetrahedra, element size {h} mm')
    lines += [
        f"young_modulus = {fmt(g.young_kpa / 1000.0, 4)}  # {g.young_kpa:.1f} kPa",
        f"poisson_ratio = {fmt(g.poisson, 3)}",
        "density = 1.0e-9         # 1000 kg/m³",
        "",
    ]
    if g.mesh == "box":
        lines += [
            "[gel.box]",
            f"min = {fvec(g.box_min(), 2)}",
            f"max = {fvec(g.box_max(), 2)}",
            f"nodes = {NODES}",
            "",
        ]
    lines += [
        "[gel.fixed]",
        f"below_z = {fmt(g.bottom, 2)}           # the bottom face is fixed",
        "",
        "[needle]",
        f"length = {fmt(sc.needle_l, 1)}",
        f"diameter = {fmt(sc.needle_d, 2)}",
        "young_modulus = 200000.0",
        "poisson_ratio = 0.3",
        "density = 7.85e-9        # steel",
        f"beams = {sc.beams}               # about 3 mm each",
        "",
        "[interaction]",
        f"puncture_force = {fmt(sc.puncture, 4)}  # p_f [N]",
        "surface_friction = 0.3   # μ_s",
        "shaft_friction = 0.1     # μ_n",
        "shaft_resistance = 0.0   # r_0 [N]",
        "constraint_spacing = 10.0  # d_n [mm]",
        "",
        "[inverse]",
        "delta_q = 0.01           # [rad]",
        "blend_distance = 20.0    # d [mm]",
        'jacobian = "hybrid"',
        "max_base_step = 5.0      # [mm]",
        "",
        "[path]",
        f"approach = {fmt(APPROACH, 1)}",
        f"samples = {SAMPLES}",
        f'formula = {{ x = "{sc.formula[0]}", y = "{sc.formula[1]}", z = "{sc.formula[2]}" }}',
        "",
    ]
    for o in sc.obstacles:
        lines += [
            "[[obstacles]]",
            f'name = "{o.name}"',
            f"center = {fvec(o.center, 3)}",
            f"radius = {fmt(o.radius, 2)}  # surface {o.gap:.2f} mm from the rest path's centre line",
            "",
        ]
    lines += [
        "[insertion]",
        "advance_per_step = 0.1   # path length per step [mm]",
        "",
    ]
    return "\n".join(lines)


SLOT_DESC = {name: desc for name, _, _, desc in SLOTS}


def generate(seed, out, only=None):
    # Gmsh slots need the gmsh module: refuse before writing anything rather than leave a
    # partial set (the earlier slots written, the rest missing).
    needs_gmsh = [n for n, _, scenario, _ in SLOTS if scenario.startswith("gmsh") and (not only or n in only)]
    if needs_gmsh:
        try:
            import gmsh  # noqa: F401, PLC0415
        except ImportError:
            raise SystemExit(
                f"gen_suite.py: the slots {', '.join(needs_gmsh)} need the gmsh Python module, which is "
                "missing: pip install -r tools/requirements.txt (or --only the other slots); nothing written"
            ) from None
    os.makedirs(out, exist_ok=True)
    rows = []
    for name, path_kind, scenario, desc in SLOTS:
        if only and name not in only:
            continue
        rng = random.Random(f"{seed}/{name}")
        rejects = {}
        for _ in range(MAX_TRIES):
            sc = draw(rng, name, path_kind, scenario, seed)
            try:
                check_scene(sc)
                break
            except Reject as e:
                rejects[str(e)] = rejects.get(str(e), 0) + 1
        else:
            raise SystemExit(f"{name}: no acceptable scene in {MAX_TRIES} draws: {rejects}")
        mesh_info = None
        if sc.gel.mesh == "gmsh":
            mesh_info = gmsh_mesh(sc, os.path.join(out, f"{name}.msh"))
        with open(os.path.join(out, f"{name}.toml"), "w", encoding="utf-8", newline="\n") as f:
            f.write(scene_toml(sc, mesh_info))
        rej = "; ".join(f"{v}x {k}" for k, v in sorted(rejects.items())) or "none"
        print(f"{name}: {sc.kind}, {sc.shape}; rejected draws: {rej}", file=sys.stderr)
        g = sc.gel
        varies = (
            f"{sc.shape}; gel {g.shape} at ({g.center[0]:.0f}, {g.center[1]:.0f}, {g.bottom:.0f}) "
            f"{g.size[0]:.0f}x{g.size[1]:.0f}x{g.size[2]:.0f}, {g.young_kpa:.1f} kPa, ν {g.poisson:.2f}"
            f"{', Gmsh' if g.mesh == 'gmsh' else ''}; needle Ø {sc.needle_d:.2f} x {sc.needle_l:.0f}; "
            f"{len(sc.obstacles)} obstacle(s)"
            + (f" (gap {', '.join(f'{o.gap:.2f}' for o in sc.obstacles)} mm)" if sc.obstacles else "")
        )
        rows.append(f"| `{name}` | {desc} | {varies} | {seed} |")
    print("\n".join(rows))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED, help=f"random seed (default {DEFAULT_SEED})")
    ap.add_argument("--out", default="scenes/suite", help="output folder (default scenes/suite)")
    ap.add_argument("--only", nargs="*", help="write only these slots")
    ap.add_argument("--list", action="store_true", help="list the slots and exit")
    a = ap.parse_args()
    if a.list:
        for name, path_kind, scenario, desc in SLOTS:
            print(f"{name:18} {path_kind:12} {scenario:14} {desc}")
        return
    generate(a.seed, a.out, a.only)


if __name__ == "__main__":
    main()
