"""The InferenceModule's losses pinned: each training scheme, trajectory start, rollout target and
rigidness estimator, three Adam steps at a fixed seed on a tiny random batch, against the values
recorded in ``inference_losses.json``. A change to how the module is built or how its loss is
assembled must leave every term as it was (float tolerance); a change meant to alter a loss
re-records the file and says why in its commit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from tests.models.test_inference import _batch, _modules

RECORDED = json.loads((Path(__file__).parent / "inference_losses.json").read_text())
AUTHORS = {"one_step_windows": None, "refined_steps": 0, "truth_steps": 2}  # the authors' code's loss lengths
CASES = {
    "paper": {"training_scheme": "paper", **AUTHORS, "tail_horizon": 2, "tail_detach_rigidness": True},
    "paper_whole_window": {"training_scheme": "paper", "one_step_windows": 2},
    "joint_refined": {"trajectory_start": "refined", "tail_horizon": 1},
    "joint_truth": {"trajectory_start": "truth", "param_weight": 0.5},
    "joint_both": {"trajectory_start": "both", "truth_steps": 3, "proposal_noise": 0.01},
    "joint_both_bernoulli": {"trajectory_start": "both", "rigidness_estimator": "bernoulli"},
    "proposals_both": {"rollout_target": "proposals", "refine_weight": 0.0, "trajectory_start": "both", "rigid_fit_start": True},
    "proposals_refined": {"rollout_target": "proposals", "refine_weight": 0.0},
    "no_rigidness_paper": {"training_scheme": "paper", **AUTHORS, "rigidness": False},
}


def _batch_for(case: dict) -> dict:
    torch.manual_seed(1)
    batch = _batch(labels=True)
    if case.get("rollout_target") == "proposals":  # an actuated particle, and the proposals' frames past the window
        batch["kinematic"][:, 0] = True
        batch["target_proposals"] = torch.cat([batch["proposals"], torch.rand(2, 2, 24, 3)], 1)
    return batch


def test_every_case_is_recorded():
    assert set(CASES) == set(RECORDED)


@pytest.mark.parametrize("name", sorted(CASES))
def test_losses_over_three_steps_are_the_recorded_ones(name):
    torch.manual_seed(0)
    _, module = _modules(lr=1e-3, **CASES[name])
    batch = _batch_for(CASES[name])
    optimiser = module.configure_optimizers()
    for step, recorded in enumerate(RECORDED[name]):
        torch.manual_seed(10 + step)  # the proposal jitter's draw
        losses = module._losses(batch, noise=True)
        assert set(losses) == set(recorded), step
        for key, value in recorded.items():
            assert float(losses[key]) == pytest.approx(value, rel=2e-5, abs=1e-6), (step, key)
        optimiser.zero_grad()
        losses["loss"].backward()
        optimiser.step()
