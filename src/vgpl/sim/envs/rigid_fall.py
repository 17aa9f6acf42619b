"""RigidFall: three rigid 4x4x4 cubes stacked with horizontal jitter, dropped on a floor.

Parameter: gravity (m/s^2, along y). 192 particles, 3 rigid instances, no action.
"""

from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.contacts import project_particle_contacts, project_planes, push_rigid_out_of_planes
from vgpl.sim.neighbors import radius_pairs
from vgpl.sim.scene import RolloutSample, Scene, lattice, rotation_y


class RigidFall(Scene):
    name = "rigid_fall"
    param_names = ("gravity",)
    default_camera = dict(eye=(0.2, 0.875, 2.0), target=(0.0, 0.5, 0.0), fov_y=50.0)
    instance_colors = ((0.85, 0.25, 0.2), (0.25, 0.7, 0.3), (0.25, 0.4, 0.85))
    action_dim = 0
    vertical_symmetry = True  # a floor only; jitter and yaw are symmetric about the y axis

    def __init__(
        self,
        param_low=(-15.0,),
        param_high=(-5.0,),
        n_steps: int = 120,
        dt: float = 1.0 / 60.0,
        substeps: int = 2,
        iterations: int = 4,
        camera: dict | None = None,
        n_cubes: int = 3,
        cube_size: int = 4,
        spacing: float = 0.05,
        base_height: float = 0.4,
        stack_gap: float = 0.1,
        jitter: float = 0.06,
        friction: float = 0.5,
    ) -> None:
        super().__init__(list(param_low), list(param_high), n_steps, dt, substeps, iterations, camera)
        self.cube = lattice((cube_size,) * 3, spacing)
        self.n_cubes, self.spacing = n_cubes, spacing
        self.cube_extent = (cube_size - 1) * spacing + spacing  # particle centres span + one radius each side
        self.base_height, self.stack_gap, self.jitter, self.friction = base_height, stack_gap, jitter, friction
        per = self.cube.shape[0]
        self.instance = np.repeat(np.arange(n_cubes), per)
        self.rigid = np.ones(n_cubes, dtype=bool)
        self.type_names = ("cube",) * n_cubes
        self.inv_mass = np.ones(n_cubes * per, dtype=np.float32)
        self.radius = np.full(n_cubes * per, spacing / 2, dtype=np.float32)
        self.rest_offsets = np.tile(self.cube, (n_cubes, 1)).astype(np.float32)
        self.floor = np.array([0.0, 1.0, 0.0, 0.0], dtype=np.float32)

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        params = self.sample_params(rng, params)
        cubes, y = [], self.base_height
        for _ in range(self.n_cubes):
            centre = np.array([rng.uniform(-self.jitter, self.jitter), y, rng.uniform(-self.jitter, self.jitter)])
            # cube diagonal rotated by yaw: keep the stack gap larger than the rotated extent
            cubes.append(self.cube @ rotation_y(rng.uniform(0.0, np.pi / 2)).T + centre)
            y += self.cube_extent + self.stack_gap * rng.uniform(0.5, 1.5)
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
        return {"contact": radius_pairs(x, 1.6 * self.spacing, ctx["allowed"])}

    def project(self, p, x, ctx, pairs, frame):
        p = project_particle_contacts(p, x, self._bodies, *pairs["contact"], distance=self.spacing, friction=self.friction)
        return project_planes(p, x, self._bodies, ctx["planes"], friction=self.friction)

    def finalize(self, p, ctx, frame):
        return push_rigid_out_of_planes(self.shape_match(p), self._bodies, ctx["planes"])
