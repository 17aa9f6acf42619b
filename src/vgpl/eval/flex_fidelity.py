"""How close vgpl's engine comes to the authors' FleX rollouts, started from the same state.

:func:`replay` starts a scene from each FleX rollout's first frame with that rollout's parameter and
simulates as many frames as FleX recorded; :func:`position_mse_x1e4` compares two sets of rollouts
frame by frame; :func:`rigid_fall_outcomes` summarises how RigidFall's cubes end up. The chaos floor
is the same engine against itself from a start shifted by ``jitter``: how far two runs of one world
part when they start 1 mm apart, the scale any other world's error is read against.
"""

from __future__ import annotations

import numpy as np

from vgpl.data.flex_rollouts import FlexRollout
from vgpl.sim.scene import RolloutSample, Scene


def replay(scene: Scene, rollouts: list[FlexRollout], jitter: float = 0.0, seed: int = 0) -> np.ndarray:
    """[R, T, N, 3] the scene's rollouts from each FleX rollout's frame 0 (positions, velocities when
    recorded) and parameter, T = the FleX rollout's length; ``jitter`` (m) adds Gaussian noise of that
    standard deviation to every start coordinate."""
    if scene.action_dim:
        raise ValueError(f"env '{scene.name}': replaying FleX rollouts drives no actions yet (RigidFall only)")
    lengths = {r.positions.shape[0] for r in rollouts}
    if len(lengths) != 1:
        raise ValueError(f"FleX rollouts of different lengths {sorted(lengths)}: replay them in groups of one length")
    for r in rollouts:
        if r.positions.shape[1] != scene.n_particles or not np.array_equal(r.instance, scene.instance):
            raise ValueError(f"FleX rollout {r.name}: {r.positions.shape[1]} particles in instances {np.bincount(r.instance).tolist()}, "
                             f"env '{scene.name}' has {scene.n_particles} in {np.bincount(scene.instance).tolist()}")
    n_frames = lengths.pop()
    rng = np.random.default_rng(seed)
    samples = []
    for r in rollouts:
        start = r.positions[0] + (rng.normal(0.0, jitter, r.positions[0].shape) if jitter > 0 else 0.0)
        velocity = None if r.velocities is None else r.velocities[0]
        samples.append(RolloutSample(start.astype(np.float32), r.params, np.zeros((n_frames, 0), np.float32), velocity))
    n_steps, scene.n_steps = scene.n_steps, n_frames
    try:
        return scene.simulate(samples).positions.numpy()
    finally:
        scene.n_steps = n_steps


def position_mse_x1e4(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[T] per-frame position MSE x 1e4 of two [R, T, N, 3] sets: the mean over rollouts, particles
    and coordinates of the squared difference (vgpl's unit; the mean squared 3D distance is 3x this)."""
    return ((a - b) ** 2).mean(axis=(0, 2, 3)) * 1e4


def rigid_fall_outcomes(positions: np.ndarray, instance: np.ndarray, gravity: np.ndarray, dt: float, floor_band: float = 0.05) -> dict:
    """How the cubes end up, from [R, T, N, 3] positions, instance ids [N], gravity [R] (m/s²) and the frame step dt (s).

    cubes_on_floor: cubes whose lowest particle ends within ``floor_band`` (m) of the floor, of R x M;
    resting_height: [min, max] over rollouts of the lowest particle at the last frame (m);
    lowest: the lowest any particle goes (m; below 0: sunk into the floor);
    bottom_slide: [min, max] horizontal travel of the bottom cube's centroid, first to last frame (m);
    first_contact: [min, max] first frame at which the bottom cube's centroid stops falling freely
    (its acceleration departs from gravity by more than a quarter).
    """
    r, t = positions.shape[:2]
    m = int(instance.max()) + 1
    lowest_per_cube = np.stack([positions[:, -1, instance == k, 1].min(-1) for k in range(m)], 1)  # [R, M]
    resting = positions[:, -1, :, 1].min(-1)
    bottom = positions[:, :, instance == 0].mean(2)  # [R, T, 3]
    slide = np.linalg.norm((bottom[:, -1] - bottom[:, 0])[:, [0, 2]], axis=-1)
    accel = bottom[:, 2:, 1] - 2 * bottom[:, 1:-1, 1] + bottom[:, :-2, 1]  # [R, T - 2] per frame², at frames 1 .. T - 2
    free = gravity[:, None] * dt**2
    off = np.abs(accel - free) > 0.25 * np.abs(free)
    first = np.where(off.any(1), off.argmax(1) + 1, t)
    return {
        "cubes_on_floor": int((lowest_per_cube < floor_band).sum()),
        "cubes": r * m,
        "resting_height": [float(resting.min()), float(resting.max())],
        "lowest": float(positions[..., 1].min()),
        "bottom_slide": [float(slide.min()), float(slide.max())],
        "first_contact": [int(first.min()), int(first.max())],
    }
