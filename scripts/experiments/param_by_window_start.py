"""Where in the video does an inference module read P well? (session 58, a diagnostic)

Runs a trained InferenceModule (no rollouts, only its P head) on one window per video starting at
each of several frames, on train and test videos, and prints the parameter MAE, bias, correlation
and spread per start. A bias that changes with the start while train and test agree is the window,
not overfitting: FluidCube's cube still sinks until about frame 16, and from frame 10 its splash
reads as a thin fluid (session 58: test viscosity MAE 22.4% from frame 10, 16.5% from frame 20).

Usage: python scripts/experiments/param_by_window_start.py CHECKPOINT START [START ...] -- HYDRA_OVERRIDES...
e.g.   python scripts/experiments/param_by_window_start.py /tmp/r/checkpoints/standard/fluid_cube/inference/last.ckpt 10 15 20 \
         -- env=fluid_cube experiment=standard paths.root_dir=/tmp/r
The overrides name the data (``paths.root_dir``, ``env``); each start needs proposals for START + observed frames.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from torch.utils.data import DataLoader, Subset

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import GroundingWindows, split_with_proposals
from vgpl.models.inference import InferenceModule

CONF = Path(__file__).resolve().parents[2] / "conf"


@torch.no_grad()
def inferred_params(module: InferenceModule, windows: GroundingWindows, n: int, chunk: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """(true [n, P], inferred [n, P]) physical parameters of the first ``n`` windows."""
    true, inferred = [], []
    for batch in DataLoader(Subset(windows, range(n)), batch_size=chunk):  # batched as the module's own val_dataloader
        out = module.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
        true.append(batch["params"])
        inferred.append(out["params"])
    return torch.cat(true).numpy(), torch.cat(inferred).numpy()


def main(checkpoint: str, starts: list[int], overrides: list[str], n_videos: int = 100) -> None:
    with initialize_config_dir(str(CONF), version_base=None):
        cfg = compose("config", overrides=overrides)
    scene = scene_of(cfg)
    module, trained = load_stage(checkpoint, InferenceModule, env=scene.name, n_particles=scene.n_particles)
    observed, pool = int(trained.model.inference.observed), str(trained.model.inference.get("window_pool", "last"))
    span = scene.param_high - scene.param_low
    for split in ("train", "test"):
        rollouts, proposals = split_with_proposals(cfg.data.root, scene.name, split, pool)  # the videos with proposals, paired
        for start in starts:
            # one window per video (span 0) at this start; horizon 0: P needs only the observed frames
            windows = GroundingWindows(rollouts, proposals, scene, observed, 0, start, 1, 0, pool)
            n = min(n_videos, len(windows))
            true, inferred = inferred_params(module, windows, n)
            for j, name in enumerate(scene.param_names):
                t, p = true[:, j], inferred[:, j]
                print(f"{split:5s} from frame {start:3d}, {n} videos, {name}: MAE {100 * np.abs(p - t).mean() / span[j]:.1f}% "
                      f"bias {100 * (p - t).mean() / span[j]:+.1f}% corr {np.corrcoef(p, t)[0, 1]:.2f} std {p.std():.3g} (true {t.std():.3g})",
                      flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    if "--" not in args or args.index("--") < 2:
        sys.exit(__doc__)
    cut = args.index("--")
    main(args[0], [int(s) for s in args[1:cut]], args[cut + 1 :])
