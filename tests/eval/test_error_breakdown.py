"""The future-error breakdown splits the paper's mean MSE exactly: per instance, into the
instances' centroid errors and the rest, and by the physical parameter."""

import torch

from vgpl.eval.error_breakdown import error_breakdown


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
