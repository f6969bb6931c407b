#!/usr/bin/env python3
"""Opens every VTK file of a run folder with VTK's XML reader (ParaView's) and with meshio.

    python3 tests/vtk/check_vtk.py DIR

Checks, and exits non-zero naming the file on any failure:
- every `.pvd` collection parses, names files that exist, starts at time 0 with increasing
  times, and `run.pvd` has the five parts of every frame;
- every `.vtu` opens in VTK's reader without error and (unless empty) in meshio, both see the same points
  and cells, the arrays of each object are present with one tuple per point or cell and
  finite values, and its `TimeValue` is the collection's time;
- the gel's points are at rest: the same in every frame, the motion is in `displacement`.
"""
import glob
import math
import os
import sys
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy

EXPECTED = {
    "gel": (["displacement"], ["strain", "von_mises_kPa", "region", "inverted"]),
    "needle": (["constraint_force_N", "arc_length_mm"], []),
    "path": (["arc_length_mm"], []),
    "obstacles": ([], ["obstacle", "radius_mm", "clearance_mm"]),
    "constraints": (["force_N", "lambda_N", "kind", "id"], []),
}
PARTS = list(EXPECTED)


class Failure(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failure(what)




def read_vtk(path):
    """The grid read by VTK's XML reader; a reader error or warning fails."""
    errors = []
    obs = vtk.vtkFileOutputWindow()  # keep VTK quiet on stderr; errors are caught below
    vtk.vtkOutputWindow.SetInstance(obs)
    obs.SetFileName(os.devnull)
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.AddObserver("ErrorEvent", lambda *a: errors.append("error"))
    reader.AddObserver("WarningEvent", lambda *a: errors.append("warning"))
    reader.SetFileName(path)
    reader.Update()
    check(not errors and reader.GetErrorCode() == 0, f"{path}: VTK's reader reported {errors}")
    return reader.GetOutput()


def arrays(data):
    return {data.GetArrayName(i): vtk_to_numpy(data.GetArray(i)) for i in range(data.GetNumberOfArrays())}


def check_vtu(path, time):
    part = os.path.basename(path).rsplit("_", 1)[0]
    check(part in EXPECTED, f"{path}: unknown object {part!r}")
    g = read_vtk(path)
    n, m = g.GetNumberOfPoints(), g.GetNumberOfCells()
    pd, cd = arrays(g.GetPointData()), arrays(g.GetCellData())
    want_p, want_c = EXPECTED[part]
    for name in want_p:
        check(name in pd, f"{path}: point array {name!r} missing (has {list(pd)})")
        check(len(pd[name]) == n, f"{path}: {name} has {len(pd[name])} tuples for {n} points")
    for name in want_c:
        check(name in cd, f"{path}: cell array {name!r} missing (has {list(cd)})")
        check(len(cd[name]) == m, f"{path}: {name} has {len(cd[name])} tuples for {m} cells")
    for name, a in {**pd, **cd}.items():
        # The clearance is +inf before the needle enters the gel (nothing inserted to measure).
        ok = np.isfinite(a) | (np.isposinf(a) if name == "clearance_mm" else False)
        check(np.all(ok), f"{path}: {name} is not finite")
    fd = arrays(g.GetFieldData())
    check("TimeValue" in fd, f"{path}: no TimeValue field")
    check(math.isclose(fd["TimeValue"][0], time, rel_tol=1e-12, abs_tol=1e-12),
          f"{path}: TimeValue {fd['TimeValue'][0]} but the collection says {time}")
    if n == 0:
        # meshio 5.3 cannot read an empty grid (the constraints before the first step); VTK did.
        return part, g
    mesh = meshio.read(path)
    check(len(mesh.points) == n, f"{path}: meshio reads {len(mesh.points)} points, VTK {n}")
    check(sum(len(c.data) for c in mesh.cells) == m, f"{path}: meshio reads other cells than VTK")
    check(np.array_equal(mesh.points, vtk_to_numpy(g.GetPoints().GetData())),
          f"{path}: meshio and VTK read other points")
    for name in want_p:
        check(np.array_equal(np.asarray(mesh.point_data[name]).reshape(pd[name].shape), pd[name]),
              f"{path}: meshio and VTK read other {name}")
    return part, g


def main(folder):
    pvds = sorted(glob.glob(os.path.join(folder, "*.pvd")))
    check(pvds, f"{folder}: no .pvd collection")
    seen = set()
    rest = None
    for pvd in pvds:
        root = ET.parse(pvd).getroot()
        check(root.get("type") == "Collection", f"{pvd}: not a VTK collection")
        sets = root.findall("./Collection/DataSet")
        check(sets, f"{pvd}: empty")
        times = [float(d.get("timestep")) for d in sets]
        check(times[0] == 0.0, f"{pvd}: first time {times[0]}, not 0")
        check(all(a <= b for a, b in zip(times, times[1:])), f"{pvd}: times not increasing")
        if os.path.basename(pvd) == "run.pvd":
            frames = {}
            for d in sets:
                frames.setdefault(float(d.get("timestep")), []).append(d.get("file"))
            check(all(len(f) == len(PARTS) for f in frames.values()), f"{pvd}: a frame lacks a part")
        for d in sets:
            f = os.path.join(folder, d.get("file"))
            check(os.path.isfile(f), f"{pvd}: names {d.get('file')}, which does not exist")
            if f in seen:
                continue
            seen.add(f)
            part, g = check_vtu(f, float(d.get("timestep")))
            if part == "gel":
                pts = vtk_to_numpy(g.GetPoints().GetData())
                if rest is None:
                    rest = pts
                check(np.array_equal(pts, rest), f"{f}: the gel's points moved (should stay at rest)")
    on_disk = set(glob.glob(os.path.join(folder, "*.vtu")))
    check(on_disk == seen, f"{folder}: files in no collection: {sorted(on_disk - seen)}")
    print(f"check_vtk: {len(seen)} .vtu files and {len(pvds)} collections of {folder} open in "
          f"VTK {vtk.vtkVersion.GetVTKVersion()} and meshio {meshio.__version__}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: check_vtk.py DIR")
    try:
        main(sys.argv[1])
    except (Failure, Exception) as e:  # any reader exception is a failure too
        sys.exit(f"check_vtk: FAILED: {e}")
