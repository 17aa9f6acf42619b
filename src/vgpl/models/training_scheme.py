"""What each of the InferenceModule's trajectory rollouts is fed: the config group
``inference_scheme`` (``model.inference.net.scheme``).

- ``paper`` (``PaperScheme``): each of the paper's two networks rolls the prior with the true
  values of the other's outputs. dX and Q roll from the refined frames with the true P; P rolls
  from the true frames with the true G and Q.
- ``joint`` (``JointScheme``): every rollout takes the module's own G, Q and P. ``start`` says where
  it starts: ``refined`` (the refined first frames), ``truth`` (the true ones: P and Q learn, dX
  only from its direct L1) or ``both`` (P from the true start, dX through the refined one).

A run is (start [B, H, N, 3], G [B, N, M], Q [B, M], P [B, P]); ``rollout`` starts from the
refined frames, ``rollout_from_truth`` from the true ones.
"""

from __future__ import annotations

import torch

STARTS = ("refined", "truth", "both")


class PaperScheme:
    name = "paper"
    start = "refined"

    def dx_params(self, batch: dict, params: torch.Tensor) -> torch.Tensor:
        """The P that dX and Q learn with [B, P]: the true one."""
        return batch["params"].to(params)

    def trajectories(self, refined, true_start, grouping, rigidness, params, batch, with_rigidness: bool) -> dict[str, tuple]:
        """refined / true_start [B, H, N, 3] -> {"rollout": dX and Q's run, "rollout_from_truth": P's run}.
        ``with_rigidness`` false (the w/o-rigidness module): P's run takes Q = 0, as the module's."""
        true_q = batch["rigid"].to(rigidness) if with_rigidness else torch.zeros_like(rigidness)
        return {"rollout": (refined, grouping, rigidness, self.dx_params(batch, params)),
                "rollout_from_truth": (true_start, batch["grouping"].to(grouping), true_q, params)}


class JointScheme:
    name = "joint"

    def __init__(self, start: str = "refined") -> None:
        if start not in STARTS:
            raise ValueError(f"model.inference.net.scheme.start={start!r}, expected 'refined' (the paper's start), 'truth' or 'both'")
        self.start = start

    def dx_params(self, batch: dict, params: torch.Tensor) -> torch.Tensor:
        """The P that dX and Q learn with [B, P]: the module's own."""
        return params

    def trajectories(self, refined, true_start, grouping, rigidness, params, batch, with_rigidness: bool) -> dict[str, tuple]:
        """The runs ``start`` asks for; with ``both`` P learns from the true start only (detached in the refined one)."""
        runs = {"refined": {"rollout": (refined, grouping, rigidness, params)},
                "truth": {"rollout_from_truth": (true_start, grouping, rigidness, params)},
                "both": {"rollout": (refined, grouping, rigidness, params.detach()),
                         "rollout_from_truth": (true_start, grouping, rigidness, params)}}
        return runs[self.start]
