"""How an observed window's proposals are read from the visual prior's sliding windows.

The VisualPrior predicts all F frames of every F-frame window, so each frame of a video is predicted
by up to F windows. The paper keeps one: each frame from the window that ends at it (``last``).
``mean`` (not the paper) averages, for each frame of an observed window [a, b), the windows that
hold it and end by frame b - 1, so no frame after the observation is read; where no such window
exists (the last frame, or a frame before the first window's end) it is the paper's proposal.
"""

from __future__ import annotations

import torch

WINDOW_POOLS = ("last", "mean")


def check_window_pool(pool: str, option: str) -> str:
    """``pool`` if it is one of WINDOW_POOLS, else a ValueError naming ``option``."""
    if pool not in WINDOW_POOLS:
        raise ValueError(f"{option}={pool!r}: expected 'last' (the paper: each frame from the window ending at it) "
                         "or 'mean' (each frame averaged over the windows that end within the observed frames)")
    return pool


def pool_windows(positions: torch.Tensor, slots: torch.Tensor | None, pool: str, index=...) -> torch.Tensor:
    """The proposals of one observed window of T frames: ``positions[index]`` pooled with ``slots[index]``.

    Args: positions [..., T', N, 3] (the paper's, ``propose_windows``), slots [..., T', F, N, 3] of
    the same frames (slot k of frame t: the window starting at t - k; NaN where none) or None
    (proposals with no windows: the recorded particles), pool in WINDOW_POOLS, ``index`` the
    leading dimensions' index that picks the observed window out of both (``numpy.s_[:, :t]``;
    the last frame it keeps is the last observed one). Returns [..., T, N, 3].
    """
    check_window_pool(pool, "window_pool")
    positions = positions[index]
    if pool == "last" or slots is None:
        return positions
    slots = slots[index]
    t, f = slots.shape[-4], slots.shape[-3]
    frame, slot = torch.arange(t)[:, None], torch.arange(f)[None, :]
    ends_within = (frame - slot + f - 1 <= t - 1).to(slots.device)  # [T, F]: the window ends by the last observed frame
    kept = ends_within[..., None, None] & ~slots.isnan()
    count = kept.sum(-3)
    total = torch.where(kept, slots, torch.zeros((), dtype=slots.dtype, device=slots.device)).sum(-3)
    return torch.where(count > 0, total / count.clamp(min=1), positions)
