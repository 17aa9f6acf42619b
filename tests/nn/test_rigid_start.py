"""rigid_start: start frames with each instance fitted rigidly to its last-frame shape, by its rigidness."""

from __future__ import annotations

import math

import torch

from vgpl.nn.rigid_start import rigid_start


def turned(points: torch.Tensor, angle: float, shift: list[float]) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return points @ rot.T + torch.tensor(shift)


def scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One video, 4 frames: instance 0 (8 particles) turns and falls rigidly, instance 1 (4 particles) is free."""
    torch.manual_seed(0)
    cube, blob = torch.rand(8, 3) * 0.1, torch.rand(4, 3) * 0.1 + 0.5
    frames = torch.stack([torch.cat([turned(cube, 0.1 * k, [0.0, -0.02 * k, 0.01 * k]), blob + 0.003 * k]) for k in range(4)])[None]
    grouping = torch.zeros(1, 12, 2)
    grouping[0, :8, 0], grouping[0, 8:, 1] = 1.0, 1.0
    return frames, grouping, torch.tensor([[1.0, 0.0]])


def test_a_rigid_motion_is_kept_and_free_particles_are_untouched():
    frames, grouping, labels = scene()
    assert torch.allclose(rigid_start(frames, grouping, labels), frames, atol=1e-6)
    noisy = frames + 0.01 * torch.randn_like(frames)
    out = rigid_start(noisy, grouping, labels)
    assert torch.equal(out[:, :, 8:], noisy[:, :, 8:])  # the free instance as it came
    # each earlier frame of the rigid instance is its last-frame shape moved rigidly: pairwise distances kept
    for k in range(4):
        assert torch.allclose(torch.cdist(out[0, k, :8], out[0, k, :8]), torch.cdist(noisy[0, -1, :8], noisy[0, -1, :8]), atol=1e-5)
    # and the frame-to-frame motion of the rigid instance is nearer the truth than the noisy frames'
    motion = lambda x: x[:, 1:, :8] - x[:, :-1, :8]  # noqa: E731
    assert (motion(out) - motion(frames)).norm() < 0.7 * (motion(noisy) - motion(frames)).norm()


def test_nothing_rigid_leaves_the_frames_as_they_are():
    frames, grouping, _ = scene()
    assert torch.equal(rigid_start(frames, grouping, torch.zeros(1, 2)), frames)


def test_rigidness_blends_the_fit_with_the_frames_as_they_came():
    frames, grouping, labels = scene()
    noisy = frames + 0.01 * torch.randn_like(frames)
    fitted = rigid_start(noisy, grouping, labels)
    half = rigid_start(noisy, grouping, torch.tensor([[0.5, 0.0]]))
    assert torch.allclose(half[:, :, :8], 0.5 * (fitted[:, :, :8] + noisy[:, :, :8]), atol=1e-6)
    # a free instance given rigidness 1 is fitted too: its particles keep their last-frame distances
    both = rigid_start(noisy, grouping, torch.ones(1, 2))
    assert torch.allclose(torch.cdist(both[0, 0, 8:], both[0, 0, 8:]), torch.cdist(noisy[0, -1, 8:], noisy[0, -1, 8:]), atol=1e-5)
    assert torch.equal(both[:, :, :8], fitted[:, :, :8])


def test_the_fit_carries_no_gradient_and_keeps_float32_under_bf16_autocast():
    frames, grouping, labels = scene()
    noisy = (frames + 0.01 * torch.randn_like(frames)).requires_grad_(True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = rigid_start(noisy, grouping, labels)
    assert not out.requires_grad and out.dtype == torch.float32
    assert torch.allclose(out, rigid_start(noisy.detach(), grouping, labels))


def test_actuated_particles_take_part_in_the_fit_and_keep_their_positions():
    frames, grouping, labels = scene()
    noisy = frames + 0.01 * torch.randn_like(frames)
    kinematic = torch.zeros(12, dtype=torch.bool)
    kinematic[0] = True
    out = rigid_start(noisy, grouping, labels, kinematic)
    assert torch.equal(out[:, :, 0], noisy[:, :, 0])
    assert torch.equal(out[:, :, 1:], rigid_start(noisy, grouping, labels)[:, :, 1:])
