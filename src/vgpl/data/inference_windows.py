"""Windows for the InferenceModule: T observed frames of VisualPrior proposals, with the ground
truth of those frames and of ``horizon`` frames after them."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset

from vgpl.data.proposals import Proposals, read_proposals
from vgpl.data.schema import DatasetError
from vgpl.data.trajectories import NormStats, Rollouts, ground_truth_grouping, load_split
from vgpl.data.window_pool import check_window_pool, pool_windows
from vgpl.sim.scene import Scene


def proposals_path(root: str | Path, env: str, split: str) -> Path:
    return Path(root) / env / "proposals" / f"{split}.h5"


def split_with_proposals(root: str | Path, env: str, split: str, window_pool: str = "last") -> tuple[Rollouts, Proposals]:
    """The R rollouts of the split that its exported proposals cover, and those proposals: the first R,
    or any R consecutive ones (say videos 300-599, whose proposals a visual prior trained on videos
    300-899 makes as cleanly as it does its own training videos' while it holds 0-299 out), refused by
    file name when the proposals' rollout_ids are not those rollouts', or when ``window_pool`` needs
    the windows' slots and the visual prior's file has none."""
    path = proposals_path(root, env, split)
    proposals = read_proposals(path, window_pool)
    ids = proposals.rollout_ids
    split_first = int(load_split(root, env, split, max_rollouts=1).rollout_ids[0])  # a split's ids are consecutive
    offset = max(int(ids[0]) - split_first, 0) if len(ids) else 0
    rollouts = load_split(root, env, split, max_rollouts=len(ids), first_rollout=offset)
    if not torch.equal(rollouts.rollout_ids, ids):
        raise DatasetError(f"{path}: 'rollout_ids' do not match the dataset's; re-export with task=export_proposals")
    return rollouts, proposals


class InferenceWindows(Dataset):
    """Item: proposals [T, N, 3], logits [T, N, M], positions [T + k, N, 3] (truth), planes
    [T + k, K, 4], params [P], kinematic [N], rigid [M] (the true rigidness, only logged). Windows start at ``start_frame`` and every
    ``stride``-th frame after it, up to ``start_frame + span`` when ``span`` is given. The proposals
    may cover only the first frames of each video, as far as the last window's observed frames.
    ``window_pool`` reads each window's proposals from the visual prior's windows (``pool_windows``).
    ``target_proposals``: items also hold the proposals of the observed and the ``horizon`` future
    frames [T + k, N, 3] (``target_proposals``), which the inference module rolls against when it
    trains without trajectories; the proposals must then cover those future frames too."""

    def __init__(self, rollouts: Rollouts, proposals: Proposals, scene: Scene, observed: int, horizon: int,
                 start_frame: int = 0, stride: int = 1, span: int | None = None, window_pool: str = "last",
                 target_proposals: bool = False) -> None:
        self.r, self.p, self.observed, self.horizon = rollouts, proposals, observed, horizon
        self.window_pool = check_window_pool(window_pool, "model.inference.window_pool")
        n_rollouts, n_frames = rollouts.positions.shape[:2]
        last = n_frames - observed - horizon
        if last < start_frame:
            raise ValueError(f"rollouts of {n_frames} frames are too short for {start_frame} skipped + {observed} observed + {horizon} future frames")
        if span is not None:
            last = min(last, start_frame + span)
        needed = last + observed + (horizon if target_proposals else 0)
        if proposals.positions.shape[1] < needed:
            future = f" + {horizon} future (rollout_target=proposals)" if target_proposals else ""
            raise DatasetError(
                f"proposals cover the first {proposals.positions.shape[1]} frames, windows up to frame {last} + {observed} observed{future} need "
                f"{needed} (exported for a smaller model.inference.window_span, or without rollout_target=proposals?); re-export with task=export_proposals")
        self.target_proposals = target_proposals
        self.index = [(r, s) for r in range(n_rollouts) for s in range(start_frame, last + 1, stride)]
        self.planes = scene.planes_at(rollouts.actions)
        self.kinematic = torch.as_tensor(scene.kinematic)
        self.grouping = ground_truth_grouping(rollouts)

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k: int) -> dict:
        r, s = self.index[k]
        seen, full = slice(s, s + self.observed), slice(s, s + self.observed + self.horizon)
        return {
            "proposals": pool_windows(self.p.positions, self.p.slots, self.window_pool, (r, seen)),
            "logits": self.p.logits[r, seen],
            "positions": self.r.positions[r, full], "planes": self.planes[r, full],
            "params": self.r.params[r], "kinematic": self.kinematic, "rigid": self.r.rigid,
            "grouping": self.grouping,
            **({"target_proposals": pool_windows(self.p.positions, self.p.slots, self.window_pool, (r, full))} if self.target_proposals else {}),
        }


class InferenceDataModule(L.LightningDataModule):
    def __init__(self, root: str, scene: Scene, observed: int = 10, horizon: int = 5, batch_size: int = 2,
                 start_frame: int = 0, stride: int = 1, span: int | None = None, num_workers: int = 0,
                 val_span: int | None = None, window_pool: str = "last", target_proposals: bool = False) -> None:
        """Training windows start every ``stride`` frames within ``span`` frames of ``start_frame``;
        validation windows (on the test split) every ``observed`` frames within ``val_span`` (None:
        ``span``; 0: only the evaluation's window, one per test video). ``window_pool`` and
        ``target_proposals``: as InferenceWindows."""
        super().__init__()
        if val_span is not None and val_span < 0:
            raise ValueError(f"model.inference.val_window_span={val_span}: expected a frame count >= 0, or null for window_span")
        self.span, self.val_span = span, span if val_span is None else val_span
        self.root, self.scene = root, scene
        self.observed, self.horizon, self.batch_size = observed, horizon, batch_size
        self.start_frame, self.stride, self.num_workers = start_frame, stride, num_workers
        self.window_pool = check_window_pool(window_pool, "model.inference.window_pool")
        self.target_proposals = target_proposals
        self.train: Rollouts | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train is None:
            env = self.scene.name
            self.train, self.train_proposals = split_with_proposals(self.root, env, "train", self.window_pool)
            self.test, self.test_proposals = split_with_proposals(self.root, env, "test", self.window_pool)
            if self.train_proposals.positions.shape[2] != self.scene.n_particles:
                raise DatasetError(f"{proposals_path(self.root, env, 'train')}: {self.train_proposals.positions.shape[2]} particles, env {env} has {self.scene.n_particles}")
            self.stats = NormStats.from_rollouts(self.train, torch.as_tensor(self.scene.kinematic))

    def train_dataloader(self) -> DataLoader:
        ds = InferenceWindows(self.train, self.train_proposals, self.scene, self.observed, self.horizon, self.start_frame, self.stride, self.span, self.window_pool,
                              self.target_proposals)
        return DataLoader(ds, batch_size=self.batch_size, shuffle=True, num_workers=self.num_workers, drop_last=len(ds) > self.batch_size)

    def val_dataloader(self) -> DataLoader:
        ds = InferenceWindows(self.test, self.test_proposals, self.scene, self.observed, self.horizon, self.start_frame, self.observed, self.val_span,
                             self.window_pool, self.target_proposals)
        return DataLoader(ds, batch_size=self.batch_size, shuffle=False, num_workers=self.num_workers)
