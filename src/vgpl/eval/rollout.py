"""Multi-step rollouts of the dynamics prior and the paper's future-prediction error."""

from __future__ import annotations

import torch

FUTURE = "future_mse_x1e4@{}"  # metric key: the mean squared position error x 1e4 at T+k (``future_mse``)


def rollout(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int, history: int | None = None) -> torch.Tensor:
    """Roll the model forward from the first ``history`` frames of ``positions``.

    Args: positions [B, >= H(+n_steps for kinematic parts), N, 3] (frames after the history are
    used only to drive kinematic particles); grouping [B, N, M]; rigidness [B, M]; params [B, P];
    planes [B, H + n_steps, K, 4]; kinematic [N] bool.
    Returns: predicted positions [B, n_steps, N, 3].
    """
    h = history or model.hparams.history
    window = positions[:, :h]
    out = []
    for k in range(n_steps):
        driven = positions[:, h + k] if positions.shape[1] > h + k else None
        nxt = model.step(window, grouping, rigidness, params, planes[:, k : k + h + 1], kinematic, driven)
        out.append(nxt)
        window = torch.cat([window[:, 1:], nxt[:, None]], 1)
    return torch.stack(out, 1)


def future_mse(pred: torch.Tensor, truth: torch.Tensor, horizons=(1, 5, 10, 20)) -> dict[str, float]:
    """Mean squared position error x 1e4 at each horizon (mean over scenes, particles and
    coordinates, as the paper's code: F.mse_loss). pred, truth [B, n_steps, N, 3]."""
    return {FUTURE.format(k): float(((pred[:, k - 1] - truth[:, k - 1]) ** 2).mean() * 1e4) for k in horizons if k <= pred.shape[1]}
