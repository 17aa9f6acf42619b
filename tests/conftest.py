from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from vgpl.sim.envs import make_scene

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _two_threads():
    torch.set_num_threads(2)


def simulate(name: str, seeds=(0,), params=None, **scene_kwargs):
    """Simulate rollouts of env ``name`` from the given seeds (optionally with fixed params)."""
    scene = make_scene(name, **scene_kwargs)
    samples = [scene.sample(np.random.default_rng(s), params) for s in seeds]
    return scene, scene.simulate(samples)
