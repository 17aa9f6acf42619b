"""Rigid transforms used by the dynamics prior's rigid head (plain functions, tested alone).

They act on absolute positions, so they always run in float32, also under bf16 autocast (bf16's
0.4% relative precision is millimetres on positions, a fifth of a frame's displacement).
"""

from __future__ import annotations

import functools

import torch


def float32_physics(fn):
    """Run ``fn`` with autocast off and floating tensor arguments in float32."""

    @functools.wraps(fn)
    def wrapper(*args):
        with torch.autocast(device_type="cuda" if any(a.is_cuda for a in args) else "cpu", enabled=False):
            return fn(*(a.float() if a.is_floating_point() else a for a in args))

    return wrapper


@float32_physics
def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit rotation matrices [..., 3, 3] from (w, x, y, z) quaternions [..., 4] (normalised here)."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(*q.shape[:-1], 3, 3)


@float32_physics
def soft_centroids(pos: torch.Tensor, grouping: torch.Tensor) -> torch.Tensor:
    """Instance centroids [B, M, 3] = sum_i G_im x_i / sum_i G_im; pos [B, N, 3], grouping [B, N, M]."""
    weight = grouping.sum(1).clamp_min(1e-8)  # [B, M]
    return torch.einsum("bnm,bnc->bmc", grouping, pos) / weight[..., None]


@float32_physics
def rigid_displacement(pos: torch.Tensor, grouping: torch.Tensor, rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """Displacement [B, N, 3] that moves each particle with its instances' rigid motions.

    Particle i of instance m goes to c_m + R_m (x_i - c_m) + t_m; soft grouping averages over m.
    Args: pos [B, N, 3]; grouping [B, N, M]; rotation [B, M, 3, 3]; translation [B, M, 3].
    """
    centre = soft_centroids(pos, grouping)  # [B, M, 3]
    rel = pos[:, :, None, :] - centre[:, None]  # [B, N, M, 3]
    moved = centre[:, None] + torch.einsum("bmij,bnmj->bnmi", rotation, rel) + translation[:, None]
    return torch.einsum("bnm,bnmc->bnc", grouping, moved - pos[:, :, None, :])


@float32_physics
def momentum_projection(pos: torch.Tensor, grouping: torch.Tensor, disp: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The rigid motion of each instance that carries the linear and angular momentum of per-particle
    displacements: translation t_m = the instance's mean displacement, angular step w_m = I_m^-1 L_m
    (inertia tensor I_m and angular momentum L_m = sum_i G_im r_i x (d_i - t_m) about the centroid),
    the least-squares rigid fit of the displacements to first order in the rotation.

    A contact that pushes one particle moves and turns its whole body as an impulse would, which a
    head on the instance's mean embedding has to learn. I_m is regularised by 1e-3 of its mean
    diagonal, so a line of particles (a rope) does not make it singular.
    Args: pos [B, N, 3]; grouping [B, N, M]; disp [B, N, 3].
    Returns: (rotation [B, M, 3, 3] for rigid_displacement(), translation [B, M, 3]).
    """
    translation = soft_centroids(disp, grouping)  # the mean displacement, [B, M, 3]
    rel = pos[:, :, None, :] - soft_centroids(pos, grouping)[:, None]  # [B, N, M, 3]
    spin = torch.linalg.cross(rel, disp[:, :, None, :] - translation[:, None], dim=-1)
    momentum = torch.einsum("bnm,bnmc->bmc", grouping, spin)
    eye = torch.eye(3, device=pos.device)
    inertia = torch.einsum("bnm,bnmij->bmij", grouping, rel.square().sum(-1)[..., None, None] * eye - rel[..., :, None] * rel[..., None, :])
    ridge = 1e-3 * inertia.diagonal(dim1=-2, dim2=-1).mean(-1) + 1e-9  # [B, M]
    # solve_ex: the ridge keeps the system regular, and skipping solve's singularity check keeps the host from waiting on the device
    omega = torch.linalg.solve_ex(inertia + ridge[..., None, None] * eye, momentum)[0]
    # quaternion (1, w / 2): a rotation by |w| to first order, smooth at w = 0 (normalised inside)
    rotation = quaternion_to_matrix(torch.cat([torch.ones_like(omega[..., :1]), omega / 2], -1))
    return rotation, translation
