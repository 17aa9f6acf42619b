"""MassRope as the authors' FleX scene builds it: a rigid mass hanging from a rope whose far end is a
pin driven by an undamped random walk that is pulled toward the origin.

Particles, in the authors' row order (96):
- the mass, 81 particles: a 5x5x5 lattice of spacing 0.055 minus its 44 corner-most points, in
  x-outer, y, z-inner order, its lower corner at ``origin``;
- the rope, 14 particles, from the mass up to the pin, ``rope_length / rope_segments`` apart; its
  first particle sits ``spacing / 1.1`` above the mass's last particle (80), to which it is tied,
  so the rope's pull turns the mass;
- the pin (kinematic), the rope's far end, moved by the actions.

Instance 0 = mass (rigid), 1 = rope and pin. Parameter: rope stiffness in [0.25, 1.2], FleX's
spring stiffness, the fraction of a spring's violation that one solver pass removes. Action: the
pin's position and velocity [T, 6].

The solver follows FleX's unified particle solver (Macklin et al. 2014) with this scene's settings:
inverse masses 0.15 for the mass, 2 for its tied particle, 0.5 for the rope's first particle, 1 for
the others; stretch springs of the given stiffness, bending springs (particle k to k + 2) at half
of it, and a tie spring of stiffness 1. Each pass solves the constraint groups one after another
(rope-mass contacts, then springs), each averaged over the particle's active constraints and scaled
by ``relaxation``, then shape-matches the mass with every particle weighted alike. The mass starts
moving at ``kick`` (FleX's initial velocity of the mass), the rope at rest.
"""

from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.scene import RolloutSample, Scene, lattice, random_walk_1d
from vgpl.sim.shape_matching import best_rotation


class MassRope(Scene):
    name = "mass_rope"
    type_names = ("sphere", "rope")
    param_names = ("stiffness",)
    default_camera = dict(eye=(0.13, 2.0, 3.2), target=(0.0, 1.3, 0.0), fov_y=40.0)  # the authors' eye
    instance_colors = ((0.85, 0.25, 0.2), (0.9, 0.8, 0.3))
    floor_y = None
    action_dim = 6

    def __init__(
        self,
        param_low=(0.25,),
        param_high=(1.2,),
        n_steps: int = 201,
        dt: float = 1.0 / 60.0,
        substeps: int = 2,
        iterations: int = 4,
        camera: dict | None = None,
        spacing: float = 0.055,
        origin=(0.0, 1.0, 0.0),
        rope_length: float = 0.7,
        rope_segments: int = 14,
        mass_inv_mass: float = 0.15,
        tie_inv_mass: float = 2.0,
        rope_first_inv_mass: float = 0.5,
        tie_stiffness: float = 1.0,
        bend_ratio: float = 0.5,
        contact_distance: float = 0.055,
        relaxation: float = 1.1,
        kick=(-0.0066, 0.9907, 0.0107),
        pin_noise: float = 0.1,
        pin_pull: float = 0.1,
        gravity: float = -9.8,
    ) -> None:
        """spacing: the mass's lattice spacing (m); origin: its lower corner (m); rope_length (m) over
        rope_segments springs; *_inv_mass: inverse masses; tie_stiffness: the mass-rope spring's
        stiffness; bend_ratio: bending over stretch stiffness; contact_distance: rope-mass contact
        distance (m); relaxation: scale of each averaged constraint group; kick: the mass's initial
        velocity (m/s); pin_noise (m/s per frame) and pin_pull (1/frame): the pin walk; gravity (m/s^2)."""
        super().__init__(list(param_low), list(param_high), n_steps, dt, substeps, iterations, camera)
        ball = lattice((5, 5, 5), spacing)
        ball = ball[(np.round(ball / spacing) ** 2).sum(-1) <= 6]  # 5x5x5 minus the 44 corner-most points
        self.mass_rest = ball - ball.min(0) + spacing / 2  # FleX voxel centres: the lower corner half a spacing in
        self.n_mass, self.n_rope = len(ball), int(rope_segments)
        self.tie = self.n_mass - 1  # the rope is tied to the mass's last particle
        self.pin_index = self.n_mass + self.n_rope
        self.origin = np.asarray(origin, dtype=np.float64)
        self.segment, self.tie_length = rope_length / rope_segments, spacing / 1.1
        n = self.pin_index + 1
        self.instance = np.concatenate([np.zeros(self.n_mass, np.int64), np.ones(self.n_rope + 1, np.int64)])
        self.rigid = np.array([True, False])
        inv_mass = np.ones(n, dtype=np.float32)
        inv_mass[: self.n_mass], inv_mass[self.tie], inv_mass[self.n_mass], inv_mass[self.pin_index] = mass_inv_mass, tie_inv_mass, rope_first_inv_mass, 0.0
        self.inv_mass = inv_mass
        self.radius = np.concatenate([np.full(self.n_mass, spacing / 2), np.full(self.n_rope + 1, self.segment / 2)]).astype(np.float32)
        self.rest_offsets = np.concatenate([self.mass_rest - self.mass_rest.mean(0), np.zeros((self.n_rope + 1, 3))]).astype(np.float32)
        # springs: the tie, then the rope's stretch springs (k, k+1), then its bending springs (k, k+2)
        chain = np.arange(self.n_mass, n)
        self.spring_ends = np.stack([np.concatenate([[self.tie], chain[:-1], chain[:-2]]), np.concatenate([[self.n_mass], chain[1:], chain[2:]])])
        self.spring_rest = np.concatenate([[self.tie_length], np.full(self.n_rope, self.segment), np.full(self.n_rope - 1, 2 * self.segment)]).astype(np.float32)
        self.spring_scale = np.concatenate([[tie_stiffness], np.ones(self.n_rope), np.full(self.n_rope - 1, bend_ratio)]).astype(np.float32)
        self.spring_free = np.arange(len(self.spring_rest)) == 0  # the tie's stiffness is not the parameter
        self.contact_distance, self.relaxation = float(contact_distance), float(relaxation)
        self.kick = np.asarray(kick, dtype=np.float32)
        self.pin_walk = (float(pin_noise), float(pin_pull), 0.0)
        self.g = float(gravity)

    def layout(self) -> np.ndarray:
        """[N, 3] FleX's frame 0: the mass at ``origin``, the rope straight up from its tie to the pin."""
        mass = self.mass_rest + self.origin
        rope = mass[self.tie] + np.outer(self.tie_length + np.arange(self.n_rope + 1) * self.segment, [0.0, 1.0, 0.0])
        return np.concatenate([mass, rope]).astype(np.float32)

    def initial_velocities(self) -> np.ndarray:
        """[N, 3] FleX's start: the mass moving at ``kick``, the rope and pin at rest."""
        v = np.zeros((self.n_particles, 3), dtype=np.float32)
        v[: self.n_mass] = self.kick
        return v

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        params = self.sample_params(rng, params)
        positions = self.layout()
        pin = positions[self.pin_index].astype(np.float64)
        x, vx = random_walk_1d(rng, self.n_steps, self.dt, *self.pin_walk, start=pin[0])
        z, vz = random_walk_1d(rng, self.n_steps, self.dt, *self.pin_walk, start=pin[2])
        actions = np.zeros((self.n_steps, 6), dtype=np.float32)
        actions[:, 0], actions[:, 1], actions[:, 2], actions[:, 3], actions[:, 5] = x, pin[1], z, vx, vz
        return RolloutSample(positions, params, actions, self.initial_velocities())

    def gravity(self, ctx: dict, batch: int) -> torch.Tensor:
        return torch.tensor([0.0, self.g, 0.0], device=ctx["stiffness"].device).expand(batch, 1, 3)

    def prepare(self, params, actions):
        device = params.device
        scale = torch.as_tensor(self.spring_scale, device=device)
        stiffness = torch.where(torch.as_tensor(self.spring_free, device=device), scale, scale * params[:, :1])  # [B, S]
        inv_mass = torch.as_tensor(self.inv_mass, device=device)
        ends = torch.as_tensor(self.spring_ends, device=device)
        w = inv_mass[ends]  # [2, S]
        rest = torch.as_tensor(self.mass_rest, dtype=torch.float32, device=device)
        return {
            "stiffness": stiffness,
            "ends": ends,
            "share": w / w.sum(0),  # [2, S] each end's part of a correction
            "spring_rest": torch.as_tensor(self.spring_rest, device=device),
            "spring_count": torch.zeros(len(self.inv_mass), device=device).index_add_(0, ends.reshape(-1), (w > 0).reshape(-1).float()),
            "rigid_rest": rest - rest.mean(0),
            "inv_mass": inv_mass,
        }

    def kinematics(self, p, ctx, frame):
        # FleX moves the pin to the next frame's position before that frame's substeps
        t = min(int(np.ceil(frame - 1e-6)), ctx["actions"].shape[1] - 1)
        p = p.clone()
        p[:, self.pin_index] = ctx["actions"][:, t, :3]
        return p

    def project(self, p, x, ctx, pairs, frame):
        delta, count = self.contact_corrections(p, ctx["inv_mass"])
        p = p + delta * (self.relaxation / count.clamp_min(1.0)).unsqueeze(-1)
        p = p + self.spring_corrections(p, ctx) * (self.relaxation / ctx["spring_count"].clamp_min(1.0))[:, None]
        return self.match_mass(p, ctx["rigid_rest"])

    def spring_corrections(self, p: torch.Tensor, ctx: dict) -> torch.Tensor:
        """[B, N, 3] the summed corrections of every spring (FleX's spring constraint)."""
        i, j = ctx["ends"]
        d = p[:, i] - p[:, j]  # [B, S, 3]
        length = d.norm(dim=-1).clamp_min(1e-9)
        corr = (ctx["stiffness"] * (length - ctx["spring_rest"]) / length).unsqueeze(-1) * d
        share_i, share_j = ctx["share"][:, None, :, None]
        return torch.zeros_like(p).index_add_(1, i, -share_i * corr).index_add_(1, j, share_j * corr)

    def contact_corrections(self, p: torch.Tensor, inv_mass: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The summed rope-mass contact corrections [B, N, 3] and each particle's active contacts [B, N]:
        a rope particle (or the pin) closer than ``contact_distance`` to a mass particle is pushed
        apart from it, the push split by inverse mass."""
        mass, rope = p[:, : self.n_mass], p[:, self.n_mass :]
        gap = rope[:, :, None] - mass[:, None]  # [B, R, M, 3]
        dist = gap.norm(dim=-1).clamp_min(1e-9)
        depth = (self.contact_distance - dist).clamp_min(0.0)
        w_mass, w_rope = inv_mass[: self.n_mass], inv_mass[self.n_mass :]
        total = (w_rope[:, None] + w_mass[None]).clamp_min(1e-12)  # [R, M]
        push = (depth / dist).unsqueeze(-1) * gap
        active = (depth > 0).to(p.dtype)
        delta = torch.cat([-((w_mass / total)[None, ..., None] * push).sum(1), ((w_rope[:, None] / total)[None, ..., None] * push).sum(2)], 1)
        return delta, torch.cat([active.sum(1), active.sum(2)], 1)

    def match_mass(self, p: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
        """p [B, N, 3] with the mass moved to the best rigid motion of ``rest`` [M, 3] (offsets from its centroid)."""
        mass = p[:, : self.n_mass]
        centroid = mass.mean(1, keepdim=True)
        rot = best_rotation(torch.einsum("bki,kj->bij", mass - centroid, rest))
        return torch.cat([centroid + torch.einsum("bij,kj->bki", rot, rest), p[:, self.n_mass :]], 1)

    def finalize(self, p, x, ctx, frame):
        return p  # the mass is shape-matched in every pass already
