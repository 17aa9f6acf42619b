"""Multi-step rollouts of the dynamics prior and the paper's future-prediction error."""

from __future__ import annotations

import torch

FUTURE = "future_mse_x1e4@{}"  # metric key: the mean squared position error x 1e4 at T+k (``future_mse``)
NO_MOTION = "no_motion_mse_x1e4@{}"  # the same for the last observed frame held still (``future_mse(..., key=NO_MOTION)``)


def rollout(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int, history: int | None = None) -> torch.Tensor:
    """Roll the model forward from the first ``history`` frames of ``positions``.

    Args: positions [B, >= H(+n_steps with kinematic particles), N, 3] (frames after the history
    only drive the kinematic particles); grouping [B, N, M]; rigidness [B, M]; params [B, P];
    planes [B, H + n_steps, K, 4]; kinematic [N] bool.
    Returns: predicted positions [B, n_steps, N, 3].
    """
    return rollout_runs(model, [(positions, grouping, rigidness, params, planes, n_steps)], kinematic, history)[0]


def rollout_runs(model, runs: list[tuple], kinematic: torch.Tensor, history: int | None = None) -> list[torch.Tensor]:
    """Several rollouts of different lengths as one batch: ``rollout`` of each run, in one call of
    the model a step for all runs still rolling (a run of L steps takes part in the first L).

    Args: runs, each (positions [B_i, H(+L_i with kinematic particles), N, 3] (the start and the
    frames that drive kinematic particles), grouping [B_i, N, M], rigidness [B_i, M], params
    [B_i, P], planes [B_i, H + L_i, K, 4], L_i >= 1); kinematic [N] bool.
    Returns each run's predicted positions [B_i, L_i, N, 3], in the order given.
    """
    h = history or model.hparams.history
    for i, (positions, *_, planes, length) in enumerate(runs):
        for what, x, read in (("planes", planes, True), ("positions (the kinematic particles' driven frames)", positions, kinematic.any())):
            if read and x.shape[1] < h + length:
                raise ValueError(f"rollout: run {i} of {length} steps needs {h + length} frames of {what} (history {h} + {length}), got {x.shape[1]}")
    order = sorted(range(len(runs)), key=lambda i: -runs[i][5])  # longest first: the runs still rolling are a prefix
    longest = runs[order[0]][5]

    def padded(x: torch.Tensor, frames: int) -> torch.Tensor:  # the last frame repeated: frames no active run reads
        return torch.cat([x, x[:, -1:].expand(-1, frames - x.shape[1], *x.shape[2:])], 1) if x.shape[1] < frames else x

    def joined(j: int, pad: bool = False) -> torch.Tensor | None:  # the runs' j-th inputs as one batch (one run's as given: may be None)
        parts = [padded(runs[i][j], h + longest) if pad else runs[i][j] for i in order]
        return parts[0] if len(parts) == 1 else torch.cat(parts)

    positions, grouping, rigidness, params, planes = joined(0, pad=True), joined(1), joined(2), joined(3), joined(4, pad=True)
    lengths = torch.tensor([runs[i][5] for i in order for _ in range(runs[i][0].shape[0])])
    window, out = positions[:, :h], []
    for k in range(longest):
        active = int((lengths > k).sum())
        rows = slice(0, active)
        window = window[rows]
        nxt = model.step(window, *(None if x is None else x[rows] for x in (grouping, rigidness, params)), planes[rows, k : k + h + 1], kinematic,
                         positions[rows, h + k])
        out.append(nxt)
        window = torch.cat([window[:, 1:], nxt[:, None]], 1)
    found, first = [None] * len(runs), 0
    for i in order:
        b, length = runs[i][0].shape[0], runs[i][5]
        found[i] = torch.stack([step[first : first + b] for step in out[:length]], 1)
        first += b
    return found


def future_mse(pred: torch.Tensor, truth: torch.Tensor, horizons=(1, 5, 10, 20), key: str = FUTURE) -> dict[str, float]:
    """Mean squared position error x 1e4 at each horizon (mean over scenes, particles and
    coordinates, as the paper's code: F.mse_loss), under ``key``. pred, truth [B, n_steps, N, 3]."""
    return {key.format(k): float(((pred[:, k - 1] - truth[:, k - 1]) ** 2).mean() * 1e4) for k in horizons if k <= pred.shape[1]}
