"""The test-time fit against a prior whose physics is known: ballistic motion under gravity P."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from vgpl.eval.test_time_fit import TestTimeFit, fit_to_own_frames, own_frames_error
from vgpl.nn.rigid_start import rigid_start

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


class Recording(Ballistic):
    """The ballistic prior, keeping the first window it steps from (the rollout's start)."""

    def __init__(self) -> None:
        super().__init__()
        self.first = None

    def step(self, window, *args, **kwargs):
        if self.first is None:
            self.first = window.detach().clone()
        return super().step(window, *args, **kwargs)


def test_a_rigid_start_rolls_each_body_q_calls_rigid_as_one_and_keeps_the_targets():
    """A 27-particle cube falling, 2 mm of noise on every particle of every frame: with ``rigid_start``
    the prior rolls from the start frames fitted rigidly (vgpl.nn.rigid_start), whose particle
    velocities are the body's (their error a fraction of the noisy frames'), and the fit still
    compares with the frames as they came; an instance whose Q is below 0.5 starts as it came."""
    torch.manual_seed(0)
    b, n = 2, 27
    grid = torch.stack(torch.meshgrid(*[torch.arange(3.0) * 0.03] * 3, indexing="ij"), -1).reshape(n, 3)
    frames = falling([-10.0] * b, n=n) * torch.tensor([0.0, 1.0, 0.0]) + grid  # a cube, not a line
    noisy = frames + 0.002 * torch.randn_like(frames)

    def starts(q: float, rigid: bool) -> torch.Tensor:
        prior = Recording()
        fit_to_own_frames(prior, noisy, torch.ones(b, n, 1), torch.full((b, 1), q), torch.zeros(b, 1), torch.zeros(b, 10, 0, 4),
                          torch.zeros(n, dtype=torch.bool), TestTimeFit(0, 0.05, False, rigid), to_physical)
        return prior.first

    fitted = starts(0.9, True)
    assert torch.allclose(fitted, rigid_start(noisy[:, :2], torch.ones(b, n, 1), torch.ones(b, 1)), atol=1e-6)
    velocity_error = lambda x: (x[:, 1] - x[:, 0] - (frames[:, 1] - frames[:, 0])).pow(2).mean().sqrt()  # noqa: E731
    assert velocity_error(fitted) < 0.3 * velocity_error(noisy[:, :2])
    assert torch.equal(starts(0.2, True), noisy[:, :2]) and torch.equal(starts(0.9, False), noisy[:, :2])
    with torch.no_grad():  # the targets are the frames as they came: the error of the fitted start's rollout against them
        prior = Ballistic()
        fitted_frames = torch.cat([fitted, noisy[:, 2:]], 1)
        expected = own_frames_error(prior, fitted_frames, torch.ones(b, n, 1), torch.ones(b, 1), torch.full((b, 1), -10.0), torch.zeros(b, 10, 0, 4),
                                    torch.zeros(n, dtype=torch.bool))
    out = fit_to_own_frames(Ballistic(), noisy, torch.ones(b, n, 1), torch.full((b, 1), 0.9), torch.zeros(b, 1), torch.zeros(b, 10, 0, 4),
                            torch.zeros(n, dtype=torch.bool), TestTimeFit(0, 0.05, False, True), lambda x: torch.full_like(x, -10.0))
    assert torch.allclose(out["error_before"], expected)
