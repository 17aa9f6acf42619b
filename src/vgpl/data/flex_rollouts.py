"""Reader for the FleX rollouts of the paper's authors (RigidFall and MassRope).

Their code writes one HDF5 file per frame, ``<root>/<rollout>/<frame>.h5``, each holding that
frame's ``positions`` [N + S, 3] (particles, then S shape rows), ``shape_quats`` [S, 4] and the
rollout's ``scene_params``; their demo rollouts also hold ``velocities``. The same rollouts can be
packed one group per rollout (``<file>.h5:/<rollout>/positions`` [T, N + S, 3], ...). Either layout
reads into :class:`FlexRollout`, vgpl's view of a rollout: particles, grouping, rigidness and the
physical parameter in vgpl's units.

Rows, as the authors' generator writes them:
- RigidFall: 192 cube particles (3 cubes of 64, x-outer, y, z-inner), then the floor.
  ``scene_params`` = [n_instance, gravity, x0, y0, z0, x1, y1, z1, x2, y2, z2, draw_mesh].
- MassRope: 81 mass particles, 14 rope particles, then the pin, whose row at frame t holds the pin's
  position at frame t + 1 (the action). ``scene_params`` = [x, y, z, length, stiffness, draw_mesh].
  vgpl's MassRope has the same 96 particles in the same order; the reader puts the pin row back at
  the frame it belongs to, and frame 0's pin where FleX creates it, straight above the rope's last
  particle at the pin's height.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch


@dataclass(frozen=True)
class FlexLayout:
    """How one env's rows and parameters are laid out in the authors' files."""

    n_particles: int  # particle rows before the shape rows
    n_rows: int  # rows of ``positions`` per frame
    instance: tuple[int, ...]  # [N] instance of each particle
    rigid: tuple[bool, ...]  # [M]
    param_index: int  # the physical parameter's index in ``scene_params``
    pin_row: int | None = None  # the row holding the pin's next position (MassRope)


LAYOUTS = {
    "rigid_fall": FlexLayout(192, 193, tuple(np.repeat(np.arange(3), 64).tolist()), (True, True, True), param_index=1),
    "mass_rope": FlexLayout(96, 96, (0,) * 81 + (1,) * 15, (True, False), param_index=4, pin_row=95),
}


class FlexFormatError(ValueError):
    """A file that is not an authors' rollout of the expected env; the message names the file."""


@dataclass
class FlexRollout:
    """One FleX rollout in vgpl's terms.

    positions: [T, N, 3] particles (shape rows dropped), metres; velocities: [T, N, 3] or None;
    params: [1] the physical parameter (RigidFall gravity in m/s², MassRope stiffness);
    instance: [N] instance ids; rigid: [M] rigidness; scene_params: the authors' raw vector;
    pin: [T, 3] the pin's position at each frame (MassRope: the last particle's row, frame t's being
    the row the authors stored at t - 1), else None.
    """

    env: str
    name: str
    positions: np.ndarray
    velocities: np.ndarray | None
    params: np.ndarray
    instance: np.ndarray
    rigid: np.ndarray
    scene_params: np.ndarray
    pin: np.ndarray | None = None


def read_flex_rollouts(path: str | Path, env: str) -> list[FlexRollout]:
    """Every rollout under ``path``, in the order of their numeric names.

    ``path`` is a packed file (one group per rollout), a folder of rollout folders
    (``<path>/<rollout>/<frame>.h5``) or one rollout folder (``<path>/<frame>.h5``).
    """
    if env not in LAYOUTS:
        raise ValueError(f"env '{env}': the authors released FleX rollouts of {sorted(LAYOUTS)} only")
    path = Path(path)
    if path.is_file():
        return _read_packed(path, env)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such file or folder of FleX rollouts")
    if list(path.glob("*.h5")):
        return [_read_frames(path, env)]
    folders = sorted((p for p in path.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name))
    if not folders:
        raise FlexFormatError(f"{path}: holds neither <frame>.h5 files nor numbered rollout folders")
    return [_read_frames(folder, env) for folder in folders]


def _read_packed(path: Path, env: str) -> list[FlexRollout]:
    try:
        file = h5py.File(path, "r")
    except OSError as err:
        raise FlexFormatError(f"{path}: not a readable HDF5 file ({err})") from err
    with file:
        names = sorted((k for k in file if k.isdigit()), key=int)
        if not names:
            raise FlexFormatError(f"{path}: no rollout groups (expected groups named 0, 1, ...)")
        out = []
        for name in names:
            group = file[name]
            arrays = {key: np.asarray(group[key]) for key in ("positions", "velocities", "scene_params") if key in group}
            out.append(_rollout(f"{path}:/{name}", name, arrays, env))
        return out


def _read_frames(folder: Path, env: str) -> FlexRollout:
    frames = list(folder.glob("*.h5"))
    odd = sorted(p.name for p in frames if not p.stem.isdigit())
    if odd:
        raise FlexFormatError(f"{folder}: frame files must be named <frame>.h5 with a number, found {odd[0]}")
    frames.sort(key=lambda p: int(p.stem))  # numbers as numbers: 2.h5 before 10.h5
    per_frame: dict[str, list[np.ndarray]] = {}
    for frame in frames:
        try:
            with h5py.File(frame, "r") as f:
                for key in ("positions", "velocities", "scene_params"):
                    if key in f:
                        per_frame.setdefault(key, []).append(np.asarray(f[key]))
        except OSError as err:
            raise FlexFormatError(f"{frame}: not a readable HDF5 file ({err})") from err
    arrays = {key: np.stack(v) for key, v in per_frame.items() if key != "scene_params" and len(v) == len(frames)}
    if "scene_params" in per_frame:
        arrays["scene_params"] = per_frame["scene_params"][0]
    return _rollout(str(folder), folder.name, arrays, env)


def _rollout(where: str, name: str, arrays: dict[str, np.ndarray], env: str) -> FlexRollout:
    layout = LAYOUTS[env]
    for key in ("positions", "scene_params"):
        if key not in arrays:
            raise FlexFormatError(f"{where}: no '{key}' (an authors' {env} rollout holds positions and scene_params per frame)")
    positions = arrays["positions"]
    if positions.ndim != 3 or positions.shape[1:] != (layout.n_rows, 3):
        raise FlexFormatError(f"{where}: 'positions' has shape {positions.shape}, expected [T, {layout.n_rows}, 3] for {env}")
    scene_params = np.asarray(arrays["scene_params"], dtype=np.float64).reshape(-1)
    if scene_params.shape[0] <= layout.param_index:
        raise FlexFormatError(f"{where}: 'scene_params' holds {scene_params.shape[0]} values, expected more than {layout.param_index} for {env}")
    velocities = arrays.get("velocities")
    n = layout.n_particles
    positions = positions[:, :n].astype(np.float32)
    pin = None
    if layout.pin_row is not None:
        stored = positions[:, layout.pin_row].copy()  # frame t's row: the pin at t + 1
        first = np.array([positions[0, layout.pin_row - 1, 0], stored[0, 1], positions[0, layout.pin_row - 1, 2]], np.float32)
        pin = np.concatenate([first[None], stored[:-1]])
        positions[:, layout.pin_row] = pin
    return FlexRollout(
        env=env,
        name=name,
        positions=positions,
        velocities=None if velocities is None else velocities[:, :n].astype(np.float32),
        params=np.array([scene_params[layout.param_index]], dtype=np.float32),
        instance=np.asarray(layout.instance, dtype=np.int64),
        rigid=np.asarray(layout.rigid, dtype=bool),
        scene_params=scene_params,
        pin=pin,
    )


def same_length(rollouts: list[FlexRollout]) -> int:
    """The one length T the rollouts share; a clear error where they differ."""
    lengths = {r.positions.shape[0] for r in rollouts}
    if len(lengths) != 1:
        raise ValueError(f"FleX rollouts of different lengths {sorted(lengths)}: use them in groups of one length")
    return lengths.pop()


def pin_actions(pin: np.ndarray, dt: float) -> np.ndarray:
    """[T, 6] vgpl's MassRope actions from a pin path [T, 3]: position, and the velocity that moved
    it there from the previous frame (m/s; 0 at frame 0)."""
    velocity = np.concatenate([np.zeros((1, 3), np.float32), np.diff(pin, axis=0) / dt])
    return np.concatenate([pin, velocity], 1).astype(np.float32)


def as_rollouts(rollouts: list[FlexRollout], scene):
    """The FleX rollouts as a test split of ``scene``'s env (vgpl.data.trajectories.Rollouts): the
    learned models read them as they read the env's own shards (MassRope's actions: the pin's path)."""
    from vgpl.data.trajectories import Rollouts

    env = {r.env for r in rollouts}
    if env != {scene.name}:
        raise ValueError(f"FleX rollouts of {sorted(env)} given as the test split of env '{scene.name}'")
    same_length(rollouts)
    if rollouts[0].positions.shape[1] != scene.n_particles:
        raise ValueError(f"FleX rollouts of {rollouts[0].positions.shape[1]} particles given as the test split of env '{scene.name}' "
                         f"({scene.n_particles} particles)")
    positions = torch.as_tensor(np.stack([r.positions for r in rollouts]))
    if scene.action_dim:
        actions = torch.as_tensor(np.stack([pin_actions(r.pin, scene.dt) for r in rollouts]))
    else:
        actions = positions.new_zeros(len(rollouts), positions.shape[1], 0)
    return Rollouts(
        positions=positions,
        params=torch.as_tensor(np.stack([r.params for r in rollouts])),
        actions=actions,
        instance=torch.as_tensor(rollouts[0].instance),
        rigid=torch.as_tensor(rollouts[0].rigid),
        param_low=torch.as_tensor(scene.param_low, dtype=torch.float32),
        param_high=torch.as_tensor(scene.param_high, dtype=torch.float32),
        env=scene.name,
        rollout_ids=torch.arange(len(rollouts)),
    )
