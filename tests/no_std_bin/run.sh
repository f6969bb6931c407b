#!/usr/bin/env bash
# Builds the no_std smoke binary (needle-core + libc only) and runs it; fails loudly.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cargo build --release --manifest-path "$here/Cargo.toml"
target="${CARGO_TARGET_DIR:-$here/target}"
bin="$target/release/needle-no-std-bin"
if [[ ! -x "$bin" ]]; then
    echo "no_std_bin: binary $bin not found" >&2
    exit 1
fi
set +e
out="$("$bin")"
rc=$?
set -e
echo "$out"
if [[ $rc -ne 0 ]]; then
    echo "no_std_bin: FAILED with exit code $rc" >&2
    exit "$rc"
fi
if [[ "$out" != *"finite=true"* ]]; then
    echo "no_std_bin: FAILED: unexpected output" >&2
    exit 1
fi
echo "no_std_bin: OK"
