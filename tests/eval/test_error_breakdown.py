"""The future-error breakdown splits the paper's mean MSE exactly: per instance, into the
instances' centroid errors and the rest, and by the physical parameter."""

import pytest
import torch

from vgpl.eval.error_breakdown import error_breakdown, rollout_mse_x1e4
from vgpl.models.rollout import future_mse


def test_translation_is_all_centroid_error_and_a_spin_none():
    instance = torch.tensor([0, 0, 1, 1])
    truth = torch.zeros(4, 2, 4, 3)
    params = torch.tensor([[-15.0], [-12.0], [-8.0], [-5.0]])
    shifted = truth.clone()
    shifted[:, 1, :2, 0] = 0.01 * torch.arange(1, 5)[:, None]  # instance 0 moved along x at T+2, more in later rollouts
    out = error_breakdown(shifted, truth, instance, params, step=2, param_names=["gravity"], bins=2)
    expected = (0.01 * torch.arange(1, 5)) ** 2 / 6 * 1e4  # 2 of 4 particles, 1 of 3 coordinates
    assert abs(out["mse"] - float(expected.mean())) < 1e-4
    assert abs(out["centroid_share"] - 1.0) < 1e-6
    assert out["instance_mse"][1] == 0.0 and out["instance_mse"][0] > 0
    assert abs(out["max"] - float(expected[-1])) < 1e-4
    assert abs(out["top10pct_share"] - float(expected[-1] / expected.sum())) < 1e-6  # the worst of 4 rollouts
    low, high = out["by_gravity"]
    assert (low["rollouts"], high["rollouts"]) == (2, 2) and low["high"] == high["low"] == -10.0
    assert abs(low["mse"] - float(expected[:2].mean())) < 1e-4 and abs(high["mse"] - float(expected[2:].mean())) < 1e-4

    spun = truth.clone()
    spun[:, 0, 0, 0], spun[:, 0, 1, 0] = 0.02, -0.02  # opposite moves about the centroid: it stays put
    out = error_breakdown(spun, truth, instance, params, step=1)
    assert out["centroid_share"] < 1e-6 and out["mse"] > 0 and list(out)[-1] == "by_param0"


def test_per_rollout_errors_average_to_the_papers_future_mse():
    gen = torch.Generator().manual_seed(0)
    pred, truth = torch.randn(5, 20, 7, 3, generator=gen) * 0.01, torch.zeros(5, 20, 7, 3)
    pred[3, 19] += 1.0  # one rollout diverges at T+20: it carries the mean
    per_rollout = rollout_mse_x1e4(pred, truth, 20)
    assert per_rollout.shape == (5,) and int(per_rollout.argmax()) == 3
    for k in (1, 20):
        assert float(rollout_mse_x1e4(pred, truth, k).mean()) == pytest.approx(future_mse(pred, truth)[f"future_mse_x1e4@{k}"], rel=1e-5)
    assert error_breakdown(pred, truth, torch.zeros(7, dtype=torch.long), torch.rand(5, 1, generator=gen), 20)["top10pct_share"] > 0.99
