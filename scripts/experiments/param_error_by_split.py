"""Is an inference module's parameter error the data it trained on, or a bias? (session 40, RigidFall)

Per split (train: the videos it trained on; test: held out), each checkpoint's P over the first 10
frames of the exported proposals (its EMA weights, as task=evaluate reads it): MAE and mean signed
error, in % of the range. A train error far below the test error is the training videos' share; a
signed error shared by both splits is where the rollout loss through the prior has its optimum.

Usage: python scripts/experiments/param_error_by_split.py DATA_ROOT ENV CKPT [CKPT ...]
"""

from __future__ import annotations

import sys

import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import split_with_proposals
from vgpl.eval.grounding import infer_in_chunks
from vgpl.models.inference import InferenceModule

FRAMES = 10


def main(root: str, env: str, checkpoints: list[str]) -> None:
    print("| checkpoint | split | videos | parameter | MAE, % of range | mean signed error, pts |\n|---|---|---|---|---|---|")
    for split in ("train", "test"):
        rollouts, proposals = split_with_proposals(root, env, split)
        for ckpt in checkpoints:
            module, cfg = load_stage(ckpt, InferenceModule, env=env)
            module.eval()
            with torch.no_grad():
                p = infer_in_chunks(module, proposals.positions[:, :FRAMES], proposals.logits[:, :FRAMES],
                                    torch.as_tensor(scene_of(cfg).kinematic), chunk=10)["params_normalised"]
            error = (p - module.normalise_params(rollouts.params)) * 50  # [B, P]; normalised units span [-1, 1]
            for j, name in enumerate(scene_of(cfg).param_names):
                print(f"| {ckpt} | {split} | {len(error)} | {name} | {error[:, j].abs().mean():.2f} | {error[:, j].mean():+.2f} |")


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__.splitlines()[-1].strip())
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
