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
}


def run_task(cfg: DictConfig) -> dict:
    name = cfg.task.name
    if name not in TASKS:
        raise ValueError(f"unknown task.name '{name}': expected one of {sorted(TASKS)}")
    module, function = TASKS[name].split(":")
    return getattr(importlib.import_module(module), function)(cfg)
