"""The paper's three environments and a registry that builds them by name."""

from __future__ import annotations

from vgpl.sim.envs.fluid_cube import FluidCube
from vgpl.sim.envs.mass_rope import MassRope
from vgpl.sim.envs.rigid_fall import RigidFall
from vgpl.sim.scene import Scene

ENVS: dict[str, type[Scene]] = {cls.name: cls for cls in (RigidFall, FluidCube, MassRope)}


def make_scene(name: str, **kwargs) -> Scene:
    """Build an environment by name, e.g. ``make_scene("fluid_cube", n_steps=50)``."""
    if name not in ENVS:
        raise ValueError(f"unknown env '{name}': expected one of {sorted(ENVS)}")
    return ENVS[name](**kwargs)
