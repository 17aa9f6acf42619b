"""A split's videos read from their shard files on demand, for splits whose video does not fit in memory."""

from __future__ import annotations

from pathlib import Path

import h5py
import torch

from vgpl.data.schema import reading
from vgpl.data.shard import video_frame_shape


class StreamedVideos:
    """Stands in for the in-memory uint8 video array [R, T, H, W, 3] of ``Rollouts.images``.

    ``videos[r, frames]`` (``frames`` an int or a slice) reads rollout r's frames from its shard
    file: the files store one gzip chunk per frame, so a 4-frame window decompresses 4 frames.
    Files open on first use in each process and are never pickled, so every DataLoader worker
    opens its own handles. ``sources[r]`` = (shard file, index of the rollout in it).
    """

    def __init__(self, sources: list[tuple[Path, int]]) -> None:
        if not sources:
            raise ValueError("StreamedVideos needs at least one rollout")
        self.sources = sources
        frame_shape = None
        for path in dict.fromkeys(p for p, _ in sources):  # every file once, in order
            with h5py.File(path, "r") as h:
                frame_shape = video_frame_shape(h, path, frame_shape)
        self.shape = (len(sources), *frame_shape)
        self._files: dict[Path, h5py.File] = {}

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> torch.Tensor:
        if not (isinstance(key, tuple) and len(key) == 2):
            raise IndexError("StreamedVideos is indexed as videos[rollout, frames]")
        r, frames = key
        path, i = self.sources[int(r)]
        if path not in self._files:
            self._files[path] = h5py.File(path, "r")
        with reading(path):
            return torch.from_numpy(self._files[path]["images"][i, frames])

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_files": {}}  # open h5py files cannot cross into worker processes
