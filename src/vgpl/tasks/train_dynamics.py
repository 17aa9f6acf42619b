"""task=train_dynamics: train the DynamicsPrior on ground-truth G, Q, P, then evaluate rollouts;
task=evaluate_dynamics: the same evaluation from a checkpoint path alone."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from vgpl.checkpoint import init_from_spec, load_stage, scene_of
from vgpl.data.flex_rollouts import as_rollouts, read_flex_rollouts
from vgpl.data.schema import DatasetError
from vgpl.data.trajectories import Rollouts, TrajectoryDataModule, load_split, true_window
from vgpl.eval.error_breakdown import error_breakdown
from vgpl.eval.preview import write_gif
from vgpl.eval.tensorboard_media import add_gif, rollout_video
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.rollout import NO_MOTION, future_mse, rollout
from vgpl.sim.scene import Scene
from vgpl.tasks.identifiability import (
    check_sweep_frames,
    check_sweep_rigidness,
    check_window_starts,
    gradient_agreement_by_start,
    rigidness_grid_option,
    rigidness_metrics,
    sweep_metrics,
)
from vgpl.tasks.stage import dynamics_stage, fit, setup_run, stopping

log = logging.getLogger(__name__)


def evaluate_rollouts(
    model: DynamicsPrior, scene: Scene, test: Rollouts, observed: int, n_steps: int, max_rollouts: int | None = None, start_frame: int = 0
) -> tuple[dict, torch.Tensor, torch.Tensor]:
    """Future MSE x 1e4 on the test split ``test``: observe ``observed`` frames from ``start_frame``
    on, roll ``n_steps`` forward, on its first ``max_rollouts`` rollouts. ``metrics`` also holds the
    same error of the guess that nothing moves after the last observed frame (``no_motion_mse_x1e4@k``,
    the scale the prior's is read against) and ``breakdown@<n_steps>``: where the error at the last
    predicted frame comes from (per instance, centroid share, by parameter; ``vgpl.eval.error_breakdown``).

    Returns: (metrics, predictions [R, n_steps, N, 3], ground truth [R, n_steps, N, 3]).
    """
    h = model.hparams.history
    start = start_frame + observed - h
    if start + h + n_steps > test.positions.shape[1]:
        raise ValueError(f"eval: {start_frame} + {observed} observed + {n_steps} predicted frames exceed the {test.positions.shape[1]}-frame rollouts")
    n = test.positions.shape[0] if max_rollouts is None else min(max_rollouts, test.positions.shape[0])
    positions, grouping, rigidness, params, planes, kinematic = true_window(scene, test, start, h + n_steps, n)
    model.eval()
    with torch.no_grad():
        pred = rollout(model, positions, grouping, rigidness, params, planes, kinematic, n_steps)
    truth = positions[:, h:]
    breakdown = error_breakdown(pred, truth, torch.as_tensor(scene.instance), params, n_steps, list(scene.param_names))
    still = positions[:, h - 1 : h].expand_as(truth)  # the last observed frame, held
    return future_mse(pred, truth) | future_mse(still, truth, key=NO_MOTION) | {f"breakdown@{n_steps}": breakdown}, pred, truth


def train_dynamics(cfg: DictConfig) -> dict:
    """Train the DynamicsPrior into ``<ckpt_dir>/dynamics/`` (``dynamics_unconstrained/`` with
    ``model.dynamics.net.rigid_head=none``) and evaluate its test rollouts."""
    setup_run(cfg)
    scene = scene_of(cfg)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = cfg.model.dynamics
    dm = TrajectoryDataModule(cfg.data.root, scene, history=spec.history, horizon=spec.net.get("rollout_steps", 1), batch_size=spec.batch_size, start_frame=cfg.env.get("start_frame", 0),
                             train_span=spec.get("window_span"))
    dm.setup()
    model: DynamicsPrior = hydra.utils.instantiate(
        spec.net, _convert_="all", param_low=scene.param_low.tolist(), param_high=scene.param_high.tolist(),
        n_instances=scene.n_instances, radius=cfg.env.graph_radius, history=spec.history,
    )
    model.set_stats(dm.stats)
    stage = dynamics_stage(model.hparams.rigid_head == "none")
    init_from_spec(model, spec, "dynamics", scene.name, scene.n_particles)
    trainer, last = fit(cfg, stage, spec, model, dm)
    if not trainer.is_global_zero:  # under DDP the other ranks stop here; rank 0 evaluates and writes
        return {"env": scene.name, "checkpoint": str(last)}
    metrics, pred, truth = evaluate_rollouts(
        model, scene, load_split(cfg.data.root, scene.name, "test"), cfg.eval.observed, cfg.eval.n_steps, cfg.eval.get("max_rollouts"),
        cfg.env.get("start_frame", 0),
    )
    writer = trainer.logger.experiment
    scalars = {k: v for k, v in metrics.items() if not isinstance(v, dict)}  # breakdown@<n> goes to metrics.json only
    for key, value in scalars.items():
        writer.add_scalar(f"test/{key}", value, trainer.global_step)
    add_gif(writer, "test/rollout_truth_vs_prediction", rollout_video(scene.camera, scene.instance, truth[0], pred[0]), trainer.global_step)
    writer.flush()
    result = {"env": scene.name, "checkpoint": str(last), **stopping(trainer), "max_degree": model.max_degree_seen, **metrics}
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    log.info("test rollouts: %s", scalars)
    return result


def load_dynamics(path: str | Path, env: str | None = None) -> tuple[DynamicsPrior, DictConfig]:
    """Model and resolved training config from a checkpoint path alone (config.yaml beside it)."""
    return load_stage(path, DynamicsPrior, env=env)


def window_start(override: int | None, trained: int, n_frames: int) -> int:
    """The first frame evaluate_dynamics' windows start at: ``task.start_frame`` when given, else the
    prior's own ``env.start_frame`` (``trained``); refused unless 0 <= it < ``n_frames``."""
    if override is None:
        return int(trained)
    if not isinstance(override, int) or isinstance(override, bool) or not 0 <= override < n_frames:
        raise ValueError(f"task.start_frame={override!r}: expected null (the prior's env.start_frame, {trained}) or a frame in 0..{n_frames - 1} of the test rollouts")
    return override


def evaluate_dynamics(cfg: DictConfig) -> dict:
    if cfg.get("ckpt_path") in (None, "???"):
        raise ValueError("task=evaluate_dynamics needs ckpt_path=<path to a .ckpt>")
    model, train_cfg = load_dynamics(cfg.ckpt_path, env=cfg.env.name)  # env= is honoured: another env's prior is refused, naming both
    scene = scene_of(train_cfg)
    root = cfg.data.root
    flex = cfg.task.get("flex_rollouts")
    test = as_rollouts(read_flex_rollouts(flex, scene.name), scene) if flex else load_split(root, scene.name, "test")
    if test.positions.shape[2] != scene.n_particles:
        raise DatasetError(f"{root}/{scene.name}: {test.positions.shape[2]} particles, checkpoint {cfg.ckpt_path} expects {scene.n_particles}")
    starts = list(cfg.task.get("gradient_starts") or [])
    if starts:  # refused before an hour of rollouts, not after
        check_window_starts(starts, test.positions.shape[1], cfg.model.inference.observed, cfg.model.inference.horizon)
    q_grid = rigidness_grid_option(cfg.task.get("rigidness_grid"))  # so is a grid without both labels
    sweep_rigidness = check_sweep_rigidness(cfg.task.get("param_sweep_rigidness"))
    sweep_history, sweep_target = cfg.task.get("param_sweep_history", "truth"), cfg.task.get("param_sweep_target", "truth")
    check_sweep_frames(sweep_history, sweep_target)
    start = window_start(cfg.task.get("start_frame"), train_cfg.env.get("start_frame", 0), test.positions.shape[1])
    metrics, pred, truth = evaluate_rollouts(model, scene, test, cfg.eval.observed, cfg.eval.n_steps, cfg.eval.get("max_rollouts"), start)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)  # run.py's Hydra makes it; a direct call may not have
    result = {"env": scene.name, "checkpoint": str(cfg.ckpt_path), "test": flex or "test split", "start_frame": start, **metrics}
    # metrics.json is rewritten after each part, so a later part that fails or is stopped (no
    # proposals; the gradient agreement can take an hour) keeps the numbers of the earlier ones
    write_metrics = lambda: (out / "metrics.json").write_text(json.dumps(result, indent=1))  # noqa: E731
    write_metrics()
    write_gif(rollout_video(scene.camera, scene.instance, truth[0], pred[0]), out / "rollout_truth_vs_prediction.gif", fps=15)
    grid = int(cfg.task.get("param_grid", 0))
    if grid > 0:
        result |= sweep_metrics(model, scene, test, cfg, start, out, grid, cfg.eval.get("max_rollouts"), sweep_history,
                                int(cfg.task.get("param_grid_refine", 0)), sweep_rigidness, sweep_target)
        log.info("identifiability: %s", {k: v for k, v in result.items() if "param_mae" in k})
        write_metrics()
    if q_grid > 0:
        result |= rigidness_metrics(model, scene, test, cfg, start, q_grid, cfg.eval.get("max_rollouts"))
        log.info("rigidness through the prior: %s", {k: v for k, v in result.items() if k.startswith("rigidness_")})
        write_metrics()
    if starts:
        inf = cfg.model.inference
        result |= gradient_agreement_by_start(model, scene, test, inf.observed, inf.horizon, starts, out, cfg.eval.get("max_rollouts"))
        write_metrics()
    return result
