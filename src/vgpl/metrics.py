"""The paper's metrics (docs/paper.md): parameter error as % of range, position MSE x 1e4,
probability of the correct rigidness label."""

from __future__ import annotations

import torch


def param_signed_error_pct(pred: torch.Tensor, truth: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """(P_hat - P) / (high - low) x 100 per scene and parameter [B, P] (pred, truth [B, P] physical).
    Its mean over scenes is the estimate's global offset (bias), which the MAE folds in."""
    return (pred - truth) / (high - low) * 100.0


def param_error_pct(pred: torch.Tensor, truth: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """|P_hat - P| / (high - low) x 100 per scene and parameter [B, P] (pred, truth [B, P] physical)."""
    return param_signed_error_pct(pred, truth, low, high).abs()


def midpoint_error_pct(truth: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """The error of guessing the middle of each parameter's range, % of range, per scene and
    parameter [B, P] (truth [B, P] physical): the constant predictor any estimate should beat."""
    return param_error_pct(((low + high) / 2).expand_as(truth), truth, low, high)


def position_mse_x1e4(pred: torch.Tensor, truth: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Mean squared position error x 1e4 over particles (``mask`` [N] selects), frames, coords."""
    if mask is not None:
        pred, truth = pred[..., mask, :], truth[..., mask, :]
    return float(((pred - truth) ** 2).mean() * 1e4)


def rms_mm(mse_x1e4: float) -> float:
    """The RMS position error per coordinate in mm of a mean squared error given x 1e4 (m²)."""
    return 10.0 * mse_x1e4**0.5


def mean_abs_acceleration_mm(positions: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Mean |x_(t+1) - 2 x_t + x_(t-1)| x 1e3: the per-frame acceleration in mm per frame squared,
    over rollouts, frames, particles (``mask`` [N] selects) and coordinates. positions [R, T, N, 3]
    in metres, T >= 3. The second difference is linear, so ``mean_abs_acceleration_mm(pred - truth)``
    is the acceleration error of ``pred``: the noise a parameter network must average away to read
    a force such as gravity from the frames."""
    if positions.shape[1] < 3:
        raise ValueError(f"mean_abs_acceleration_mm: {positions.shape[1]} frames, a second difference needs at least 3")
    if mask is not None:
        positions = positions[..., mask, :]
    accel = positions[:, 2:] - 2.0 * positions[:, 1:-1] + positions[:, :-2]
    return float(accel.abs().mean() * 1e3)


def correct_rigidness_prob(rigidness: torch.Tensor, rigid: torch.Tensor) -> torch.Tensor:
    """Probability given to the true label per scene and instance [B, M]: q where rigid, 1 - q elsewhere."""
    return torch.where(rigid[None].bool(), rigidness, 1.0 - rigidness)


def mean_per_type(probs: torch.Tensor, types) -> dict:
    """probs [R, M, ...] averaged over the videos and the instances of each object type
    (``types`` names each of the M instances): type -> [...], in the order types first appear."""
    return {name: video.mean(0) for name, video in per_video_per_type(probs, types).items()}


def per_video_per_type(probs: torch.Tensor, types) -> dict:
    """probs [R, M, ...] averaged over the instances of each object type, video by video:
    type -> [R, ...], in the order types first appear."""
    return {name: probs[:, [m for m, n in enumerate(types) if n == name]].mean(1) for name in dict.fromkeys(types)}
