"""The motion-alone probe beside DensePhysNet: flow statistics and a ridge read a parameter that
the flow shows, and nothing where the flow does not show it."""

from __future__ import annotations

import torch

from vgpl.eval.flow_statistics import flow_statistics, window_flow_statistics
from vgpl.eval.linear_probe import Ridge


def falling_blob_flow(gravity: torch.Tensor, frames: int = 6, size: int = 16) -> torch.Tensor:
    """[B, frames, size, size, 2]: a 4x4 blob whose downward flow grows by ``gravity`` px/frame each
    frame pair, on a still background."""
    flow = torch.zeros(len(gravity), frames, size, size, 2)
    for t in range(frames):
        flow[:, t, 4:8, 4:8, 1] = gravity[:, None, None] * (t + 1)
    return flow


def test_the_statistics_are_the_mean_flow_the_moving_flow_and_the_moving_share():
    flow = falling_blob_flow(torch.tensor([0.5]), frames=2)
    stats = flow_statistics(flow).view(1, 2, 5)
    moving = torch.tensor([[0.0, 0.5, 0.0, 0.5, 16 / 256], [0.0, 1.0, 0.0, 1.0, 16 / 256]])  # [pair, (all x, y, moving x, y, share)]
    moving[:, 1] *= 16 / 256
    assert torch.allclose(stats[0], moving)
    assert torch.equal(flow_statistics(torch.zeros(1, 3, 8, 8, 2)), torch.zeros(1, 15))  # nothing moves: no division by zero


def test_a_ridge_on_the_statistics_reads_a_parameter_the_flow_shows_and_not_one_it_hides():
    gen = torch.Generator().manual_seed(0)
    g_train, g_test = torch.rand(40, generator=gen) + 0.5, torch.rand(20, generator=gen) + 0.5
    windows = [{"flow": f, "params": g[None]} for f, g in zip(falling_blob_flow(g_train), g_train)]
    x, y = window_flow_statistics(windows, batch_size=16)
    assert x.shape == (40, 30) and torch.equal(y[:, 0], g_train)
    ridge = Ridge.fit(x, y, alpha=1e-3)
    x_test, _ = window_flow_statistics([{"flow": f, "params": g[None]} for f, g in zip(falling_blob_flow(g_test), g_test)])
    assert (ridge.predict(x_test)[:, 0] - g_test).abs().max() < 1e-3
    hidden_train, hidden_test = torch.rand(40, 1, generator=gen), torch.rand(20, 1, generator=gen)  # a parameter the flow does not show
    guess = (hidden_train.mean() - hidden_test).abs().mean()  # the training mean's error
    assert (Ridge.fit(x, hidden_train, alpha=1e-3).predict(x_test) - hidden_test).abs().mean() > 0.8 * guess
