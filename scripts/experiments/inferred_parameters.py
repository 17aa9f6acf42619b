"""Does an inference checkpoint's P follow the scene? (session 23 for FluidCube, 24 for all envs; a diagnostic)

For each checkpoint given, P for the test videos from their exported proposals over the
evaluation's window (``observed`` frames from the env's ``start_frame``), without the rollouts of
task=evaluate (seconds, not minutes). Per parameter: the MAE and mean signed error as % of the
range, the correlation r with the truth and the spread (std) of the normalised P against the
truth's (~0.58 for a uniform draw). A constant predictor has r ~ 0 and a spread ~ 0.

Usage: python scripts/experiments/inferred_parameters.py CKPT [CKPT ...] --env fluid_cube [--root data/standard]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import proposals_path
from vgpl.data.proposals import read_proposals
from vgpl.data.trajectories import load_split
from vgpl.eval.grounding import infer_in_chunks
from vgpl.models.inference import InferenceModule


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--env", required=True, choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--root", default="data/standard")
    parser.add_argument("--observed", type=int, default=10, help="frames observed (eval.observed)")
    args = parser.parse_args()
    path = proposals_path(args.root, args.env, "test")
    proposals = read_proposals(path)
    test = load_split(args.root, args.env, "test", max_rollouts=len(proposals.rollout_ids))
    if not torch.equal(test.rollout_ids, proposals.rollout_ids):
        raise ValueError(f"{path}: rollout_ids differ from the test split's")
    for ckpt in args.checkpoints:
        module, cfg = load_stage(ckpt, InferenceModule, env=args.env)
        module.eval()
        seen = slice(cfg.env.get("start_frame", 0), cfg.env.get("start_frame", 0) + args.observed)
        with torch.no_grad():
            inferred = infer_in_chunks(module, proposals.positions[:, seen], proposals.logits[:, seen],
                                       torch.as_tensor(scene_of(cfg).kinematic), chunk=10)["params_normalised"]
        truth = module.normalise_params(test.params)
        for k, name in enumerate(scene_of(cfg).param_names):
            error = (inferred[:, k] - truth[:, k]) * 50  # % of the range: normalised units span [-1, 1]
            r = np.corrcoef(inferred[:, k].numpy(), truth[:, k].numpy())[0, 1] if inferred[:, k].std() > 0 else 0.0
            print(f"{ckpt}: {name} MAE {error.abs().mean():.1f}% of the range (bias {error.mean():+.1f}%), r = {r:.2f}, "
                  f"spread {inferred[:, k].std():.3f} (truth {truth[:, k].std():.3f})")


if __name__ == "__main__":
    main()
