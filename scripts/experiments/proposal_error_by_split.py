"""Do the exported proposals fit the inference module's training videos better than the test ones?

The visual prior trains on every training video, the module's 300 among them, so its proposals of those
can be cleaner than of the test videos; a module that learns P from the clean ones then reads the test
ones' through an offset (FluidCube, session 59: 0.587 against 1.738 x 1e4, viscosity bias -13 against -24).
Prints the position MSE x 1e4 of frames [FIRST, LAST) per split, against the recorded particles, and
with ``--block B`` per block of B consecutive training videos too: a visual prior trained with
``model.visual.first_rollout=B`` holds the first block out and saw the second
(scripts/experiments/gpu_held_out_visual.sh). With ``--against OTHER_ROOT``, also the paired
difference (this - other) on the same videos with its 95% bootstrap interval: two visual priors'
proposals of one dataset compared video by video.

    python scripts/experiments/proposal_error_by_split.py DATA_ROOT ENV [--frames 20 30] [--block 300] [--against OTHER_ROOT]
        DATA_ROOT holds <env>/{train,test}/shard_*.h5 and <env>/proposals/{train,test}.h5
"""

from __future__ import annotations

import argparse

import torch

from vgpl.data.grounding import split_with_proposals
from vgpl.data.schema import DatasetError
from vgpl.eval.metrics import position_mse_x1e4
from vgpl.eval.paired import paired_bootstrap


def summary(per_video: torch.Tensor) -> dict:
    return {"videos": len(per_video), "mean": float(per_video.mean()), "median": float(per_video.median())}


def per_video_error(data_root: str, env: str, first: int, last: int) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """{split: (rollout ids [R], position MSE x 1e4 over frames [first, last) of each video [R])}."""
    out = {}
    for split in ("train", "test"):
        truth, prop = split_with_proposals(data_root, env, split)  # refuses proposals of other rollouts
        out[split] = torch.as_tensor(truth.rollout_ids), torch.stack([torch.as_tensor(position_mse_x1e4(p[first:last], t[first:last]))
                                                                      for p, t in zip(prop.positions, truth.positions)])
    return out


def paired_by_split(errors: dict, other_errors: dict, other_root: str, env: str) -> dict:
    """{split: paired_bootstrap(other, this)}: this root's proposal error minus the other's (both from
    ``per_video_error``), video by video; refuses the other root's proposals of other videos."""
    out = {}
    for split, (ids, this) in errors.items():
        other_ids, other = other_errors[split]
        if not torch.equal(ids, other_ids):
            raise DatasetError(f"{other_root}/{env}/proposals/{split}.h5 holds other videos than the first root's "
                               f"({len(other_ids)} against {len(ids)}); export both for the same rollouts")
        out[split] = paired_bootstrap(other, this)
    return out


def error_by_split(errors: dict, block: int | None = None) -> dict:
    """{split: {videos, mean, median}} of ``per_video_error``'s errors; with ``block``, also
    {"train videos a-b": ...} for each block of ``block`` consecutive training videos."""
    out = {}
    for split, (ids, per_video) in errors.items():
        out[split] = summary(per_video)
        if split == "train" and block:
            for k in range(0, len(ids), block):
                out[f"train videos {int(ids[k])}-{int(ids[min(k + block, len(ids)) - 1])}"] = summary(per_video[k:k + block])
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root"), parser.add_argument("env")
    parser.add_argument("--frames", type=int, nargs=2, default=(20, 30), metavar=("FIRST", "LAST"))
    parser.add_argument("--block", type=int, default=None, help="also the training videos in blocks of this many")
    parser.add_argument("--against", default=None, metavar="OTHER_ROOT", help="also this root's proposals of the same videos, paired")
    args = parser.parse_args()
    if args.block is not None and args.block < 1:
        parser.error(f"--block {args.block}: expected a number of videos >= 1")
    try:  # a missing or mismatched proposals file: its one-line message, not a traceback
        errors = per_video_error(args.data_root, args.env, *args.frames)
        pairs = paired_by_split(errors, per_video_error(args.against, args.env, *args.frames), args.against, args.env) if args.against else {}
    except DatasetError as e:
        raise SystemExit(str(e)) from None
    for split, e in error_by_split(errors, block=args.block).items():
        print(f"{split}: {e['videos']} videos, frames {args.frames[0]}-{args.frames[1] - 1}: MSE x 1e4 mean {e['mean']:.3f}, median {e['median']:.3f}")
    for split, d in pairs.items():
        print(f"{split}: this - {args.against}: {d['mean_diff']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}] (95%), "
              f"this lower on {1 - d['reference_lower_share']:.0%} of {d['videos']} videos")
