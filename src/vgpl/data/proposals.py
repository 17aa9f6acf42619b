"""Particle proposals of the VisualPrior over whole videos, and their HDF5 file.

File (one per split, written atomically): positions float32 [R, T, N, 3] (metres), grouping
logits float32 [R, T, N, M], rollout_ids int64 [R]; the visual prior's also slots float32
[R, T, F, N, 3] (every window's prediction of every frame it holds, NaN where no window:
``vgpl.data.window_pool``); attrs: env, split, visual_checkpoint, source ("visual", or "truth"
for ``truth_proposals``), noise_std (metres), format_version.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch
from tqdm.auto import tqdm

from vgpl.atomic_write import atomic_path
from vgpl.data.schema import DatasetError
from vgpl.data.window_pool import check_window_pool

PROPOSALS_VERSION = 1
TRUTH_LOGIT = 20.0  # the true instance's logit in truth_proposals (0 elsewhere): softmax > 0.9999 on it


@dataclass
class Proposals:
    positions: torch.Tensor  # [R, T, N, 3]
    logits: torch.Tensor  # [R, T, N, M]
    rollout_ids: torch.Tensor  # [R]
    attrs: dict
    slots: torch.Tensor | None = None  # [R, T, F, N, 3]: frame t as the window starting at t - k predicts it (NaN: no window); None: not kept


@torch.no_grad()
def propose_windows(model, images: torch.Tensor, batch_size: int = 64, progress: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Slide the model's F-frame window one frame at a time over each video. Keeps the last frame
    of every window (the paper's temporal protocol; the first F - 1 frames come from the first
    window) and every window's prediction of every frame it holds. Windows run on the model's
    device; the outputs are on the CPU.

    Args: images uint8 [R, T, H, W, 3]. Returns positions [R, T, N, 3], logits [R, T, N, M] (the
    paper's), slots [R, T, F, N, 3] (slot k of frame t: the window starting at frame t - k; NaN
    where that window is not in the video).
    """
    model.eval()
    f = model.hparams.frames
    r, t = images.shape[:2]
    if t < f:
        raise ValueError(f"videos of {t} frames are shorter than the visual prior's {f}-frame window")
    starts = [(i, s) for i in range(r) for s in range(t - f + 1)]
    pos = torch.zeros(r, t, model.hparams.n_particles, 3)
    logits = torch.zeros(r, t, model.hparams.n_particles, model.hparams.n_instances)
    slots = torch.full((r, t, f, model.hparams.n_particles, 3), float("nan"))
    held = torch.arange(f)
    for k in tqdm(range(0, len(starts), batch_size), desc="proposals", disable=not progress, unit="batch"):
        chunk = starts[k : k + batch_size]
        frames = torch.stack([images[i, s : s + f] for i, s in chunk]).to(model.device)
        p, g = (x.cpu() for x in model.propose(frames))
        for (i, s), pi, gi in zip(chunk, p, g):
            slots[i, s + held, held] = pi
            if s == 0:
                pos[i, :f], logits[i, :f] = pi, gi
            else:
                pos[i, s + f - 1], logits[i, s + f - 1] = pi[-1], gi[-1]
    return pos, logits, slots


def propose_videos(model, images: torch.Tensor, batch_size: int = 64, progress: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's proposals of ``propose_windows``: positions [R, T, N, 3], logits [R, T, N, M]."""
    return propose_windows(model, images, batch_size, progress)[:2]


def proposal_source(source: str, noise_std: float, source_option: str, noise_option: str, exported: bool = False) -> tuple[str, float]:
    """Check where proposals come from, as the options ``source_option`` / ``noise_option`` give it:
    ``visual`` (the visual prior's, no noise), ``truth`` (``truth_proposals``, noise >= 0) or, where
    ``exported`` allows it, ``exported`` (a file task=export_proposals wrote, ``exported_proposals``).
    Returns (source, noise_std); a bad value raises ValueError naming its option."""
    sources = {"visual": "the visual prior's proposals", "truth": "the recorded particles, a diagnostic",
               "exported": "the test split's proposals file that task=export_proposals wrote"}
    if not exported:
        del sources["exported"]
    if source not in sources:
        choices = [f"'{name}' ({what})" for name, what in sources.items()]
        raise ValueError(f"{source_option}={source!r}: expected {', '.join(choices[:-1])} or {choices[-1]}")
    noise_std = float(noise_std)
    if noise_std < 0 or (noise_std > 0 and source != "truth"):
        raise ValueError(f"{noise_option}={noise_std}: expected 0, or a std > 0 (metres) with {source_option}=truth")
    return source, noise_std


def truth_proposals(positions: torch.Tensor, instance: torch.Tensor, n_instances: int, noise_std: float = 0.0,
                    generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The recorded particles as proposals: what a perfect visual prior would give, or, with
    ``noise_std`` > 0, one whose every coordinate in every frame is off by independent Gaussian
    noise of that std (metres). Not the paper: a diagnostic that tells the errors of the visual
    stage from those of the inference module (docs/design.md).

    Args: positions [R, T, N, 3], instance [N] (ids < n_instances). Returns positions [R, T, N, 3],
    logits [R, T, N, M] (TRUTH_LOGIT on the true instance, 0 on the others).
    """
    if noise_std < 0:
        raise ValueError(f"noise_std={noise_std}: expected a standard deviation >= 0 (metres)")
    noise = torch.randn(positions.shape, generator=generator, dtype=positions.dtype) * noise_std if noise_std > 0 else 0.0
    onehot = torch.nn.functional.one_hot(instance.long(), n_instances).to(positions.dtype)
    logits = (TRUTH_LOGIT * onehot).expand(*positions.shape[:2], *onehot.shape).clone()
    return positions + noise, logits


def write_proposals(path: str | Path, proposals: Proposals) -> Path:
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.create_dataset("positions", data=proposals.positions.numpy().astype(np.float32), chunks=(1, *proposals.positions.shape[1:]))
        f.create_dataset("logits", data=proposals.logits.numpy().astype(np.float32), chunks=(1, *proposals.logits.shape[1:]))
        f.create_dataset("rollout_ids", data=proposals.rollout_ids.numpy().astype(np.int64))
        if proposals.slots is not None:
            f.create_dataset("slots", data=proposals.slots.numpy().astype(np.float32), chunks=(1, *proposals.slots.shape[1:]))
        for k, v in {**proposals.attrs, "format_version": PROPOSALS_VERSION}.items():
            f.attrs[k] = v
    return Path(path)


def read_proposals(path: str | Path, window_pool: str | None = None) -> Proposals:
    """Load a proposals file and check its keys and shapes (the caller matches its rollout_ids).

    ``window_pool`` (``vgpl.data.window_pool``) says whether the windows' slots are read: None
    reads whatever the file holds; ``last`` never reads them (MassRope's training slots are
    68 MB, FluidCube's about 250 MB); ``mean`` needs them, and a visual prior's file without
    them (exported before they were kept) is refused, naming the file.
    """
    path = Path(path)
    if window_pool is not None:
        check_window_pool(window_pool, "window_pool")
    if not path.is_file():
        raise DatasetError(f"{path}: no proposals file (make it with task=export_proposals)")
    try:
        with h5py.File(path, "r") as f:
            missing = [k for k in ("positions", "logits", "rollout_ids") if k not in f]
            if missing:
                raise DatasetError(f"{path}: key '{missing[0]}' missing; not a vgpl proposals file")
            attrs = dict(f.attrs)
            if window_pool == "mean" and "slots" not in f and attrs.get("source", "visual") == "visual":
                raise DatasetError(f"{path}: no 'slots' (exported before they were kept), window_pool='mean' needs them; "
                                   "re-export with task=export_proposals")
            slots = torch.as_tensor(f["slots"][()]) if "slots" in f and window_pool != "last" else None
            out = Proposals(torch.as_tensor(f["positions"][()]), torch.as_tensor(f["logits"][()]), torch.as_tensor(f["rollout_ids"][()]),
                            attrs, slots)
    except OSError as e:
        raise DatasetError(f"{path}: not a readable HDF5 file ({e})") from e
    if out.positions.shape[:3] != out.logits.shape[:3] or out.positions.shape[0] != out.rollout_ids.shape[0]:
        raise DatasetError(f"{path}: 'positions' {tuple(out.positions.shape)}, 'logits' {tuple(out.logits.shape)} and 'rollout_ids' disagree")
    if out.slots is not None and (out.slots.shape[:2] != out.positions.shape[:2] or out.slots.shape[3:] != out.positions.shape[2:]):
        raise DatasetError(f"{path}: 'slots' {tuple(out.slots.shape)} do not match 'positions' {tuple(out.positions.shape)} (expected [R, T, F, N, 3])")
    return out


def exported_proposals(path: str | Path, rollout_ids: torch.Tensor, frames: int, window_pool: str | None = None) -> Proposals:
    """The proposals a file holds for ``rollout_ids`` [R] (in that order), frames [0, ``frames``):
    what the visual prior that exported them gives over those videos, without that prior (it may
    be on another machine). Refused, naming the file, where it lacks a rollout or covers fewer
    frames, or holds proposals that are not the visual prior's; ``window_pool`` as read_proposals."""
    prop = read_proposals(path, window_pool)
    source = str(prop.attrs.get("source", "visual"))
    if source != "visual":
        raise DatasetError(f"{path}: {source} proposals (task.source={source}); eval.proposals=exported evaluates the visual prior's")
    row = {int(i): k for k, i in enumerate(prop.rollout_ids.tolist())}
    missing = [int(i) for i in rollout_ids.tolist() if int(i) not in row]
    if missing:
        raise DatasetError(f"{path}: no proposals for rollout_ids {missing[:5]}{' ...' if len(missing) > 5 else ''} of the test split "
                           f"({len(row)} exported); re-export with task=export_proposals and the evaluation's eval.max_rollouts")
    if prop.positions.shape[1] < frames:
        raise DatasetError(f"{path}: proposals of {prop.positions.shape[1]} frames, the evaluation reads {frames} (start_frame + "
                           "max(observed, eval.max_observed)); re-export with a larger model.inference.window_span")
    take = torch.tensor([row[int(i)] for i in rollout_ids.tolist()], dtype=torch.long)
    return Proposals(prop.positions[take, :frames], prop.logits[take, :frames], prop.rollout_ids[take], prop.attrs,
                     None if prop.slots is None else prop.slots[take, :frames])
