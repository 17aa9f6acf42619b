"""How well each of the visual prior's window slots, the paper's proposals and the pooled ones
(``window_pool=mean``) place the particles of one observed window, from an exported proposals file.

The visual prior predicts all F frames of every F-frame window; slot k of frame t is the window
starting at t - k, and the paper keeps slot F - 1 (the window ending at the frame). Printed and
written as JSON, on the movable particles of the first ``--videos`` videos of the split, frames
[start, start + observed) (start: the env's start_frame, as the evaluation observes):
- position MSE x 1e4 of each slot (where its window is in the video), of the paper's proposals
  (``last``), of ``pool_windows(..., "mean")`` and of every slot's plain mean (which reads
  windows that end after the observation, so no method may use it);
- per frame, ``last`` against ``mean``;
- each slot's mean error along the true motion, mm (> 0: ahead of the truth), on particles that
  move more than 1 mm a frame (session 51, MassRope: slot 0 +3.2, slot 3 -3.0: the paper's lag).

    python scripts/experiments/window_slots.py --root data/s51 --env mass_rope [--videos 100] [--json out.json]

Session 51 measured this with a /tmp script (docs/experiments.md); this is it, kept.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from vgpl.data.grounding import split_with_proposals
from vgpl.data.window_pool import pool_windows
from vgpl.eval.metrics import position_mse_x1e4
from vgpl.sim.envs import ENVS, make_scene

CONF = Path(__file__).resolve().parents[2] / "conf" / "env"
MOVING_MM = 1.0  # a particle counts as moving where it travels more than this in a frame


def slot_report(proposals, slots: torch.Tensor, truth: torch.Tensor, movable: torch.Tensor) -> dict:
    """proposals (the paper's) [R, T, N, 3], slots [R, T, F, N, 3], truth [R, T, N, 3] of one
    observed window (frame 0 of it: the window's first), movable [N] bool. See the module docstring."""
    f = slots.shape[2]
    pooled = pool_windows(proposals, slots, "mean")
    out = {"last": position_mse_x1e4(proposals, truth, movable), "mean": position_mse_x1e4(pooled, truth, movable),
           "all_slots_mean": position_mse_x1e4(slots.nanmean(2), truth, movable)}
    # the truth's direction of motion: central differences inside the window, one-sided at its ends
    velocity = torch.gradient(truth, dim=1)[0]  # [R, T, N, 3], metres a frame
    speed = velocity.norm(dim=-1, keepdim=True)
    moving = (speed[..., 0] > MOVING_MM * 1e-3) & movable  # [R, T, N]
    direction = velocity / speed.clamp(min=1e-12)
    slot_mse, slot_lead = [], []
    for k in range(f):
        s = slots[:, :, k]
        have = ~s.isnan().any(-1)  # [R, T, N]
        keep = have & movable
        slot_mse.append(position_mse_x1e4(s[keep], truth[keep]) if keep.any() else float("nan"))
        lead = ((s - truth) * direction).sum(-1)[have & moving]
        slot_lead.append(float(lead.mean() * 1e3) if lead.numel() else float("nan"))
    per_frame = [{"frame": t, "last": position_mse_x1e4(proposals[:, t], truth[:, t], movable),
                  "mean": position_mse_x1e4(pooled[:, t], truth[:, t], movable)} for t in range(truth.shape[1])]
    return out | {"slot_mse_x1e4": slot_mse, "slot_lead_mm": slot_lead, "per_frame": per_frame}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", required=True, help="dataset root with <env>/{test,proposals} (task=export_proposals wrote the slots)")
    parser.add_argument("--env", required=True, choices=sorted(ENVS))
    parser.add_argument("--split", default="test")
    parser.add_argument("--videos", type=int, default=100)
    parser.add_argument("--observed", type=int, default=10)
    parser.add_argument("--start", type=int, help="first observed frame (default: the env's start_frame, conf/env)")
    parser.add_argument("--json", help="write the numbers here")
    args = parser.parse_args()
    start = int(OmegaConf.load(CONF / f"{args.env}.yaml").start_frame) if args.start is None else args.start
    videos, proposals = split_with_proposals(args.root, args.env, args.split, "mean")  # refused by name without slots
    n = min(args.videos, len(videos.rollout_ids))
    seen = np.s_[:n, start : start + args.observed]
    if proposals.slots is None:
        raise SystemExit(f"{args.root}/{args.env}/proposals/{args.split}.h5: {proposals.attrs.get('source')} proposals have no windows")
    if proposals.positions.shape[1] < start + args.observed:
        raise SystemExit(f"{args.root}/{args.env}/proposals/{args.split}.h5: {proposals.positions.shape[1]} frames, the window needs {start + args.observed}")
    movable = ~torch.as_tensor(make_scene(args.env).kinematic)
    report = {"root": args.root, "env": args.env, "split": args.split, "videos": n, "frames": [start, start + args.observed],
              **slot_report(proposals.positions[seen], proposals.slots[seen], videos.positions[seen], movable)}
    f = len(report["slot_mse_x1e4"])
    print(f"{args.env} {args.split}, {n} videos, frames {start}-{start + args.observed - 1}, position MSE x 1e4 (movable particles)")
    print(f"  last (the paper's, slot {f - 1}) {report['last']:.3f}   mean (window_pool=mean) {report['mean']:.3f}   "
          f"every slot's mean (reads past the window) {report['all_slots_mean']:.3f}")
    print("  slot:      " + "".join(f"{k:>9d}" for k in range(f)))
    print("  MSE x 1e4: " + "".join(f"{v:9.3f}" for v in report["slot_mse_x1e4"]))
    print("  lead, mm:  " + "".join(f"{v:+9.2f}" for v in report["slot_lead_mm"]))
    print("  per frame, last -> mean: " + ", ".join(f"{start + r['frame']}: {r['last']:.3f} -> {r['mean']:.3f}" for r in report["per_frame"]))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
