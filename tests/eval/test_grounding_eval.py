from __future__ import annotations

import torch
from omegaconf import OmegaConf

from vgpl.data.trajectories import Rollouts
from vgpl.eval.grounding import evaluate_grounding
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import InferenceModule
from vgpl.models.visual_prior import VisualPrior
from vgpl.sim.envs import make_scene


def test_rigidness_curve_is_the_same_whatever_the_chunk_of_videos():
    torch.manual_seed(0)
    scene = make_scene("rigid_fall", n_steps=40)
    n, m, r, t = scene.n_particles, scene.n_instances, 5, 40
    dyn = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), m, radius=0.08, width=16)
    visual = VisualPrior(n, m, channels=[4, 4, 4, 4], hidden=16, downsample=2)
    inf = InferenceModule(scene.param_low.tolist(), scene.param_high.tolist(), n, m, radius=0.08, width=16)
    inf.set_stats(dyn)
    test = Rollouts(
        positions=torch.rand(r, t, n, 3) * 0.3, params=torch.full((r, 1), -10.0), actions=torch.zeros(r, t, 0),
        instance=torch.as_tensor(scene.instance), rigid=torch.as_tensor(scene.rigid), param_low=torch.as_tensor(scene.param_low),
        param_high=torch.as_tensor(scene.param_high), env=scene.name, images=torch.randint(0, 255, (r, t, 120, 160, 3), dtype=torch.uint8),
    )
    full = OmegaConf.create({"rigidness": True, "refinement": True, "params": True})
    kwargs = dict(observed=6, n_steps=5, max_observed=8)
    one = evaluate_grounding(dyn, visual, inf, scene, test, full, chunk=r, **kwargs)
    split = evaluate_grounding(dyn, visual, inf, scene, test, full, chunk=2, **kwargs)
    assert set(one.rigidness_curve) == {"cube"} and len(one.rigidness_curve["cube"]) == 8
    for name, curve in one.rigidness_curve.items():
        torch.testing.assert_close(torch.tensor(split.rigidness_curve[name]), torch.tensor(curve))
    assert split.metrics == one.metrics
