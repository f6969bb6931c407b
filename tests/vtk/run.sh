#!/usr/bin/env bash
# ParaView test of a run's VTK files (issue "outputs"): runs the simple scene with VTK frames
# every 100 steps and opens every `.vtu` and `.pvd` it wrote with VTK's own XML reader (the one
# ParaView uses) and meshio (tests/vtk/check_vtk.py); then checks that the checker refuses a
# truncated file. Installs the readers (tests/vtk/requirements.txt) into a virtual environment
# (tests/vtk/.venv, or $VTK_VENV) when missing. Exit code non-zero on any failure.
#
#   bash tests/vtk/run.sh
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
venv="${VTK_VENV:-$here/.venv}"
die() { echo "tests/vtk/run.sh: $*" >&2; exit 1; }

command -v python3 >/dev/null || die "python3 is missing"
if [ ! -x "$venv/bin/python" ]; then
  if ! python3 -m venv "$venv" 2>/dev/null; then
    [ "$(id -u)" -eq 0 ] || die "python3 -m venv failed; install python3-venv as root"
    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv \
      || die "apt-get install python3-venv failed"
    rm -rf "$venv"
    python3 -m venv "$venv" || die "python3 -m venv $venv failed"
  fi
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$here/requirements.txt" \
  || die "pip install -r $here/requirements.txt failed"

out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cd "$root"
cargo run --release -q -p needle-host --bin needle -- run simple --quiet --out "$out/run" \
  --vtk-every 100 || die "needle run simple failed (exit $?)"
"$venv/bin/python" "$here/check_vtk.py" "$out/run"

# The check must be able to fail: a truncated gel frame is refused.
cp -r "$out/run" "$out/broken"
truncate -s 2000 "$out/broken/gel_00300.vtu"
if "$venv/bin/python" "$here/check_vtk.py" "$out/broken" 2>"$out/err"; then
  die "check_vtk.py accepted a truncated file"
fi
grep -q "gel_00300.vtu" "$out/err" || die "the refusal does not name the file: $(cat "$out/err")"
echo "tests/vtk/run.sh: a truncated frame is refused: $(cat "$out/err")"
