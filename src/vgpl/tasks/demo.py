"""task=demo (the default job until the learning pipeline lands): a small dataset of every
environment plus a preview GIF and PNG of each."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from hydra import compose
from omegaconf import DictConfig, OmegaConf, open_dict

from vgpl.data.shard import read_shard
from vgpl.eval.preview import preview_frames, write_gif, write_png
from vgpl.tasks.generate import generate

log = logging.getLogger(__name__)


def demo(cfg: DictConfig) -> dict:
    out = Path(cfg.paths.output_dir) / "preview"
    results, stills = {}, []
    for env in cfg.task.envs:
        env_cfg = compose(config_name="config", overrides=[f"env={env}"]).env
        if cfg.task.get("n_steps"):
            env_cfg.scene.n_steps = cfg.task.n_steps
        n = int(cfg.task.n_rollouts)
        sub = OmegaConf.merge(cfg, {"data": {"n_rollouts": n, "train_fraction": (n - 1) / n if n > 1 else 1.0}})  # the last one is the test split
        with open_dict(sub):
            sub.env = env_cfg  # replaced, not merged: a merge would keep keys of the default env that this one lacks
        summary = generate(sub)
        shard = read_shard(summary["shards"][0])
        frames = preview_frames(shard)
        gif = write_gif(frames, out / f"{env}.gif")
        still = shard.images[0, len(frames) // 2]
        png = write_png(still, out / f"{env}.png")
        stills.append(still)
        log.info("%s: %d shard(s) under %s, preview %s", env, len(summary["shards"]), summary["root"], gif)
        results[env] = {**summary, "preview": str(gif), "frame": str(png)}
    montage = write_png(np.concatenate(stills, axis=1).repeat(2, 0).repeat(2, 1), cfg.task.figure or out / "envs.png")
    log.info("one frame of each environment: %s", montage)
    return {**results, "figure": str(montage)}
