"""The position-based dynamics loop shared by all environments.

A :class:`Scene` describes one environment: its particles (instances, rigidness, masses, radii),
how a rollout's random initial state, parameters and actions are drawn, and which constraints are
projected. :meth:`Scene.simulate` advances many rollouts of one environment together as tensors.
Each frame (dt) is split into substeps; each substep rebuilds the neighbour pairs, predicts
positions from velocities, projects the constraints a few times (Jacobi over particles, like
FleX) and derives velocities from the position change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vgpl.sim.camera import Camera
from vgpl.sim.contacts import Bodies
from vgpl.sim.renderer import SplatRenderer
from vgpl.sim.shape_matching import shape_match


@dataclass
class RolloutSample:
    """The random draws that define one rollout (all numpy, drawn from the rollout's own seed).

    positions: [N, 3] initial positions; params: [P] physical parameters in physical units;
    actions: [T, A] kinematic state per frame (container or pin position and velocity);
    velocities: [N, 3] initial velocities, None at rest (a recorded frame's positions, velocities
    and the actions from that frame on continue the recorded rollout: vgpl.eval.param_response).
    """

    positions: np.ndarray
    params: np.ndarray
    actions: np.ndarray
    velocities: np.ndarray | None = None


@dataclass
class Trajectories:
    """Simulated rollouts: positions and velocities [B, T, N, 3], params [B, P], actions [B, T, A]."""

    positions: torch.Tensor
    velocities: torch.Tensor
    params: torch.Tensor
    actions: torch.Tensor


class Scene:
    """Base class of the environments. Subclasses fill the particle description in ``__init__``
    and implement :meth:`sample`, :meth:`project`, and where needed the other hooks."""

    name: str = ""
    param_names: tuple[str, ...] = ()
    action_dim: int = 0
    default_camera: dict = {}
    instance_colors: tuple[tuple[float, float, float], ...] = ()  # RGB of each instance
    floor_y: float | None = 0.0  # drawn floor height (None: no floor)
    type_names: tuple[str, ...] = ()  # object type of each instance
    # a rotation about the vertical axis through the origin maps a video to another of the same
    # parameters (a floor as the only plane, objects placed symmetrically; vgpl.data.vertical_symmetry)
    vertical_symmetry: bool = False

    def __init__(
        self,
        param_low: list[float],
        param_high: list[float],
        n_steps: int,
        dt: float = 1.0 / 60.0,
        substeps: int = 2,
        iterations: int = 4,
        camera: dict | None = None,
    ) -> None:
        self.camera = Camera(**{**self.default_camera, **(camera or {})})
        low, high = np.asarray(param_low, dtype=np.float64), np.asarray(param_high, dtype=np.float64)
        if low.shape != (len(self.param_names),) or high.shape != low.shape:
            raise ValueError(
                f"env '{self.name}': param_low/param_high must each hold {len(self.param_names)} value(s) "
                f"for {list(self.param_names)}, got {list(low)} and {list(high)}"
            )
        if np.any(low > high):
            raise ValueError(
                f"env '{self.name}': parameter range has low > high for "
                f"{[n for n, lo, hi in zip(self.param_names, low, high) if lo > hi]}: low={list(low)}, high={list(high)}"
            )
        if n_steps < 2:
            raise ValueError(f"env '{self.name}': n_steps must be >= 2, got {n_steps}")
        self.param_low, self.param_high = low, high
        self.n_steps, self.dt, self.substeps, self.iterations = int(n_steps), float(dt), int(substeps), int(iterations)
        # particle description, filled by subclasses
        self.instance = np.zeros(0, dtype=np.int64)  # [N] instance id
        self.rigid = np.zeros(0, dtype=bool)  # [M] rigidness of each instance
        self.inv_mass = np.zeros(0, dtype=np.float32)  # [N]
        self.radius = np.zeros(0, dtype=np.float32)  # [N] contact radius
        self.rest_offsets = np.zeros((0, 3), dtype=np.float32)  # [N, 3] offset from the rest centroid (rigid)

    # ---- description -------------------------------------------------------------------------
    @property
    def n_particles(self) -> int:
        return int(self.instance.shape[0])

    @property
    def n_instances(self) -> int:
        return int(self.rigid.shape[0])

    @property
    def instance_types(self) -> list[str]:
        """Object type of each instance [M] (e.g. cube, fluid): rigidness is reported per type."""
        return list(self.type_names)

    def renderer(self) -> SplatRenderer:
        """A renderer with this scene's camera, instance colours and (slightly enlarged) radii."""
        colors = np.asarray(self.instance_colors, dtype=np.float32)[self.instance]
        return SplatRenderer(self.camera, colors, self.radius * 1.15, self.floor_y)

    def sample_params(self, rng: np.random.Generator, params=None) -> np.ndarray:
        """[P] parameters uniform in [param_low, param_high], or ``params`` when given (the draw is
        made either way, so the rest of the rollout's random stream is the same)."""
        drawn = rng.uniform(self.param_low, self.param_high).astype(np.float32)
        return drawn if params is None else np.asarray(params, dtype=np.float32).reshape(drawn.shape)

    def sample(self, rng: np.random.Generator, params=None) -> RolloutSample:
        """Draw one rollout's initial state, parameters (or use ``params`` [P]) and actions."""
        raise NotImplementedError

    def initial_velocities(self) -> np.ndarray | None:
        """[N, 3] the velocities every rollout starts with, or None: at rest."""
        return None

    # ---- hooks -------------------------------------------------------------------------------
    def prepare(self, params: torch.Tensor, actions: torch.Tensor) -> dict:
        """Per-batch tensors derived from parameters ([B, P]) and actions ([B, T, A])."""
        return {}

    def gravity(self, ctx: dict, batch: int) -> torch.Tensor:
        """[B, 1, 3] gravitational acceleration."""
        g = torch.tensor([0.0, -9.81, 0.0], device=self._bodies.inv_mass.device)
        return g.expand(batch, 1, 3)

    def neighbours(self, x: torch.Tensor, ctx: dict) -> dict:
        """Pair lists valid for one substep (built from its start positions, with a skin)."""
        return {}

    def kinematics(self, p: torch.Tensor, ctx: dict, frame: float) -> torch.Tensor:
        """Impose kinematic particles at fractional frame time ``frame``; returns p."""
        return p

    def kinematic_positions(self, positions: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """positions [B, T, N, 3] with the kinematic particles (the pin) put where the actions
        [B, T, A] drive them at each frame, as the engine records them; the others unchanged."""
        if not self.kinematic.any():
            return positions
        ctx = {"actions": actions}
        return torch.stack([self.kinematics(positions[:, t], ctx, float(t)) for t in range(positions.shape[1])], 1)

    def project(self, p: torch.Tensor, x: torch.Tensor, ctx: dict, pairs: dict, frame: float) -> torch.Tensor:
        raise NotImplementedError

    def finalize(self, p: torch.Tensor, x: torch.Tensor, ctx: dict, frame: float) -> torch.Tensor:
        """Once per substep after the constraint iterations, from the substep's start x (default: rigid
        shape matching)."""
        return self.shape_match(p)

    def stored(self, x: torch.Tensor) -> torch.Tensor:
        """The positions [B, N, 3] a frame records of the state x [B, N, 3] (default: x itself; a
        scene whose rigid particles end a step off a rigid motion stores them rigidly projected)."""
        return x

    def post_velocity(self, v: torch.Tensor, p: torch.Tensor, ctx: dict, pairs: dict) -> torch.Tensor:
        return v

    def planes_at(self, actions: torch.Tensor) -> torch.Tensor:
        """Boundary half-spaces at every frame: actions [B, T, A] -> [B, T, K, 4] rows (n, d) with
        n . x >= d inside (K = 0 where the scene has none). The learned models see them as
        kinematic ghost nodes."""
        return actions.new_zeros(*actions.shape[:2], 0, 4)

    @property
    def kinematic(self) -> np.ndarray:
        """[N] bool: particles driven by actions (inverse mass 0), e.g. MassRope's pin."""
        return self.inv_mass == 0

    # ---- the loop ----------------------------------------------------------------------------
    def bodies(self, device: torch.device | str = "cpu") -> Bodies:
        """The particle description as tensors on ``device``."""
        return Bodies(
            instance=torch.as_tensor(self.instance, device=device),
            rigid_particle=torch.as_tensor(self.rigid[self.instance], device=device),
            inv_mass=torch.as_tensor(self.inv_mass, device=device),
            radius=torch.as_tensor(self.radius, device=device),
            n_instances=self.n_instances,
        )

    def shape_match(self, p: torch.Tensor) -> torch.Tensor:
        """Project rigid instances onto rigid motions of their rest shape (removes numerical drift)."""
        return shape_match(p, self._rest_offsets, self._bodies.instance, self._bodies.rigid_index, self.n_instances)[0]

    @torch.no_grad()
    def simulate(self, samples: list[RolloutSample], device: str | torch.device = "cpu") -> Trajectories:
        """Advance the rollouts of ``samples`` together for ``n_steps`` frames (frame 0 is the initial state)."""
        device = torch.device(device)
        self._bodies = self.bodies(device)
        self._rest_offsets = torch.as_tensor(self.rest_offsets, device=device)
        x = torch.as_tensor(np.stack([s.positions for s in samples]), dtype=torch.float32, device=device)
        params = torch.as_tensor(np.stack([s.params for s in samples]), dtype=torch.float32, device=device)
        actions = torch.as_tensor(np.stack([s.actions for s in samples]), dtype=torch.float32, device=device)
        b, n, _ = x.shape
        ctx = self.prepare(params, actions)
        ctx["actions"] = actions
        for k, s in enumerate(samples):
            if s.velocities is not None and np.shape(s.velocities) != np.shape(s.positions):
                raise ValueError(f"{self.name}: sample {k} has velocities of shape {np.shape(s.velocities)}, expected its positions' {np.shape(s.positions)}")
        v = torch.stack([torch.zeros_like(x[0]) if s.velocities is None else torch.as_tensor(s.velocities, dtype=torch.float32, device=device)
                         for s in samples])
        pos = torch.empty(b, self.n_steps, n, 3, device=device)
        vel = torch.empty_like(pos)
        pos[:, 0], vel[:, 0] = x, v
        dts = self.dt / self.substeps
        dynamic = (self._bodies.inv_mass > 0).to(x.dtype)[None, :, None]
        g = self.gravity(ctx, b)
        for t in range(1, self.n_steps):
            for s in range(self.substeps):
                pairs = self.neighbours(x, ctx)
                frame = t - 1 + (s + 1) / self.substeps
                v = v + g * dts * dynamic
                p = self.kinematics(x + v * dts, ctx, frame)
                for _ in range(self.iterations):
                    p = self.project(p, x, ctx, pairs, frame)
                p = self.finalize(p, x, ctx, frame)
                v = self.post_velocity((p - x) / dts, p, ctx, pairs)
                x = p
            pos[:, t], vel[:, t] = self.stored(x), v
        return Trajectories(pos, vel, params, actions)


def lattice(shape: tuple[int, int, int], spacing: float) -> np.ndarray:
    """[nx*ny*nz, 3] points of a centred cubic lattice."""
    axes = [(np.arange(k) - (k - 1) / 2.0) * spacing for k in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def random_walk_1d(
    rng: np.random.Generator, n_steps: int, dt: float, noise: float, spring: float, damping: float, start: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Mean-reverting random walk of a kinematic actuator, as the authors' scenes drive theirs: each
    frame v = v (1 - damping) + U(-noise, noise) - spring x, then x += v dt, with x the world
    coordinate (so the walk is pulled toward 0 from ``start``).

    Returns positions and velocities, each [n_steps]; position ``start`` and velocity 0 at frame 0.
    """
    x, v = np.full(n_steps, float(start)), np.zeros(n_steps)
    kicks = rng.uniform(-noise, noise, size=n_steps)
    for t in range(1, n_steps):
        v[t] = v[t - 1] * (1.0 - damping) + kicks[t] - spring * x[t - 1]
        x[t] = x[t - 1] + v[t] * dt
    return x, v
