#!/usr/bin/env python3
"""Gate of the core's instruction counts (deterministic, unlike wall time).

Runs the gungraun benches of the core's inverse step (valgrind's callgrind), reads the
instruction count (Ir) of each bench and compares it with the committed baseline
`core/benches/instructions_baseline.json`. Fails (exit 1) when a bench counts more than 10 % above
its baseline, or when a bench of the baseline is missing. `--update` writes the counts measured as
the new baseline instead.

Needs valgrind and `gungraun-runner` at the version of the `gungraun` crate (0.20.0):
`cargo install gungraun-runner --version 0.20.0 --locked`.
"""

import argparse
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
BASELINE = ROOT / "core" / "benches" / "instructions_baseline.json"
LIMIT = 0.10


def measure() -> dict:
    out = subprocess.run(
        ["cargo", "bench", "-p", "needle-core", "--bench", "inverse_instructions", "--",
         "--output-format=json"],
        cwd=ROOT, check=True, stdout=subprocess.PIPE, text=True,
    ).stdout
    counts = {}
    for line in out.splitlines():
        line = line.strip()
        if not line.startswith("{"):
            continue
        bench = json.loads(line)
        metrics = bench["profiles"][0]["data"]["parts"][0]["metrics"]
        counts[bench["id"]] = int(metrics["Ir"]["values"]["new"])
    if not counts:
        sys.exit("check_instructions: the bench printed no instruction count")
    return counts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--update", action="store_true", help="write the measured counts as the baseline")
    args = ap.parse_args()
    counts = measure()
    if args.update:
        BASELINE.write_text(json.dumps(counts, indent=2, sort_keys=True) + "\n")
        print(f"baseline written: {BASELINE.relative_to(ROOT)}")
        for k, v in sorted(counts.items()):
            print(f"  {k}: {v} instructions")
        return 0
    base = json.loads(BASELINE.read_text())
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
    passed = len(base) - failed
    print(f"instructions: {passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
