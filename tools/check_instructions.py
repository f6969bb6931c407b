#!/usr/bin/env python3
"""Gate of the instruction counts of the core and the host (deterministic, unlike wall time).

Runs the gungraun benches (valgrind's callgrind) of the core's inverse step
(`core/benches/inverse_instructions.rs`) and of the host's per-step CPU kernels, the gel's
element pass and the needle's free motion (`host/benches/element_instructions.rs`), reads the
instruction count (Ir) of each bench and compares it with the committed baseline next to the
bench (`core/benches/instructions_baseline.json`, `host/benches/instructions_baseline.json`).
Fails (exit 1) when a bench counts more than 10 % above its baseline, or when a bench of a
baseline is missing. `--update` writes the counts measured as the new baselines instead.

Needs valgrind and `gungraun-runner` at the version of the `gungraun` crate (0.20.0):
`cargo install gungraun-runner --version 0.20.0 --locked`.
"""

import argparse
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
# (package, bench target, baseline file)
GATES = [
    ("needle-core", "inverse_instructions", ROOT / "core" / "benches" / "instructions_baseline.json"),
    ("needle-host", "element_instructions", ROOT / "host" / "benches" / "instructions_baseline.json"),
]
LIMIT = 0.10


def measure(package: str, bench: str) -> dict:
    out = subprocess.run(
        ["cargo", "bench", "-p", package, "--bench", bench, "--", "--output-format=json"],
        cwd=ROOT, check=True, stdout=subprocess.PIPE, text=True,
    ).stdout
    counts = {}
    for line in out.splitlines():
        line = line.strip()
        if not line.startswith("{"):
            continue
        result = json.loads(line)
        metrics = result["profiles"][0]["data"]["parts"][0]["metrics"]
        counts[result["id"]] = int(metrics["Ir"]["values"]["new"])
    if not counts:
        sys.exit(f"check_instructions: {package} bench {bench} printed no instruction count")
    return counts


def gate(counts: dict, base: dict) -> int:
    """Prints one line per bench; returns the number of failures."""
    failed = 0
    for k, b in sorted(base.items()):
        n = counts.get(k)
        if n is None:
            print(f"FAIL {k}: in the baseline but not measured")
            failed += 1
            continue
        change = n / b - 1.0
        verdict = "FAIL" if change > LIMIT else "ok"
        failed += verdict == "FAIL"
        print(f"{verdict:4} {k}: {n} instructions, baseline {b} ({change:+.1%}, limit +{LIMIT:.0%})")
    for k in sorted(set(counts) - set(base)):
        print(f"new  {k}: {counts[k]} instructions (not in the baseline: run with --update)")
    return failed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--update", action="store_true", help="write the measured counts as the baselines")
    args = ap.parse_args()
    total, failed = 0, 0
    for package, bench, baseline in GATES:
        counts = measure(package, bench)
        if args.update:
            baseline.write_text(json.dumps(counts, indent=2, sort_keys=True) + "\n")
            print(f"baseline written: {baseline.relative_to(ROOT)}")
            for k, v in sorted(counts.items()):
                print(f"  {k}: {v} instructions")
            continue
        if not baseline.exists():
            print(f"FAIL {baseline.relative_to(ROOT)}: no baseline (run with --update)")
            total += 1
            failed += 1
            continue
        base = json.loads(baseline.read_text())
        total += len(base)
        failed += gate(counts, base)
    if args.update:
        return 0
    print(f"instructions: {total - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
