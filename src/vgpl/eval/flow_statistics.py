"""What the optical flow alone says about a parameter: a few statistics of each observed frame
pair's flow, and a ridge from them to P fitted on the training videos. DensePhysNet's decoder
reads P from a learned representation of the same flow; this probe, with no network, measures how
much of that score the visible motion explains."""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Dataset

MOVING_PX = 0.1  # a pixel moves when its flow is faster than this (pixels per frame)


def flow_statistics(flow: torch.Tensor, moving_px: float = MOVING_PX) -> torch.Tensor:
    """flow [B, T, H, W, 2] (pixels per frame) -> [B, 5 T]: for each frame pair the mean flow
    (x, y) over all pixels, the mean flow (x, y) over the pixels moving faster than ``moving_px``
    (0 where none does) and the share of those pixels."""
    moving = (flow.norm(dim=-1) > moving_px).to(flow.dtype)  # [B, T, H, W]
    count = moving.sum((2, 3))  # [B, T]
    mean_moving = (flow * moving[..., None]).sum((2, 3)) / count.clamp_min(1.0)[..., None]  # [B, T, 2]
    share = count / (flow.shape[2] * flow.shape[3])
    return torch.cat([flow.mean((2, 3)), mean_moving, share[..., None]], -1).flatten(1)


@torch.no_grad()
def window_flow_statistics(windows: Dataset, batch_size: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """``flow_statistics`` [R, 5 T] and true parameters [R, P] of every window of ``windows``
    (items with ``flow`` [T, H, W, 2] and ``params`` [P], as vgpl.data.flow_windows.FlowWindows)."""
    stats, params = [], []
    for batch in DataLoader(windows, batch_size=batch_size):
        stats.append(flow_statistics(batch["flow"].float()))
        params.append(batch["params"])
    return torch.cat(stats), torch.cat(params)
