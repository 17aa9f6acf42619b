"""Is a rigidness near 0.5 by itself out of the MassRope prior's reach? (session 25; a diagnostic, ~10 min on 2 cores)

The recorded frames, true grouping and stiffness of the first 100 test videos, rolled 20 steps
by the prior as task=train_dynamics evaluates it (``evaluate_rollouts``), with every rigid
instance's Q set to 1, 0.9, 0.75, 0.5, 0.25, 0; the T+20 MSE x 1e4 for each.

Usage: python scripts/experiments/prior_rigidness_fence.py
"""

from __future__ import annotations

import dataclasses

import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.trajectories import load_split
from vgpl.eval.error_breakdown import rollout_mse_x1e4
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.tasks.train_dynamics import evaluate_rollouts


def main() -> None:
    torch.set_num_threads(2)
    prior, cfg = load_stage("checkpoints/standard/mass_rope/dynamics/last.ckpt", DynamicsPrior, env="mass_rope")
    scene = scene_of(cfg)
    test = load_split("data/standard", "mass_rope", "test", max_rollouts=100)
    for q in (1.0, 0.9, 0.75, 0.5, 0.25, 0.0):
        fenced = dataclasses.replace(test, rigid=test.rigid.float() * q)
        _, pred, truth = evaluate_rollouts(prior, scene, fenced, observed=10, n_steps=20, start_frame=cfg.env.get("start_frame", 0))
        e = rollout_mse_x1e4(pred, truth, 20)
        print(f"sphere Q={q:.2f}: T+20 mean {e.mean():.1f} median {e.median():.1f} max {e.max():.0f}, videos > 1e3: {(e > 1e3).sum().item()}")


if __name__ == "__main__":
    main()
