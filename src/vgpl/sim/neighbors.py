"""Fixed-radius neighbour pairs for batched particle scenes."""

from __future__ import annotations

import torch


def radius_pairs(
    pos: torch.Tensor, radius: float, allowed: torch.Tensor | None = None, return_distance: bool = False
) -> tuple[torch.Tensor, ...]:
    """Directed pairs (i, j), i != j, of particles closer than ``radius`` within each scene.

    Args:
        pos: [B, N, 3] positions.
        radius: search radius.
        allowed: optional [N, N] bool mask of particle pairs that may interact.

    Returns:
        (i, j): two [E] int64 tensors of flat indices into ``pos.reshape(B * N, 3)``, sorted by
        scene, then i, then j (so the order of a scene's pairs does not depend on the batch);
        with ``return_distance`` also their [E] distances (to cut sub-lists without recomputing).
    """
    b, n, _ = pos.shape
    dist = torch.cdist(pos, pos, compute_mode="donot_use_mm_for_euclid_dist")  # [B, N, N]
    close = dist < radius
    close &= ~torch.eye(n, dtype=torch.bool, device=pos.device)
    if allowed is not None:
        close &= allowed
    scene, i, j = close.nonzero(as_tuple=True)
    if return_distance:
        return scene * n + i, scene * n + j, dist[scene, i, j]
    return scene * n + i, scene * n + j
