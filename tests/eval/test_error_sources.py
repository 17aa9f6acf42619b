from __future__ import annotations

import numpy as np
import pytest
import torch

from vgpl.eval.error_sources import VARIANTS, RolloutInputs, error_sources, error_sources_rows, with_truth
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.rollout import rollout
from vgpl.sim.envs import make_scene


def _inputs(r=3, h=4, n=5, m=2, seed=0) -> RolloutInputs:
    g = torch.Generator().manual_seed(seed)
    return RolloutInputs(torch.rand(r, h, n, 3, generator=g), torch.softmax(torch.randn(r, n, m, generator=g), -1),
                         torch.rand(r, m, generator=g), torch.rand(r, 1, generator=g))


def test_a_true_start_position_keeps_the_inferred_velocities_and_the_reverse():
    inferred, true = _inputs(seed=0), _inputs(seed=1)
    moved = with_truth(inferred, true, ("start_positions",))
    torch.testing.assert_close(moved.window[:, -1], true.window[:, -1])
    torch.testing.assert_close(moved.window.diff(dim=1), inferred.window.diff(dim=1))
    moving = with_truth(inferred, true, ("start_velocities",))
    torch.testing.assert_close(moving.window[:, -1], inferred.window[:, -1])
    torch.testing.assert_close(moving.window.diff(dim=1), true.window.diff(dim=1))
    both = with_truth(inferred, true, ("start_positions", "start_velocities", "params"))
    assert both.window is true.window and both.params is true.params
    assert both.grouping is inferred.grouping and both.rigidness is inferred.rigidness


def test_an_unknown_input_is_refused_by_name():
    with pytest.raises(ValueError, match=r"unknown inputs \['gravity'\]"):
        with_truth(_inputs(), _inputs(), ("params", "gravity"))


def _prior_world(r=4, n_steps=6):
    """A scene whose 'truth' is the prior itself rolled from known inputs, so the prior's own error is 0."""
    torch.manual_seed(0)
    scene = make_scene("rigid_fall", n_steps=12)
    n, m = scene.n_particles, scene.n_instances
    dyn = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), m, radius=0.08, width=16).eval()
    h = dyn.hparams.history
    kinematic = torch.as_tensor(scene.kinematic)
    base = torch.as_tensor(scene.sample(np.random.default_rng(0)).positions).float()  # [N, 3], the cubes stacked
    window = base[None, None] + 0.01 * torch.arange(h).float()[None, :, None, None] * torch.tensor([0.0, -1.0, 0.0])
    window = window.expand(r, -1, -1, -1).clone() + 0.002 * torch.randn(r, 1, n, 3)
    true = RolloutInputs(window, torch.nn.functional.one_hot(torch.as_tensor(scene.instance).long(), m).float().expand(r, -1, -1),
                         torch.ones(r, m), torch.linspace(-14.0, -6.0, r)[:, None])
    planes = torch.zeros(r, h + n_steps, 0, 4)
    driven = torch.zeros(r, n_steps, n, 3)
    truth = rollout(dyn, torch.cat([true.window, driven], 1), true.grouping, true.rigidness, true.params, planes, kinematic, n_steps)
    return dyn, true, driven, planes, kinematic, truth


def test_the_input_that_carries_the_error_is_the_one_whose_swap_removes_it():
    dyn, true, driven, planes, kinematic, truth = _prior_world()
    # the inference got everything right except gravity, read 4 m/s^2 too weak
    inferred = RolloutInputs(true.window, true.grouping, true.rigidness, true.params + 4.0)
    sources = error_sources(dyn, inferred, true, driven, planes, kinematic, truth, horizons=(1, 3, 6), chunk=3)
    assert list(sources) == list(VARIANTS)
    assert sources["inferred"]["future_mse_x1e4@6"] > 1e-3
    for name in ("true parameters", "all true"):
        assert sources[name]["future_mse_x1e4@6"] == pytest.approx(0.0, abs=1e-6), name
        assert sources[name]["vs_inferred@6"]["high"] < 0  # the swap lowers the error on the paired videos
    for name in ("true start positions", "true start velocities", "true start", "true grouping", "true rigidness"):
        assert sources[name]["future_mse_x1e4@6"] == pytest.approx(sources["inferred"]["future_mse_x1e4@6"], rel=1e-5), name
    assert sources["inferred"]["future_mse_x1e4@6"] == pytest.approx(sum(sources["inferred"]["per_video@6"]) / 4, rel=1e-5)


def test_a_wrong_start_velocity_is_told_from_a_wrong_start_position():
    dyn, true, driven, planes, kinematic, truth = _prior_world()
    fast = true.window + 0.05 * torch.arange(true.window.shape[1]).float()[None, :, None, None] * torch.tensor([1.0, 0.0, 0.0])
    fast = fast - fast[:, -1:] + true.window[:, -1:]  # the same last frame, a wrong motion
    inferred = RolloutInputs(fast, true.grouping, true.rigidness, true.params)
    sources = error_sources(dyn, inferred, true, driven, planes, kinematic, truth, horizons=(1, 6))
    assert sources["true start velocities"]["future_mse_x1e4@6"] == pytest.approx(0.0, abs=1e-6)
    assert sources["true start positions"]["future_mse_x1e4@6"] == pytest.approx(sources["inferred"]["future_mse_x1e4@6"], rel=1e-5)
    assert sources["inferred"]["future_mse_x1e4@6"] > 1e-3
    header, rows = error_sources_rows(sources)
    assert header == ["inputs from the truth", "T+1", "T+6", "T+6 minus inferred [95% CI]"]
    assert [r[0] for r in rows] == list(VARIANTS) and rows[0][-1] == ""  # the reference has no difference from itself
    assert rows[2][2] == "0.00"
