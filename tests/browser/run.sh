#!/usr/bin/env bash
# Browser test of the replay page (docs/replay.md): builds the demo replay
# (host/examples/replay_demo.rs) and the replay of a real run (`needle run simple --out`) into a
# temporary folder and checks both in headless Chromium with replay.test.mjs. Installs what a fresh machine lacks: Debian's chromium (as root) and the
# pinned playwright-core (npm ci). Exit code non-zero on any failure.
#
#   bash tests/browser/run.sh                                  # the test
#   bash tests/browser/run.sh --screenshot docs/img/replay.png  # and keep its screenshot
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
keep_screenshot=""
while [ $# -gt 0 ]; do
  case "$1" in
    --screenshot) keep_screenshot="${2:?--screenshot needs a file}"; shift 2 ;;
    *) echo "usage: $0 [--screenshot FILE.png]" >&2; exit 2 ;;
  esac
done

die() { echo "run.sh: $*" >&2; exit 1; }
as_root_install() {
  [ "$(id -u)" -eq 0 ] || die "$1 is missing; install it as root: apt-get install -y $2"
  echo "run.sh: $1 is missing: apt-get install -y $2" >&2
  apt-get update -q || die "apt-get update failed"
  # shellcheck disable=SC2086 # $2 may name several packages
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q $2 || die "apt-get install -y $2 failed"
}

export CHROMIUM="${CHROMIUM:-/usr/bin/chromium}"
if [ ! -x "$CHROMIUM" ]; then
  as_root_install "$CHROMIUM" chromium
  [ -x "$CHROMIUM" ] || die "$CHROMIUM is still missing after installing chromium"
fi
command -v node >/dev/null || as_root_install node "nodejs npm"
command -v npm >/dev/null || as_root_install npm npm
node_major="$(node -p 'process.versions.node.split(".")[0]')"
[ "$node_major" -ge 20 ] || die "Node.js $(node --version) is too old: playwright-core needs Node.js 20 or later"
command -v cargo >/dev/null || die "cargo is missing (https://rustup.rs)"

(cd "$here" && npm ci --no-audit --no-fund --loglevel=error) || die "npm ci failed"

out="$(mktemp -d "${TMPDIR:-/tmp}/needle-replay-test.XXXXXX")"
# Two pages: the synthetic demo (mesh obstacles, 120 frames) and a real run of the simple scene
# (`needle run --out DIR` writes DIR/replay.html); the screenshot kept is the real run's.
(cd "$root" && cargo run --release --quiet -p needle-host --example replay_demo -- "$out/demo") \
  || die "the replay demo failed (output in $out)"
(cd "$root" && cargo run --release --quiet -p needle-host --bin needle -- run simple --quiet \
  --out "$out/run" >/dev/null) || die "needle run simple failed (output in $out)"

for page in demo run; do
  node "$here/replay.test.mjs" "$out/$page/replay.html" --screenshot "$out/$page/screenshot.png" \
    --template "$root/host/assets/replay.html" \
    || die "the browser test of the $page page failed; its replay and screenshot are in $out/$page"
done
if [ -n "$keep_screenshot" ]; then
  mkdir -p "$(dirname "$keep_screenshot")"
  cp "$out/run/screenshot.png" "$keep_screenshot"
  echo "screenshot kept in $keep_screenshot"
fi
rm -rf "$out"
