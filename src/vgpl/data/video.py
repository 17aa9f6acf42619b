"""Windows of video frames with their ground-truth particles, for the VisualPrior."""

from __future__ import annotations

import lightning as L
from torch.utils.data import DataLoader, Dataset

from vgpl.data.trajectories import NormStats, Rollouts, load_split


class VideoWindows(Dataset):
    """Every window of ``frames`` consecutive frames (every ``stride``-th start) of every rollout.

    Item: frames uint8 [F, H, W, 3], positions [F, N, 3] (metres), instance [N].
    """

    def __init__(self, rollouts: Rollouts, frames: int = 4, start_frame: int = 0, stride: int = 1) -> None:
        if rollouts.images is None:
            raise ValueError("VideoWindows needs rollouts loaded with images=True")
        self.r, self.frames = rollouts, frames
        n_rollouts, n_frames = rollouts.positions.shape[:2]
        self.index = [(r, t) for r in range(n_rollouts) for t in range(start_frame, n_frames - frames + 1, stride)]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k: int) -> dict:
        r, t = self.index[k]
        window = slice(t, t + self.frames)
        return {"frames": self.r.images[r, window], "positions": self.r.positions[r, window], "instance": self.r.instance}


class VideoDataModule(L.LightningDataModule):
    """Train/test video windows of one environment; position statistics from the training split.

    ``stream``: read the training videos window by window from their shard files instead of
    holding them in memory (a 900-video RigidFall split is 6.2 GB of uint8, a MassRope one 10 GB);
    the test videos are held in memory either way. ``first_rollout``: train on the training videos
    from this one on, so that the first ones (the inference module's, ``model.inference.max_rollouts``)
    are held out and their proposals err as the test videos' do."""

    def __init__(self, root: str, env: str, frames: int = 4, batch_size: int = 32, start_frame: int = 0, stride: int = 1,
                 max_rollouts: int | None = None, max_test_rollouts: int | None = None, num_workers: int = 0,
                 stream: bool = False, first_rollout: int = 0) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.train: Rollouts | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train is None:
            hp = self.hparams
            self.train = load_split(hp.root, hp.env, "train", images=True, max_rollouts=hp.max_rollouts, stream=hp.stream,
                                    first_rollout=hp.first_rollout)
            self.test = load_split(hp.root, hp.env, "test", images=True, max_rollouts=hp.max_test_rollouts)
            self.stats = NormStats.from_rollouts(self.train)

    def _loader(self, rollouts: Rollouts, shuffle: bool, stride: int) -> DataLoader:
        hp = self.hparams
        ds = VideoWindows(rollouts, hp.frames, hp.start_frame, stride)
        return DataLoader(ds, batch_size=hp.batch_size, shuffle=shuffle, num_workers=hp.num_workers, drop_last=shuffle and len(ds) > hp.batch_size)

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train, True, self.hparams.stride)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.test, False, self.hparams.frames)  # non-overlapping test windows
