"""Gravity read from falling bodies by least squares, with no learned model: how much of it the
observed frames of a RigidFall video carry, given positions as good as the proposals.

Every RigidFall body starts at rest and falls freely over the first frames, so its height is
y_t = y_0 + g s_t, with one profile s_t that the engine's integrator fixes for every scene (about
t dt / 4 + t^2 dt^2 / 2 with two substeps; measured from the truth, not assumed). Knowing s leaves
one unknown per video, g, and one offset per body: a straight-line fit of the heights against s.
Without the profile a free parabola per body is needed, and its curvature is far noisier.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

UP = 1  # gravity acts along y (vgpl.sim.envs.rigid_fall)


def body_heights(positions: torch.Tensor, instance: torch.Tensor) -> torch.Tensor:
    """positions [V, T, N, 3], instance [N] or [V, N] (body ids 0..M-1) -> heights [V, T, M] of
    each body's centroid."""
    onehot = torch.nn.functional.one_hot(instance.long(), int(instance.max()) + 1).to(positions.dtype)
    if onehot.dim() == 2:
        onehot = onehot.expand(positions.shape[0], -1, -1)  # [V, N, M]
    return torch.einsum("vtn,vnm->vtm", positions[..., UP], onehot) / onehot.sum(1)[:, None, :]


def free_fall_profile(heights: torch.Tensor, gravity: torch.Tensor, tolerance: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
    """The profile s [T] with y_t = y_0 + g s_t, measured on true heights [V, T, M] and gravity [V]
    (the median over bodies, so a few that are not falling freely do not move it), and which bodies
    [V, M] bool fall freely from rest over these frames: within ``tolerance`` metres of it in every
    frame. A body that lands, or that starts touching another and is pushed (the layout's level
    jitter can leave two cubes closer than the contact distance), is left out of the fit.

    Raises ValueError naming the first video none of whose bodies falls freely: observe fewer frames."""
    drop = (heights - heights[:, :1]) / gravity[:, None, None]  # [V, T, M]
    profile = drop.permute(1, 0, 2).reshape(drop.shape[1], -1).median(1).values
    off = ((drop - profile[None, :, None]).abs() * gravity.abs()[:, None, None]).amax(1)  # [V, M], metres
    free = off <= tolerance
    if not bool(free.any(1).all()):
        v = int(torch.nonzero(~free.any(1))[0])
        raise ValueError(f"not a free fall from rest over the first {heights.shape[1]} frames: no body of video {v} is within "
                         f"{tolerance * 1000:g} mm of the common profile (the nearest is {float(off[v].min()) * 1000:.2f} mm off); observe fewer frames")
    return profile, free


def fit_gravity(heights: torch.Tensor, profile: torch.Tensor, free: torch.Tensor | None = None) -> torch.Tensor:
    """Least-squares g [V] of y[v, t, m] = a[v, m] + g[v] s[t] (one offset per body, a shared g)
    from heights [V, T, M] and the profile s [T], over the bodies ``free`` [V, M] marks (default all)."""
    s = profile - profile.mean()
    y = heights - heights.mean(1, keepdim=True)
    w = torch.ones(heights.shape[0], heights.shape[2], dtype=heights.dtype) if free is None else free.to(heights.dtype)
    return torch.einsum("vtm,t,vm->v", y, s, w) / (w.sum(1) * (s * s).sum())


@dataclass
class FreeFallSplit:
    """A split's bodies over the fitted frames: true heights [V, T, M], the proposals' height error
    [V, T, M], true gravity [V], the profile [T], the bodies in free fall [V, M] bool and the
    proposals' position MSE (m^2). Heights are linear in positions, so proposals with their error
    scaled are truth + scale x error here."""

    truth: torch.Tensor
    error: torch.Tensor
    gravity: torch.Tensor
    profile: torch.Tensor
    free: torch.Tensor
    position_mse: float

    @classmethod
    def of(cls, rollouts, proposals, frames: int) -> FreeFallSplit:
        """From a split's Rollouts and its Proposals (vgpl.data.inference_windows.split_with_proposals),
        frames 0..frames-1."""
        truth = rollouts.positions[:, :frames].double()
        error = proposals.positions[:, :frames].double() - truth
        heights, gravity = body_heights(truth, rollouts.instance), rollouts.params[:, 0].double()
        return cls(heights, body_heights(error, rollouts.instance), gravity, *free_fall_profile(heights, gravity), float(error.pow(2).mean()))

    def fit(self, scale: float = 1.0) -> torch.Tensor:
        """fit_gravity [V] of the proposals with their error scaled by ``scale``, over the free bodies."""
        return fit_gravity(self.truth + scale * self.error, self.profile, self.free)


def calibration(fitted: torch.Tensor, gravity: torch.Tensor) -> tuple[float, float]:
    """(a, b) of the least-squares line gravity ~ a + b fitted, both [V] (on a training split)."""
    a, b = torch.linalg.lstsq(torch.stack([torch.ones_like(fitted), fitted], 1), gravity[:, None]).solution[:, 0]
    return float(a), float(b)
