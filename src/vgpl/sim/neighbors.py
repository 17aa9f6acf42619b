"""Fixed-radius neighbour pairs for batched particle scenes."""

from __future__ import annotations

import torch


def radius_pairs(
    pos: torch.Tensor,
    radius: float,
    allowed: torch.Tensor | None = None,
    return_distance: bool = False,
    unique: bool = False,
) -> tuple[torch.Tensor, ...]:
    """Directed pairs (i, j), i != j, of particles closer than ``radius`` within each scene.

    Args:
        pos: [B, N, 3] positions.
        radius: search radius.
        allowed: optional [N, N] bool mask of particle pairs that may interact.
        unique: return each unordered pair once (i < j) instead of both directions, for
            symmetric constraints that update both ends (half the per-pair work).

    Returns:
        (i, j): two [E] int64 tensors of flat indices into ``pos.reshape(B * N, 3)``, sorted by
        scene, then i, then j (so the order of a scene's pairs does not depend on the batch);
        with ``return_distance`` also their [E] distances (to cut sub-lists without recomputing).
    """
    b, n, _ = pos.shape
    dist = torch.cdist(pos, pos, compute_mode="use_mm_for_euclid_dist")  # [B, N, N]
    close = dist < radius
    others = torch.ones(n, n, dtype=torch.bool, device=pos.device)
    close &= others.triu(1) if unique else others.fill_diagonal_(False)
    if allowed is not None:
        close &= allowed
    scene, i, j = close.nonzero(as_tuple=True)
    if return_distance:
        return scene * n + i, scene * n + j, dist[scene, i, j]
    return scene * n + i, scene * n + j
