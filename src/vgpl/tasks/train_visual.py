"""task=train_visual: train the VisualPrior on rendered video; task=export_proposals: run it over
every video with the paper's sliding window and write the proposals of each split to HDF5
(``task.source=truth`` writes the recorded particles instead, a perfect visual prior for diagnosis)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.inference_windows import proposals_path
from vgpl.data.proposals import Proposals, proposal_source, propose_windows, truth_proposals, write_proposals
from vgpl.data.shard import read_first_rollouts
from vgpl.data.trajectories import load_split
from vgpl.data.video import VideoDataModule
from vgpl.models.rollout_target import future_proposal_frames
from vgpl.models.visual_prior import VisualPrior
from vgpl.tasks.stage import fit, setup_run, stage_checkpoint, stopping

log = logging.getLogger(__name__)


def train_visual(cfg: DictConfig) -> dict:
    """Train the VisualPrior into ``<ckpt_dir>/visual/``; returns the test position MSE x 1e4 (metres^2)."""
    setup_run(cfg)
    scene = scene_of(cfg)
    spec = cfg.model.visual
    dm = VideoDataModule(cfg.data.root, scene.name, spec.frames, spec.batch_size, cfg.env.get("start_frame", 0), spec.frame_stride,
                         spec.max_rollouts, cfg.eval.get("max_rollouts"), stream=bool(spec.get("stream_video", False)),
                         first_rollout=int(spec.get("first_rollout", 0)))
    dm.setup()
    model: VisualPrior = hydra.utils.instantiate(spec.net, _convert_="all", n_particles=scene.n_particles, n_instances=scene.n_instances, frames=spec.frames)
    model.set_stats(dm.stats)
    model.set_camera(scene.camera)
    model.set_structure(scene)
    trainer, last = fit(cfg, "visual", spec, model, dm)
    if not trainer.is_global_zero:  # under DDP rank 0 alone evaluates and writes
        return {"env": scene.name, "checkpoint": str(last)}
    model.eval()
    errors, correct, count = [], 0, 0
    with torch.no_grad():
        for batch in dm.val_dataloader():
            pos, logits = model.propose(batch["frames"])
            errors.append(((pos - batch["positions"]) ** 2).mean((1, 2, 3)))
            correct += int((logits.argmax(-1) == batch["instance"][:, None]).sum())
            count += logits.shape[0] * logits.shape[1] * logits.shape[2]
    result = {"env": scene.name, "checkpoint": str(last), **stopping(trainer), "visual_mse_x1e4": float(torch.cat(errors).mean() * 1e4), "grouping_accuracy": correct / max(count, 1)}
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    log.info("visual prior on the test split: %s", result)
    return result


def export_split(model: VisualPrior, root: str, env: str, split: str, checkpoint: str, max_rollouts: int | None = None, progress: bool = True,
                 max_frames: int | None = None) -> Path:
    """Proposals for the first ``max_frames`` frames (None: all) of the first ``max_rollouts``
    rollouts of a split, shard by shard (bounded memory), with every window's slots (``window_pool``)."""
    files = sorted((Path(root) / env / split).glob("shard_*.h5"))
    if not files:
        raise FileNotFoundError(f"{Path(root) / env / split}: no shard_*.h5 files (generate them with task=generate env={env})")
    positions, logits, slots, ids = [], [], [], []
    for _, shard in read_first_rollouts(files, max_rollouts, images=True, frames=max_frames):
        p, g, k = propose_windows(model, torch.as_tensor(shard.images), progress=progress)
        positions.append(p), logits.append(g), slots.append(k), ids.append(torch.as_tensor(shard.rollout_ids))
    prop = Proposals(torch.cat(positions), torch.cat(logits), torch.cat(ids),
                     {"env": env, "split": split, "visual_checkpoint": checkpoint, "source": "visual", "noise_std": 0.0}, torch.cat(slots))
    return write_proposals(proposals_path(root, env, split), prop)


def export_truth_split(root: str, env: str, split: str, noise_std: float, seed: int, max_rollouts: int | None = None,
                       max_frames: int | None = None) -> Path:
    """``truth_proposals`` of the first ``max_frames`` frames (None: all) of the first
    ``max_rollouts`` rollouts of a split; needs no video. The noise is drawn from ``seed``."""
    r = load_split(root, env, split, max_rollouts=max_rollouts)
    generator = torch.Generator().manual_seed(seed)
    pos, logits = truth_proposals(r.positions[:, :max_frames], r.instance, int(r.rigid.shape[0]), noise_std, generator)
    prop = Proposals(pos, logits, r.rollout_ids, {"env": env, "split": split, "visual_checkpoint": "none", "source": "truth", "noise_std": noise_std})
    return write_proposals(proposals_path(root, env, split), prop)


def proposal_frames(cfg: DictConfig) -> int | None:
    """Frames of each video the inference module reads: its windows start at most
    ``window_span`` frames after ``start_frame`` and observe ``observed`` frames, and with
    ``rollout_target=proposals`` roll ``horizon`` frames past them (None: all frames). The
    evaluation proposes its own test frames, so nothing later is needed."""
    spec = cfg.model.inference
    span = spec.get("window_span")
    future = future_proposal_frames(spec)
    return None if span is None else int(cfg.env.get("start_frame", 0) + span + spec.observed + future)


def export_proposals(cfg: DictConfig) -> dict:
    """Proposals of the train split (the inference module's training data) and of the test split
    (its validation data), for the frames the inference module reads (``proposal_frames``).

    ``task.source``: ``visual`` (the VisualPrior's checkpoint over each video) or ``truth`` (the
    recorded particles plus ``task.noise_std`` metres of Gaussian noise; no video or visual prior
    needed). ``task=evaluate`` proposes its test videos itself (``eval.proposals`` chooses how)."""
    task = cfg.get("task") or {}
    source, noise_std = proposal_source(task.get("source", "visual"), task.get("noise_std", 0.0), "task.source", "task.noise_std")
    setup_run(cfg)
    scene = scene_of(cfg)
    frames = proposal_frames(cfg)
    model, ckpt, seen = None, None, {}
    if source == "visual":
        ckpt = stage_checkpoint(cfg, "visual")
        model, trained = load_stage(ckpt, VisualPrior, env=scene.name, n_particles=scene.n_particles)
        seen = {"visual_first_rollout": held_out_videos(trained, cfg.model.inference.get("max_rollouts"))}
        if torch.cuda.is_available():  # the windows are independent: propose them on the GPU where there is one
            model = model.cuda()
    paths = {}
    for i, (split, limit) in enumerate((("train", cfg.model.inference.get("max_rollouts")), ("test", cfg.eval.get("max_rollouts")))):
        if source == "visual":
            path = export_split(model, cfg.data.root, scene.name, split, str(ckpt), limit, cfg.data.progress, frames)
        else:
            path = export_truth_split(cfg.data.root, scene.name, split, noise_std, cfg.seed + i, limit, frames)
        paths[split] = str(path)
        log.info("%s proposals of the %s split (%s frames): %s", source, split, "all" if frames is None else frames, paths[split])
    return {"env": scene.name, "source": source, "noise_std": noise_std, **seen, **paths}


def held_out_videos(trained: DictConfig, module_videos: int | None) -> int:
    """The first training video the visual prior (its training config ``trained``) learned from;
    warns when it learned from any of the inference module's first ``module_videos`` (None: all):
    the proposals of those can be cleaner than the test videos', and a module that reads P from
    them is then offset on the test ones."""
    first = int(trained.model.visual.get("first_rollout", 0))
    if module_videos is None or first < module_videos:
        fix = (f"; model.visual.first_rollout={module_videos} holds them out" if module_videos is not None
               else ": every training video is the module's (model.inference.max_rollouts=null), so none can be held out")
        log.warning("the visual prior trained on training videos from %d on, among them the inference module's (model.inference.max_rollouts=%s): "
                    "their proposals can fit better than the test videos'%s", first, module_videos, fix)
    return first
