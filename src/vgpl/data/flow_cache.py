"""Estimated optical flow computed once per dataset split and kept next to its shards:
``<data.root>/<env>/flow/<split>.h5`` holds Farneback's flow between consecutive frames of every
rollout, from the first frame on, as float16 [R, F, H, W, 2] (pixels per frame; float16 keeps
under 0.004 px of error below 8 px). Consecutive-frame flow does not depend on the window a frame
pair falls in, so every window of every epoch reads the same numbers the estimator gave once.

The file records the split's ``config_hash`` (the shards'), the rollout ids and how many frame
pairs it holds; a cache that does not match what is asked for is rebuilt, atomically.
"""

from __future__ import annotations

import logging
from pathlib import Path

import h5py
import numpy as np
import torch
from tqdm.auto import tqdm

from vgpl.atomic_write import atomic_path
from vgpl.data.dataset_claim import written_by
from vgpl.data.flow import FARNEBACK, farneback_flow
from vgpl.data.trajectories import Rollouts

log = logging.getLogger(__name__)

METHOD = "farneback(" + ", ".join(f"{k}={v}" for k, v in FARNEBACK.items()) + ")"  # recorded in the cache: other settings rebuild it


def flow_cache_path(root: str | Path, env: str, split: str) -> Path:
    return Path(root) / env / "flow" / f"{split}.h5"


def split_config_hash(root: str | Path, env: str, split: str) -> str:
    """The config_hash of the split's shards (they all share it)."""
    return str(written_by(sorted((Path(root) / env / split).glob("shard_*.h5"))[0]))


def cache_matches(path: Path, config_hash: str, rollout_ids: torch.Tensor, pairs: int) -> bool:
    """True when ``path`` holds at least ``pairs`` frame pairs of these rollouts of this dataset,
    as its first ones (an evaluation of the first 100 test videos reads a cache of all 200)."""
    if not path.is_file():
        return False
    try:
        with h5py.File(path, "r") as f:
            return (str(f.attrs["config_hash"]) == config_hash and str(f.attrs["method"]) == METHOD and f["flow"].shape[1] >= pairs
                    and np.array_equal(f["rollout_ids"][: len(rollout_ids)], rollout_ids.numpy()))
    except (OSError, KeyError):
        return False


def ensure_flow_cache(root: str | Path, env: str, split: str, rollouts: Rollouts, pairs: int, progress: bool = False) -> Path:
    """The cache of ``split`` holding the first ``pairs`` frame pairs of every rollout of
    ``rollouts`` (loaded with images), written when missing or not matching."""
    path = flow_cache_path(root, env, split)
    if pairs >= rollouts.images.shape[1]:
        raise ValueError(f"{path}: {pairs} frame pairs asked of {rollouts.images.shape[1]}-frame videos")
    config_hash = split_config_hash(root, env, split)
    if cache_matches(path, config_hash, rollouts.rollout_ids, pairs):
        return path
    log.info("estimating optical flow once for %s/%s (%d videos, %d frame pairs each) into %s", env, split, len(rollouts.rollout_ids), pairs, path)
    h, w = rollouts.images.shape[2:4]
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        flow = f.create_dataset("flow", (len(rollouts.rollout_ids), pairs, h, w, 2), dtype=np.float16, chunks=(1, 1, h, w, 2))
        for r in tqdm(range(len(rollouts.rollout_ids)), desc=f"optical flow {split}", unit="video", disable=not progress):
            flow[r] = farneback_flow(torch.as_tensor(np.asarray(rollouts.images[r, : pairs + 1]))).numpy().astype(np.float16)
        f.create_dataset("rollout_ids", data=rollouts.rollout_ids.numpy())
        f.attrs.update({"config_hash": config_hash, "method": METHOD, "env": env, "split": split})
    return path


class CachedFlow:
    """Reads windows of a flow cache: ``window(r, start, pairs)`` -> float32 [pairs, H, W, 2] of the
    r-th rollout (its position in the cache). The file opens on first use, in each process."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = None

    def window(self, r: int, start: int, pairs: int) -> torch.Tensor:
        if self._file is None:
            self._file = h5py.File(self.path, "r")
        return torch.from_numpy(self._file["flow"][r, start : start + pairs].astype(np.float32))

    def __getstate__(self) -> dict:  # DataLoader workers reopen the file
        return {"path": self.path, "_file": None}
