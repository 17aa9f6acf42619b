"""RigidFall: three rigid 4x4x4 cubes stacked with horizontal jitter, dropped on a floor.

Parameter: gravity (m/s^2, along y). 192 particles, 3 rigid instances, no action.

The scene draws what the authors' generator draws: cube j's lattice corner sits at offsets
x, z ~ U(offset) and y ~ U(levels[j], levels[j] + level_jitter), with no rotation (``yaw`` = 0), so
the cubes start one contact distance apart and fall together. Contacts are a part of the scene
(``contacts``): by default FleX's soft per-particle contacts calibrated to the authors' rollouts
(vgpl.sim.particle_contacts.ParticleContacts).
"""

from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.neighbors import radius_pairs
from vgpl.sim.particle_contacts import BodyContacts, ParticleContacts
from vgpl.sim.scene import RolloutSample, Scene, lattice, rotation_y


class RigidFall(Scene):
    name = "rigid_fall"
    param_names = ("gravity",)
    default_camera = dict(eye=(0.2, 0.875, 2.0), target=(0.1, 0.3, 0.05), fov_y=40.0)  # the authors' eye; aimed at the stack
    instance_colors = ((0.85, 0.25, 0.2), (0.25, 0.7, 0.3), (0.25, 0.4, 0.85))
    action_dim = 0
    vertical_symmetry = True  # the floor is the only plane: a turn about a vertical axis is a rollout of the same gravity

    def __init__(
        self,
        param_low=(-15.0,),
        param_high=(-5.0,),
        n_steps: int = 120,
        dt: float = 1.0 / 60.0,
        substeps: int = 2,
        iterations: int = 4,
        camera: dict | None = None,
        cube_size: int = 4,
        spacing: float = 0.05,
        levels=(0.09, 0.30, 0.51),
        level_jitter: float = 0.01,
        offset=(0.0, 0.1),
        yaw: float = 0.0,
        contacts: ParticleContacts | BodyContacts | None = None,
    ) -> None:
        """levels: [n_cubes] lowest y of each cube's lattice corner (m); level_jitter: width of its
        uniform draw above that (m); offset: (low, high) of the corner's x and z draws (m); yaw:
        largest rotation about y (radians, drawn uniform in [0, yaw])."""
        super().__init__(list(param_low), list(param_high), n_steps, dt, substeps, iterations, camera)
        self.cube = lattice((cube_size,) * 3, spacing)
        self.levels, self.level_jitter, self.offset, self.yaw = [float(v) for v in levels], float(level_jitter), tuple(offset), float(yaw)
        self.n_cubes, self.spacing = len(self.levels), spacing
        self.half_extent = cube_size * spacing / 2  # lattice corner -> centre: half a spacing inside each face
        self.contacts = contacts if contacts is not None else ParticleContacts()
        per = self.cube.shape[0]
        self.instance = np.repeat(np.arange(self.n_cubes), per)
        self.rigid = np.ones(self.n_cubes, dtype=bool)
        self.type_names = ("cube",) * self.n_cubes
        self.inv_mass = np.ones(self.n_cubes * per, dtype=np.float32)
        self.radius = np.full(self.n_cubes * per, spacing / 2, dtype=np.float32)
        self.rest_offsets = np.tile(self.cube, (self.n_cubes, 1)).astype(np.float32)
        self.floor = np.array([0.0, 1.0, 0.0, 0.0], dtype=np.float32)

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        params = self.sample_params(rng, params)
        cubes = []
        for level in self.levels:  # the authors' draw order: x, y, z per cube
            x = rng.uniform(*self.offset)
            y = rng.uniform(level, level + self.level_jitter)
            z = rng.uniform(*self.offset)
            turn = rotation_y(rng.uniform(0.0, self.yaw)) if self.yaw > 0 else np.eye(3)
            cubes.append(self.cube @ turn.T + np.array([x, y, z]) + self.half_extent)
        positions = np.concatenate(cubes).astype(np.float32)
        return RolloutSample(positions, params, np.zeros((self.n_steps, 0), dtype=np.float32))

    def prepare(self, params: torch.Tensor, actions: torch.Tensor) -> dict:
        planes = self.planes_at(actions)[:, 0]  # the floor does not move
        instance = self._bodies.instance
        allowed = instance[:, None] != instance[None, :]
        return {"gravity": params[:, 0], "planes": planes, "allowed": allowed}

    def planes_at(self, actions: torch.Tensor) -> torch.Tensor:
        floor = torch.as_tensor(self.floor, dtype=actions.dtype, device=actions.device)
        return floor.expand(*actions.shape[:2], 1, 4)

    def gravity(self, ctx: dict, batch: int) -> torch.Tensor:
        g = torch.zeros(batch, 1, 3, device=ctx["gravity"].device)
        g[:, 0, 1] = ctx["gravity"]
        return g

    def neighbours(self, x: torch.Tensor, ctx: dict) -> dict:
        return {"contact": radius_pairs(x, self.contacts.search_radius, ctx["allowed"])}

    def project(self, p, x, ctx, pairs, frame):
        return self.contacts.project(p, x, self._bodies, pairs["contact"], ctx["planes"], self.shape_match)

    def finalize(self, p, x, ctx, frame):
        return self.contacts.finalize(p, x, self._bodies, ctx["planes"], self.shape_match)

    def stored(self, x: torch.Tensor) -> torch.Tensor:
        return self.contacts.stored(x, self.shape_match)
