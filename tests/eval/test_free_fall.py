"""Gravity from a least-squares free-fall fit (vgpl.eval.free_fall)."""

from __future__ import annotations

import pytest
import torch

from vgpl.eval.free_fall import body_heights, fit_gravity, free_fall_profile

DT = 1 / 60


def falls(gravity: torch.Tensor, frames: int = 10, bodies: int = 3) -> torch.Tensor:
    """Heights [V, T, M] of bodies dropped from rest a quarter frame before frame 0 (as the engine's
    two substeps give), from heights 0.5, 0.6, ..."""
    t = torch.arange(frames, dtype=torch.float64) * DT
    shape = DT / 4 * t + t * t / 2
    return 0.5 + 0.1 * torch.arange(bodies, dtype=torch.float64)[None, None] + gravity[:, None, None] * shape[None, :, None]


def test_the_fit_recovers_gravity_and_averages_out_per_body_offsets():
    gravity = torch.tensor([-5.0, -9.81, -15.0], dtype=torch.float64)
    heights = falls(gravity)
    profile, free = free_fall_profile(heights, gravity)
    assert bool(free.all())
    assert profile[0] == 0 and profile[9] == pytest.approx(DT * 9 * DT / 4 + (9 * DT) ** 2 / 2)
    torch.testing.assert_close(fit_gravity(heights, profile), gravity)
    shifted = heights + torch.tensor([0.01, -0.02, 0.03], dtype=torch.float64)  # a constant offset per body: no effect
    torch.testing.assert_close(fit_gravity(shifted, profile), gravity)
    # a per-frame error that is not a constant moves it: +1 cm on the last frame of every body
    bumped = heights.clone()
    bumped[:, -1] += 0.01
    s = profile - profile.mean()
    expected = gravity + 0.01 * s[-1] / (s * s).sum()  # the closed form of the least-squares slope
    torch.testing.assert_close(fit_gravity(bumped, profile), expected)


def test_a_body_that_lands_or_is_pushed_is_left_out_and_a_video_without_a_free_body_refused():
    gravity = torch.tensor([-9.81, -12.0, -6.0], dtype=torch.float64)
    heights = falls(gravity)
    heights[1, 7:, 2] = heights[1, 6, 2]  # video 1's third body stops at frame 6
    heights[2, 1:, 0] += 0.002 * torch.arange(1, 10, dtype=torch.float64)  # video 2's first body pushed upwards from the start
    profile, free = free_fall_profile(heights, gravity)
    assert free.tolist() == [[True] * 3, [True, True, False], [False, True, True]]
    torch.testing.assert_close(fit_gravity(heights, profile, free), gravity)  # the free bodies give it exactly
    assert abs(float(fit_gravity(heights, profile)[2]) + 6.0) > 0.1  # with the pushed body in, off
    heights[1, 7:, :2] = heights[1, 6, :2]  # every body of video 1 lands
    with pytest.raises(ValueError, match="first 10 frames: no body of video 1 is within 0.1 mm of the common profile .*observe fewer frames"):
        free_fall_profile(heights, gravity)


def test_body_heights_are_the_centroids_vertical_coordinate():
    positions = torch.zeros(2, 3, 4, 3)
    positions[..., 1] = torch.tensor([1.0, 3.0, 10.0, 20.0])  # particles 0-1 are body 0, 2-3 body 1
    instance = torch.tensor([0, 0, 1, 1])
    assert torch.equal(body_heights(positions, instance), torch.tensor([2.0, 15.0]).expand(2, 3, 2))
    assert torch.equal(body_heights(positions, instance.expand(2, 4)), torch.tensor([2.0, 15.0]).expand(2, 3, 2))


def test_a_split_scales_the_proposals_error_in_heights_as_in_positions_and_calibrates_by_a_line():
    from types import SimpleNamespace

    from vgpl.eval.free_fall import FreeFallSplit, calibration

    torch.manual_seed(0)
    gravity = torch.tensor([-6.0, -9.0, -13.0], dtype=torch.float64)
    instance = torch.tensor([0, 0, 1, 1, 2, 2])
    heights = falls(gravity)  # [3, 10, 3]: each body's two particles at its height, 5 cm apart in x
    truth = torch.zeros(3, 10, 6, 3, dtype=torch.float64)
    truth[..., 1] = heights.repeat_interleave(2, -1)
    truth[..., 0] = torch.tensor([0.0, 0.05] * 3, dtype=torch.float64)
    noisy = truth + 0.01 * torch.randn_like(truth)
    split = FreeFallSplit.of(SimpleNamespace(positions=truth, instance=instance, params=gravity[:, None]),
                             SimpleNamespace(positions=noisy), 10)
    assert split.position_mse == pytest.approx(float((noisy - truth).pow(2).mean()))
    profile, _ = free_fall_profile(heights, gravity)
    for scale in (1.0, 0.5):
        torch.testing.assert_close(split.fit(scale), fit_gravity(body_heights(truth + scale * (noisy - truth), instance), profile))
    torch.testing.assert_close(split.fit(0.0), gravity)
    assert calibration(2.0 + 0.5 * gravity, gravity) == pytest.approx((-4.0, 2.0))  # gravity = -4 + 2 x fitted
