"""A proposals file split into float16 parts small enough to come back from a device call, and joined again.

A lent GPU's call returns at most 8 files of 16 MB (64 MB together). FluidCube's standard exports
(300 training videos, 30 frames, 348 particles) are 63 MB of positions and logits alone and about
250 MB with the windows' slots, so the slots stay behind (``window_pool=last``, the paper's, only)
and positions and logits travel as float16. ``pack`` prints the rounding error it makes, in the
project's metric (position MSE x 1e4), to show it is far below the proposals' own error.

    python scripts/experiments/proposals_parts.py pack data/gpu/fluid_cube/proposals/train.h5 $OUT --rollouts 100
        -> $OUT/train_part0.npz, train_part1.npz, ... (the split's name is the file's stem)
    python scripts/experiments/proposals_parts.py unpack /tmp/parts/train_part*.npz --to data/standard/fluid_cube/proposals/train.h5
        -> one float32 proposals file (vgpl.data.proposals.write_proposals), its attrs restored
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from vgpl.data.proposals import Proposals, read_proposals, write_proposals
from vgpl.eval.metrics import position_mse_x1e4


def pack(path: Path, out: Path, rollouts: int) -> list[Path]:
    """Parts of at most ``rollouts`` rollouts each: positions, logits (float16), rollout_ids, attrs (JSON)."""
    prop = read_proposals(path, window_pool="last")
    half = prop.positions.half()
    rounded = half.float()
    print(f"{path}: positions {tuple(prop.positions.shape)}; float16 rounding: max {float((rounded - prop.positions).abs().max()):.2e} m, "
          f"position MSE x 1e4 {position_mse_x1e4(rounded, prop.positions):.2e}")
    out.mkdir(parents=True, exist_ok=True)
    attrs = json.dumps({k: v.item() if isinstance(v, np.generic) else v for k, v in prop.attrs.items()})
    written = []
    for k, start in enumerate(range(0, len(prop.rollout_ids), rollouts)):
        part = slice(start, start + rollouts)
        written.append(out / f"{path.stem}_part{k}.npz")
        np.savez(written[-1], positions=half[part].numpy(), logits=prop.logits[part].half().numpy(),
                 rollout_ids=prop.rollout_ids[part].numpy(), attrs=np.array(attrs))
        print(f"  {written[-1]}: {written[-1].stat().st_size / 2**20:.1f} MiB")
    return written


def unpack(parts: list[Path], to: Path) -> Path:
    """One float32 proposals file from ``pack``'s parts (in part order)."""
    parts = sorted(parts, key=lambda p: int(p.stem.rsplit("_part", 1)[1]))
    loaded = [np.load(p) for p in parts]
    attrs = json.loads(str(loaded[0]["attrs"]))
    attrs.pop("format_version", None)  # write_proposals stamps its own
    cat = {k: torch.as_tensor(np.concatenate([d[k] for d in loaded])) for k in ("positions", "logits", "rollout_ids")}
    path = write_proposals(to, Proposals(cat["positions"].float(), cat["logits"].float(), cat["rollout_ids"], attrs))
    print(f"{to}: {len(cat['rollout_ids'])} rollouts from {len(parts)} parts, positions {tuple(cat['positions'].shape)}")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack")
    p.add_argument("proposals", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--rollouts", type=int, default=100, help="rollouts per part (100 FluidCube ones: 10.4 MB)")
    u = sub.add_parser("unpack")
    u.add_argument("parts", type=Path, nargs="+")
    u.add_argument("--to", type=Path, required=True)
    args = parser.parse_args()
    if args.command == "pack":
        pack(args.proposals, args.out, args.rollouts)
    else:
        unpack(args.parts, args.to)


if __name__ == "__main__":
    main()
