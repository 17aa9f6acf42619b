"""Contacts solved per particle, as FleX's unified particle solver solves them (Macklin et al. 2014).

Each particle of a rigid body is pushed out of its contacts on its own; shape matching then moves
the body to the best rigid fit of its pushed particles. A contact at the bottom layer of a cube is
thereby shared with the rest of the cube, so a falling body sinks into the floor and into other
bodies for a few frames and springs back: FleX's soft contacts. Particle-particle corrections are
averaged over each particle's active contacts (Jacobi, as FleX's local relaxation) and scaled by
``relaxation``; plane corrections are scaled by ``plane_relaxation``. With ``floor_pass`` each
substep ends with one more plane pass that is not shape matched: the particles that touch the floor
keep its friction, so a body that rocks turns about its stuck edge instead of sliding on it, and its
particles end the substep slightly off a rigid motion, as FleX's do (the scene stores them rigidly
projected, as the authors stored theirs).

The alternative, :class:`BodyContacts`, resolves every contact on the whole body at once
(vgpl.sim.contacts): hard contacts, no sinking.

Both take p [B, N, 3] predicted positions, x_prev [B, N, 3] the substep's start positions, the
:class:`Bodies`, neighbour pairs and planes [B, K, 4] (n_x, n_y, n_z, d, free side n . x >= d).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from vgpl.sim.contacts import Bodies, project_particle_contacts, project_planes, push_rigid_out_of_planes
from vgpl.sim.vector import squared_norm_rowwise

ShapeMatch = Callable[[torch.Tensor], torch.Tensor]


def tangential_stop(move: torch.Tensor, normal: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """[E, 3] Coulomb friction correction: cancels the tangential part of ``move`` [E, 3] along unit
    ``normal`` [E, 3], at most ``limit`` [E] long. Lengths come from elementwise arithmetic only
    (``squared_norm_rowwise``), so a rollout does not depend on its batch."""
    tangential = move - (move * normal).sum(-1, keepdim=True) * normal
    length = squared_norm_rowwise(tangential).sqrt()
    return -(torch.minimum(length, limit) / length.clamp_min(1e-12))[:, None] * tangential


@dataclass
class ParticleContacts:
    """FleX-style contacts: per-particle corrections, then shape matching, in every iteration.

    distance: particle-particle contact distance between different instances (m);
    plane_distance: how far particle centres stay from a plane (FleX's collision distance, m);
    friction, plane_friction: Coulomb coefficients against particles and planes;
    relaxation, plane_relaxation: scale of the averaged particle and of the plane corrections;
    floor_pass: end each substep on a plane pass that is not shape matched (see the module).
    The defaults are FleX's RigidFall settings, with friction and the relaxations fitted to the
    authors' rollouts (benchmarks/flex_fidelity.py). Every particle has the same mass, as in
    RigidFall: a pair's correction is split evenly between its two particles.
    """

    distance: float = 0.055
    plane_distance: float = 0.01
    friction: float = 0.15
    plane_friction: float = 1.0
    relaxation: float = 1.25
    plane_relaxation: float = 0.5
    floor_pass: bool = True

    @property
    def search_radius(self) -> float:
        """Neighbour search radius (m): pairs are found once per substep, with a skin for the motion."""
        return 1.5 * self.distance

    def project(self, p, x_prev, bodies: Bodies, pairs, planes, shape_match: ShapeMatch) -> torch.Tensor:
        b, n, _ = p.shape
        flat, prev = p.reshape(-1, 3), x_prev.reshape(-1, 3)
        move = flat - prev
        delta = torch.zeros_like(flat)
        i, j = pairs
        if i.numel():
            d = flat.index_select(0, i) - flat.index_select(0, j)
            length = squared_norm_rowwise(d).sqrt()
            normal = d / length.clamp_min(1e-9)[:, None]
            depth = (self.distance - length).clamp_min(0.0)  # each directed pair moves its i by half
            rel = move.index_select(0, i) - move.index_select(0, j)
            corr = 0.5 * depth[:, None] * normal + 0.5 * tangential_stop(rel, normal, self.friction * depth) * (depth > 0)[:, None]
            count = torch.zeros(b * n, dtype=p.dtype, device=p.device).index_add_(0, i, (depth > 0).to(p.dtype))
            delta = delta.index_add_(0, i, corr) * (self.relaxation / count.clamp_min(1.0))[:, None]
        delta = delta + self.plane_corrections(p, move, planes)
        return shape_match((flat + delta).reshape(b, n, 3))

    def plane_corrections(self, p, move, planes, friction_scale: float | None = None) -> torch.Tensor:
        """[B*N, 3] corrections of p [B, N, 3] out of the planes [B, K, 4], scaled by ``plane_relaxation``,
        and Coulomb friction on the particles' substep motion ``move`` [B*N, 3], scaled by
        ``friction_scale`` (default: ``plane_relaxation`` too)."""
        friction_scale = self.plane_relaxation if friction_scale is None else friction_scale
        n = p.shape[1]
        delta = torch.zeros_like(move)
        normals, offsets = planes[..., :3], planes[..., 3]
        signed = torch.einsum("bnc,bkc->bnk", p, normals) - offsets[:, None, :] - self.plane_distance
        scene, particle, k = (signed < 0).nonzero(as_tuple=True)
        if scene.numel():
            idx = scene * n + particle
            normal = normals[scene, k]
            depth = -signed[scene, particle, k]
            corr = self.plane_relaxation * depth[:, None] * normal
            corr = corr + friction_scale * tangential_stop(move.index_select(0, idx), normal, self.plane_friction * depth)
            delta = delta.index_add(0, idx, corr)
        return delta

    def finalize(self, p, x_prev, bodies: Bodies, planes, shape_match: ShapeMatch) -> torch.Tensor:
        """With ``floor_pass``, the substep's last plane pass, not shape matched; else p as it is."""
        if not self.floor_pass:
            return p
        delta = self.plane_corrections(p, (p - x_prev).reshape(-1, 3), planes, friction_scale=1.0)
        return p + delta.reshape(p.shape)

    def stored(self, x, shape_match: ShapeMatch) -> torch.Tensor:
        """The positions a frame records: rigidly projected after a floor pass, else x itself."""
        return shape_match(x) if self.floor_pass else x


@dataclass
class BodyContacts:
    """Contacts resolved on whole rigid bodies (vgpl.sim.contacts): hard, no sinking.

    distance: particle-particle contact distance (m); planes keep each particle its radius away;
    friction: Coulomb coefficient of every contact.
    """

    distance: float = 0.05
    friction: float = 0.5

    @property
    def search_radius(self) -> float:
        return 1.6 * self.distance

    def project(self, p, x_prev, bodies: Bodies, pairs, planes, shape_match: ShapeMatch) -> torch.Tensor:
        p = project_particle_contacts(p, x_prev, bodies, *pairs, distance=self.distance, friction=self.friction)
        return project_planes(p, x_prev, bodies, planes, friction=self.friction)

    def finalize(self, p, x_prev, bodies: Bodies, planes, shape_match: ShapeMatch) -> torch.Tensor:
        return push_rigid_out_of_planes(shape_match(p), bodies, planes)

    def stored(self, x, shape_match: ShapeMatch) -> torch.Tensor:
        return x  # rigid after every substep already
