"""What the InferenceModule's rigidness Q is to the dynamics prior: the config group
``rigidness_estimator`` (``model.inference.net.rigidness_estimator``).

- ``blend`` (the paper): Q is the prior's blend weight between its rigid and per-particle heads,
  learnt through the gradient of the rollout.
- ``bernoulli``: Q is the probability that an instance is rigid; the prior sees the label Q > 0.5,
  and Q learns from the trajectory L1 expected over the label, Q L1(rigid) + (1 - Q) L1(free),
  exact per instance.
"""

from __future__ import annotations

import torch

from vgpl.models.rollout import rollout


def tile_batch(z: torch.Tensor, copies: int) -> torch.Tensor:
    """[B, ...] -> [copies * B, ...]: the batch repeated ``copies`` times, copy-major."""
    return z.repeat(copies, *([1] * (z.dim() - 1)))


class BlendRigidness:
    name = "blend"

    def prior_input(self, prob: torch.Tensor) -> torch.Tensor:
        """Q [B, M] -> what the prior is given: Q itself."""
        return prob

    def loss(self, *args, **kwargs) -> dict:
        """No loss of its own: Q learns through the rollouts it blends."""
        return {}


class BernoulliRigidness:
    name = "bernoulli"

    def prior_input(self, prob: torch.Tensor) -> torch.Tensor:
        """Q [B, M] -> the label Q > 0.5 the prior is given."""
        return (prob > 0.5).to(prob)

    def loss(self, dynamics, run: tuple, target: torch.Tensor, prob: torch.Tensor, at_labels: torch.Tensor, planes: torch.Tensor,
             kinematic: torch.Tensor) -> dict:
        """{"rigidness": Q's loss}: the run that trains P (start [B, H, N, 3], G, labels [B, M], P)
        rolled with each instance's label flipped, against target [B, L, N, 3]; at_labels [B] its
        L1 at the labels the module gave."""
        start, grouping, labels, params = run
        flipped = flipped_label_errors(dynamics, start, target, grouping, labels, params.detach(), planes, kinematic)
        return {"rigidness": expected_rigidness_error(prob, labels, at_labels, flipped)}


@torch.no_grad()
def flipped_label_errors(dynamics, start, target, grouping, labels, params, planes, kinematic) -> torch.Tensor:
    """The trajectory L1 [B, M] with instance m's label flipped (1 - label), the others kept, for
    every m: one rollout of M B scenes, copy-major, without gradient. start [B, H, N, 3], target
    [B, L, N, 3], grouping [B, N, M], labels [B, M] in {0, 1}, params [B, P], planes as rollout's."""
    b, m = labels.shape
    flipped = labels[None].repeat(m, 1, 1)  # [M copies, B, M]
    each = torch.arange(m, device=labels.device)
    flipped[each, :, each] = 1.0 - flipped[each, :, each]
    targets = tile_batch(target, m)
    future = rollout(dynamics, torch.cat([tile_batch(start, m), targets], 1), tile_batch(grouping, m), flipped.reshape(m * b, m),
                     tile_batch(params, m), tile_batch(planes, m), kinematic, target.shape[1])
    error = ((future - targets) / dynamics.disp_std).abs()[:, :, ~kinematic].mean((1, 2, 3))
    return error.reshape(m, b).T


def expected_rigidness_error(prob, labels, at_labels, flipped) -> torch.Tensor:
    """The trajectory L1 expected over each instance's label, mean over scenes and instances:
    Q L1(rigid) + (1 - Q) L1(free), whose gradient in Q is L1(rigid) - L1(free), exactly.
    prob [B, M] Q; labels [B, M] the prior's labels; at_labels [B] L1 at them; flipped [B, M]
    L1 with each label flipped (``flipped_label_errors``)."""
    at_labels = at_labels.detach()[:, None].expand_as(flipped)
    rigid = torch.where(labels > 0.5, at_labels, flipped)
    free = torch.where(labels > 0.5, flipped, at_labels)
    return (prob * rigid + (1.0 - prob) * free).mean()
