"""Windows of particle trajectories for the learned modules, and their normalisation statistics.

A sample is a window of ``history`` frames ending at t and ``horizon`` frames after it, from one
rollout, with the ground-truth grouping G (one-hot instance), rigidness Q, parameters P and the
kinematic boundaries. Statistics come from the training split only and travel with checkpoints.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from vgpl.data.schema import DatasetError, reading
from vgpl.data.shard import read_first_rollouts, video_frame_shape
from vgpl.data.streamed_videos import StreamedVideos
from vgpl.sim.scene import Scene


@dataclass
class Rollouts:
    """All rollouts of a split in memory: positions [R, T, N, 3], params [R, P], actions [R, T, A],
    instance [N], rigid [M], param_low/high [P], rollout_ids [R]; images uint8 [R, T, H, W, 3]
    when loaded with ``images=True`` (a StreamedVideos read on demand with ``stream=True``);
    the engine's velocities [R, T, N, 3] with ``velocities=True`` (to restart it from a frame)."""

    positions: torch.Tensor
    params: torch.Tensor
    actions: torch.Tensor
    instance: torch.Tensor
    rigid: torch.Tensor
    param_low: torch.Tensor
    param_high: torch.Tensor
    env: str
    rollout_ids: torch.Tensor | None = None
    images: torch.Tensor | StreamedVideos | None = None
    velocities: torch.Tensor | None = None


def load_split(root: str | Path, env: str, split: str, images: bool = False, max_rollouts: int | None = None,
               stream: bool = False, velocities: bool = False, first_rollout: int = 0) -> Rollouts:
    """Read the shards of ``root/env/split`` (validated), in rollout order: ``max_rollouts``
    rollouts (None: every one) from the ``first_rollout``-th on, and only the files that hold them.
    Videos are read straight into one array, with no copy per shard, or with ``stream=True`` left
    in their files and read window by window (StreamedVideos: memory independent of the split's size)."""
    folder = Path(root) / env / split
    files = sorted(folder.glob("shard_*.h5"))
    if not files:
        manifest = read_manifest(Path(root) / env)
        if split == "test" and manifest is not None and float(manifest.get("train_fraction", 0.0)) >= 1.0:
            raise DatasetError(f"{folder}: no test split: {Path(root) / env / 'dataset.json'} records data.train_fraction=1.0, so generation "
                               f"writes none; generate a dataset with data.train_fraction below 1 (into another data.root) to evaluate")
        raise DatasetError(f"{folder}: no shard_*.h5 files (generate them with task=generate env={env})")
    if first_rollout < 0:
        raise ValueError(f"load_split: first_rollout={first_rollout}, expected >= 0")
    # shard files hold consecutive rollouts in order, so the first files suffice
    last = None if max_rollouts is None else first_rollout + max_rollouts
    read = list(read_first_rollouts(files, last))  # the video, if asked for, is read below, straight into one array
    manifest = read_manifest(Path(root) / env)
    for f, shard in read:
        check_belongs(f, shard, env, manifest)
    shards = [shard for _, shard in read]
    seen: dict[int, Path] = {}
    for f, shard in read:  # a stray copy of a shard would train on its rollouts twice
        for rid in shard.rollout_ids.tolist():
            if rid in seen:
                raise DatasetError(f"{f}: rollout {rid} is also in {seen[rid]}: every rollout id of a split must be unique "
                                   "(a copied or misplaced shard file? remove it)")
            seen[rid] = f
    order = np.argsort(np.concatenate([s.rollout_ids for s in shards]), kind="stable")[first_rollout:]  # the kept rollouts
    if len(order) == 0:
        raise DatasetError(f"{folder}: {sum(len(s.rollout_ids) for s in shards)} rollouts, none from first_rollout={first_rollout} on")
    cat = lambda key: torch.as_tensor(np.concatenate([getattr(s, key) for s in shards])[order])  # noqa: E731
    first = shards[0]
    in_files = [(f, i) for f, s in read for i in range(len(s.rollout_ids))]
    sources = [in_files[k] for k in order]  # (shard file, index in it) of each kept rollout
    videos = None if not images else StreamedVideos(sources) if stream else _read_videos(sources)
    return Rollouts(
        cat("positions"), cat("params"), cat("actions"), torch.as_tensor(first.instance), torch.as_tensor(first.rigid),
        torch.as_tensor(np.asarray(first.attrs["param_low"], np.float32)), torch.as_tensor(np.asarray(first.attrs["param_high"], np.float32)),
        str(first.attrs["env"]), cat("rollout_ids"), videos, cat("velocities") if velocities else None,
    )


def read_manifest(folder: Path) -> dict | None:
    """The folder's ``dataset.json`` (the configuration that generated it), or None for a folder
    written without one."""
    path = folder / "dataset.json"
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise DatasetError(f"{path}: unreadable ({error}); it records which configuration generated {folder}") from None


def check_belongs(path: Path, shard, env: str, manifest: dict | None) -> None:
    """Refuse a shard that is not of this folder: another env's (its ``env`` attribute), another
    configuration's (``config_hash`` or ``seed`` against dataset.json), or with a parameter range
    other than the one the folder was generated with. DatasetError names the file, the attribute
    and both values."""
    attrs = shard.attrs
    if str(attrs["env"]) != env:
        raise DatasetError(f"{path}: attribute env={str(attrs['env'])!r}, expected {env!r}, the env of its folder (a shard copied "
                           "from another env's folder? remove it)")
    if manifest is None:
        return
    where = path.parent.parent / "dataset.json"
    for key in ("config_hash", "seed"):
        if key in manifest and str(attrs[key]) != str(manifest[key]):
            raise DatasetError(f"{path}: attribute {key}={attrs[key]!s}, but {where} records {key}={manifest[key]!s}: a shard of "
                               "another configuration (copied into this split?); remove it, or generate it again here")
    for key in ("param_low", "param_high"):
        if key in manifest and not np.allclose(np.asarray(attrs[key], float), np.asarray(manifest[key], float)):
            raise DatasetError(f"{path}: attribute {key}={np.asarray(attrs[key]).tolist()}, but {where} records {key}={manifest[key]}: "
                               "its parameters were drawn from another range")
    low, high = np.asarray(manifest.get("param_low", attrs["param_low"]), float), np.asarray(manifest.get("param_high", attrs["param_high"]), float)
    out = ((shard.params < low - 1e-6 * (high - low)) | (shard.params > high + 1e-6 * (high - low))).any(1)
    if out.any():
        raise DatasetError(f"{path}: 'params' of rollout(s) {shard.rollout_ids[out].tolist()} lie outside [{low.tolist()}, {high.tolist()}], "
                           f"the range {where} records")


def _read_videos(sources: list[tuple[Path, int]]) -> torch.Tensor:
    """The videos at (shard file, index in it), in this order, into one uint8 array [R, T, H, W, 3]:
    each file opened once, and h5py reads each run of consecutive rollouts straight into it."""
    out = None
    rows_of: dict[Path, list[tuple[int, int]]] = {}
    for row, (path, i) in enumerate(sources):
        rows_of.setdefault(path, []).append((row, i))
    for path, rows in rows_of.items():
        with h5py.File(path, "r") as h:
            shape = video_frame_shape(h, path, None if out is None else out.shape[1:])
            if out is None:
                out = np.empty((len(sources), *shape), np.uint8)
            start = 0
            for k in range(1, len(rows) + 1):  # split into runs where row and index both step by one
                if k == len(rows) or rows[k] != (rows[k - 1][0] + 1, rows[k - 1][1] + 1):
                    (row, i), n = rows[start], k - start
                    with reading(path):
                        h["images"].read_direct(out, np.s_[i : i + n], np.s_[row : row + n])
                    start = k
    return torch.from_numpy(out)


def _std(x: torch.Tensor) -> torch.Tensor:
    """Per-axis std [3], floored at 1e-3 of the largest axis: an axis with no motion (a cube
    falling straight down) must not turn float noise into huge normalised inputs."""
    std = x.std(0)
    return std.clamp_min(max(float(std.max()) * 1e-3, 1e-8)).float()


@dataclass
class NormStats:
    """Mean and std of per-frame displacements and of positions, each [3]."""

    disp_mean: torch.Tensor
    disp_std: torch.Tensor
    pos_mean: torch.Tensor
    pos_std: torch.Tensor

    @classmethod
    def from_rollouts(cls, r: Rollouts, kinematic: torch.Tensor | None = None) -> NormStats:
        pos = r.positions if kinematic is None else r.positions[:, :, ~kinematic]
        disp = (pos[:, 1:] - pos[:, :-1]).reshape(-1, 3).double()
        flat = pos.reshape(-1, 3).double()
        return cls(disp.mean(0).float(), _std(disp), flat.mean(0).float(), _std(flat))


def ground_truth_grouping(rollouts: Rollouts) -> torch.Tensor:
    """[N, M] one-hot grouping G from the recorded instance ids."""
    return torch.nn.functional.one_hot(rollouts.instance, int(rollouts.rigid.shape[0])).float()


def true_window(scene: Scene, test: Rollouts, start: int, n_frames: int, n: int) -> tuple:
    """The first ``n`` rollouts' frames ``start`` .. ``start + n_frames - 1`` with their true grouping and
    rigidness: (positions [n, F, N, 3] (a copy), grouping [n, N, M], rigidness [n, M], params [n, P],
    planes [n, F, K, 4], kinematic [N]), the arguments the prior's sweeps take in this order."""
    frames = slice(start, start + n_frames)
    return (test.positions[:n, frames].clone(), ground_truth_grouping(test).expand(n, -1, -1), test.rigid.float().expand(n, -1),
            test.params[:n], scene.planes_at(test.actions[:n, frames]), torch.as_tensor(scene.kinematic))


class TrajectoryWindows(Dataset):
    """Every window (rollout r, frame t) with ``history`` frames up to t and ``horizon`` after,
    inside frames [start_frame, start_frame + span) when ``span`` is given."""

    def __init__(self, rollouts: Rollouts, scene: Scene, history: int = 4, horizon: int = 1, start_frame: int = 0,
                 span: int | None = None) -> None:
        self.r, self.history, self.horizon = rollouts, history, horizon
        n_rollouts, n_frames = rollouts.positions.shape[:2]
        first = start_frame + history - 1
        last = n_frames - horizon - 1 if span is None else min(n_frames, start_frame + span) - horizon - 1
        if last < first:
            within = f"rollouts of {n_frames} frames are" if span is None else f"window_span={span} (frames {start_frame} to {start_frame + span - 1}) is"
            raise ValueError(f"{within} too short for history={history} + horizon={horizon}")
        self.index = [(r, t) for r in range(n_rollouts) for t in range(first, last + 1)]
        self.planes = scene.planes_at(rollouts.actions)  # [R, T, K, 4]
        self.grouping = ground_truth_grouping(rollouts)
        self.kinematic = torch.as_tensor(scene.kinematic)

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k: int) -> dict:
        r, t = self.index[k]
        window = slice(t - self.history + 1, t + self.horizon + 1)
        return {
            "positions": self.r.positions[r, window],  # [H + k, N, 3]
            "planes": self.planes[r, window],  # [H + k, K, 4]
            "params": self.r.params[r],
            "grouping": self.grouping,  # [N, M]
            "rigidness": self.r.rigid.float(),  # [M]
            "kinematic": self.kinematic,  # [N]
        }


class TrajectoryDataModule(L.LightningDataModule):
    """Train/test windows of one environment's HDF5 dataset; ``stats`` from the training split."""

    def __init__(self, root: str, scene: Scene, history: int = 4, horizon: int = 1, batch_size: int = 4, num_workers: int = 0, start_frame: int = 0,
                 train_span: int | None = None) -> None:
        super().__init__()
        self.train_span = train_span  # training windows only within this many frames from start_frame (validation: all)
        self.root, self.scene = root, scene
        self.history, self.horizon, self.batch_size, self.num_workers, self.start_frame = history, horizon, batch_size, num_workers, start_frame
        self.train: Rollouts | None = None
        self.test: Rollouts | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train is None:
            self.train = load_split(self.root, self.scene.name, "train")
            self.test = load_split(self.root, self.scene.name, "test")
            n = self.scene.n_particles
            if self.train.positions.shape[2] != n:
                raise DatasetError(f"{self.root}/{self.scene.name}: dataset has {self.train.positions.shape[2]} particles, env config has {n}")
            self.stats = NormStats.from_rollouts(self.train, torch.as_tensor(self.scene.kinematic))

    def _loader(self, rollouts: Rollouts, shuffle: bool) -> DataLoader:
        ds = TrajectoryWindows(rollouts, self.scene, self.history, self.horizon, self.start_frame, self.train_span if shuffle else None)
        return DataLoader(ds, batch_size=self.batch_size, shuffle=shuffle, num_workers=self.num_workers, drop_last=shuffle)

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train, True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.test, False)
