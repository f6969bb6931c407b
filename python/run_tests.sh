#!/usr/bin/env bash
# The Python bindings' tests: creates the virtual environment python/.venv when it is missing
# (Debian's system Python refuses `pip install` outside one), installs the pinned build backend,
# NumPy and pytest (requirements-test.txt), builds and installs the module `needle` in release
# (`pip install ./python`: maturin, pyo3), and runs python/tests with pytest. Fails loudly.
#
#   bash python/run_tests.sh                 # everything
#   bash python/run_tests.sh -k callback     # extra arguments go to pytest
#
# The Rust build goes to $CARGO_TARGET_DIR, by default the workspace's target/ (the crates the
# workspace's release build compiled are reused). The parity test runs the CLI `needle run
# simple --json` through `cargo run --release` (or $NEEDLE_BIN when set).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/.." && pwd)"
venv="$here/.venv"
python="${PYTHON:-python3}"

die() { echo "python/run_tests.sh: $*" >&2; exit 1; }

command -v cargo >/dev/null || die "cargo is missing (https://rustup.rs)"
command -v "$python" >/dev/null || die "$python is missing: apt-get install -y python3 python3-venv"

if [ ! -x "$venv/bin/python" ]; then
  echo "python/run_tests.sh: creating $venv with $("$python" --version 2>&1)"
  if ! "$python" -m venv "$venv"; then
    # Debian's python3 has no ensurepip without python3-venv.
    rm -rf "$venv"
    [ "$(id -u)" -eq 0 ] || die "$python -m venv failed; install python3-venv as root: apt-get install -y python3-venv"
    echo "python/run_tests.sh: $python -m venv failed: apt-get install -y python3-venv" >&2
    apt-get update -q || die "apt-get update failed"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv || die "apt-get install -y python3-venv failed"
    "$python" -m venv "$venv" || die "$python -m venv still fails after installing python3-venv"
  fi
fi
vpy="$venv/bin/python"
# As `source .venv/bin/activate`: maturin's build hook runs the `maturin` of PATH.
export VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH"

pip=("$vpy" -m pip --disable-pip-version-check)
"${pip[@]}" install -q -r "$here/requirements-test.txt" || die "pip install -r requirements-test.txt failed"

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target}"
echo "python/run_tests.sh: building and installing the module (release, CARGO_TARGET_DIR=$CARGO_TARGET_DIR)"
# The pinned maturin of the venv builds it (no isolated build environment to download); always
# rebuilt and reinstalled, whatever version the venv holds.
"${pip[@]}" install --no-build-isolation --no-deps --force-reinstall "$here" \
  || die "pip install ./python failed"

cd "$here"
set +e
"$vpy" -m pytest -v -rA "$@" tests
rc=$?
set -e
[ "$rc" -eq 0 ] || die "pytest failed (exit code $rc)"
echo "python/run_tests.sh: OK"
