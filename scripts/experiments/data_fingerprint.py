"""Does a dataset generated on another machine hold the same trajectories as this one's?

Prints, per split, the rollout ids and float64 sums of the particle positions over the first
``--frames`` frames (those the inference module and the evaluation read) and over all frames,
plus the first rollouts' own sums. Run it on both machines and compare: proposals exported from one
machine's video are matched to the other's trajectories by rollout id alone.

    python scripts/experiments/data_fingerprint.py data/gpu fluid_cube [--frames 60]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from vgpl.data.trajectories import load_split


def fingerprint(root: str, env: str, frames: int) -> dict:
    """{split: {rollouts, ids (min, max), sum_first_<frames>, sum_all, first_rollouts_all}} of ``root/env``'s splits."""
    out = {}
    for split in ("train", "test"):
        r = load_split(root, env, split)
        pos = r.positions.double().numpy()
        ids = r.rollout_ids.numpy()
        out[split] = {"rollouts": len(ids), "ids": [int(ids.min()), int(ids.max())],
                      f"sum_first_{frames}": float(pos[:, :frames].sum()), "sum_all": float(pos.sum()),
                      "first_rollouts_all": [float(x) for x in pos[:3].sum(axis=(1, 2, 3))]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("env")
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    print(json.dumps(fingerprint(args.root, args.env, args.frames), indent=1))


if __name__ == "__main__":
    main()
