"""Position-based fluids (Macklin & Mueller 2013): density constraints and XSPH viscosity.

Kernels are normalised so that a particle inside a cubic lattice at the rest spacing has
density 1; the constraint is unilateral (C = max(rho - 1, 0)) like FleX's, so a free surface
does not clump and no artificial pressure term is needed.
"""

from __future__ import annotations

import math

import torch

from vgpl.sim.vector import PairIndex, squared_norm


def poly6(r2: torch.Tensor, h: float) -> torch.Tensor:
    """Poly6 kernel W(r) from squared distances, zero beyond h."""
    return (315.0 / (64.0 * math.pi * h**9)) * (h * h - r2).clamp_min(0.0) ** 3


def spiky_grad_scale(r: torch.Tensor, h: float) -> torch.Tensor:
    """|grad W_spiky|(r) / r, so that grad W = scale * (p_i - p_j)."""
    return -(45.0 / (math.pi * h**6)) * (h - r).clamp_min(0.0) ** 2 / r.clamp_min(1e-9)


def lattice_rest_density(spacing: float, h: float) -> float:
    """Poly6 density of a particle inside an infinite cubic lattice (unit masses)."""
    k = math.ceil(h / spacing)
    rng = torch.arange(-k, k + 1, dtype=torch.float64) * spacing
    grid = torch.stack(torch.meshgrid(rng, rng, rng, indexing="ij"), -1).reshape(-1, 3)
    return float(poly6((grid**2).sum(-1), h).sum())


def density(p: torch.Tensor, pairs: PairIndex, h: float, rest_density: float) -> torch.Tensor:
    """Normalised density rho / rho_0 of every particle, counting its pairs and itself.

    Args: p [B, N, 3]; pairs: unordered pairs of the batch (``radius_pairs(unique=True)``);
    h kernel radius.
    Returns: [B, N] (meaningful for fluid particles).
    """
    b, n, _ = p.shape
    return _density(poly6(squared_norm(pairs.difference(p.reshape(b * n, 3))), h), pairs, h, rest_density).reshape(b, n)


def _density(kernel: torch.Tensor, pairs: PairIndex, h: float, rest_density: float) -> torch.Tensor:
    """[B * N] normalised densities from the [E] kernel values of the pairs."""
    rho = torch.full((pairs.size,), float(poly6(torch.zeros(()), h)), dtype=kernel.dtype, device=kernel.device)
    return pairs.accumulate(kernel, rho) / rest_density


def project_density(
    p: torch.Tensor,
    pairs: PairIndex,
    fluid: torch.Tensor,
    inv_mass: torch.Tensor,
    h: float,
    rest_density: float,
    relaxation: float,
) -> torch.Tensor:
    """One Jacobi pass of the unilateral PBF density constraint.

    Only fluid particles carry a constraint, but solid particles count towards their density and
    take the pressure reaction (two-way coupling, as in FleX): a light solid floats.

    Args: p [B, N, 3]; pairs: unordered pairs with at least one fluid particle; fluid [N] bool;
    inv_mass [N]; relaxation: CFM epsilon added to the denominator.
    Returns: [B, N, 3] corrected positions (solids move particle-wise: shape-match them after).
    """
    b, n, _ = p.shape
    flat = p.reshape(b * n, 3)
    w = inv_mass.repeat(b)
    d = pairs.difference(flat)
    r2 = squared_norm(d)
    constraint = (_density(poly6(r2, h), pairs, h, rest_density) - 1.0).clamp_min(0.0) * fluid.repeat(b)
    # grad_{p_i} W_ij / rho0; the gradient with respect to p_j is its negative
    grad = (spiky_grad_scale(r2.sqrt(), h) / rest_density).unsqueeze(-1) * d
    grad2 = squared_norm(grad)
    denom = w * squared_norm(pairs.accumulate_antisymmetric(grad))
    denom = denom.index_add_(0, pairs.i, w.index_select(0, pairs.j) * grad2).index_add_(0, pairs.j, w.index_select(0, pairs.i) * grad2)
    lam = -constraint / (denom + relaxation)
    delta = pairs.accumulate_antisymmetric(pairs.gather_sum(lam).unsqueeze(-1) * grad)
    return (flat + w.unsqueeze(-1) * delta).reshape(b, n, 3)


def xsph_viscosity(v: torch.Tensor, p: torch.Tensor, pairs: PairIndex, h: float, rest_density: float, coefficient: torch.Tensor) -> torch.Tensor:
    """XSPH velocity smoothing v_i += c * sum_j (v_j - v_i) W_ij / rho_0 over fluid pairs.

    Args: v, p [B, N, 3]; pairs: unordered fluid pairs; coefficient [B] per-scene c in [0, 1].
    Returns: [B, N, 3] smoothed velocities.
    """
    b, n, _ = v.shape
    flat_v = v.reshape(b * n, 3)
    weight = poly6(squared_norm(pairs.difference(p.reshape(b * n, 3))), h) / rest_density
    delta = pairs.accumulate_antisymmetric(-weight.unsqueeze(-1) * pairs.difference(flat_v))  # i pulled towards v_j
    scene_c = coefficient.repeat_interleave(n)
    return (flat_v + scene_c.unsqueeze(-1) * delta).reshape(b, n, 3)
