"""Is the inference module's P invariant to the scene's symmetries? (session 42, RigidFall; a diagnostic)

RigidFall's physics has only a floor, and its cubes are jittered and yawed symmetrically about
the vertical axis through the origin: a rotation of a whole video about that axis is another video
of the same gravity (tests/data/test_vertical_symmetry.py simulates it). The module's P should not
change. For each checkpoint, P of the exported proposals (over the evaluation's observed frames, as
``inferred_parameters.py``) is read for ``--rotations`` K rotations by 2 pi k / K, and the script
prints per rotation the gravity MAE (% of the range) and bias,
the per-video spread across the rotations, and the MAE of their average (test-time averaging
over the group). A spread comparable to the error means the module reads scene layout as well as
the fall (the 300 training videos' layouts: session 40's train/test gap), and the average may be
better than any one rotation. The proposals' errors come from one camera, so a rotated video
also looks as if seen from elsewhere: a rotation far worse than the identity says which.
Session 42, 100 test videos: session 41's module spread 3.27 points, its average 5.51% against
4.68% unturned; trained with ``param_rotation`` 1.94 and 4.65% against 4.37%.

Usage: python scripts/experiments/symmetric_parameters.py CKPT [CKPT ...] --env rigid_fall --root data/gpu_h200 \
           [--split test] [--rotations 8] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import math

import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import split_with_proposals
from vgpl.data.vertical_symmetry import about_vertical
from vgpl.eval.grounding import infer_in_chunks
from vgpl.models.inference import InferenceModule
from vgpl.sim.envs import ENVS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--env", required=True, choices=sorted(ENVS), help="an env whose scene has vertical_symmetry")
    parser.add_argument("--root", default="data/standard")
    parser.add_argument("--observed", type=int, default=10, help="frames observed (eval.observed)")
    parser.add_argument("--split", default="test", choices=["train", "test"])
    parser.add_argument("--rotations", type=int, default=8, help="K rotations by 2 pi k / K")
    parser.add_argument("--json", help="also write the numbers here")
    args = parser.parse_args()
    if args.rotations < 1:
        parser.error(f"--rotations {args.rotations}: expected >= 1")
    if not ENVS[args.env].vertical_symmetry:
        parser.error(f"--env {args.env}: its scene is not symmetric about the vertical axis (Scene.vertical_symmetry), "
                     "so a turned video is not one of the same parameters")
    videos, proposals = split_with_proposals(args.root, args.env, args.split)
    results = {}
    for ckpt in args.checkpoints:
        module, cfg = load_stage(ckpt, InferenceModule, env=args.env)
        module.eval()
        scene, start = scene_of(cfg), cfg.env.get("start_frame", 0)
        seen = slice(start, start + args.observed)
        kinematic = torch.as_tensor(scene.kinematic)
        truth = module.normalise_params(videos.params)[:, 0]
        estimates, names = [], []
        for k in range(args.rotations):
            moved = about_vertical(proposals.positions[:, seen], 2 * math.pi * k / args.rotations)
            with torch.no_grad():
                p = infer_in_chunks(module, moved, proposals.logits[:, seen], kinematic, chunk=10)["params_normalised"][:, 0]
            estimates.append(p)
            names.append(f"{360 * k / args.rotations:g} deg")
        estimates = torch.stack(estimates)  # [rotations, videos], normalised
        errors = (estimates - truth) * 50  # % of the range
        average = (estimates.mean(0) - truth) * 50
        row = {
            "videos": len(truth),
            "per_rotation": {n: {"mae_pct": e.abs().mean().item(), "bias_pct": e.mean().item()} for n, e in zip(names, errors)},
            "spread_pct": (estimates.std(0) * 50).mean().item(),
            "average_mae_pct": average.abs().mean().item(),
            "average_bias_pct": average.mean().item(),
        }
        results[ckpt] = row
        print(f"{ckpt} ({args.split}, {len(truth)} videos): gravity MAE % of the range (bias)")
        for n, v in row["per_rotation"].items():
            print(f"  {n:>18}: {v['mae_pct']:.2f} ({v['bias_pct']:+.2f})")
        print(f"  per-video spread across the {len(names)} rotations: {row['spread_pct']:.2f}")
        print(f"  their average: {row['average_mae_pct']:.2f} ({row['average_bias_pct']:+.2f})")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"split": args.split, "rotations": args.rotations, "root": args.root, "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
