"""The test-time fit against a prior whose physics is known: ballistic motion under gravity P."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from vgpl.eval.test_time_fit import TestTimeFit, fit_to_own_frames

DT, LOW, HIGH = 1.0 / 60.0, -15.0, -5.0


class Ballistic(torch.nn.Module):
    """A stand-in dynamics prior: x_{t+1} = 2 x_t - x_{t-1} + (0, P dt^2, 0), P the gravity [B, 1]."""

    def __init__(self) -> None:
        super().__init__()
        self.hparams = SimpleNamespace(history=2)
        self.register_buffer("disp_std", torch.full((3,), 0.01))

    def step(self, window, grouping, rigidness, params, planes, kinematic, driven=None):
        drop = torch.zeros_like(window[:, -1])
        drop[..., 1] = params[:, :1] * DT**2
        return 2 * window[:, -1] - window[:, -2] + drop


def to_physical(normalised):
    return LOW + (normalised + 1.0) / 2.0 * (HIGH - LOW)


def falling(gravity: list[float], frames: int = 10, n: int = 5) -> torch.Tensor:
    """[B, frames, n, 3] particles thrown up at 1 m/s under each gravity."""
    t = torch.arange(frames, dtype=torch.float32)[None, :, None] * DT
    g = torch.tensor(gravity)[:, None, None]
    pos = torch.zeros(len(gravity), frames, n, 3)
    pos[..., 0] = torch.arange(n, dtype=torch.float32) * 0.1
    pos[..., 1] = 1.0 * t + 0.5 * g * t**2
    return pos


def fit(positions, start_normalised, steps=300, lr=0.05, **options):
    """``fit_to_own_frames`` against the ballistic prior; ``options``: its chunk and progress."""
    b = positions.shape[0]
    return fit_to_own_frames(Ballistic(), positions, torch.ones(b, 5, 1), torch.full((b, 1), 0.5), torch.full((b, 1), start_normalised),
                             torch.zeros(b, positions.shape[1], 0, 4), torch.zeros(5, dtype=torch.bool), TestTimeFit(steps, lr, rigidness=True), to_physical,
                             **options)


def test_the_fit_finds_each_videos_gravity_from_its_own_frames_and_videos_do_not_interact():
    frames = falling([-12.0, -6.5])
    out = fit(frames, 0.0)  # both start at the midpoint, -10
    assert to_physical(out["params_normalised"][:, 0]).tolist() == pytest.approx([-12.0, -6.5], abs=0.05)
    assert bool((out["error_after"] < 0.01 * out["error_before"]).all())
    alone = fit(frames[1:], 0.0)  # Adam is elementwise: a video fitted alone ends where it ended in the batch
    assert torch.allclose(alone["params_normalised"], out["params_normalised"][1:], atol=1e-6)


def test_the_fit_never_leaves_the_range():
    out = fit(falling([-20.0]), 0.0)  # motion no gravity in the range explains
    assert LOW < float(to_physical(out["params_normalised"][0, 0])) < LOW + 0.2


def test_zero_steps_keep_the_estimate_and_bad_settings_are_named():
    out = fit(falling([-12.0]), 0.3, steps=0)
    assert float(out["params_normalised"][0, 0]) == pytest.approx(0.3, abs=1e-5)
    with pytest.raises(ValueError, match="eval.test_time_fit.steps=-1"):
        TestTimeFit(-1)
    with pytest.raises(ValueError, match="eval.test_time_fit.lr=0"):
        TestTimeFit(5, 0)
    with pytest.raises(ValueError, match="2 observed frames leave nothing to fit"):
        fit(falling([-12.0], frames=2), 0.0)


def test_the_progress_bar_counts_videos_across_chunks(capsys):
    frames = falling([-12.0, -9.0, -6.5])
    fit(frames, 0.0, steps=2, chunk=2, progress=True)
    bar = capsys.readouterr().err
    assert "test-time fit (2 steps)" in bar and "3/3" in bar and "video" in bar
    fit(frames, 0.0, steps=2, chunk=2)
    assert "test-time fit" not in capsys.readouterr().err  # off by default
