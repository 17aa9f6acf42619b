from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from vgpl.sim.envs import make_scene

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _two_threads():
    torch.set_num_threads(2)


_SIMULATED: dict = {}


def simulate(name: str, seeds=(0,), params=None, **scene_kwargs):
    """Simulate rollouts of env ``name`` from the given seeds (optionally with fixed params). The engine
    is deterministic, so a simulation asked for again is a copy of the first (FluidCube's take seconds)."""
    key = (name, tuple(seeds), None if params is None else tuple(params), tuple(sorted(scene_kwargs.items())))
    if key not in _SIMULATED:
        scene = make_scene(name, **scene_kwargs)
        samples = [scene.sample(np.random.default_rng(s), params) for s in seeds]
        _SIMULATED[key] = (scene, scene.simulate(samples))
    return copy.deepcopy(_SIMULATED[key])
