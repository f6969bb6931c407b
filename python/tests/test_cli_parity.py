"""`needle.run` is `needle run`: the simple benchmark scene gives the CLI's figures.

The CLI is $NEEDLE_BIN when set, else `cargo run --release -p needle-host --bin needle` from
the repository (built when missing, into $CARGO_TARGET_DIR or target/).
"""

import json
import os
import subprocess

import pytest

import needle
from conftest import ROOT


def cli_run(*args):
    """`needle run ARGS --json --quiet`: its summary (the exit code is the outcome's)."""
    tail = ["run", *args, "--json", "--quiet"]
    binary = os.environ.get("NEEDLE_BIN")
    if binary:
        cmd = [binary, *tail]
    else:
        cmd = ["cargo", "run", "--release", "--quiet", "-p", "needle-host", "--bin", "needle", "--", *tail]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    # 0 reached, 3 diverged, 4 missed the target, 5 hit an obstacle, 6 reached off the path: a
    # summary in each case.
    assert done.returncode in (0, 3, 4, 5, 6), f"{' '.join(cmd)}: exit {done.returncode}\n{done.stderr}"
    return json.loads(done.stdout)


FIGURES = ("e_mean_mm", "e_max_mm", "e_final_mm", "e_last_mm", "final_depth_mm",
           "path_deviation_mean_mm", "path_deviation_max_mm", "target_shift_max_mm",
           "entry_shift_max_mm", "max_strain", "needle_strain_max")
COUNTS = ("outcome", "steps", "steps_planned", "steps_nominal", "steps_to_target",
          "puncture_step", "completed", "obstacle_hit", "gs_not_converged_steps")


def test_the_simple_scene_gives_the_clis_figures():
    cli = cli_run("simple")
    steps = []
    result = needle.run("simple", callback=lambda r: steps.append(r.step))
    py = result.summary
    print()
    print(f"{'':24} {'needle run simple':>20} {'needle.run(simple)':>20}")
    for key in FIGURES + COUNTS:
        print(f"{key:24} {cli[key]!s:>20} {py[key]!s:>20}")
    for key in COUNTS:
        assert py[key] == cli[key], key
    # The same loop on the same machine: the same numbers, to rounding of the last bit at most.
    for key in FIGURES:
        assert py[key] == pytest.approx(cli[key], rel=1e-12, abs=1e-12), key
    assert [c["min_mm"] for c in py["clearances"]] == pytest.approx(
        [c["min_mm"] for c in cli["clearances"]], rel=1e-12
    )
    # The whole insertion with its settling steps, every step called back.
    assert py["outcome"] == "reached"
    assert steps == list(range(py["steps"])) and len(result) == py["steps"]
    # Within the paper's bounds for the simple scene (0.5 / 1.8 mm).
    assert py["e_mean_mm"] < 0.5 and py["e_max_mm"] < 1.8
    # e_mean and e_max are over the steps with the tip inside the gel: punctured, and not the
    # step that punctured (it ends on the surface it indented; its error is e_puncture_mm).
    assert result.errors[result.inside].mean() == pytest.approx(py["e_mean_mm"], rel=1e-9)
    assert result.errors[result.inside].max() == py["e_max_mm"]
    at_puncture = result.punctured & ~result.inside
    assert at_puncture.sum() == 1
    assert result.errors[at_puncture][0] == py["e_puncture_mm"]


def test_overrides_give_the_clis_figures_with_the_same_set():
    overrides = {"gel.box.nodes": 600, "inverse.method": "paper"}
    cli = cli_run("simple", "--set", "gel.box.nodes=600", "--set", 'inverse.method="paper"',
                  "--steps", "200")
    py = needle.run("simple", overrides=overrides, steps=200).summary
    for key in COUNTS:
        assert py[key] == cli[key], key
    for key in FIGURES:
        assert py[key] == pytest.approx(cli[key], rel=1e-12, abs=1e-12), key
