"""Where a rollout's future error comes from: which instance, how much is the instance moving as a
whole (its centroid) rather than turning or deforming, and how it depends on the physical
parameter. The paper's future MSE is one mean; this splits it so a long-horizon miss can be traced."""

from __future__ import annotations

import torch

from vgpl.nn.rigid import soft_centroids


def rollout_mse_x1e4(pred: torch.Tensor, truth: torch.Tensor, step: int) -> torch.Tensor:
    """Squared position error x 1e4 of each rollout at predicted frame ``step`` (1-based, T+k),
    the mean over particles and coordinates [R]; its mean over rollouts is the future MSE.
    pred, truth [R, T, N, 3]."""
    return ((pred[:, step - 1] - truth[:, step - 1]) ** 2).mean((1, 2)) * 1e4


def error_breakdown(
    pred: torch.Tensor, truth: torch.Tensor, instance: torch.Tensor, params: torch.Tensor, step: int,
    param_names: list[str] | None = None, bins: int = 3,
) -> dict:
    """Split the squared position error at predicted frame ``step`` (1-based, as the paper's T+k).

    Args: pred, truth [R, T, N, 3]; instance [N] (instance index of each particle); params [R, P]
    physical parameters of each rollout; ``bins`` equal-width bins of each parameter's observed range.

    Returns (all MSE x 1e4, the paper's unit): ``mse`` (the mean, = future MSE at ``step``),
    ``median``/``p90``/``max`` over rollouts, ``top10pct_share`` (fraction of the total carried by
    the worst tenth of rollouts), ``instance_mse`` [M], ``centroid_share`` (fraction of the error
    that is each instance's centroid error: per instance the error splits exactly into its mean and
    the deviations from it), and ``by_<param>`` (per bin: its range and the mean MSE in it, None for an empty bin so the JSON stays strict).
    """
    diff = pred[:, step - 1] - truth[:, step - 1]  # [R, N, 3]
    d2 = diff**2
    per_rollout = rollout_mse_x1e4(pred, truth, step)
    instance = torch.as_tensor(instance, dtype=torch.long)
    m = int(instance.max()) + 1
    one_hot = torch.nn.functional.one_hot(instance, m).to(diff).expand(diff.shape[0], -1, -1)  # [R, N, M]
    centroid = soft_centroids(diff, one_hot)  # [R, M, 3], each instance's mean error
    worst = per_rollout.sort(descending=True).values[: max(1, len(per_rollout) // 10)]
    out = {
        "step": step,
        "mse": float(per_rollout.mean()),
        "median": float(per_rollout.median()),
        "p90": float(per_rollout.quantile(0.9)),
        "max": float(per_rollout.max()),
        "top10pct_share": float(worst.sum() / per_rollout.sum().clamp(min=1e-30)),
        "instance_mse": [float(d2[:, instance == i].mean() * 1e4) for i in range(m)],
        "centroid_share": float((centroid[:, instance] ** 2).mean() / d2.mean().clamp(min=1e-30)),
    }
    names = param_names or [f"param{j}" for j in range(params.shape[1])]
    for j, name in enumerate(names):
        p = params[:, j]
        edges = torch.linspace(float(p.min()), float(p.max()), bins + 1)
        which = torch.bucketize(p, edges[1:-1], right=True)  # bin 0 .. bins-1, the maximum in the last
        out[f"by_{name}"] = [
            {"low": float(edges[b]), "high": float(edges[b + 1]), "rollouts": int((which == b).sum()),
             "mse": float(per_rollout[which == b].mean()) if (which == b).any() else None}
            for b in range(bins)
        ]
    return out
