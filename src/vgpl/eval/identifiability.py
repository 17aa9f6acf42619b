"""How far the frozen dynamics prior itself pins down the physical parameters.

The InferenceModule learns P only through the prior's rollout loss. If that loss, fed the *true*
positions, grouping and rigidness, is nearly flat in P, no inference module can ground P through
it. This sweeps each parameter over its range (the others at their true values) and takes, per
scene, the value of lowest rollout L1: the "oracle" estimate. Its error is a floor for what the
inference module can reach with the same window and prior.

The oracle says whether the loss has its minimum at the truth; ``param_gradient_agreement`` says
whether gradient descent on P, from a wrong value, is pushed towards it: a window can have its
minimum at the truth and still a gradient that points the right way no more often than a coin.
"""

from __future__ import annotations

import torch

from vgpl.models.rollout import rollout


def rollout_l1_per_scene(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int,
                         chunk: int | None = None) -> torch.Tensor:
    """[B]: the mean L1 (units of the displacement std, the inference module's loss) of the rollout
    from the first H true frames of ``positions`` [B, H + n_steps, N, 3] against the rest, over the
    movable particles; ``params`` [B, P] physical. ``chunk``: scenes rolled at a time (None: all;
    the same numbers, each scene's rollout is its own)."""
    if chunk is not None and chunk < 1:
        raise ValueError(f"rollout_l1_per_scene: chunk={chunk}, expected at least 1 scene per rollout batch")
    b = positions.shape[0]
    if chunk is not None and chunk < b:
        pick = lambda x, s: None if x is None else x[s]  # noqa: E731  (the stand-in priors of the tests have no G, Q)
        return torch.cat([rollout_l1_per_scene(model, positions[s], pick(grouping, s), pick(rigidness, s), params[s], planes[s], kinematic, n_steps)
                          for s in (slice(i, i + chunk) for i in range(0, b, chunk))])
    h = model.hparams.history
    pred = rollout(model, positions, grouping, rigidness, params, planes, kinematic, n_steps)
    return ((pred - positions[:, h : h + n_steps]) / model.disp_std).abs()[:, :, ~kinematic].mean((1, 2, 3))


def snapped_to_grid(truth: torch.Tensor, values: torch.Tensor, offsets: torch.Tensor | None) -> torch.Tensor:
    """truth [B, P] normalised -> the nearest of the grid ``values`` [G], then, with ``offsets`` [R], the
    nearest of the refined values around it: what a perfect prior's argmin reads."""
    nearest = values[(truth.unsqueeze(-1) - values).abs().argmin(-1)]  # [B, P]
    if offsets is None:
        return nearest
    around = (nearest.unsqueeze(-1) + offsets).clamp(-1.0, 1.0)  # [B, P, R]
    return around.gather(-1, (truth.unsqueeze(-1) - around).abs().argmin(-1, keepdim=True))[..., 0]


def oracle_param_sweep(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int, grid: int = 9,
                       refine: int = 0, chunk: int = 16) -> dict:
    """Sweep each parameter over ``grid`` evenly spaced values of its range, then, with ``refine`` > 1,
    over ``refine`` evenly spaced values within one grid step either side of each scene's argmin.

    A coarse grid alone misreads the prior, whose own error can be most of the grid's; 9 + 9
    coarse-to-fine values cost 18 rollouts for the resolution of a 33-point grid.

    Args: model, a DynamicsPrior (``to_physical``, ``normalise_params``, ``disp_std``);
    positions [B, H + n_steps, N, 3] true; grouping [B, N, M]; rigidness [B, M]; params [B, P]
    physical, true; planes [B, H + n_steps, K, 4]; kinematic [N] bool. ``chunk``: scenes rolled
    at a time (the same numbers, bounded memory).
    Returns: ``oracle_params`` [B, P] (physical, the argmin per scene), ``oracle_param_mae_pct`` [P]
    (its error, % of range), ``oracle_param_bias_pct`` [P] (its mean signed error, oracle - truth: a
    prior that moves too little for the true P asks for a stronger one), ``grid_param_mae_pct`` [P] (what a perfect prior's argmin scores with
    this grid and refinement: the truth snapped to the nearest grid value, then to the nearest
    refined value around it; 25 / (grid - 1) % for uniform truth without refinement, so 3.1% of a
    9-point oracle is the grid's own), ``midpoint_param_mae_pct`` [P] (a constant guess at the
    middle of the range), ``loss_curve`` [P, grid] (mean rollout L1 of the coarse grid in units of
    the displacement std, the inference module's loss) and ``grid`` [grid] (normalised).
    """
    if grid < 2:
        raise ValueError(f"oracle_param_sweep: grid={grid}, expected at least 2 values")
    if refine == 1 or refine < 0:
        raise ValueError(f"oracle_param_sweep: refine={refine} (task.param_grid_refine or task.identifiability.refine), "
                         "expected 0 (the grid alone) or at least 2 values")
    values = torch.linspace(-1.0, 1.0, grid)
    step = 2.0 / (grid - 1)
    offsets = torch.linspace(-step, step, refine) if refine else None
    truth = model.normalise_params(params)  # [B, P] in [-1, 1]

    def best(j: int, candidates: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """candidates [B, C] normalised values of parameter j -> (argmin [B], losses [B, C])."""
        losses = []
        for c in candidates.unbind(1):
            guess = truth.clone()
            guess[:, j] = c
            losses.append(rollout_l1_per_scene(model, positions, grouping, rigidness, model.to_physical(guess), planes, kinematic, n_steps, chunk))
        loss = torch.stack(losses, 1)
        return candidates.gather(1, loss.argmin(1, keepdim=True))[:, 0], loss

    oracle, curves = [], []
    with torch.no_grad():
        for j in range(params.shape[1]):
            coarse, loss = best(j, values.expand(truth.shape[0], -1))
            curves.append(loss.mean(0))
            if refine:  # ties (the clamped ends) go to the first, as on the coarse grid
                coarse, _ = best(j, (coarse[:, None] + offsets).clamp(-1.0, 1.0))
            oracle.append(coarse)
    oracle = torch.stack(oracle, 1)  # [B, P]
    nearest = snapped_to_grid(truth, values, offsets)
    return {
        "oracle_params": model.to_physical(oracle),
        "oracle_param_mae_pct": ((oracle - truth).abs() * 50.0).mean(0),
        "oracle_param_bias_pct": ((oracle - truth) * 50.0).mean(0),
        "grid_param_mae_pct": ((nearest - truth).abs() * 50.0).mean(0),
        "midpoint_param_mae_pct": (truth.abs() * 50.0).mean(0),
        "loss_curve": torch.stack(curves),
        "grid": values,
    }


def rigidness_sweep(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int, types,
                    values=(0.0, 0.25, 0.5, 0.75, 1.0), chunk: int = 16) -> dict:
    """Does the prior's rollout loss, from the true frames and P, prefer each object type's true rigidness?

    For each type (``types`` names each of the M instances), the Q of all its instances is set to
    each of ``values`` (the first 0, the last 1) and every other instance keeps its true Q; the
    per-scene argmin is the "rigidness oracle". The inference module learns Q only through this
    loss, as it learns P: a type whose loss does not prefer its true label cannot be read right.

    Args: as ``oracle_param_sweep``; rigidness [B, M] true (0 or 1); types [M].
    Returns type -> {``l1`` [V] (the mean rollout L1 at each value, units of the displacement std),
    ``truth_preferred`` (share of scenes whose L1 at the true label is below the one at the
    opposite label), ``oracle_correct`` (the mean probability the per-scene argmin gives the true
    label, as task=evaluate's rigidness_prob)}, and ``values`` [V].
    """
    values = torch.as_tensor(values, dtype=torch.float32)
    if len(values) < 2 or values[0] != 0.0 or values[-1] != 1.0:
        raise ValueError(f"rigidness_sweep: values={values.tolist()}, expected at least two, from 0 (non-rigid) to 1 (rigid)")
    if len(types) != rigidness.shape[1]:
        raise ValueError(f"rigidness_sweep: {len(types)} type names for {rigidness.shape[1]} instances")
    result: dict = {"values": values}
    with torch.no_grad():
        for name in dict.fromkeys(types):
            members = torch.tensor([t == name for t in types])
            losses = []
            for v in values.tolist():
                q = torch.where(members, torch.full_like(rigidness, v), rigidness)
                losses.append(rollout_l1_per_scene(model, positions, grouping, q, params, planes, kinematic, n_steps, chunk))
            loss = torch.stack(losses, 1)  # [B, V]
            rigid = rigidness[:, members].mean(1) > 0.5  # [B] the type's true label
            at_truth, at_opposite = torch.where(rigid, loss[:, -1], loss[:, 0]), torch.where(rigid, loss[:, 0], loss[:, -1])
            argmin = values[loss.argmin(1)]
            result[name] = {"l1": loss.mean(0), "truth_preferred": float((at_truth < at_opposite).float().mean()),
                            "oracle_correct": float(torch.where(rigid, argmin, 1.0 - argmin).mean())}
    return result


def param_gradient_agreement(model, positions, grouping, rigidness, params, planes, kinematic, n_steps: int,
                             probes=(-0.75, -0.25, 0.25, 0.75), margin: float = 0.1, chunk: int = 16) -> dict:
    """Does the rollout L1's gradient in each parameter point to its true value?

    For parameter j and each probe value v (normalised, the other parameters at their true values),
    the rollout from the true history is differentiated in P_j at v. A scene *agrees* when
    -dL/dP_j has the sign of (truth_j - v); scenes whose truth is within ``margin`` of v are left
    out (their sign is the noise of a minimum). The prior's weights get no gradient.

    Args: as ``oracle_param_sweep`` (``chunk`` too). Returns: ``agreement`` [P, V] (share of the counted scenes that
    agree; a zero gradient does not agree), ``counted`` [P, V] (scenes counted), ``median_abs_grad``
    [P, V] (over all scenes, per normalised unit of P) and ``probes`` [V].
    """
    probes = torch.as_tensor(probes, dtype=torch.float32)
    truth = model.normalise_params(params).detach()  # [B, P]
    agreement, counted, magnitude = (torch.zeros(params.shape[1], len(probes)) for _ in range(3))
    for j in range(params.shape[1]):
        for k, v in enumerate(probes.tolist()):
            value = torch.full((params.shape[0],), v, requires_grad=True)
            guess = torch.cat([truth[:, :j], value[:, None], truth[:, j + 1 :]], 1)
            loss = rollout_l1_per_scene(model, positions, grouping, rigidness, model.to_physical(guess), planes, kinematic, n_steps, chunk)
            # a prior blind to P leaves the loss outside the graph: its gradient is zero
            grad = torch.autograd.grad(loss.sum(), value)[0] if loss.requires_grad else torch.zeros_like(value)
            away = (truth[:, j] - v).abs() > margin
            agrees = torch.sign(-grad) == torch.sign(truth[:, j] - v)
            counted[j, k] = away.sum()
            agreement[j, k] = agrees[away].float().mean() if away.any() else float("nan")
            magnitude[j, k] = grad.abs().median()
    return {"agreement": agreement, "counted": counted, "median_abs_grad": magnitude, "probes": probes}
