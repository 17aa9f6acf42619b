"""Test-time fit: refine one video's physical parameters P (and rigidness Q) by gradient through
the frozen dynamics prior, against that video's own refined frames. No ground truth: the target
is what the inference module made of the observed frames.

The amortised estimate (the inference module's) is the start. The prior is rolled from the first
``history`` refined frames through the rest of the observed window; the loss is the L1 between
that rollout and the refined frames, in units of the prior's displacement std, over the movable
particles. P is optimised as tanh(u) over its normalised range, so it never leaves the range; Q as
sigmoid(v). Each video has its own P and Q, and Adam is elementwise, so videos fitted together
in one batch do not affect each other. ``rigid_start`` first fits each instance the amortised Q
calls rigid (Q > 0.5) rigidly over the start frames (``vgpl.nn.rigid_start``), so the prior rolls
from one body's motion rather than the refined frames' frame-to-frame noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from vgpl.models.rollout import rollout
from vgpl.nn.rigid_start import rigid_start


@dataclass
class TestTimeFit:
    """The fit's settings: ``steps`` Adam steps (0: off) at rate ``lr`` on the pre-activations of
    P and, with ``rigidness``, of Q; ``rigid_start``: roll from the start frames with each instance the
    amortised Q calls rigid fitted rigidly."""

    steps: int = 0
    lr: float = 0.05
    rigidness: bool = True
    rigid_start: bool = False

    __test__ = False  # not a pytest class

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 0:
            raise ValueError(f"eval.test_time_fit.steps={self.steps!r}: expected a number of steps >= 0 (0: off)")
        if not self.lr > 0:
            raise ValueError(f"eval.test_time_fit.lr={self.lr!r}: expected a positive learning rate")


def own_frames_error(dynamics, positions, grouping, rigidness, params, planes, kinematic) -> torch.Tensor:
    """[B] L1 of the prior's rollout from the first H frames of ``positions`` [B, T, N, 3] against
    its other T - H frames, in units of the displacement std, over movable particles. grouping
    [B, N, M], rigidness [B, M] (what the prior takes), params [B, P] physical, planes [B, T, K, 4],
    kinematic [N] (their positions in ``positions`` drive them)."""
    h = dynamics.hparams.history
    n_roll = positions.shape[1] - h
    future = rollout(dynamics, positions, grouping, rigidness, params, planes, kinematic, n_roll)
    return ((future - positions[:, h:]) / dynamics.disp_std).abs()[:, :, ~kinematic].mean((1, 2, 3))


def fit_to_own_frames(dynamics, positions, grouping, rigidness, params_normalised, planes, kinematic, fit: TestTimeFit,
                      to_physical, chunk: int = 16, progress: bool = False) -> dict:
    """Fit P (and Q) of every video to its own frames, ``chunk`` videos at a time (``progress``: a
    bar over the videos).

    Args: positions [B, T, N, 3] the refined observed frames (T > the prior's history); grouping
    [B, N, M]; rigidness [B, M] the amortised Q (a probability); params_normalised [B, P] the
    amortised P in [-1, 1]; planes [B, T, K, 4]; kinematic [N]; ``to_physical`` maps normalised P
    to physical units (the inference module's).
    Returns params_normalised [B, P], rigidness [B, M] after the fit, and the own-frames error [B]
    before and after it (``error_before``, ``error_after``).
    """
    if positions.shape[1] <= dynamics.hparams.history:
        raise ValueError(f"test-time fit: {positions.shape[1]} observed frames leave nothing to fit after the prior's history of "
                         f"{dynamics.hparams.history}; observe more frames (eval.observed)")
    parts = []
    with tqdm(total=positions.shape[0], desc=f"test-time fit ({fit.steps} steps)", unit="video", disable=not progress) as bar:
        for i in range(0, positions.shape[0], chunk):
            s = slice(i, i + chunk)
            parts.append(_fit_chunk(dynamics, positions[s].detach(), grouping[s].detach(), rigidness[s].detach(), params_normalised[s].detach(),
                                    planes[s], kinematic, fit, to_physical))
            bar.update(positions[s].shape[0])
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def refit_inferred(out: dict, inference, dynamics, positions, planes, kinematic, fit: TestTimeFit, rigidness: bool = True,
                   chunk: int = 16, progress: bool = False) -> dict:
    """Replace the inference module's P (and Q) in ``out`` (``InferenceModule.infer``'s dict) by
    their test-time fit to ``positions`` [B, T, N, 3], the refined observed frames with the
    actuated particles placed (``fit_to_own_frames``). Q is fitted when ``fit.rigidness`` and
    ``rigidness`` (the ablation infers it) and the module's estimator is ``blend``; ``progress``
    shows a bar over the videos. Returns ``fit_to_own_frames``' result."""
    fit_q = bool(fit.rigidness and rigidness and inference.estimator.name == "blend")
    fitted = fit_to_own_frames(dynamics, positions, out["grouping"], out["rigidness_prob"], out["params_normalised"], planes, kinematic,
                               TestTimeFit(fit.steps, fit.lr, fit_q, fit.rigid_start), inference.to_physical, chunk, progress)
    out["params_normalised"], out["params"] = fitted["params_normalised"], inference.to_physical(fitted["params_normalised"])
    if fit_q:
        out["rigidness_prob"], out["rigidness"] = fitted["rigidness"], inference.prior_rigidness(fitted["rigidness"])
    return fitted


def _fit_chunk(dynamics, positions, grouping, rigidness, params_normalised, planes, kinematic, fit: TestTimeFit, to_physical) -> dict:
    if fit.rigid_start:  # the start frames, each instance the amortised Q calls rigid moved as one body; the targets as they are
        h = dynamics.hparams.history
        positions = torch.cat([rigid_start(positions[:, :h], grouping, (rigidness > 0.5).to(positions), kinematic), positions[:, h:]], 1)
    eps = 1e-4
    u = torch.atanh(params_normalised.clamp(-1 + eps, 1 - eps)).clone().requires_grad_(True)
    v = torch.logit(rigidness.clamp(eps, 1 - eps)).clone().requires_grad_(fit.rigidness)
    weights = [u, v] if fit.rigidness else [u]
    optimiser = torch.optim.Adam(weights, lr=fit.lr)
    error = lambda: own_frames_error(dynamics, positions, grouping, torch.sigmoid(v), to_physical(torch.tanh(u)), planes, kinematic)  # noqa: E731
    with torch.enable_grad():
        before = error().detach()
        for _ in range(fit.steps):
            optimiser.zero_grad()
            error().sum().backward()  # a sum: each video's P and Q get their own video's gradient
            optimiser.step()
        with torch.no_grad():
            after = error()
    return {"params_normalised": torch.tanh(u).detach(), "rigidness": torch.sigmoid(v).detach() if fit.rigidness else rigidness,
            "error_before": before, "error_after": after}
