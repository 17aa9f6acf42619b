"""Does the inference module read gravity from the fall? (session 34, RigidFall, a diagnostic)

Per test video: the module's gravity error (P from the exported proposals over frames 0-9, as
task=evaluate reads it) against the error of task=free_fall_gravity's calibrated free-fall fit on
the same proposals. Prints each checkpoint's MAE, the correlation of its errors with the fit's,
the MAE of the mean of the two estimates, and for two checkpoints the correlation of their errors.

Usage: python scripts/experiments/module_vs_free_fall.py DATA_ROOT CKPT [CKPT]
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import split_with_proposals
from vgpl.eval.free_fall import FreeFallSplit, calibration
from vgpl.eval.grounding import infer_in_chunks
from vgpl.eval.metrics import param_signed_error_pct
from vgpl.models.inference import InferenceModule

FRAMES = 10


def main(root: str, checkpoints: list[str]) -> None:
    train = FreeFallSplit.of(*split_with_proposals(root, "rigid_fall", "train"), FRAMES)
    test, proposals = split_with_proposals(root, "rigid_fall", "test")
    held_out = FreeFallSplit.of(test, proposals, FRAMES)
    a, b = calibration(train.fit(), train.gravity)
    low, high = float(test.param_low[0]), float(test.param_high[0])
    fit_error = param_signed_error_pct((a + b * held_out.fit()).clamp(low, high), held_out.gravity, low, high)
    print(f"{root}: calibrated free-fall fit, gravity MAE {fit_error.abs().mean():.2f}%")
    errors = []
    for ckpt in checkpoints:
        module, cfg = load_stage(ckpt, InferenceModule, env="rigid_fall")
        module.eval()
        with torch.no_grad():
            p = infer_in_chunks(module, proposals.positions[:, :FRAMES], proposals.logits[:, :FRAMES],
                                torch.as_tensor(scene_of(cfg).kinematic), chunk=10)["params_normalised"][:, 0].double()
        error = (p - module.normalise_params(test.params)[:, 0].double()) * 50  # normalised units span [-1, 1]
        errors.append(error)
        r = np.corrcoef(error.numpy(), fit_error.numpy())[0, 1]
        print(f"{ckpt}: gravity MAE {error.abs().mean():.2f}%, correlation of its errors with the fit's {r:.2f}, "
              f"mean of the two estimates {((error + fit_error) / 2).abs().mean():.2f}%")
    if len(errors) == 2:
        print(f"the two checkpoints: correlation of their errors {np.corrcoef(errors[0].numpy(), errors[1].numpy())[0, 1]:.2f}, "
              f"mean of their estimates {((errors[0] + errors[1]) / 2).abs().mean():.2f}%")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
