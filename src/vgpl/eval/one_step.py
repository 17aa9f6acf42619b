"""One step of a dynamics prior from the true history, and how its acceleration compares with the
truth's: a prior whose one-step motion reacts too little to the forces (a slope under 1) biases the
parameters that a rollout through it fits (history noise teaches that; docs/design.md).
"""

from __future__ import annotations

import torch

from vgpl.data.trajectories import Rollouts, true_window


def one_step_accelerations(model, scene, rollouts: Rollouts, start: int, frames: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(predicted, true) accelerations [V, F, N, 3], per frame^2, of every particle at frames
    t = start + H .. start + frames - 1 (F = frames - H), each predicted by one ``model.step``
    from the true H frames before t, with the true ground-truth grouping, rigidness and
    parameters, and kinematic particles driven by the truth (theirs are then exact).
    Acceleration at t: x_t - 2 x_{t-1} + x_{t-2}."""
    h = model.hparams.history
    if start + frames > rollouts.positions.shape[1]:
        raise ValueError(f"one_step_accelerations: frames {start}..{start + frames - 1} exceed the {rollouts.positions.shape[1]}-frame rollouts")
    positions, grouping, rigidness, params, planes, kinematic = true_window(scene, rollouts, start, frames, rollouts.positions.shape[0])
    pred, true = [], []
    for t in range(h, frames):
        window = positions[:, t - h : t + 1]
        nxt = model.step(window[:, :h], grouping, rigidness, params, planes[:, t - h : t + 1], kinematic, window[:, h])
        before = -2 * window[:, h - 1] + window[:, h - 2]
        pred.append(nxt + before)
        true.append(window[:, h] + before)
    return torch.stack(pred, 1), torch.stack(true, 1)


def slope(pred: torch.Tensor, true: torch.Tensor) -> float:
    """Least-squares slope through the origin of ``pred`` on ``true`` (same shape, any):
    sum(pred * true) / sum(true * true); 1 is a prior with the true magnitude of response."""
    return float((pred * true).sum() / (true * true).sum())
