"""How predictable is the ground truth itself? Shift every instance's initial position rigidly by
``eps`` (a random direction per instance), simulate again with the same engine, and measure the
future MSE x 1e4 between the two trajectories at the evaluation's horizons. If a tiny shift grew
as fast as a learned model's error, no model could beat that error; if it stays small, the model's
error is its own. The shift is applied at frame 0 and frames are counted from there, as RigidFall's
evaluation does; envs whose evaluation drops early frames (``start_frame``, MassRope) are not
modelled that way yet.

    python -m vgpl.eval.sensitivity rigid_fall   # JSON on stdout (100 rollouts, eps 1e-5 .. 1e-2)
"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np
import torch

from vgpl.sim.envs import make_scene
from vgpl.sim.scene import Scene


def engine_sensitivity(scene: Scene, n_rollouts: int, eps: list[float], history: int = 4,
                       horizons: tuple[int, ...] = (1, 5, 10, 20), seed: int = 0) -> dict[str, dict[str, float]]:
    """Per ``eps`` (metres): the mean over ``n_rollouts`` of the MSE x 1e4 between perturbed and
    unperturbed trajectories at T+k, k in ``horizons``, counting frames as the rollout evaluation
    does (``history`` observed frames from frame 0, T+1 is frame ``history``); also the median at
    the last horizon. ``scene.n_steps`` must reach ``history + max(horizons)`` frames."""
    if scene.n_steps < history + max(horizons):
        raise ValueError(f"engine_sensitivity: scene.n_steps={scene.n_steps}, need at least history + max(horizons) = {history + max(horizons)}")
    rng = np.random.default_rng(seed)
    samples = [scene.sample(rng) for _ in range(n_rollouts)]
    base = scene.simulate(samples).positions  # [R, T, N, 3]
    movable = ~np.asarray(scene.kinematic)
    out = {}
    for e in eps:
        # the same directions for every eps, so the rows differ only in the shift's size
        directions = np.random.default_rng(seed + 1).normal(size=(n_rollouts, scene.n_instances, 3))
        shifts = e * directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        perturbed = [
            dataclasses.replace(s, positions=(s.positions + shifts[r][scene.instance] * movable[:, None]).astype(np.float32))
            for r, s in enumerate(samples)
        ]
        per_frame = ((scene.simulate(perturbed).positions - base) ** 2).mean((2, 3)) * 1e4  # [R, T]
        row = {f"T+{k}": float(per_frame[:, history + k - 1].mean()) for k in horizons}
        row[f"T+{max(horizons)} median"] = float(per_frame[:, history + max(horizons) - 1].median())
        out[f"{e:g}"] = row
    return out


def main(argv: list[str]) -> None:
    env = argv[0] if argv else "rigid_fall"
    torch.set_num_threads(min(2, torch.get_num_threads()))
    scene = make_scene(env, n_steps=24)
    result = engine_sensitivity(scene, 100, [1e-5, 1e-4, 1e-3, 1e-2])
    print(json.dumps({"env": env, "n_rollouts": 100, "eps_m": result}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
