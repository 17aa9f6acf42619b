"""What the InferenceModule's loss rolls besides its scheme's trajectories, and how far
(``model.inference.net.training``).

``refined_steps`` and ``truth_steps`` set how many frames the run from the refined start
(``rollout``) and the run from the true start (``rollout_from_truth``) roll: null, through the rest
of the window and ``horizon`` frames past it; 0, no such run. ``one_step_windows`` adds one-step
predictions from the last k refined histories (null: every one). The authors' code trains dX and Q
by one step from every refined history of the window (``one_step_windows: null, refined_steps: 0``)
and P by 2 steps from the true frames (``truth_steps: 2``), the defaults.

Beyond the paper: ``tail_horizon`` k > 0 adds an L1 of k frames rolled from the LAST h refined
frames, where the evaluation starts and which the trajectories never start from
(``tail_detach_rigidness`` keeps Q out of it: from noisy frames Q can absorb the start's errors);
``proposal_noise`` s > 0 jitters every training proposal by a std drawn per window in [0, s] metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

Run = tuple[str, int, tuple, int]  # (loss name, first frame, (start, G, Q, P), frames rolled)


@dataclass(frozen=True)
class LossRuns:
    one_step_windows: int | None = None
    refined_steps: int | None = 0
    truth_steps: int | None = 2
    tail_horizon: int = 0
    tail_detach_rigidness: bool = False
    proposal_noise: float = 0.0

    def __post_init__(self) -> None:
        for name in ("refined_steps", "truth_steps"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"model.inference.net.training.{name}={value}: expected null (the window and horizon), 0 (no such run) "
                                 "or a number of frames")
        if not self.proposal_noise >= 0:
            raise ValueError(f"model.inference.net.training.proposal_noise={self.proposal_noise!r}, expected a std in metres >= 0 (0: off, the paper)")

    def runs(self, refined: torch.Tensor, grouping, rigidness, dx_params, trajectories: dict[str, tuple], history: int, horizon: int) -> list[Run]:
        """Every rollout of the loss from the window's refined frames [B, T, N, 3] and the scheme's
        ``trajectories`` (name -> start, G, Q, P); the one-step and tail runs take G, Q and ``dx_params``."""
        t, h = refined.shape[1], history
        firsts = list(range(t - h))
        firsts = firsts if self.one_step_windows is None else firsts[-self.one_step_windows:] if self.one_step_windows > 0 else []
        runs = [("one_step", s, (refined[:, s : s + h], grouping, rigidness, dx_params), 1) for s in firsts]
        n_roll = t - h + horizon
        steps = {"rollout": self.refined_steps, "rollout_from_truth": self.truth_steps}
        steps = {name: n_roll if steps[name] is None else steps[name] for name in trajectories}
        if steps and max(steps.values()) > n_roll:
            raise ValueError(f"model.inference.net.training: refined_steps={self.refined_steps}, truth_steps={self.truth_steps}: "
                             f"a window holds {n_roll} frames after the prior's history (observed - history + horizon)")
        runs += [(name, 0, inputs, steps[name]) for name, inputs in trajectories.items() if steps[name] > 0]
        if self.tail_horizon > 0:
            q_tail = rigidness.detach() if self.tail_detach_rigidness else rigidness
            runs.append(("tail", t - h, (refined[:, t - h :], grouping, q_tail, dx_params), self.tail_horizon))
        return runs
