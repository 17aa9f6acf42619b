"""FluidCube: a light rigid cube (4x4x3) floating on fluid (10x10x3) in a 5-wall container that
is shaken along x by a mean-reverting random walk.

Parameter: viscosity in [1, 100], mapped to the XSPH coefficient c = viscosity / 100 per substep.
348 particles, instance 0 = cube (rigid), instance 1 = fluid. Action: container centre position
and velocity [T, 6].
"""

from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.contacts import project_particle_contacts, project_planes, push_rigid_out_of_planes
from vgpl.sim.fluid import lattice_rest_density, project_density, xsph_viscosity
from vgpl.sim.neighbors import radius_pairs
from vgpl.sim.scene import RolloutSample, Scene, lattice, random_walk_1d
from vgpl.sim.vector import PairIndex


class FluidCube(Scene):
    name = "fluid_cube"
    type_names = ("cube", "fluid")
    param_names = ("viscosity",)
    default_camera = dict(eye=(0.0, 0.95, 1.35), target=(0.0, 0.05, 0.0), fov_y=45.0)
    instance_colors = ((0.95, 0.6, 0.15), (0.2, 0.45, 0.9))
    action_dim = 6

    def __init__(
        self,
        param_low=(1.0,),
        param_high=(100.0,),
        n_steps: int = 300,
        dt: float = 1.0 / 60.0,
        substeps: int = 2,
        iterations: int = 4,
        camera: dict | None = None,
        spacing: float = 0.055,
        fluid_shape=(10, 3, 10),
        cube_shape=(4, 3, 4),
        container_half=(0.3025, 0.3025),
        kernel_radius: float = 0.1,
        relaxation: float = 10.0,
        cube_inv_mass: float = 2.0,
        shake_noise: float = 0.15,
        shake_spring: float = 0.1,
        shake_damping: float = 0.05,
        cube_jitter: float = 0.1,
    ) -> None:
        super().__init__(list(param_low), list(param_high), n_steps, dt, substeps, iterations, camera)
        self.spacing, self.h, self.relaxation = spacing, kernel_radius, relaxation
        self.container_half = tuple(container_half)
        self.shake = (shake_noise, shake_spring, shake_damping)
        self.cube_jitter = cube_jitter
        self.cube = lattice(tuple(cube_shape), spacing)
        self.fluid = lattice(tuple(fluid_shape), spacing)
        self.fluid_height = (fluid_shape[1] - 1) * spacing
        n_cube, n_fluid = len(self.cube), len(self.fluid)
        self.instance = np.concatenate([np.zeros(n_cube, np.int64), np.ones(n_fluid, np.int64)])
        self.rigid = np.array([True, False])
        self.inv_mass = np.concatenate([np.full(n_cube, cube_inv_mass), np.ones(n_fluid)]).astype(np.float32)
        self.radius = np.full(n_cube + n_fluid, spacing / 2, dtype=np.float32)
        self.rest_offsets = np.concatenate([self.cube, np.zeros_like(self.fluid)]).astype(np.float32)
        self.rest_density = lattice_rest_density(spacing, kernel_radius)

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        params = self.sample_params(rng, params)
        r = self.spacing / 2
        fluid = self.fluid + np.array([0.0, r + self.fluid_height / 2, 0.0])
        cube_y = r + self.fluid_height + self.spacing + (self.cube[:, 1].max() - self.cube[:, 1].min()) / 2 + 0.02
        jitter = rng.uniform(-self.cube_jitter, self.cube_jitter, size=2)
        cube = self.cube + np.array([jitter[0], cube_y, jitter[1]])
        x, v = random_walk_1d(rng, self.n_steps, self.dt, *self.shake)
        actions = np.zeros((self.n_steps, 6), dtype=np.float32)
        actions[:, 0], actions[:, 3] = x, v
        positions = np.concatenate([cube, fluid]).astype(np.float32)
        return RolloutSample(positions, params, actions)

    def prepare(self, params: torch.Tensor, actions: torch.Tensor) -> dict:
        fluid = self._bodies.instance == 1
        return {
            "xsph": params[:, 0] / 100.0,
            "fluid": fluid,
            "density_pairs": fluid[:, None] | fluid[None, :],
        }

    def container_planes(self, actions: torch.Tensor, frame: float) -> torch.Tensor:
        """[B, 5, 4] floor and four walls of the container at fractional ``frame``."""
        lo = min(int(frame), actions.shape[1] - 1)
        hi = min(lo + 1, actions.shape[1] - 1)
        cx = torch.lerp(actions[:, lo, 0], actions[:, hi, 0], frame - lo)  # [B]
        hx, hz = self.container_half
        b = cx.shape[0]
        planes = torch.zeros(b, 5, 4, device=actions.device)
        planes[:, 0, 1] = 1.0  # floor y >= 0
        planes[:, 1, 0], planes[:, 1, 3] = 1.0, cx - hx  # x >= cx - hx
        planes[:, 2, 0], planes[:, 2, 3] = -1.0, -(cx + hx)  # x <= cx + hx
        planes[:, 3, 2], planes[:, 3, 3] = 1.0, -hz
        planes[:, 4, 2], planes[:, 4, 3] = -1.0, -hz
        return planes

    def planes_at(self, actions: torch.Tensor) -> torch.Tensor:
        b, t, _ = actions.shape
        return self.container_planes(actions.reshape(b * t, 1, -1), 0.0).reshape(b, t, 5, 4)

    def neighbours(self, x, ctx):
        # one distance pass per substep, each pair once; the fluid-only and contact lists are cut
        # from it. The symmetric fluid constraints update both ends of a pair, the particle
        # contacts take both directions.
        i, j, dist = radius_pairs(x, 1.1 * self.h, ctx["density_pairs"], return_distance=True, unique=True)
        fluid = ctx["fluid"].repeat(x.shape[0])
        both = fluid.index_select(0, i) & fluid.index_select(0, j)
        contact = ~both & (dist < 1.6 * self.spacing)
        ci, cj = i[contact], j[contact]
        size = fluid.shape[0]
        return {
            "density": PairIndex.from_pairs(i, j, size),
            "fluid": PairIndex.from_pairs(i[both], j[both], size),
            "contact": (torch.cat([ci, cj]), torch.cat([cj, ci])),
        }

    def project(self, p, x, ctx, pairs, frame):
        p = project_density(p, pairs["density"], ctx["fluid"], self._bodies.inv_mass, self.h, self.rest_density, self.relaxation)
        p = self.shape_match(p)
        p = project_particle_contacts(p, x, self._bodies, *pairs["contact"], distance=self.spacing)
        return project_planes(p, x, self._bodies, self.container_planes(ctx["actions"], frame))

    def finalize(self, p, x, ctx, frame):
        return push_rigid_out_of_planes(self.shape_match(p), self._bodies, self.container_planes(ctx["actions"], frame))

    def post_velocity(self, v, p, ctx, pairs):
        return xsph_viscosity(v, p, pairs["fluid"], self.h, self.rest_density, ctx["xsph"])
