"""task=ground: ground one video from its frames alone (vgpl.grounder.Grounder) and write the
estimates (grounding.json) and a GIF of the video beside the engine's rendering of the refined
particles and the predicted future (grounding.gif) to ``paths.output_dir``."""

from __future__ import annotations

import json
import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from vgpl.data.video_file import read_actions, read_video
from vgpl.eval.preview import write_gif
from vgpl.eval.test_time_fit import TestTimeFit
from vgpl.grounder import Grounder, Grounding
from vgpl.tasks.stage import setup_run

log = logging.getLogger(__name__)


def ground(cfg: DictConfig) -> dict:
    setup_run(cfg)
    spec = cfg.task
    if spec.get("video") in (None, "???"):
        raise ValueError("task=ground needs task.video=<an MP4, a folder of PNG frames, or a dataset shard .h5>")
    grounder = Grounder.from_checkpoints(spec.get("ckpt_dir") or cfg.paths.ckpt_dir, observed=cfg.eval.get("observed"))
    frames, actions = read_video(spec.video, int(spec.get("rollout", 0)))
    if spec.get("actions"):
        actions = read_actions(spec.actions)
    fit = TestTimeFit(**(cfg.eval.get("test_time_fit") or {}))
    grounding = grounder.ground(frames, actions, int(spec.n_future), fit)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    record = {"video": str(spec.video), **({"rollout": int(spec.rollout)} if str(spec.video).endswith(".h5") else {}),
              **({"test_time_fit": asdict(fit)} if fit.steps else {}), **grounding.to_json()}
    (out / "grounding.json").write_text(json.dumps(record, indent=1))
    write_gif(side_by_side(grounder.scene, frames, grounding), out / "grounding.gif", fps=10)
    summary = {"env": grounding.env, "params": grounding.params, "rigidness": record["rigidness"], "output_dir": str(out)}
    log.info("grounded %s: %s", spec.video, summary)
    return summary


def side_by_side(scene, frames: np.ndarray, grounding: Grounding) -> np.ndarray:
    """[T + F, H, 2 W, 3] uint8: left, the video from the observed frames on (black past its end);
    right, the engine's rendering of the refined particles, then of the predicted future."""
    s = grounding.start_frame
    estimate = torch.cat([grounding.positions, grounding.future])
    right = scene.renderer().render(estimate).numpy()
    left = np.zeros_like(right)
    shown = np.asarray(frames)[s : s + len(right)]
    left[: len(shown)] = shown
    return np.concatenate([left, right], axis=2)
