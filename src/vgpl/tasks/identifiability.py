"""How far the trained dynamics prior pins down P, from a checkpoint: the sweep that
``task=evaluate_dynamics`` reports, and the pipeline's gate before the inference module trains.

The inference module can only ground P through the prior's rollout loss. When the per-scene
argmin of that loss over P (the "oracle", ``vgpl.eval.identifiability``) is no better than a
constant mid-range guess, training the inference module cannot ground P either, and the sweep
costs minutes where the training costs much more.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import torch
from omegaconf import DictConfig

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.inference_windows import proposals_path
from vgpl.data.proposals import read_proposals
from vgpl.data.schema import DatasetError
from vgpl.data.trajectories import Rollouts, load_split, true_window
from vgpl.eval.figures import gradient_agreement_figure, params_figure, save
from vgpl.eval.identifiability import oracle_param_sweep, param_gradient_agreement, rigidness_sweep
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.nn.rigid_start import rigid_start
from vgpl.sim.scene import Scene
from vgpl.tasks.stage import stage_checkpoint

log = logging.getLogger(__name__)

ON_FAIL = ("warn", "stop", "off")


class IdentifiabilityError(RuntimeError):
    """The dynamics prior's rollout loss does not identify a physical parameter."""


def inference_window(scene: Scene, test: Rollouts, observed: int, horizon: int, start_frame: int, max_rollouts: int | None) -> tuple:
    """``true_window`` over the inference module's window (``observed`` frames from ``start_frame`` on,
    plus ``horizon``) of the first ``max_rollouts`` test rollouts (None: all), the window the prior's
    sweeps roll; refused when it runs past the rollouts' end."""
    n_frames = observed + horizon
    if start_frame + n_frames > test.positions.shape[1]:
        raise ValueError(f"identifiability: {start_frame} + {observed} observed + {horizon} frames exceed the {test.positions.shape[1]}-frame rollouts")
    n = test.positions.shape[0] if max_rollouts is None else min(max_rollouts, test.positions.shape[0])
    return true_window(scene, test, start_frame, n_frames, n)


def check_sweep_rigidness(value) -> float | None:
    """Refuse a ``task.param_sweep_rigidness`` that is neither null (the true labels) nor a Q in [0, 1]."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
        raise ValueError(f"task.param_sweep_rigidness={value!r}: expected null (every instance's true label) or a rigidness Q in [0, 1] "
                         "given to every instance (0: as VGPL w/o rigidness's prior sees them)")
    return float(value)


def check_sweep_frames(history: str, target: str) -> None:
    """Refuse a ``task.param_sweep_history`` other than ``truth``, ``proposals`` or ``proposals_rigid``, or a
    ``task.param_sweep_target`` other than ``truth`` or ``proposals``."""
    if history not in ("truth", "proposals", "proposals_rigid"):
        raise ValueError(f"task.param_sweep_history={history!r}: expected 'truth' (the simulator's positions), 'proposals' "
                         "(the VisualPrior's exported test proposals) or 'proposals_rigid' (those, each rigid instance fitted "
                         "rigidly to its shape in the last start frame)")
    if target not in ("truth", "proposals"):
        raise ValueError(f"task.param_sweep_target={target!r}: expected 'truth' (the simulator's positions) or 'proposals' "
                         "(the VisualPrior's exported test proposals)")


def evaluate_identifiability(model: DynamicsPrior, scene: Scene, test: Rollouts, root: str, observed: int, horizon: int, grid: int,
                             max_rollouts: int | None = None, start_frame: int = 0, history: str = "truth", refine: int = 0,
                             rigidness: float | None = None, target: str = "truth") -> dict:
    """``oracle_param_sweep`` on the first ``max_rollouts`` rollouts of the test split ``test``
    (read from ``root``), over the inference module's training window: ``observed`` frames from
    ``start_frame`` on plus ``horizon`` more, rolled from the first H, over ``grid`` values and then
    ``refine`` around each scene's best. ``history="proposals"``
    starts the rollouts from the VisualPrior's exported proposals instead of the true positions
    (what an inference module without refinement would see); ``"proposals_rigid"`` from those with every
    rigid instance fitted rigidly to its shape in the last start frame (``rigid_start``). ``target="proposals"`` compares the
    rollouts with the proposals of the frames they roll into instead of the true positions (the loss
    of ``rollout_target=proposals``, a module trained without trajectories). Actuated (kinematic)
    particles stay where the actions put them in both, as the inference module places them.
    ``rigidness``: the Q every instance is rolled with (None: the true labels; 0: the prior of VGPL
    w/o rigidness)."""
    check_sweep_frames(history, target)
    h = model.hparams.history
    positions, grouping, labels, params, planes, kinematic = inference_window(scene, test, observed, horizon, start_frame, max_rollouts)
    labels = labels if rigidness is None else torch.full_like(labels, rigidness)
    n, n_frames = positions.shape[:2]
    if history != "truth" or target == "proposals":
        path = proposals_path(root, scene.name, "test")
        proposals = read_proposals(path, "last")  # the paper's proposals; the slots stay on disk
        first = start_frame if history != "truth" else start_frame + h
        last = start_frame + (n_frames if target == "proposals" else h) - 1
        if proposals.positions.shape[0] < n or not torch.equal(proposals.rollout_ids[:n], test.rollout_ids[:n]) or proposals.positions.shape[1] <= last:
            raise DatasetError(f"{path}: proposals do not cover the first {n} test rollouts' frames {first}..{last}; re-export with task=export_proposals "
                               "(rollout_target=proposals exports the frames past the observed window too)")
        frames = slice(first - start_frame, last - start_frame + 1)  # the window's frames taken from the proposals, one contiguous run
        positions[:, frames] = torch.where(kinematic[:, None], positions[:, frames], proposals.positions[:n, first : last + 1].to(positions))
    if history == "proposals_rigid":
        positions[:, :h] = rigid_start(positions[:, :h], grouping, (labels > 0.5).to(positions), kinematic)
    model.eval()
    return oracle_param_sweep(model, positions, grouping, labels, params, planes, kinematic, n_frames - h, grid, refine) | {"truth": params}


def sweep_metrics(model: DynamicsPrior, scene: Scene, test: Rollouts, cfg: DictConfig, start_frame: int, out: Path, grid: int,
                  max_rollouts: int | None, history: str = "truth", refine: int = 0, rigidness: float | None = None,
                  target: str = "truth") -> dict:
    """Run the sweep over ``cfg.model.inference``'s window from ``start_frame`` on and return its flat metrics
    (``oracle_param_mae_pct/<name>``, ``oracle_param_bias_pct/<name>``, ``grid_param_mae_pct/<name>``, ``midpoint_param_mae_pct/<name>``,
    ``rollout_l1_over_grid/<name>``);
    the scatter of oracle against truth goes to ``out/oracle_<name>.png``."""
    inf = cfg.model.inference
    sweep = evaluate_identifiability(model, scene, test, cfg.data.root, inf.observed, inf.horizon, grid, max_rollouts, start_frame, history, refine,
                                     rigidness, target)
    result: dict = {"param_sweep_history": history, "param_sweep_target": target, "param_grid": grid, "param_grid_refine": refine,
                    "param_sweep_rigidness": rigidness}
    for j, name in enumerate(scene.param_names):
        result[f"oracle_param_mae_pct/{name}"] = float(sweep["oracle_param_mae_pct"][j])
        result[f"oracle_param_bias_pct/{name}"] = float(sweep["oracle_param_bias_pct"][j])
        result[f"grid_param_mae_pct/{name}"] = float(sweep["grid_param_mae_pct"][j])
        result[f"midpoint_param_mae_pct/{name}"] = float(sweep["midpoint_param_mae_pct"][j])
        result[f"rollout_l1_over_grid/{name}"] = [round(float(v), 5) for v in sweep["loss_curve"][j]]
        save(params_figure(sweep["truth"][:, j], sweep["oracle_params"][:, j], float(scene.param_low[j]), float(scene.param_high[j]), name,
                           f"{scene.name}: argmin of the prior's rollout L1"), out / f"oracle_{name}.png")
    return result


def check_rigidness_grid(values: int) -> None:
    """Refuse a ``task.rigidness_grid`` that cannot hold both labels (0 and 1)."""
    if values < 2:
        raise ValueError(f"task.rigidness_grid={values}: expected 0 (skip) or at least 2 values from 0 to 1")


def rigidness_grid_option(value) -> int:
    """A config's rigidness grid (None or 0: no sweep), refused by ``check_rigidness_grid`` before any rollout when it cannot sweep."""
    values = int(value or 0)
    if values > 0:
        check_rigidness_grid(values)
    return values


def rigidness_metrics(model: DynamicsPrior, scene: Scene, test: Rollouts, cfg: DictConfig, start_frame: int, values: int,
                      max_rollouts: int | None) -> dict:
    """``rigidness_sweep`` of each object type's Q over ``values`` evenly spaced values in [0, 1], over
    ``cfg.model.inference``'s window (from ``start_frame`` on) from the true frames and P of the first ``max_rollouts`` test
    rollouts: ``rollout_l1_over_rigidness/<type>`` [values], ``rigidness_truth_preferred/<type>`` and
    ``rigidness_oracle_correct/<type>`` (docs/design.md)."""
    check_rigidness_grid(values)
    inf = cfg.model.inference
    window = inference_window(scene, test, inf.observed, inf.horizon, start_frame, max_rollouts)
    model.eval()
    sweep = rigidness_sweep(model, *window, window[0].shape[1] - model.hparams.history, scene.instance_types,
                            torch.linspace(0.0, 1.0, values).tolist())
    result: dict = {"rigidness_grid": sweep["values"].tolist()}
    for name in dict.fromkeys(scene.instance_types):
        result[f"rollout_l1_over_rigidness/{name}"] = [round(float(v), 5) for v in sweep[name]["l1"]]
        result[f"rigidness_truth_preferred/{name}"] = sweep[name]["truth_preferred"]
        result[f"rigidness_oracle_correct/{name}"] = sweep[name]["oracle_correct"]
    return result


def check_window_starts(starts: list[int], n_frames: int, observed: int, horizon: int) -> None:
    """Refuse ``task.gradient_starts`` whose windows (``observed`` + ``horizon`` frames) leave ``n_frames``-frame rollouts."""
    last = n_frames - observed - horizon
    if not starts or min(starts) < 0 or max(starts) > last:
        raise ValueError(f"task.gradient_starts={list(starts)}: every start + {observed} observed + {horizon} frames must fit in the "
                         f"{n_frames}-frame rollouts (starts 0..{last})")


def gradient_agreement_by_start(model: DynamicsPrior, scene: Scene, test: Rollouts, observed: int, horizon: int, starts: list[int],
                                out: Path, max_rollouts: int | None = None) -> dict:
    """``param_gradient_agreement`` over windows of the inference module's length (``observed`` +
    ``horizon`` frames, from the true history) starting at each frame of ``starts``, on the first
    ``max_rollouts`` test rollouts. Which windows teach P? Those whose gradient points to the truth.

    Returns ``param_gradient_agreement/<name>``: {start: [share per probe]}, and
    ``param_gradient_median_abs/<name>`` the same for the median |dL/dP|; the curves go to
    ``out/gradient_agreement_<name>.png``."""
    check_window_starts(starts, test.positions.shape[1], observed, horizon)
    model.eval()
    rows = []
    for start in starts:
        rows.append(param_gradient_agreement(model, *inference_window(scene, test, observed, horizon, start, max_rollouts),
                                             observed + horizon - model.hparams.history))
        log.info("gradient agreement, window from frame %d: %s", start, [[round(v, 3) for v in r] for r in rows[-1]["agreement"].tolist()])
    result: dict = {"gradient_starts": list(starts), "gradient_probes": rows[0]["probes"].tolist()}
    for j, name in enumerate(scene.param_names):
        agreement = torch.stack([r["agreement"][j] for r in rows])  # [S, V]
        result[f"param_gradient_agreement/{name}"] = {str(s): [round(float(v), 4) for v in a] for s, a in zip(starts, agreement)}
        result[f"param_gradient_median_abs/{name}"] = {str(s): [round(float(r["median_abs_grad"][j, k]), 5) for k in range(len(r["probes"]))]
                                                       for s, r in zip(starts, rows)}
        save(gradient_agreement_figure(list(starts), agreement, rows[0]["probes"], name, f"{scene.name}: which windows teach {name}"),
             out / f"gradient_agreement_{name}.png")
    return result


def unidentified(metrics: dict, names, max_ratio: float) -> dict[str, tuple[float, float]]:
    """Parameters whose oracle MAE is not below ``max_ratio`` x the midpoint's: {name: (oracle, midpoint)}."""
    failed = {}
    for name in names:
        oracle, midpoint = metrics[f"oracle_param_mae_pct/{name}"], metrics[f"midpoint_param_mae_pct/{name}"]
        if not oracle < max_ratio * midpoint:
            failed[name] = (oracle, midpoint)
    return failed


def identifiability_summary(result: dict) -> str:
    """One Markdown line per parameter for the pipeline's report."""
    lines = [f"\nIdentifiability of P through the dynamics prior (oracle argmin of its rollout L1, {result['checkpoint']}):\n"]
    refine = result["param_grid_refine"]
    grid = f"{result['param_grid']}-point grid" + (f", refined by {refine} values around each scene's best" if refine else "")
    for name in result["param_names"]:
        lines.append(f"- {name}: oracle {result[f'oracle_param_mae_pct/{name}']:.1f}% (mean signed error "
                     f"{result[f'oracle_param_bias_pct/{name}']:+.1f}) against the range midpoint's "
                     f"{result[f'midpoint_param_mae_pct/{name}']:.1f}% (a perfect prior on this {grid}: "
                     f"{result[f'grid_param_mae_pct/{name}']:.1f}%; task.identifiability.grid and .refine set it)")
    for name in result.get("rigidness_types", []):
        curve = " / ".join(f"{v:.3f}" for v in result[f"rollout_l1_over_rigidness/{name}"])
        q = " / ".join(f"{v:g}" for v in result["rigidness_grid"])
        lines.append(f"- rigidness of {name}: the true label rolls better than the opposite one in "
                     f"{100 * result[f'rigidness_truth_preferred/{name}']:.0f}% of scenes (rollout L1 at Q = {q}: {curve})")
    return "\n".join(lines) + "\n"


def unpreferred_labels(metrics: dict, types) -> dict[str, float]:
    """Object types whose true rigidness the prior's rollout loss prefers to the opposite label in
    fewer than half the scenes: {type: that share}."""
    return {t: metrics[f"rigidness_truth_preferred/{t}"] for t in types if metrics[f"rigidness_truth_preferred/{t}"] < 0.5}


def check_identifiability(cfg: DictConfig) -> dict:
    """Pipeline step between ``train_dynamics`` and ``train_inference``: sweep P through the trained
    prior (``cfg.task.identifiability``: grid, max_rollouts, max_ratio, on_fail) and write
    ``identifiability.json``. ``on_fail=warn`` logs a warning, ``stop`` raises IdentifiabilityError
    (every checkpoint so far is kept; ``ckpt_path=last`` resumes), ``off`` skips the sweep.
    With ``rigidness_grid`` > 0 it also sweeps each object type's Q and warns (never stops) when
    the prior prefers the opposite of a type's true label in most scenes."""
    spec = cfg.task.identifiability
    if spec.on_fail not in ON_FAIL:
        raise ValueError(f"task.identifiability.on_fail={spec.on_fail!r}: expected one of {list(ON_FAIL)}")
    if spec.on_fail == "off":
        return {"skipped": True}
    q_grid = rigidness_grid_option(spec.get("rigidness_grid"))
    scene = scene_of(cfg)
    path = stage_checkpoint(cfg, "dynamics")
    model, _ = load_stage(path, DynamicsPrior, env=scene.name, n_particles=scene.n_particles)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    test = load_split(cfg.data.root, scene.name, "test", max_rollouts=spec.get("max_rollouts"))  # only the videos swept
    # the window the inference module about to train will see: this run's start_frame
    start = int(cfg.env.get("start_frame", 0))
    metrics = sweep_metrics(model, scene, test, cfg, start, out, int(spec.grid), spec.get("max_rollouts"), refine=int(spec.get("refine", 0)))
    types = list(dict.fromkeys(scene.instance_types)) if q_grid > 0 else []
    if types:
        metrics |= rigidness_metrics(model, scene, test, cfg, start, q_grid, spec.get("max_rollouts"))
    failed = unidentified(metrics, scene.param_names, float(spec.max_ratio))
    result = {"env": scene.name, "checkpoint": str(path), "param_names": list(scene.param_names), "rigidness_types": types, **metrics,
              "max_ratio": float(spec.max_ratio), "identified": not failed}
    (out / "identifiability.json").write_text(json.dumps(result, indent=1))
    log.info(identifiability_summary(result))
    if failed:
        detail = "; ".join(f"{n}: oracle {o:.1f}% against the midpoint's {m:.1f}% (needs < {spec.max_ratio} x)" for n, (o, m) in failed.items())
        message = (f"{path}: the prior's rollout loss does not identify {detail}. No inference module can ground it through this "
                   f"prior: retrain it, or lengthen model.inference.horizon (task.identifiability.on_fail=warn goes on anyway)")
        if spec.on_fail == "stop":
            raise IdentifiabilityError(message)
        log.warning(message)
    wrong = unpreferred_labels(metrics, types)
    if wrong:  # a warning only: Q still trains, but to the blend this loss prefers
        detail = "; ".join(f"{t}: the true label rolls better in {100 * share:.0f}% of scenes" for t, share in wrong.items())
        log.warning(f"{path}: the prior's rollout loss does not prefer the true rigidness ({detail}). The inference module learns Q "
                    "only through that loss, so Q will read the blend it prefers, and VGPL w/o rigidness can match or beat VGPL at "
                    "T+20. At a constant learning rate a prior's raw weights can swing between checkpoints, and their moving average "
                    "steadies them: train the prior with model.dynamics.ema.decay=0.999 (RigidFall's standard preset does) and "
                    "sweep it again (task=evaluate_dynamics task.rigidness_grid=5)")
    return result
