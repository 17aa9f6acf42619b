"""MassRope: a rigid sphere (81 particles) hanging from an elastic rope (14 particles) whose top
particle is pinned to an actuator at (0, 1, 0) that is driven in x and z by mean-reverting random
accelerations.

Parameter: rope stiffness in [0.25, 1.2]; each segment's XPBD compliance is
``base_compliance / stiffness``, so a stiffer rope stretches proportionally less under the same
load. Instance 0 = sphere (rigid), 1 = rope. Action: pin position and velocity [T, 6].

The rope starts at ``u`` times its static stretch, ``u ~ U(start_stretch)`` (default [0, 2]: from
its rest length to twice its sag), at rest, so the sphere bounces about its equilibrium at the
rope's own frequency. With ``start_stretch=(1, 1)`` every rope starts at equilibrium, its stretch is
a function of the stiffness, and a model of the motion can read the stiffness off the positions and
ignore its stiffness input: the learned prior then gives no gradient in stiffness (docs/design.md).
"""

from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.rope import solve_chain
from vgpl.sim.scene import RolloutSample, Scene, lattice, random_walk_1d


class MassRope(Scene):
    name = "mass_rope"
    type_names = ("sphere", "rope")
    param_names = ("stiffness",)
    default_camera = dict(eye=(0.13, 2.0, 3.2), target=(0.0, 0.55, 0.0), fov_y=25.0)
    instance_colors = ((0.85, 0.25, 0.2), (0.9, 0.8, 0.3))
    floor_y = None
    action_dim = 6

    def __init__(
        self,
        param_low=(0.25,),
        param_high=(1.2,),
        n_steps: int = 200,
        dt: float = 1.0 / 60.0,
        substeps: int = 4,
        iterations: int = 2,
        camera: dict | None = None,
        sphere_spacing: float = 0.055,
        rope_particles: int = 14,
        rope_spacing: float = 0.05,
        pin=(0.0, 1.0, 0.0),
        base_compliance: float = 2.0e-6,
        pin_noise: float = 0.1,
        pin_spring: float = 0.1,
        pin_damping: float = 0.05,
        start_stretch=(0.0, 2.0),
    ) -> None:
        super().__init__(list(param_low), list(param_high), n_steps, dt, substeps, iterations, camera)
        ball = lattice((5, 5, 5), sphere_spacing)
        keep = (np.round(ball / sphere_spacing) ** 2).sum(-1) <= 6  # 5x5x5 minus the 44 corner-most points
        self.sphere = ball[keep]
        self.n_sphere, self.n_rope = len(self.sphere), rope_particles
        self.pin = np.asarray(pin, dtype=np.float64)
        self.rope_spacing, self.base_compliance = rope_spacing, base_compliance
        self.pin_walk = (pin_noise, pin_spring, pin_damping)
        self.start_stretch = tuple(float(u) for u in start_stretch)
        if len(self.start_stretch) != 2 or not 0.0 <= self.start_stretch[0] <= self.start_stretch[1] <= 2.0:
            raise ValueError(f"MassRope: start_stretch={list(start_stretch)}, expected [low, high] with 0 <= low <= high <= 2 "
                             "(multiples of the static stretch; above 2 the rope would be compressed as it bounces)")
        self.top = int(np.argmin(np.abs(self.sphere - [0.0, self.sphere[:, 1].max(), 0.0]).sum(-1)))  # top centre: the rope's knot
        # rope particles follow the sphere: rope[0] is pinned, rope[-1] is tied to sphere[top]
        self.instance = np.concatenate([np.zeros(self.n_sphere, np.int64), np.ones(rope_particles, np.int64)])
        self.rigid = np.array([True, False])
        inv_mass = np.ones(self.n_sphere + rope_particles, dtype=np.float32)
        inv_mass[self.n_sphere] = 0.0
        self.inv_mass = inv_mass
        self.radius = np.concatenate([np.full(self.n_sphere, sphere_spacing / 2), np.full(rope_particles, rope_spacing / 2)]).astype(np.float32)
        self.rest_offsets = np.concatenate([self.sphere, np.zeros((rope_particles, 3))]).astype(np.float32)
        # chain points: rope[0..K-1] then the sphere body; the body's generalised inverse mass is 1/M
        self.chain_inv_mass = np.concatenate([inv_mass[self.n_sphere :], [1.0 / self.n_sphere]]).astype(np.float32)
        self.chain_rest = np.full(rope_particles, rope_spacing, dtype=np.float32)

    def static_stretch(self, stiffness: float, gravity: float = 9.81) -> np.ndarray:
        """[K] segment elongations at rest under the weight below each segment (unit particle masses)."""
        below = self.n_sphere + np.arange(self.n_rope - 1, -1, -1)  # mass hanging under segment k
        return gravity * below * self.base_compliance / stiffness

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        params = self.sample_params(rng, params)
        pin_x, vel_x = random_walk_1d(rng, self.n_steps, self.dt, *self.pin_walk)
        pin_z, vel_z = random_walk_1d(rng, self.n_steps, self.dt, *self.pin_walk)
        u = rng.uniform(*self.start_stretch)  # after the pin's walk: one seed, one walk whatever the range; (1, 1) gives exactly 1
        seg = self.chain_rest + u * self.static_stretch(float(params[0]))
        depth = np.concatenate([[0.0], np.cumsum(seg)])  # [K+1] distance below the pin of each chain point
        rope = self.pin + np.outer(depth[: self.n_rope], [0.0, -1.0, 0.0])
        sphere = self.sphere + self.pin - np.array([0.0, depth[-1], 0.0]) - self.sphere[self.top]
        actions = np.zeros((self.n_steps, 6), dtype=np.float32)
        actions[:, 0:3] = self.pin + np.stack([pin_x, np.zeros_like(pin_x), pin_z], -1)
        actions[:, 3], actions[:, 5] = vel_x, vel_z
        return RolloutSample(np.concatenate([sphere, rope]).astype(np.float32), params, actions)

    def prepare(self, params, actions):
        device = params.device
        return {
            "compliance": self.base_compliance / params[:, 0],
            "chain_inv_mass": torch.as_tensor(self.chain_inv_mass, device=device),
            "chain_rest": torch.as_tensor(self.chain_rest, device=device),
        }

    def kinematics(self, p, ctx, frame):
        actions = ctx["actions"]
        lo = min(int(frame), actions.shape[1] - 1)
        hi = min(lo + 1, actions.shape[1] - 1)
        pin = torch.lerp(actions[:, lo, :3], actions[:, hi, :3], frame - lo)
        p = p.clone()
        p[:, self.n_sphere] = pin
        return p

    def project(self, p, x, ctx, pairs, frame):
        # Lagrange multipliers restart every substep: project() is called `iterations` times in a
        # row, so keep them in ctx keyed by the substep's frame time.
        if ctx.get("lam_frame") != frame:
            ctx["lam"] = torch.zeros(p.shape[0], self.n_rope, device=p.device)
            ctx["lam_frame"] = frame
        rope = p[:, self.n_sphere :]
        tied = p[:, self.top : self.top + 1]
        chain = torch.cat([rope, tied], 1)
        dts = self.dt / self.substeps
        new_chain, ctx["lam"] = solve_chain(chain, ctx["lam"], ctx["chain_inv_mass"], ctx["chain_rest"], ctx["compliance"], dts)
        body_shift = new_chain[:, -1:] - tied  # rigid sphere translates as one body
        return torch.cat([p[:, : self.n_sphere] + body_shift, new_chain[:, :-1]], 1)
