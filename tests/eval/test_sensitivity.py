from __future__ import annotations

import pytest

from vgpl.eval.sensitivity import engine_sensitivity
from vgpl.sim.envs import make_scene


def test_the_engine_is_deterministic_and_a_shift_carries_over_until_contact():
    scene = make_scene("rigid_fall", n_steps=12, levels=[0.09])  # one cube: stacked cubes start within FleX's contact distance
    result = engine_sensitivity(scene, 3, [0.0, 1e-3], horizons=(1, 5, 8))
    assert all(v == 0.0 for v in result["0"].values())  # the same draws simulate to the same bits
    # a rigid shift of 1 mm per cube: squared error 1e-6 m^2 over 3 coordinates, x 1e4
    assert result["0.001"]["T+1"] == pytest.approx(1e-6 / 3 * 1e4, rel=1e-3)


def test_too_short_a_scene_is_named():
    with pytest.raises(ValueError, match="scene.n_steps=10, need at least history \\+ max\\(horizons\\) = 24"):
        engine_sensitivity(make_scene("rigid_fall", n_steps=10), 2, [1e-3])
