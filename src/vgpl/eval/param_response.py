"""How much of the engine's response to a physical parameter a dynamics prior reproduces.

The oracle (vgpl.eval.identifiability) reads a parameter off the true frames as the argmin of the
prior's rollout L1. Linearised about the truth p*, the rollout at p is P(p*) + r_P (p - p*), so the
least-squares argmin is off by

    p_hat - p* = -<e, r_P> / <r_P, r_P>,    e = P(p*) - truth (the prior's residual),

and the oracle's error is the part of the prior's residual that looks like a change of the
parameter, divided by how strongly the prior responds to it. The engine restarted from the same
true state at two parameter values gives the response the prior should have, r_E: a slope
<r_P, r_E> / <r_E, r_E> under 1 is a prior that moves too little per unit of the parameter (its
argmin then needs a larger change to explain a residual), a cosine under 1 one that moves the
wrong particles, and |e| / |r_E| how many parameter units the residual is worth.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch

from vgpl.data.trajectories import Rollouts, true_window
from vgpl.eval.one_step import slope
from vgpl.models.rollout import rollout
from vgpl.sim.scene import RolloutSample, Scene


def engine_from_frame(scene: Scene, rollouts: Rollouts, frame: int, n_steps: int, params: torch.Tensor) -> torch.Tensor:
    """[B, n_steps, N, 3]: the engine restarted from the recorded state (positions, velocities) of
    ``frame`` in the first B = len(params) rollouts, with their actions from that frame on and the
    physical ``params`` [B, P]; frames frame + 1 .. frame + n_steps. With the recorded parameters it
    continues the recording (to float precision). ``rollouts`` must hold velocities
    (``load_split(..., velocities=True)``)."""
    if rollouts.velocities is None:
        raise ValueError(f"engine_from_frame: the {rollouts.env} rollouts were loaded without velocities; load them with load_split(..., velocities=True)")
    if frame + n_steps >= rollouts.positions.shape[1]:
        raise ValueError(f"engine_from_frame: frames {frame}..{frame + n_steps} exceed the {rollouts.positions.shape[1]}-frame rollouts")
    restarted = copy.copy(scene)
    restarted.n_steps = n_steps + 1
    samples = [
        RolloutSample(rollouts.positions[b, frame].numpy(), params[b].numpy(), rollouts.actions[b, frame : frame + n_steps + 1].numpy(),
                      rollouts.velocities[b, frame].numpy())
        for b in range(params.shape[0])
    ]
    return restarted.simulate(samples).positions[:, 1:]


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[B]: per-scene inner product of [B, ...] tensors."""
    return (a * b).flatten(1).sum(1)


@dataclass
class ParamResponse:
    """Responses per normalised unit of the parameter and the prior's residual at the truth, each
    [B, K, N, 3] in units of the prior's displacement std; ``truth`` [B] normalised;
    ``restart_error`` the engine's max |restart at the recorded parameters - recording| (metres; 0
    when the restart is exact), ``movable`` [N]."""

    engine: torch.Tensor
    prior: torch.Tensor
    residual: torch.Tensor
    truth: torch.Tensor
    restart_error: float
    movable: torch.Tensor

    def per_scene(self, particles: torch.Tensor | None = None) -> dict:
        """Over the movable ``particles`` [N] bool (None: every movable one, what the oracle's L1
        sums), per scene [B]: ``slope`` <r_P, r_E> / <r_E, r_E>, ``cosine``, ``engine_response`` and
        ``prior_response`` (|r|), ``residual`` (|e|), ``linear_error_prior`` and
        ``linear_error_engine`` (-<e, r> / <r, r>: the least-squares argmin's error, normalised, with
        the prior's or the engine's response); and ``pooled_slope`` over all scenes."""
        keep = self.movable if particles is None else self.movable & particles
        r_e, r_p, e = self.engine[:, :, keep], self.prior[:, :, keep], self.residual[:, :, keep]
        ee, pp, pe = _dot(r_e, r_e), _dot(r_p, r_p), _dot(r_p, r_e)
        return {
            "slope": pe / ee,
            "cosine": pe / (ee * pp).sqrt(),
            "engine_response": ee.sqrt(),
            "prior_response": pp.sqrt(),
            "residual": _dot(e, e).sqrt(),
            "linear_error_prior": -_dot(e, r_p) / pp,
            "linear_error_engine": -_dot(e, r_e) / ee,
            "pooled_slope": slope(r_p, r_e),
        }

    def summary(self, particles: torch.Tensor | None = None) -> dict[str, float]:
        """Scalars over ``particles`` (as ``per_scene``): pooled slope, median slope and cosine,
        median |r_E|, |r_P| and |e|, and the linearised argmins' MAE as % of the range (50 x mean
        |error|, normalised; the estimate clamped to the range as the oracle's grid is)."""
        r = self.per_scene(particles)
        mae = lambda k: float(((self.truth + r[k]).clamp(-1.0, 1.0) - self.truth).abs().mean() * 50.0)  # noqa: E731
        med = lambda k: float(r[k].median())  # noqa: E731
        return {
            "pooled_slope": r["pooled_slope"],
            "median_slope": med("slope"),
            "median_cosine": med("cosine"),
            "median_engine_response": med("engine_response"),
            "median_prior_response": med("prior_response"),
            "median_residual": med("residual"),
            "linear_mae_pct_prior_response": mae("linear_error_prior"),
            "linear_mae_pct_engine_response": mae("linear_error_engine"),
            "restart_error_m": self.restart_error,
        }


def param_response(model, scene: Scene, rollouts: Rollouts, start: int, frames: int, n: int, param: int = 0,
                   delta: float = 0.1) -> ParamResponse:
    """The engine's and the prior's response to parameter ``param`` over the oracle's window.

    Window: frames ``start`` .. ``start + frames - 1`` of the first ``n`` rollouts; the prior rolls
    from the true first H frames (true G, Q, the other parameters true), the engine restarts from
    the recorded state of frame start + H - 1 (both drive kinematic particles by the recording).
    Responses are central differences over +-``delta`` (normalised units: the range is [-1, 1])
    about the truth, the pair shifted inside the range at its ends.
    """
    h = model.hparams.history
    positions, grouping, rigidness, params, planes, kinematic = true_window(scene, rollouts, start, frames, n)
    n_steps = frames - h
    truth = model.normalise_params(params)
    centre = truth.clone()
    centre[:, param] = truth[:, param].clamp(-1.0 + delta, 1.0 - delta)
    shift = torch.zeros_like(truth)
    shift[:, param] = delta
    scale = model.disp_std

    def engine_at(physical: torch.Tensor) -> torch.Tensor:
        return engine_from_frame(scene, rollouts, start + h - 1, n_steps, physical)

    def engine(p: torch.Tensor) -> torch.Tensor:
        return engine_at(model.to_physical(p)) / scale

    def prior(p: torch.Tensor) -> torch.Tensor:
        return rollout(model, positions, grouping, rigidness, model.to_physical(p), planes, kinematic, n_steps) / scale

    with torch.no_grad():
        recorded = positions[:, h:] / scale
        # at the recorded parameters themselves: their float32 round trip through normalise_params /
        # to_physical moves FluidCube's viscosity by ~1e-6 relative, which its fluid turns into
        # centimetres within 14 frames (chaos, not a restart error)
        restart_error = float((engine_at(params) - positions[:, h:]).abs().max())
        return ParamResponse(
            engine=(engine(centre + shift) - engine(centre - shift)) / (2 * delta),
            prior=(prior(centre + shift) - prior(centre - shift)) / (2 * delta),
            residual=prior(truth) - recorded,
            truth=truth[:, param],
            restart_error=restart_error,
            movable=~kinematic,
        )
