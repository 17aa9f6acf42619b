"""Is a rigidness near 0.5 by itself out of the MassRope prior's reach? (session 25; a diagnostic, ~10 min on 2 cores)

The recorded frames, true grouping and stiffness of the first 100 test videos; every rigid
instance's Q set to 1, 0.9, 0.75, 0.5, 0.25, 0; the prior's T+20 MSE x 1e4 for each.
Usage: python scripts/experiments/prior_rigidness_fence.py
"""
import torch
from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.trajectories import ground_truth_grouping, load_split
from vgpl.eval.error_breakdown import rollout_mse_x1e4
from vgpl.eval.rollout import rollout
from vgpl.models.dynamics_prior import DynamicsPrior
torch.set_num_threads(2)
dyn, cfg = load_stage("checkpoints/standard/mass_rope/dynamics/last.ckpt", DynamicsPrior, env="mass_rope")
scene, start = scene_of(cfg), cfg.env.get("start_frame", 0)
test = load_split("data/standard", "mass_rope", "test", max_rollouts=100)
R, h, t, n = len(test.params), dyn.hparams.history, 10, 20
frames = slice(start + t - h, start + t + n)
pos = test.positions[:, frames]; planes = scene.planes_at(test.actions[:, frames]); kin = torch.as_tensor(scene.kinematic)
G = ground_truth_grouping(test).expand(R, -1, -1)
for q in (1.0, 0.9, 0.75, 0.5, 0.25, 0.0):
    Q = test.rigid.float().expand(R, -1) * q
    with torch.no_grad():
        pred = rollout(dyn, pos, G, Q, test.params, planes, kin, n)
    e = rollout_mse_x1e4(pred, pos[:, h:], n)
    print(f"sphere Q={q:.2f}: T+20 mean {e.mean():.1f} median {e.median():.1f} max {e.max():.0f}, videos > 1e3: {(e > 1e3).sum().item()}")
