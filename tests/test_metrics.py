"""The evaluation's metrics: the frames' acceleration in mm per frame squared, rigidness per object type."""

import math

import pytest
import torch

from vgpl.metrics import mean_abs_acceleration_mm, mean_per_type, per_video_per_type


def test_a_uniformly_accelerated_fall_reads_its_acceleration_per_frame_squared():
    dt, g = 1.0 / 60.0, -9.81
    t = torch.arange(12, dtype=torch.float64) * dt
    z = 0.5 * g * t**2 + 0.3 * t + 1.0  # metres
    positions = torch.zeros(2, 12, 5, 3, dtype=torch.float64)
    positions[..., 2] = z[None, :, None]
    # only z accelerates: |g| dt^2 on one coordinate of three
    assert mean_abs_acceleration_mm(positions) == pytest.approx(abs(g) * dt**2 * 1e3 / 3, rel=1e-9)
    assert mean_abs_acceleration_mm(positions - positions) == 0.0


def test_independent_frame_noise_reads_as_its_second_difference_and_the_mask_selects_particles():
    """Noise of std s in every frame gives a second difference of std s sqrt(6), so a mean |.| of
    s sqrt(6) sqrt(2 / pi); a constant offset or a constant velocity adds nothing."""
    s = 0.004
    gen = torch.Generator().manual_seed(0)
    noise = torch.randn(40, 20, 50, 3, generator=gen, dtype=torch.float64) * s
    drift = torch.linspace(0, 1, 20, dtype=torch.float64)[None, :, None, None] * 0.05 + 0.2  # offset and constant velocity
    expected = s * math.sqrt(6) * math.sqrt(2 / math.pi) * 1e3
    assert mean_abs_acceleration_mm(noise + drift) == pytest.approx(expected, rel=0.02)
    mask = torch.zeros(50, dtype=torch.bool)
    mask[:10] = True
    still = noise.clone()
    still[:, :, 10:] = 0.0  # only the masked particles are noisy
    assert mean_abs_acceleration_mm(still, mask) == pytest.approx(expected, rel=0.03)
    assert mean_abs_acceleration_mm(still) == pytest.approx(expected / 5, rel=0.03)


def test_two_frames_have_no_acceleration_and_are_refused():
    with pytest.raises(ValueError, match="2 frames, a second difference needs at least 3"):
        mean_abs_acceleration_mm(torch.zeros(1, 2, 4, 3))


def test_rigidness_per_type_averages_each_videos_instances_of_that_type():
    probs = torch.tensor([[1.0, 0.5, 0.2], [0.0, 0.5, 0.6]])  # [R=2 videos, M=3 instances]
    types = ["cube", "cube", "rope"]
    per_video = per_video_per_type(probs, types)
    assert list(per_video) == ["cube", "rope"]
    torch.testing.assert_close(per_video["cube"], torch.tensor([0.75, 0.25]))
    torch.testing.assert_close(per_video["rope"], torch.tensor([0.2, 0.6]))
    assert {k: float(v) for k, v in mean_per_type(probs, types).items()} == pytest.approx({"cube": 0.5, "rope": 0.4})
