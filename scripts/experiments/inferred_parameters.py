"""Does an inference checkpoint's P follow the scene? (session 23 for FluidCube, 24 for all envs; a diagnostic)

For each checkpoint given, P for each split's videos (the test ones by default) from their exported proposals over the
evaluation's window (``observed`` frames from the env's ``start_frame``), without the rollouts of
task=evaluate (RigidFall on 2 CPU cores: about 40 s per 100 videos and checkpoint, session 81). Per parameter: the MAE and mean signed error as % of the
range, the correlation r with the truth and the spread (std) of the normalised P against the
truth's (~0.58 for a uniform draw). A constant predictor has r ~ 0 and a spread ~ 0.
``--split train test`` (session 40) sets the videos the module trained on beside the held-out ones:
a train error far below the test error is the training videos' share; a signed error shared by
both splits is where the rollout loss through the prior has its optimum.

Usage: python scripts/experiments/inferred_parameters.py CKPT [CKPT ...] --env fluid_cube [--root data/standard] [--split train test]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import split_with_proposals
from vgpl.eval.grounding import infer_in_chunks
from vgpl.models.inference import InferenceModule


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--env", required=True, choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--root", default="data/standard")
    parser.add_argument("--observed", type=int, default=10, help="frames observed (eval.observed)")
    parser.add_argument("--split", nargs="+", default=["test"], choices=["train", "test"], help="the videos P is inferred for")
    args = parser.parse_args()
    splits = {split: split_with_proposals(args.root, args.env, split) for split in args.split}
    for ckpt in args.checkpoints:
        module, cfg = load_stage(ckpt, InferenceModule, env=args.env)
        module.eval()
        scene, start = scene_of(cfg), cfg.env.get("start_frame", 0)
        seen = slice(start, start + args.observed)
        for split, (videos, proposals) in splits.items():
            with torch.no_grad():
                inferred = infer_in_chunks(module, proposals.positions[:, seen], proposals.logits[:, seen],
                                           torch.as_tensor(scene.kinematic), chunk=10)["params_normalised"]
            truth = module.normalise_params(videos.params)
            for k, name in enumerate(scene.param_names):
                error = (inferred[:, k] - truth[:, k]) * 50  # % of the range: normalised units span [-1, 1]
                r = np.corrcoef(inferred[:, k].numpy(), truth[:, k].numpy())[0, 1] if inferred[:, k].std() > 0 else 0.0
                print(f"{ckpt} ({split}, {len(truth)} videos): {name} MAE {error.abs().mean():.2f}% of the range (bias {error.mean():+.2f}%), "
                      f"r = {r:.2f}, spread {inferred[:, k].std():.3f} (truth {truth[:, k].std():.3f})")


if __name__ == "__main__":
    main()
