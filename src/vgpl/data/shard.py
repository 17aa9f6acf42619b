"""Reading and writing dataset shards (atomically: a killed writer never leaves a file that looks whole)."""

from __future__ import annotations

import errno
import logging
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from vgpl import __version__
from vgpl.atomic_write import atomic_path
from vgpl.data.schema import DATASETS, FORMAT_VERSION, DatasetError, check_values, reading, validate

log = logging.getLogger(__name__)


@dataclass
class Shard:
    """One shard in memory. Arrays as in the schema; ``images`` is None when not rendered."""

    positions: np.ndarray
    velocities: np.ndarray
    instance: np.ndarray
    rigid: np.ndarray
    params: np.ndarray
    actions: np.ndarray
    rollout_ids: np.ndarray
    images: np.ndarray | None
    attrs: dict


def write_shard(path: str | Path, shard: Shard, compression_level: int = 4, place: Callable[[Path, Path], None] = os.replace) -> Path:
    """Write ``shard`` to ``path`` through a temporary file and an atomic rename; a shard with
    non-finite values or parameters outside its range is refused before anything is written.
    ``place(tmp, path)`` does the rename (task=generate's checks the dataset folder's claim first
    and removes ``tmp`` when it refuses). The file holds no time of writing: the same shard makes
    the same bytes."""
    path = Path(path)
    check_values(path, {key: getattr(shard, key) for key in DATASETS}, shard.attrs["param_low"], shard.attrs["param_high"])
    attrs = {
        **shard.attrs,
        "format_version": FORMAT_VERSION,
        "generator_version": __version__,
    }
    try:
        with atomic_path(path, place) as tmp, h5py.File(tmp, "w") as f:
            for key in DATASETS:
                data = getattr(shard, key)
                chunks = (1, *data.shape[1:]) if data.ndim >= 3 and data.shape[-1] > 0 else None
                f.create_dataset(key, data=data, chunks=chunks)
            if shard.images is not None:
                r, t, h, w, c = shard.images.shape
                f.create_dataset("images", data=shard.images, chunks=(1, 1, h, w, c), compression="gzip", compression_opts=compression_level)
            for k, v in attrs.items():
                f.attrs[k] = v
    except OSError as error:
        if disk_full(error):
            raise OSError(errno.ENOSPC, f"{path.parent}: the disk is full ({shutil.disk_usage(path.parent).free / 1e6:.0f} MB free) while "
                                        f"writing {path.name}; its temporary file was removed and no shard was placed") from None
        raise
    return path


def disk_full(error: OSError) -> bool:
    """Whether ``error`` is a full disk (errno ENOSPC, which h5py puts in its message only)."""
    return error.errno == errno.ENOSPC or "No space left on device" in str(error) or "errno = 28" in str(error)


def read_shard(path: str | Path, images: bool = True, rollouts: int | None = None, frames: int | None = None) -> Shard:
    """Validate and load a shard file: its first ``rollouts`` rollouts (None: all) and of the video
    its first ``frames`` frames (None: all); ``images=False`` skips decoding the video. Only
    what is asked for is read (a FluidCube shard's video is 1.7 GB)."""
    return _load(path, validate(path), images, rollouts, frames)


def _load(path: str | Path, info: dict, images: bool, rollouts: int | None, frames: int | None) -> Shard:
    """The arrays of a shard file ``validate`` has passed (its ``info``), their values checked."""
    with h5py.File(path, "r") as f, reading(path):
        arrays = {key: f[key][:rollouts] if template[0] == "R" else f[key][()] for key, (_, template) in DATASETS.items()}
        video = f["images"][:rollouts, :frames] if images and "images" in f else None
    check_values(path, arrays, info["attrs"]["param_low"], info["attrs"]["param_high"])
    return Shard(**arrays, images=video, attrs=info["attrs"])


NO_VIDEO = "key 'images' missing: the dataset was generated with data.render=false; the visual stages need video"


def video_frame_shape(h: h5py.File, path: Path, expected: tuple | None = None) -> tuple:
    """The [T, H, W, 3] shape of the open shard ``h``'s video; DatasetError naming ``path`` when
    it has none, or when its shape is not ``expected`` (the split's first shard's)."""
    if "images" not in h:
        raise DatasetError(f"{path}: {NO_VIDEO}")
    shape = h["images"].shape[1:]
    if expected is not None and shape != expected:
        raise DatasetError(f"{path}: 'images' of shape [R, {', '.join(map(str, shape))}], "
                           f"the split's first shard has [R, {', '.join(map(str, expected))}]")
    return shape


def read_first_rollouts(files: list[Path], max_rollouts: int | None = None, images: bool = False,
                        frames: int | None = None) -> Iterator[tuple[Path, Shard]]:
    """(file, shard) for shard files that hold consecutive rollouts in order, read only as far as
    the first ``max_rollouts`` rollouts in all (None: every file); ``images`` and ``frames`` as in
    read_shard, and with ``images`` a file without video raises DatasetError."""
    left = max_rollouts
    for f in files:
        if left is not None and left <= 0:
            return
        shard = read_shard(f, images=images, rollouts=left, frames=frames)
        if images and shard.images is None:
            raise DatasetError(f"{f}: {NO_VIDEO}")
        yield f, shard
        if left is not None:
            left -= len(shard.rollout_ids)


def shard_is_complete(path: Path, config_hash: str) -> bool:
    """True when ``path`` is a valid shard written with ``config_hash``.

    Raises DatasetError when the file is a valid shard of a *different* configuration, so that
    a run with changed settings never silently mixes with (or overwrites) existing data.
    """
    if not path.exists():
        return False
    try:
        info = validate(path)
    except DatasetError:
        return False  # unreadable leftovers are rewritten
    found = str(info["attrs"]["config_hash"])
    if found != config_hash:
        raise DatasetError(
            f"{path}: exists with a different configuration (config_hash {found}, this run {config_hash}); "
            "choose another data.root or delete the folder"
        )
    _load(path, info, images=False, rollouts=None, frames=None)  # its values too: a shard with NaN is never counted as done
    try:
        read_every_chunk(path)
    except DatasetError as error:
        log.warning("%s; it is written again", error)
        return False
    return True


def read_every_chunk(path: Path) -> None:
    """Read every dataset of the shard ``path`` rollout by rollout (a video one rollout at a time,
    not all in memory): DatasetError naming the file when a chunk is damaged."""
    with h5py.File(path, "r") as f, reading(path):
        for key in f:
            data = f[key]
            for i in range(data.shape[0] if data.ndim else 1):
                data[i] if data.ndim else data[()]
