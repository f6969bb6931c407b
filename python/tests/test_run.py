"""Whole runs: the callback, the result's arrays and summary, errors and stopping."""

import json

import numpy as np
import pytest

import needle
from conftest import COARSE

STEPS = 30


def test_the_callback_is_called_once_per_step_in_order():
    seen = []
    result = needle.run("simple", overrides=COARSE, steps=STEPS, callback=seen.append)
    assert [r.step for r in seen] == list(range(STEPS))
    assert all(isinstance(r, needle.StepReport) for r in seen)
    assert len(result) == STEPS == result.summary["steps"]
    np.testing.assert_array_equal(result.errors, [r.error for r in seen])
    np.testing.assert_array_equal(result.tips, [r.tip for r in seen])


def test_the_result_has_arrays_and_a_summary():
    result = needle.run("simple", overrides=COARSE, steps=STEPS)
    n = STEPS
    np.testing.assert_array_equal(result.steps, np.arange(n))
    assert result.steps.dtype == np.int64
    for name in ("c", "errors", "depths"):
        a = getattr(result, name)
        assert a.shape == (n,) and a.dtype == np.float64, name
    assert result.punctured.shape == (n,) and result.punctured.dtype == np.bool_
    assert result.inside.shape == (n,) and not (result.inside & ~result.punctured).any()
    assert result.tips.shape == result.targets.shape == (n, 3)
    assert result.joints.shape == (n, 6)
    assert result.tips.dtype == result.targets.dtype == result.joints.dtype == np.float64
    np.testing.assert_allclose(result.errors, np.linalg.norm(result.tips - result.targets, axis=1))
    times = result.stage_times
    assert set(times) == {"fm", "cd", "cc", "sc", "corr", "interact", "total"}
    assert all(t.shape == (n,) and t.dtype == np.float64 for t in times.values())
    np.testing.assert_allclose(
        times["total"], sum(t for k, t in times.items() if k != "total"), rtol=1e-12
    )
    # Not in the gel yet after 3 mm of a 10 mm approach.
    assert result.error_by_depth.shape == (0, 2)
    assert len(result.reports) == n and result.reports[-1].step == n - 1

    s = result.summary
    assert isinstance(s, dict)
    assert s["scene"] == "simple" and s["controller"] == "inverse"
    assert s["steps"] == s["steps_planned"] == n
    assert s["outcome"] == result.outcome == "missed_target"  # cut short
    assert s["e_mean_mm"] is None  # NaN (never inside the gel) is null, as in --json
    assert set(s["timing"]) == {"fm", "cd", "cc", "sc", "correction", "total"}
    assert s["timing"]["total"]["mean_ms"] == pytest.approx(times["total"].mean())
    assert "outcome=missed_target" in repr(result)


class Stop(Exception):
    pass


@pytest.mark.parametrize("controller", ["inverse", "naive"])
def test_an_exception_in_the_callback_stops_the_run_and_propagates(controller):
    seen = []

    def callback(report):
        seen.append(report.step)
        if report.step == 5:
            raise Stop("enough at step 5")

    with pytest.raises(Stop, match="enough at step 5"):
        # A whole insertion: the exception, not the end of the path, stops it.
        needle.run("simple", overrides=COARSE, callback=callback, controller=controller)
    assert seen == list(range(6))


def test_a_run_stopped_by_its_callback_still_writes_its_files(tmp_path):
    def callback(report):
        if report.step == 3:
            raise Stop("enough")

    with pytest.raises(Stop):
        needle.run("simple", overrides=COARSE, callback=callback, out=tmp_path)
    # The host's early stop: steps.csv has the four steps, summary.json says why it ended.
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["steps"] == 4
    assert summary["stop_reason"]["kind"] == "interrupted"
    assert summary["outcome"] == "missed_target"
    assert len((tmp_path / "steps.csv").read_text().splitlines()) == 5
    assert (tmp_path / "replay.html").exists()


def test_a_callback_that_is_not_callable_raises():
    with pytest.raises(TypeError):
        needle.run("simple", overrides=COARSE, steps=2, callback=42)


def test_bad_run_arguments_raise_value_errors():
    with pytest.raises(ValueError, match="controller"):
        needle.run("simple", overrides=COARSE, steps=2, controller="magic")
    with pytest.raises(ValueError, match="steps"):
        needle.run("simple", overrides=COARSE, steps=0)
    with pytest.raises(ValueError, match="out"):
        needle.run("simple", overrides=COARSE, steps=2, vtk_every=1)


def test_the_naive_baseline_runs():
    result = needle.run("simple", overrides=COARSE, steps=10, controller="naive")
    assert result.summary["controller"] == "naive"
    assert len(result) == 10


def test_a_run_writes_the_cli_outputs(tmp_path):
    out = tmp_path / "out"
    result = needle.run(needle.Scene("simple", overrides=COARSE), steps=5, out=out)
    written = json.loads((out / "summary.json").read_text())
    assert written["steps"] == 5
    assert written["outcome"] == result.summary["outcome"]
    assert (out / "steps.csv").is_file()
    assert (out / "replay.html").is_file()
