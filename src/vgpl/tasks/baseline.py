"""DensePhysNet baseline: task=train_baseline trains it to predict optical flow and fits the
linear (ridge) decoder from its representation to the parameter; task=evaluate model=densephysnet
reports its parameter error on the same test videos as VGPL."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
import lightning as L
import torch
from omegaconf import DictConfig
from torch.utils.data import DataLoader

from vgpl.atomic_write import atomic_path
from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.flow import flow_error
from vgpl.data.flow_cache import CachedFlow, ensure_flow_cache
from vgpl.data.flow_windows import FlowWindows
from vgpl.data.trajectories import load_split
from vgpl.eval.compare import PER_VIDEO_PARAM
from vgpl.eval.flow_statistics import window_flow_statistics
from vgpl.eval.linear_probe import Ridge
from vgpl.eval.paired import per_video_map
from vgpl.eval.tables import write_tables
from vgpl.metrics import param_error_pct
from vgpl.models.densephysnet import DensePhysNet
from vgpl.tasks.stage import fit, setup_run, stage_checkpoint, stopping

log = logging.getLogger(__name__)

MOTION_RIDGE = "motion_ridge.pt"  # the flow statistics' ridge, beside the checkpoint and its ridge.pt


class FlowDataModule(L.LightningDataModule):
    def __init__(self, train: FlowWindows, test: FlowWindows, batch_size: int) -> None:
        super().__init__()
        self.train, self.test, self.batch_size = train, test, batch_size

    def train_dataloader(self):
        return DataLoader(self.train, batch_size=self.batch_size, shuffle=True, drop_last=len(self.train) > self.batch_size)

    def val_dataloader(self):
        return DataLoader(self.test, batch_size=self.batch_size)


@torch.no_grad()
def features(model: DensePhysNet, windows: FlowWindows, batch_size: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """Pooled representations [R, F] and true parameters [R, P] of every window."""
    model.eval()
    feats, params = [], []
    for batch in DataLoader(windows, batch_size=batch_size):
        feats.append(model.representation(batch["frames"], batch["actions"]))
        params.append(batch["params"])
    return torch.cat(feats), torch.cat(params)


@torch.no_grad()
def flow_quality(model: DensePhysNet, windows: FlowWindows, batch_size: int = 8) -> dict:
    """End-point error of the predicted flow and of predicting zero flow on the pixels that move,
    and the correlation of predicted with true flow there. Windows with ``simulator_flow`` (estimated
    flow, ``reference=True``) also give that estimate's error against the simulator's flow
    (``flow_error``, per window, on the pixels the simulator moves)."""
    model.eval()
    epe, zero, preds, truths, estimate = [], [], [], [], []
    for batch in DataLoader(windows, batch_size=batch_size):
        if "simulator_flow" in batch:
            estimate += [flow_error(est, sim) for est, sim in zip(batch["flow"], batch["simulator_flow"])]
        flow, _ = model(batch["frames"], batch["actions"])
        moving = batch["flow"].norm(dim=-1) > 0
        epe.append((flow - batch["flow"]).norm(dim=-1)[moving].mean())
        zero.append(batch["flow"].norm(dim=-1)[moving].mean())
        preds.append(flow[moving].flatten()), truths.append(batch["flow"][moving].flatten())
    p, t = torch.cat(preds), torch.cat(truths)
    corr = float(torch.corrcoef(torch.stack([p, t]))[0, 1]) if p.numel() > 1 else 0.0
    quality = {"flow_epe": float(torch.stack(epe).mean()), "flow_epe_zero": float(torch.stack(zero).mean()), "flow_correlation": corr}
    if estimate:
        quality |= {"estimated_flow_epe": sum(e["epe"] for e in estimate) / len(estimate),
                    "estimated_flow_epe_zero": sum(e["epe_zero"] for e in estimate) / len(estimate)}
    return quality


def _windows(cfg: DictConfig, scene, rollouts, stride: int | None, reference: bool = False, split: str | None = None) -> FlowWindows:
    """The baseline's windows of ``rollouts``; with estimated flow and a ``split``, read from that
    split's flow cache (computed once, next to the shards)."""
    spec = cfg.model.densephysnet
    windows = FlowWindows(rollouts, scene.camera, spec.observed, cfg.env.get("start_frame", 0), stride, spec.flow, reference)
    if spec.flow != "simulator" and split is not None:
        path = ensure_flow_cache(cfg.data.root, scene.name, split, rollouts, windows.pairs_needed, bool(cfg.data.get("progress", False)))
        windows.cache = CachedFlow(path)
    return windows


def _videos(cfg: DictConfig, scene, split: str, max_rollouts, stream: bool = False):
    return load_split(cfg.data.root, scene.name, split, images=True, max_rollouts=max_rollouts, stream=stream)


def train_baseline(cfg: DictConfig) -> dict:
    setup_run(cfg)
    scene = scene_of(cfg)
    spec = cfg.model.densephysnet
    train_videos = _videos(cfg, scene, "train", spec.get("max_rollouts"), bool(spec.get("stream_video", False)))
    train = _windows(cfg, scene, train_videos, spec.window_stride, split="train")
    test = _windows(cfg, scene, _videos(cfg, scene, "test", cfg.eval.get("max_rollouts")), None, split="test")
    model = hydra.utils.instantiate(spec.net, action_dim=scene.action_dim)
    trainer, last = fit(cfg, "densephysnet", spec, model, FlowDataModule(train, test, spec.batch_size))
    if not trainer.is_global_zero:  # under DDP rank 0 alone evaluates and writes
        return {"env": scene.name, "checkpoint": str(last)}
    # the linear decoder: one representation per training rollout, at the evaluation protocol's window
    probe = _windows(cfg, scene, train_videos, None, split="train")
    ridges = {"ridge.pt": Ridge.fit(*features(model, probe), spec.ridge_alpha),
              MOTION_RIDGE: Ridge.fit(*window_flow_statistics(probe), spec.ridge_alpha)}  # the motion alone, for the report's probe
    for name, ridge in ridges.items():
        with atomic_path(last.parent / name) as tmp:
            torch.save(ridge.state_dict(), tmp)
    result = {"env": scene.name, "checkpoint": str(last), **stopping(trainer), **flow_quality(model, test)}
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    log.info("DensePhysNet: %s", result)
    return result


def motion_alone(cfg: DictConfig, scene, test: FlowWindows, checkpoint: Path) -> torch.Tensor:
    """P [R, P] of the ``test`` windows as a ridge from their flow's statistics reads it
    (vgpl.eval.flow_statistics), fitted on the same training videos and evaluation window as
    DensePhysNet's decoder: how much of its score the visible motion explains without a network.
    The ridge task=train_baseline saved beside ``checkpoint``; for a checkpoint without one, fitted
    here on the training videos."""
    saved = checkpoint.parent / MOTION_RIDGE
    if saved.is_file():
        ridge = Ridge(**torch.load(saved))
    else:
        spec = cfg.model.densephysnet
        train = _windows(cfg, scene, _videos(cfg, scene, "train", spec.get("max_rollouts")), None, split="train")
        ridge = Ridge.fit(*window_flow_statistics(train), spec.ridge_alpha)
    return ridge.predict(window_flow_statistics(test)[0])


def evaluate_baseline(cfg: DictConfig) -> dict:
    setup_run(cfg)
    scene = scene_of(cfg)
    ckpt = stage_checkpoint(cfg, "densephysnet")
    model, _ = load_stage(ckpt, DensePhysNet, env=scene.name, n_particles=scene.n_particles)
    ridge_file = ckpt.parent / "ridge.pt"
    if not ridge_file.is_file():
        raise FileNotFoundError(f"{ridge_file}: missing; task=train_baseline writes the linear decoder beside the checkpoint")
    ridge = Ridge(**torch.load(ridge_file))
    videos = _videos(cfg, scene, "test", cfg.eval.get("max_rollouts"))
    test = _windows(cfg, scene, videos, None, split="test")
    x, y = features(model, test)
    low, high = torch.as_tensor(scene.param_low, dtype=torch.float32), torch.as_tensor(scene.param_high, dtype=torch.float32)
    err = param_error_pct(ridge.predict(x).clamp(low, high), y, test.r.param_low, test.r.param_high).mean(1)
    motion = motion_alone(cfg, scene, test, ckpt)
    motion_err = param_error_pct(motion.clamp(low, high), y, test.r.param_low, test.r.param_high).mean(1)
    record = {"env": scene.name, "method": "densephysnet", "ablation": "full", "n_test": len(test), "checkpoints": {"densephysnet": str(ckpt)},
              "param_mae_pct": float(err.mean()), "param_mae_pct_std": float(err.std()), "flow": test.flow,
              "flow_statistics_param_mae_pct": float(motion_err.mean()),
              **flow_quality(model, _windows(cfg, scene, videos, None, reference=True, split="test")),
              PER_VIDEO_PARAM: per_video_map(videos.rollout_ids, err)}  # one window a video: paired by task=compare
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(record, indent=1))
    write_tables([record], out)
    return record
