"""Does an inference module's P follow the proposals' frame-to-frame jitter? (session 60, a diagnostic)

Adds Gaussian noise to the exported proposals of one split, either independent per frame (jitter: it
shows as motion) or one static offset per particle held over the window (the same position error, no
motion), at several scales, and prints the proposals' position MSE x 1e4, their frame-to-frame
displacement error (rms, mm, movable particles) and the module's parameter MAE, bias and correlation,
one window per video from START. FluidCube, session 60: 1 mm of jitter moved a module's viscosity bias
from +0.6 to -25.9 points, static offsets of 2 mm by less than 0.1.

Usage: python scripts/experiments/param_under_jitter.py CHECKPOINT SPLIT START STD_MM [STD_MM ...] -- HYDRA_OVERRIDES...
e.g.   python scripts/experiments/param_under_jitter.py /tmp/r/checkpoints/standard/fluid_cube/inference/last.ckpt test 20 0 0.5 1 2 \
         -- env=fluid_cube experiment=standard paths.root_dir=/tmp/r
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from param_by_window_start import CONF, inferred_params

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import GroundingWindows, split_with_proposals
from vgpl.data.proposals import Proposals
from vgpl.eval.metrics import position_mse_x1e4
from vgpl.models.inference import InferenceModule


def noisy(proposals: Proposals, std: float, static: bool, seed: int = 0) -> Proposals:
    """A copy of ``proposals`` plus Gaussian noise of ``std`` metres: per frame, or one draw per particle held over every frame."""
    r, t, n, _ = proposals.positions.shape
    g = torch.Generator().manual_seed(seed)
    noise = torch.randn(r, 1 if static else t, n, 3, generator=g) * std
    return dataclasses.replace(proposals, positions=proposals.positions + noise, slots=None)


def main(checkpoint: str, split: str, start: int, stds_mm: list[float], overrides: list[str], n_videos: int = 100) -> None:
    with initialize_config_dir(str(CONF), version_base=None):
        cfg = compose("config", overrides=overrides)
    scene = scene_of(cfg)
    module, trained = load_stage(checkpoint, InferenceModule, env=scene.name, n_particles=scene.n_particles)
    observed = int(trained.model.inference.observed)
    rollouts, proposals = split_with_proposals(cfg.data.root, scene.name, split)
    span, movable, seen = scene.param_high - scene.param_low, ~torch.as_tensor(scene.kinematic), slice(start, start + observed)
    n = min(n_videos, len(rollouts.positions))
    truth = rollouts.positions[:n, seen]
    for static in (False, True):
        for std in stds_mm:
            if static and std == 0:
                continue
            p = noisy(proposals, std * 1e-3, static)
            error = p.positions[:n, seen] - truth
            jitter = error[:, 1:, movable] - error[:, :-1, movable]  # displacement error
            true, inferred = inferred_params(module, GroundingWindows(rollouts, p, scene, observed, 0, start, 1, 0), n)
            label = "static" if static else "jitter"
            for j, name in enumerate(scene.param_names):
                t, q = true[:, j], inferred[:, j]
                print(f"{split} from frame {start}, {label} {std:.2f} mm: position MSE x 1e4 {position_mse_x1e4(p.positions[:n, seen], truth):.3f}, "
                      f"displacement error {float(jitter.pow(2).mean().sqrt()) * 1e3:.2f} mm; {name}: MAE {100 * np.abs(q - t).mean() / span[j]:.1f}% "
                      f"bias {100 * (q - t).mean() / span[j]:+.1f}% corr {np.corrcoef(q, t)[0, 1]:.2f}", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    if "--" not in args or args.index("--") < 4:
        sys.exit(__doc__)
    cut = args.index("--")
    main(args[0], args[1], int(args[2]), [float(s) for s in args[3:cut]], args[cut + 1 :])
