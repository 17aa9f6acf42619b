"""Rotations about the vertical (y) axis through the origin: a symmetry of a scene whose only plane
is the floor and whose objects are placed symmetrically about that axis (``Scene.vertical_symmetry``:
RigidFall). A video turned so is another video of the same parameters. (A mirror is not one: it
turns each rigid body's particles into the reflection of their rest shape, which shape matching
cannot reach by a rotation.)"""

from __future__ import annotations

import math

import torch


def about_vertical(positions: torch.Tensor, angle: torch.Tensor | float) -> torch.Tensor:
    """positions [B, ..., 3] (metres, y up) rotated by ``angle`` (radians, float or [B]) about the
    y axis through the origin, as ``vgpl.sim.scene.rotation_y`` turns a cube."""
    b = positions.shape[0]
    angle = torch.as_tensor(angle, dtype=positions.dtype, device=positions.device).expand(b)
    angle = angle.reshape((b,) + (1,) * (positions.dim() - 2))
    x, y, z = positions.unbind(-1)
    c, s = torch.cos(angle), torch.sin(angle)
    return torch.stack([c * x + s * z, y, -s * x + c * z], -1)


def random_about_vertical(positions: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """positions [B, ..., 3], each of the B scenes rotated by its own angle uniform in [0, 2 pi)
    (drawn on the CPU, so a seeded generator gives the same angles on any device)."""
    angle = torch.rand(positions.shape[0], generator=generator) * (2 * math.pi)
    return about_vertical(positions, angle.to(positions.device))
