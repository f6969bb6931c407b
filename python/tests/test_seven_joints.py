"""A 7-joint arm (the KUKA LBR iiwa 14 R820 of scenes/robots/iiwa_complex.toml) from Python:
`Simulation` steps it with 7-long joint arrays, and `run` gives what the stepped simulation
gives, step for step."""

import numpy as np
import pytest

import needle

#: The iiwa scene on a coarse gel (sets up and steps fast), the approach in the air.
COARSE = {"gel.box.nodes": 300}
STEPS = 12


@pytest.fixture
def iiwa(root):
    return str(root / "scenes" / "robots" / "iiwa_complex.toml")


def test_a_simulation_of_a_7_joint_arm_has_7_joints(iiwa):
    sim = needle.Simulation(iiwa, overrides=COARSE)
    assert sim.name == "iiwa_complex"
    assert sim.joint_count == 7
    start = sim.joints.copy()
    assert start.shape == (7,) and start.dtype == np.float64
    reports = [sim.step() for _ in range(STEPS)]
    assert [r.step for r in reports] == list(range(STEPS))
    assert all(r.joints.shape == (7,) for r in reports)
    np.testing.assert_array_equal(reports[-1].joints, sim.joints)
    # The arm moved (the target advances 0.1 mm a step) and the tip follows it.
    assert np.abs(sim.joints - start).max() > 0.0
    assert sim.c == pytest.approx(0.1 * STEPS)
    assert all(r.error < 0.1 for r in reports)


def test_run_of_a_7_joint_arm_matches_the_stepped_simulation(iiwa):
    result = needle.run(iiwa, overrides=COARSE, steps=STEPS)
    assert result.summary["joints"] == 7
    assert result.joints.shape == (STEPS, 7)
    sim = needle.Simulation(iiwa, overrides=COARSE)
    stepped = [sim.step() for _ in range(STEPS)]
    # The same loop, the same core: the same joints and tips bit for bit.
    np.testing.assert_array_equal(result.joints, np.array([r.joints for r in stepped]))
    np.testing.assert_array_equal(result.tips, np.array([r.tip for r in stepped]))


def test_a_6_joint_scene_still_has_6_joints():
    sim = needle.Simulation("simple", overrides=COARSE)
    assert sim.joint_count == 6 and sim.joints.shape == (6,)
    assert sim.step().joints.shape == (6,)
