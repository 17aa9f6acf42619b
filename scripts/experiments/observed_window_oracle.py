"""What the observed frames alone allow for P: the prior's oracle fitted to the window the module sees. (session 49, a diagnostic)

The identifiability oracle (``task=evaluate_dynamics``) fits P per test video to the true frames of
the observed window AND the ``horizon`` frames after it, which the inference module never sees.
Here the per-video argmin of the prior's rollout L1 over P (``oracle_param_sweep``: grid, then a
finer grid about each video's best) is taken over the observed ``T`` frames only, from three
versions of them:

- ``truth``: the recorded particles (what perfect proposals would allow);
- ``proposals``: the VisualPrior's exported proposals, rolled from their first H frames and scored
  against themselves (a fit without any learned refinement);
- ``refined``: the inference module's X' + dX (its own input to the tail and the evaluation).

Kinematic particles (the pin) are the truth in every version, as the module treats them. Beside each,
the module's own P on the same videos. An amortised P well behind the refined frames' fit means the
P head, not its inputs, is the limit; a refined-frame fit no better than the module means the inputs are.

Usage: python scripts/experiments/observed_window_oracle.py INFERENCE_CKPT [--root data/standard] [--videos 100] [--grid 9 --refine 9]
       [--window-pool last|mean] (default: the pool the module was trained on)
(the dynamics prior is the one the module was trained through: ``stage_checkpoint`` of its training config)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.grounding import split_with_proposals
from vgpl.data.trajectories import true_window
from vgpl.data.window_pool import pool_windows
from vgpl.eval.grounding import infer_in_chunks
from vgpl.eval.identifiability import oracle_param_sweep
from vgpl.models.inference import InferenceModule
from vgpl.tasks.evaluate import trained_window_pool
from vgpl.tasks.stage import stage_checkpoint
from vgpl.tasks.train_dynamics import load_dynamics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("inference")
    parser.add_argument("--dynamics", help="the prior (default: the one the module trained through, stage_checkpoint(cfg, 'dynamics'))")
    parser.add_argument("--root", default="data/standard")
    parser.add_argument("--videos", type=int, default=100)
    parser.add_argument("--observed", type=int, default=10)
    parser.add_argument("--grid", type=int, default=9)
    parser.add_argument("--refine", type=int, default=9)
    parser.add_argument("--window-pool", choices=["last", "mean"], help="how the observed frames are read from the visual windows (default: the module's)")
    parser.add_argument("--json", help="write the numbers and per-video estimates here")
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    began = time.time()
    module, cfg = load_stage(args.inference, InferenceModule)
    module.eval()
    dynamics, _ = load_dynamics(args.dynamics or str(stage_checkpoint(cfg, "dynamics")), env=cfg.env.name)  # a prior of another env is refused
    dynamics.eval()
    scene, start = scene_of(cfg), int(cfg.env.get("start_frame", 0))
    pool = trained_window_pool(OmegaConf.create({"eval": {"window_pool": args.window_pool}}), cfg)
    videos, proposals = split_with_proposals(args.root, scene.name, "test", pool)
    n, t = min(args.videos, len(videos.rollout_ids)), args.observed
    seen = slice(start, start + t)
    positions, grouping, rigidness, params, planes, kinematic = true_window(scene, videos, start, t, n)
    observed = pool_windows(proposals.positions, proposals.slots, pool, np.s_[:n, seen])
    inferred = infer_in_chunks(module, observed, proposals.logits[:n, seen], kinematic, chunk=10)
    versions = {"truth": positions,
                "proposals": torch.where(kinematic[None, None, :, None], positions, observed),
                "refined": torch.where(kinematic[None, None, :, None], positions, inferred["positions"])}
    truth = dynamics.normalise_params(params)
    module_error = (inferred["params_normalised"] - truth) * 50  # % of the range
    rows = {"checkpoint": args.inference, "env": scene.name, "videos": n, "observed": t, "window_pool": pool, "grid": args.grid, "refine": args.refine,
            "module_mae_pct": module_error.abs().mean(0).tolist(), "module_bias_pct": module_error.mean(0).tolist()}
    for name, frames in versions.items():
        sweep = oracle_param_sweep(dynamics, frames, grouping, rigidness, params, planes, kinematic, t - dynamics.hparams.history,
                                   args.grid, args.refine)
        oracle = dynamics.normalise_params(sweep["oracle_params"])
        rows[name] = {"oracle_mae_pct": sweep["oracle_param_mae_pct"].tolist(), "oracle_bias_pct": sweep["oracle_param_bias_pct"].tolist(),
                      "grid_mae_pct": sweep["grid_param_mae_pct"].tolist(),
                      "module_vs_oracle_mae_pct": ((inferred["params_normalised"] - oracle).abs() * 50).mean(0).tolist(),
                      "oracle_normalised": oracle.tolist()}
        for j, p in enumerate(scene.param_names):
            print(f"{scene.name}, {n} videos, observed {t} frames from {name}: {p} oracle {rows[name]['oracle_mae_pct'][j]:.2f}% "
                  f"(bias {rows[name]['oracle_bias_pct'][j]:+.2f}; grid alone {rows[name]['grid_mae_pct'][j]:.2f}%); "
                  f"module - oracle {rows[name]['module_vs_oracle_mae_pct'][j]:.2f}%  [{time.time() - began:.0f} s]")
    for j, p in enumerate(scene.param_names):
        print(f"the module's own {p}: {rows['module_mae_pct'][j]:.2f}% (bias {rows['module_bias_pct'][j]:+.2f})")
    rows["truth_normalised"], rows["module_normalised"] = truth.tolist(), inferred["params_normalised"].tolist()
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
