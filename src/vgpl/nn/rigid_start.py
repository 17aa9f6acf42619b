"""Rigid start: noisy start frames with each instance moved as one rigid body, so the prior that
rolls from them reads a rigid body's motion instead of the frame-to-frame noise of its particles.

Used by the oracle sweep from the proposals (``task.param_sweep_history=proposals_rigid``) and by the
inference module's rollout from the proposals' start (``model.inference.net.target.rigid_fit_start``).
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

from vgpl.nn.rigid import float32_physics, soft_centroids
from vgpl.sim.shape_matching import shape_match


@torch.no_grad()
@float32_physics
def rigid_start(frames: torch.Tensor, grouping: torch.Tensor, rigidness: torch.Tensor, kinematic: torch.Tensor | None = None) -> torch.Tensor:
    """Start frames [B, H, N, 3] (metres) with every instance fitted rigidly: in each frame, the best rigid
    motion (``shape_match``) of the instance's shape in the last frame, blended with the frames as they
    came by the instance's rigidness [B, M] in [0, 1] (1: the fit, 0: unchanged). Particles belong to
    grouping [B, N, M]'s argmax. The actuated particles (``kinematic`` [N] bool, positional) take part in
    their instance's fit but keep their own positions. No gradient flows: the fit is a fixed
    preprocessing of the start."""
    m = grouping.shape[-1]
    instance = grouping.argmax(-1)  # [B, N]
    member = F.one_hot(instance, m).to(frames.dtype)  # [B, N, M]
    offsets = frames[:, -1] - torch.einsum("bnm,bmc->bnc", member, soft_centroids(frames[:, -1], member))  # [B, N, 3]
    every = torch.arange(frames.shape[2], device=frames.device)
    # shape_match takes one instance map and one set of offsets for its whole batch: one video at a time
    fitted = torch.stack([shape_match(frames[b], offsets[b], instance[b], every, m)[0] for b in range(frames.shape[0])])
    weight = torch.gather(rigidness.to(frames.dtype), 1, instance)[:, None, :, None]  # [B, 1, N, 1]
    out = frames + weight * (fitted - frames)
    return out if kinematic is None else torch.where(kinematic[:, None], frames, out)
