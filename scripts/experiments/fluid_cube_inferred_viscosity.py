"""Does an inference checkpoint's viscosity follow the scene? (session 23; a diagnostic)

For each checkpoint given, P for the 100 FluidCube test videos from frames 0-9 of their exported
proposals (the evaluation's window), without the rollouts of task=evaluate (seconds, not
minutes): the MAE as % of the range, the correlation r with the truth and the spread (std) of the
normalised P, against the truth's ~0.58. A constant predictor has r ~ 0 and a spread ~ 0.

Usage: python scripts/experiments/fluid_cube_inferred_viscosity.py CKPT [CKPT ...] [--root data/standard]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import proposals_path
from vgpl.data.proposals import read_proposals
from vgpl.data.trajectories import load_split
from vgpl.models.inference import InferenceModule


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/standard")
    args = parser.parse_args()
    proposals = read_proposals(proposals_path(args.root, "fluid_cube", "test"))
    test = load_split(args.root, "fluid_cube", "test", max_rollouts=len(proposals.rollout_ids))
    if not torch.equal(test.rollout_ids, proposals.rollout_ids):
        raise ValueError(f"{proposals_path(args.root, 'fluid_cube', 'test')}: rollout_ids differ from the test split's")
    for path in args.checkpoints:
        module, cfg = load_stage(path, InferenceModule, env="fluid_cube")
        kinematic = torch.as_tensor(scene_of(cfg).kinematic)
        with torch.no_grad():
            inferred = torch.cat([module.infer(proposals.positions[i : i + 10, :10], proposals.logits[i : i + 10, :10], kinematic)["params_normalised"]
                                  for i in range(0, len(test.params), 10)])[:, 0]
        truth = module.normalise_params(test.params)[:, 0]
        r = np.corrcoef(inferred.numpy(), truth.numpy())[0, 1]
        print(f"{path}: viscosity MAE {((inferred - truth).abs() * 50).mean():.1f}% of the range, r = {r:.2f}, "
              f"mean {inferred.mean():+.2f}, spread {inferred.std():.3f} (truth {truth.std():.3f})")


if __name__ == "__main__":
    main()
