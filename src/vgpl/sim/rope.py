"""Stretch constraints of a chain (rope) solved globally with XPBD (Macklin et al. 2016).

A heavy body on a light rope defeats Gauss-Seidel and Jacobi sweeps (the body sags to the
floor). Here every Newton iteration solves the linearised chain exactly: the system
(J W J^T + alpha/dt^2) dlambda = -C - alpha/dt^2 lambda is tridiagonal and small (one row per
segment), so a batched dense solve is cheap and the result does not depend on the mass ratio.
"""

from __future__ import annotations

import torch


def solve_chain(
    p: torch.Tensor,
    lam: torch.Tensor,
    inv_mass: torch.Tensor,
    rest_length: torch.Tensor,
    compliance: torch.Tensor,
    dt: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One XPBD Newton iteration on a chain of K+1 points joined by K distance constraints.

    Args:
        p: [B, K+1, 3] chain points (point 0 may be kinematic with inv_mass 0).
        lam: [B, K] accumulated Lagrange multipliers of this substep.
        inv_mass: [K+1] generalised inverse masses of the points.
        rest_length: [K] rest lengths.
        compliance: [B] compliance alpha (inverse stiffness) of every segment, per scene.
        dt: substep length.

    Returns: (corrected points [B, K+1, 3], updated multipliers [B, K]).
    """
    seg = p[:, 1:] - p[:, :-1]  # [B, K, 3]
    length = seg.norm(dim=-1).clamp_min(1e-9)
    normal = seg / length.unsqueeze(-1)
    constraint = length - rest_length
    alpha = (compliance / dt**2)[:, None]  # [B, 1]
    w_a, w_b = inv_mass[:-1], inv_mass[1:]
    diag = (w_a + w_b)[None, :] + alpha
    # constraints k and k+1 share point k+1, whose gradients are +n_k and -n_{k+1}
    off = -w_b[None, :-1] * (normal[:, :-1] * normal[:, 1:]).sum(-1)  # [B, K-1]
    system = torch.diag_embed(diag) + torch.diag_embed(off, 1) + torch.diag_embed(off, -1)
    rhs = -constraint - alpha * lam
    dlam = torch.linalg.solve(system, rhs)  # [B, K]
    impulse = dlam.unsqueeze(-1) * normal  # acts +on point k+1, -on point k
    dp = torch.zeros_like(p)
    dp[:, 1:] += impulse
    dp[:, :-1] -= impulse
    return p + dp * inv_mass[None, :, None], lam + dlam
