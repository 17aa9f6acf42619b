"""Task functions called by run.py: each takes the composed config and returns a summary dict."""

from __future__ import annotations

from typing import Callable

from omegaconf import DictConfig

from vgpl.tasks.demo import demo
from vgpl.tasks.generate import generate

TASKS: dict[str, Callable[[DictConfig], dict]] = {"generate": generate, "demo": demo}


def run_task(cfg: DictConfig) -> dict:
    name = cfg.task.name
    if name not in TASKS:
        raise ValueError(f"unknown task.name '{name}': expected one of {sorted(TASKS)}")
    return TASKS[name](cfg)
