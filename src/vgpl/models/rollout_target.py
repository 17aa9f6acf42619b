"""What the InferenceModule's rollouts are compared with: the config group ``rollout_target``
(``model.inference.net.target``), read here alone by the proposal export, the InferenceDataModule
and the loss.

- ``truth`` (``TruthTarget``, the paper): the simulator's trajectories.
- ``proposals`` (``ProposalsTarget``): the visual prior's particles of the same frames, slot by
  slot (the visual prior gives every particle its own slot in every frame), so the module trains
  on unlabelled videos. The actuated particles are where the actions put them, as the Grounder
  places them. The export then writes ``model.inference.horizon`` frames past each observed
  window, and the windows carry them as ``target_proposals``. Nothing reads the trajectories but
  the logged metrics, so this target has no refinement or parameter weight to set.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from hydra.utils import get_class

from vgpl.nn.rigid_start import rigid_start


class TruthTarget:
    """Rollouts compared with the simulator's trajectories. ``refine_weight``: the weight of the
    refined positions' direct L1 to the true ones (the authors' code adds it); ``param_weight`` > 0
    adds a supervised L1 on P (not the paper)."""

    name = "truth"

    def __init__(self, refine_weight: float = 1.0, param_weight: float = 0.0) -> None:
        self.refine_weight, self.param_weight = refine_weight, param_weight

    def frames(self, batch: dict, kinematic: torch.Tensor) -> torch.Tensor:
        """[B, T + horizon, N, 3] the frames rolled into: the batch's true positions."""
        return batch["positions"]

    def true_start(self, start: torch.Tensor, grouping: torch.Tensor, rigidness: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        return start


class ProposalsTarget:
    """Rollouts compared with the visual prior's particles. ``rigid_fit_start``: the "true" start P
    rolls from (the proposals' own first frames) has each instance the module's Q calls rigid
    (Q > 0.5) fitted rigidly to its last-frame shape (``vgpl.nn.rigid_start``, by the module's G; no
    gradient), so P reads a rigid body's motion rather than the proposals' noise."""

    name = "proposals"
    refine_weight = param_weight = 0.0  # nothing may read the trajectories

    def __init__(self, rigid_fit_start: bool = False) -> None:
        self.rigid_fit_start = rigid_fit_start

    def frames(self, batch: dict, kinematic: torch.Tensor) -> torch.Tensor:
        """[B, T + horizon, N, 3]: the proposals of the window and its future frames; the actuated
        particles' recorded positions (Scene.kinematic_positions gives them exactly)."""
        return torch.where(kinematic[None, None, :, None], batch["positions"], batch["target_proposals"])

    def true_start(self, start: torch.Tensor, grouping: torch.Tensor, rigidness: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        """start [B, H, N, 3], grouping [B, N, M], rigidness [B, M] -> the start P rolls from."""
        if not self.rigid_fit_start:
            return start
        return rigid_start(start, grouping.detach(), (rigidness > 0.5).to(rigidness), kinematic)


def rollout_target(net: Mapping) -> str:
    """'truth' or 'proposals': the target ``net`` (model.inference.net) rolls against."""
    target = net.get("target") or {}
    return get_class(target["_target_"]).name if "_target_" in target else TruthTarget.name


def future_proposal_frames(stage: Mapping) -> int:
    """Frames past each observed window the proposal export writes for ``stage`` (model.inference):
    its ``horizon`` when its module rolls against the proposals, else 0."""
    return int(stage["horizon"]) if rollout_target(stage.get("net") or {}) == ProposalsTarget.name else 0
