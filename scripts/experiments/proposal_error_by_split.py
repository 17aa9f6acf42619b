"""Do the exported proposals fit the inference module's training videos better than the test ones?

The visual prior trains on every training video, the module's 300 among them, so its proposals of those
can be cleaner than of the test videos; a module that learns P from the clean ones then reads the test
ones' through an offset (FluidCube, session 59: 0.587 against 1.738 x 1e4, viscosity bias -13 against -24).
Prints the position MSE x 1e4 of frames [FIRST, LAST) per split, against the recorded particles.

    python scripts/experiments/proposal_error_by_split.py DATA_ROOT ENV [--proposals ROOT] [--frames 20 30]
        DATA_ROOT holds <env>/{train,test}/shard_*.h5; ROOT (default DATA_ROOT) <env>/proposals/{train,test}.h5
"""

from __future__ import annotations

import argparse

import torch

from vgpl.data.proposals import read_proposals
from vgpl.data.trajectories import load_split
from vgpl.eval.metrics import position_mse_x1e4


def error_by_split(data_root: str, env: str, proposals_root: str, first: int, last: int) -> dict:
    """{split: {videos, mean, median}}: position MSE x 1e4 over frames [first, last) of each video."""
    out = {}
    for split in ("train", "test"):
        prop = read_proposals(f"{proposals_root}/{env}/proposals/{split}.h5", window_pool="last")
        truth = load_split(data_root, env, split, max_rollouts=len(prop.rollout_ids))
        if not torch.equal(truth.rollout_ids, prop.rollout_ids):
            raise ValueError(f"{proposals_root}/{env}/proposals/{split}.h5: rollout ids do not match {data_root}/{env}/{split}")
        per_video = torch.stack([torch.as_tensor(position_mse_x1e4(p[first:last], t[first:last]))
                                 for p, t in zip(prop.positions, truth.positions)])
        out[split] = {"videos": len(per_video), "mean": float(per_video.mean()), "median": float(per_video.median())}
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root"), parser.add_argument("env")
    parser.add_argument("--proposals", default=None, help="root of <env>/proposals (default: data_root)")
    parser.add_argument("--frames", type=int, nargs=2, default=(20, 30), metavar=("FIRST", "LAST"))
    args = parser.parse_args()
    for split, e in error_by_split(args.data_root, args.env, args.proposals or args.data_root, *args.frames).items():
        print(f"{split}: {e['videos']} videos, frames {args.frames[0]}-{args.frames[1] - 1}: MSE x 1e4 mean {e['mean']:.3f}, median {e['median']:.3f}")
