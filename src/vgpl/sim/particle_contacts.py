"""Contacts solved per particle, as FleX's unified particle solver solves them (Macklin et al. 2014).

Each particle of a rigid body is pushed out of its contacts on its own; shape matching then moves
the body to the best rigid fit of its pushed particles. A contact at the bottom layer of a cube is
thereby shared with the rest of the cube, so a falling body sinks into the floor and into other
bodies for a few frames and springs back: FleX's soft contacts. Particle-particle corrections are
averaged over each particle's active contacts (Jacobi, as FleX's local relaxation) and scaled by
``relaxation``; plane corrections are scaled by ``plane_relaxation``.

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
from vgpl.sim.vector import squared_norm

ShapeMatch = Callable[[torch.Tensor], torch.Tensor]


def tangential_stop(move: torch.Tensor, normal: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """[E, 3] Coulomb friction correction: cancels the tangential part of ``move`` [E, 3] along unit
    ``normal`` [E, 3], at most ``limit`` [E] long. Lengths are roots of ``squared_norm``'s
    matrix-vector product, whose value for a row does not depend on how many rows there are
    (``torch.linalg.norm``'s vectorised reduction does: a rollout would depend on its batch)."""
    tangential = move - (move * normal).sum(-1, keepdim=True) * normal
    length = squared_norm(tangential).sqrt()
    return -(torch.minimum(length, limit) / length.clamp_min(1e-12))[:, None] * tangential


@dataclass
class ParticleContacts:
    """FleX-style contacts: per-particle corrections, then shape matching, in every iteration.

    distance: particle-particle contact distance between different instances (m);
    plane_distance: how far particle centres stay from a plane (FleX's collision distance, m);
    friction, plane_friction: Coulomb coefficients against particles and planes;
    relaxation, plane_relaxation: scale of the averaged particle and of the plane corrections.
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
            length = squared_norm(d).sqrt()
            normal = d / length.clamp_min(1e-9)[:, None]
            depth = (self.distance - length).clamp_min(0.0)  # each directed pair moves its i by half
            rel = move.index_select(0, i) - move.index_select(0, j)
            corr = 0.5 * depth[:, None] * normal + 0.5 * tangential_stop(rel, normal, self.friction * depth) * (depth > 0)[:, None]
            count = torch.zeros(b * n, dtype=p.dtype, device=p.device).index_add_(0, i, (depth > 0).to(p.dtype))
            delta = delta.index_add_(0, i, corr) * (self.relaxation / count.clamp_min(1.0))[:, None]
        normals, offsets = planes[..., :3], planes[..., 3]
        signed = torch.einsum("bnc,bkc->bnk", p, normals) - offsets[:, None, :] - self.plane_distance
        scene, particle, k = (signed < 0).nonzero(as_tuple=True)
        if scene.numel():
            idx = scene * n + particle
            normal = normals[scene, k]
            depth = -signed[scene, particle, k]
            corr = depth[:, None] * normal + tangential_stop(move.index_select(0, idx), normal, self.plane_friction * depth)
            delta = delta.index_add(0, idx, self.plane_relaxation * corr)
        return shape_match((flat + delta).reshape(b, n, 3))

    def finalize(self, p, bodies: Bodies, planes, shape_match: ShapeMatch) -> torch.Tensor:
        return p  # shape matched in every iteration already


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

    def finalize(self, p, bodies: Bodies, planes, shape_match: ShapeMatch) -> torch.Tensor:
        return push_rigid_out_of_planes(shape_match(p), bodies, planes)
