"""Rigid shape matching (Mueller et al. 2005): project instances onto rigid motions of their rest shape."""

from __future__ import annotations

import torch


def best_rotation(cov: torch.Tensor) -> torch.Tensor:
    """Rotation R maximising tr(R^T cov) (Procrustes with reflection fix).

    Args: cov [..., 3, 3] = sum_i (p_i - c) (r_i)^T.  Returns: [..., 3, 3] proper rotations.
    """
    u, _, vh = torch.linalg.svd(cov)
    det = torch.linalg.det(u @ vh)
    fix = torch.ones_like(cov[..., 0])
    fix[..., 2] = det.sign()
    return (u * fix.unsqueeze(-2)) @ vh


def shape_match(
    p: torch.Tensor, rest_offsets: torch.Tensor, instance: torch.Tensor, rigid_index: torch.Tensor, n_instances: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Replace the particles of every rigid instance by the best rigid transform of its rest shape.

    Args:
        p: [B, N, 3] positions.
        rest_offsets: [N, 3] rest position of each particle minus its instance's rest centroid.
        instance: [N] instance id of each particle.
        rigid_index: [R] indices of the particles of rigid instances (only they take part).
        n_instances: M.

    Returns: (positions [B, N, 3], rotations [B, M, 3, 3], centroids [B, M, 3]).
    Particles of non-rigid instances are returned unchanged. All particles of a rigid instance are
    assumed to have equal mass.
    """
    b = p.shape[0]
    q, offsets, inst = p.index_select(1, rigid_index), rest_offsets.index_select(0, rigid_index), instance.index_select(0, rigid_index)
    count = torch.zeros(n_instances, dtype=p.dtype, device=p.device).index_add_(0, inst, torch.ones_like(inst, dtype=p.dtype)).clamp_min(1.0)
    centroid = torch.zeros(b, n_instances, 3, dtype=p.dtype, device=p.device).index_add_(1, inst, q) / count[:, None]
    outer = (q - centroid[:, inst]).unsqueeze(-1) * offsets.unsqueeze(-2)  # [B, R, 3, 3]
    cov = torch.zeros(b, n_instances, 3, 3, dtype=p.dtype, device=p.device).index_add_(1, inst, outer)
    rot = best_rotation(cov)
    goal = centroid[:, inst] + torch.einsum("bnij,nj->bni", rot[:, inst], offsets)
    return p.index_copy(1, rigid_index, goal), rot, centroid
