"""Task functions called by run.py: each takes the composed config and returns a summary dict.

Tasks are imported on first use, so starting one task never imports another's dependencies.
"""

from __future__ import annotations

import importlib

from omegaconf import DictConfig

TASKS: dict[str, str] = {
    "generate": "vgpl.tasks.generate:generate",
    "demo": "vgpl.tasks.demo:demo",
    "train_dynamics": "vgpl.tasks.train_dynamics:train_dynamics",
    "evaluate_dynamics": "vgpl.tasks.train_dynamics:evaluate_dynamics",
    "train_visual": "vgpl.tasks.train_visual:train_visual",
    "export_proposals": "vgpl.tasks.train_visual:export_proposals",
    "train_inference": "vgpl.tasks.train_inference:train_inference",
    "train_baseline": "vgpl.tasks.baseline:train_baseline",
    "evaluate": "vgpl.tasks.evaluate:evaluate",
    "report": "vgpl.tasks.evaluate:report",
    "free_fall_gravity": "vgpl.tasks.free_fall:free_fall_gravity",
    "pipeline": "vgpl.tasks.pipeline:pipeline",
}


def run_task(cfg: DictConfig) -> dict:
    name = cfg.task.name
    if name not in TASKS:
        raise ValueError(f"unknown task.name '{name}': expected one of {sorted(TASKS)}")
    module, function = TASKS[name].split(":")
    return getattr(importlib.import_module(module), function)(cfg)
