"""A simulation stepped from Python: reports, state and arrays with their shapes and dtypes."""

import numpy as np
import pytest

import needle
from conftest import COARSE

STAGES = {"fm", "cd", "cc", "sc", "corr", "interact", "total"}


@pytest.fixture
def sim():
    return needle.Simulation("simple", overrides=COARSE)


def test_the_embedded_scene_sets_up_and_steps(sim):
    assert sim.name == "simple"
    assert sim.steps == 0
    assert sim.planned_steps == needle.Scene("simple").planned_steps
    start = sim.tip.copy()
    reports = [sim.step() for _ in range(10)]
    assert [r.step for r in reports] == list(range(10))
    assert sim.steps == 10
    last = reports[-1]
    # 0.1 mm per step along the path, the tip following within a fraction of a millimetre.
    assert last.c == pytest.approx(1.0)
    assert sim.c == pytest.approx(1.0)
    assert np.linalg.norm(sim.tip - start) == pytest.approx(1.0, abs=0.05)
    assert all(r.error < 0.1 for r in reports)
    np.testing.assert_array_equal(last.tip, sim.tip)
    np.testing.assert_array_equal(last.joints, sim.joints)
    assert sim.error == pytest.approx(last.error)
    # Still in the air: not punctured, no obstacle clearance yet.
    assert not sim.punctured and not last.punctured and sim.depth == 0.0
    assert np.all(np.isinf(sim.clearances))


def test_a_step_report_carries_every_field(sim):
    r = sim.step()
    assert set(r.times) == STAGES
    assert all(v >= 0.0 for v in r.times.values())
    assert r.times["total"] == pytest.approx(sum(v for k, v in r.times.items() if k != "total"))
    d = r.to_dict()
    assert set(d) >= {"step", "c", "tip", "target", "error", "depth", "punctured", "times"}
    assert d["error"] == r.error
    np.testing.assert_array_equal(d["tip"], r.tip)
    assert r.error == pytest.approx(np.linalg.norm(r.tip - r.target))
    assert r.rows >= 6  # the needle base's rows at least
    assert "needle.StepReport(step=0" in repr(r)


def test_arrays_have_their_shapes_and_dtypes(sim):
    sim.step()
    for name in ("tip", "target", "entry_point"):
        a = getattr(sim, name)
        assert a.shape == (3,) and a.dtype == np.float64, name
    assert sim.joints.shape == (6,) and sim.joints.dtype == np.float64
    needle_nodes = sim.needle_positions
    assert needle_nodes.dtype == np.float64
    assert needle_nodes.shape == (41, 3)  # 40 beams
    np.testing.assert_array_equal(needle_nodes[-1], sim.tip)
    gel = sim.gel_positions
    rest = sim.gel_rest_positions
    assert gel.dtype == np.float64 and gel.ndim == 2 and gel.shape[1] == 3
    assert rest.shape == gel.shape
    assert 200 < gel.shape[0] < 400  # the mesher's box nearest 300 nodes
    tets = sim.gel_tets
    assert tets.dtype == np.int64 and tets.shape[1] == 4
    assert tets.min() == 0 and tets.max() == gel.shape[0] - 1
    surface = sim.gel_surface
    assert surface.dtype == np.int64 and surface.shape[1] == 3
    assert sim.clearances.shape == (1,)  # one obstacle
    # Fresh arrays: changing one does not change the simulation.
    tip = sim.tip
    tip[:] = 0.0
    assert np.linalg.norm(sim.tip) > 0.0
    r = sim.step()
    for a, shape in ((r.tip, (3,)), (r.target, (3,)), (r.joints, (6,))):
        assert a.shape == shape and a.dtype == np.float64


def test_the_tip_punctures_and_follows_the_path():
    # As host/examples/run_scene.rs: 150 steps, through the 10 mm approach and the puncture.
    sim = needle.Simulation("simple", overrides={"gel.box.nodes": 600})
    start = sim.tip.copy()
    punctured_at = [r.step for r in (sim.step() for _ in range(150)) if r.punctured_now]
    assert len(punctured_at) == 1 and sim.punctured
    assert sim.depth > 2.0
    assert abs(np.linalg.norm(sim.tip - start) - sim.c) < 1.0
    assert np.all(sim.clearances > 0.0)


def test_stepping_gives_the_runs_steps():
    # The run's loop adds checks and records, nothing that changes the state.
    steps = 40
    sim = needle.Simulation("simple", overrides=COARSE)
    tips = np.array([sim.step().tip for _ in range(steps)])
    result = needle.run("simple", overrides=COARSE, steps=steps)
    np.testing.assert_array_equal(tips, result.tips)
