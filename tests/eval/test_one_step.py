from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from vgpl.data.trajectories import Rollouts
from vgpl.eval.one_step import one_step_accelerations, slope

DT2 = (1 / 60) ** 2


class DampedFall:
    """A stand-in prior: constant-acceleration motion that reproduces ``share`` of gravity P along y."""

    hparams = SimpleNamespace(history=3)

    def __init__(self, share: float) -> None:
        self.share = share

    def step(self, window, grouping, rigidness, params, planes, kinematic, kinematic_next=None):
        accel = torch.zeros_like(window[:, -1])
        accel[..., 1] = self.share * params[:, :1] * DT2
        nxt = 2 * window[:, -1] - window[:, -2] + accel
        return torch.where(kinematic[None, :, None], kinematic_next, nxt) if kinematic_next is not None else nxt


def _falling(n_videos: int = 3, n_frames: int = 12, n_particles: int = 5) -> tuple[SimpleNamespace, Rollouts]:
    """Free fall under gravity P [V, 1]; particle 0 is kinematic and moves sideways at constant speed."""
    torch.manual_seed(0)
    gravity = -torch.rand(n_videos, 1) * 10 - 5
    t = torch.arange(n_frames, dtype=torch.float32)
    positions = torch.rand(n_videos, 1, n_particles, 3).repeat(1, n_frames, 1, 1)
    positions[..., 1] += (0.5 * gravity[:, None] * DT2 * t[None, :, None] ** 2)
    positions[:, :, 0] = torch.tensor([0.0, 1.0, 0.0]) + t[None, :, None] * torch.tensor([0.01, 0.0, 0.0])
    kinematic = torch.zeros(n_particles, dtype=torch.bool)
    kinematic[0] = True
    scene = SimpleNamespace(kinematic=kinematic.numpy(), planes_at=lambda actions: actions.new_zeros(*actions.shape[:2], 0, 4))
    rollouts = Rollouts(positions=positions, params=gravity, actions=torch.zeros(n_videos, n_frames, 1), instance=torch.zeros(n_particles, dtype=torch.long),
                        rigid=torch.ones(1, dtype=torch.bool), param_low=torch.tensor([-15.0]), param_high=torch.tensor([-5.0]), env="falling")
    return scene, rollouts


@pytest.mark.parametrize("share", [1.0, 0.96])
def test_slope_reads_the_share_of_gravity_a_prior_reproduces(share):
    scene, rollouts = _falling()
    pred, true = one_step_accelerations(DampedFall(share), scene, rollouts, start=2, frames=8)
    assert pred.shape == true.shape == (3, 8 - 3, 5, 3)  # frames start + H .. start + frames - 1
    movable = ~torch.as_tensor(scene.kinematic)
    # the truth's acceleration is g dt^2 along y on every movable particle, exactly (to float precision)
    assert torch.allclose(true[:, :, movable, 1], (rollouts.params * DT2)[:, :, None].expand(-1, 5, 4), rtol=1e-3)
    assert slope(pred[:, :, movable], true[:, :, movable]) == pytest.approx(share, abs=2e-3)
    # the kinematic particle is driven by the truth: its acceleration is the truth's (zero) whatever the prior
    assert torch.equal(pred[:, :, 0], true[:, :, 0])


def test_a_window_past_the_rollouts_end_is_refused():
    scene, rollouts = _falling(n_frames=12)
    with pytest.raises(ValueError, match="exceed the 12-frame rollouts"):
        one_step_accelerations(DampedFall(1.0), scene, rollouts, start=5, frames=8)
