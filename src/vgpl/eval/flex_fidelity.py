"""How close vgpl's engine comes to the authors' FleX rollouts, started from the same state.

:func:`replay` starts a scene from each FleX rollout's first frame with that rollout's parameter and
simulates as many frames as FleX recorded; :func:`position_mse_x1e4` compares two sets of rollouts
frame by frame; :func:`rigid_fall_outcomes` summarises how RigidFall's cubes end up and
:func:`mass_rope_outcomes` how MassRope's rope stretches and its mass turns. The chaos floor
is the same engine against itself from a start shifted by ``jitter``: how far two runs of one world
part when they start 1 mm apart, the scale any other world's error is read against.
"""

from __future__ import annotations

import numpy as np

from vgpl.data.flex_rollouts import FlexRollout, pin_actions, same_length
from vgpl.sim.scene import RolloutSample, Scene


def replay(scene: Scene, rollouts: list[FlexRollout], jitter: float = 0.0, seed: int = 0) -> np.ndarray:
    """[R, T, N, 3] the scene's rollouts from each FleX rollout's frame 0 and parameter, T = the FleX
    rollout's length. The start velocities are FleX's where recorded, else the scene's own start
    (MassRope: its mass's kick); MassRope's pin follows FleX's recorded path. ``jitter`` (m) adds
    Gaussian noise of that standard deviation to every start coordinate."""
    n_frames = same_length(rollouts)
    for r in rollouts:
        if r.positions.shape[1] != scene.n_particles or not np.array_equal(r.instance, scene.instance):
            raise ValueError(f"FleX rollout {r.name}: {r.positions.shape[1]} particles in instances {np.bincount(r.instance).tolist()}, "
                             f"env '{scene.name}' has {scene.n_particles} in {np.bincount(scene.instance).tolist()}")
    rng = np.random.default_rng(seed)
    samples = []
    for r in rollouts:
        start = r.positions[0] + (rng.normal(0.0, jitter, r.positions[0].shape) if jitter > 0 else 0.0)
        velocity = scene.initial_velocities() if r.velocities is None else r.velocities[0]
        actions = pin_actions(r.pin, scene.dt) if scene.action_dim else np.zeros((n_frames, 0), np.float32)
        samples.append(RolloutSample(start.astype(np.float32), r.params, actions, velocity))
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


def mass_rope_outcomes(positions: np.ndarray, n_mass: int, rest_length: float) -> dict:
    """How MassRope's rope and mass move, from [R, T, N, 3] positions whose first ``n_mass`` rows are
    the mass, then the rope from its tie to the pin (the last row); ``rest_length``: the unstretched
    length from the mass's tied (last) particle to the pin (m).

    rope_stretch: [min, max] over rollouts of the mean over frames of length / rest_length - 1;
    rope_stretch_peak: the largest stretch at any frame; mass_turn: [min, max] of the largest angle
    (degrees) the mass turns from its frame-0 orientation; mass_drop: [min, max] of how far (m) the
    mass's centroid falls below its start; pin_travel: [min, max] RMS horizontal distance (m) of the
    pin from its frame-0 position.
    """
    chain = positions[:, :, n_mass - 1 :]
    stretch = np.linalg.norm(np.diff(chain, axis=2), axis=-1).sum(-1) / rest_length - 1.0  # [R, T]
    mass = positions[:, :, :n_mass]
    centred = mass - mass.mean(2, keepdims=True)
    cov = np.einsum("rtki,rkj->rtij", centred, centred[:, 0])
    u, _, vh = np.linalg.svd(cov)
    trace = np.trace(u @ vh, axis1=-2, axis2=-1)  # rotation from frame 0 (mass layouts are exactly rigid)
    angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))  # [R, T]
    drop = mass[:, :1, :, 1].mean(-1) - mass[..., 1].mean(-1)
    pin = positions[:, :, -1, :]
    travel = np.sqrt((((pin - pin[:, :1])[..., [0, 2]]) ** 2).sum(-1).mean(-1))
    span = lambda a: [round(float(a.min()), 4), round(float(a.max()), 4)]  # noqa: E731
    return {"rope_stretch": span(stretch.mean(1)), "rope_stretch_peak": round(float(stretch.max()), 4), "mass_turn": span(angle.max(1)),
            "mass_drop": span(drop.max(1)), "pin_travel": span(travel)}
